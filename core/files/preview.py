"""What each EEVEE preview mode samples: layers of the channel spec. No bpy.

Each layer is shown through its preview image (`Channel.preview`, an RGB EXR the writer stages
beside the files) and feeds the node-group input of the same name (`Channel.name`):
shaders/node_groups.py names its inputs from here, shaders/preview.py links image to input.

The modes a user picks (`properties.HHDSettings.preview_mode`): 'HHD', 'AHD', 'SCALAR' (the
HHD file's layers: an atlas encoded as hhd or ahd), 'L1', 'L2' (the raw SH file's: any atlas) and
'ENCODED': whatever model the atlas's sidecar names, through that model's own layers and
reconstruction (`kind_of`): the kinds 'HL2', 'HBASIS_L1', 'HBASIS_L2', 'SG5' … 'SG12', 'SH_L1',
'SH_L2' (the sh_l1/sh_l2 encodings' own files: stitched, denoised, half floats, unlike the raw SH
file's), or 'HHD'/'AHD' for an HHD file.
"""

from __future__ import annotations

import numpy as np

from ..encoding import hbasis_l1, hbasis_l2, hl2, sg5, sg6, sg9, sg12, sh_l1, sh_l2
from ..encoding.hhd import DIRECTION, IZ, WA
from ..encoding.raw import SH_LAYERS
from ..encoding.spec import Channel

#: The mode that shows the model the atlas was encoded in (`kind_of`).
ENCODED = "ENCODED"
#: The HHD file's models, which the modes 'HHD', 'AHD', 'SCALAR' show.
HHD_MODELS = ("hhd", "ahd")
#: The coefficient encodings' kinds (their model, upper case) and the layers they sample.
CODED: dict[str, tuple[Channel, ...]] = {
    m.FILE.key.upper(): m.FILE.channels for m in (hl2, hbasis_l1, hbasis_l2, sg5, sg6, sg9, sg12, sh_l1, sh_l2)
}
MODES: dict[str, tuple[Channel, ...]] = {
    "HHD": (IZ, WA, DIRECTION),
    "AHD": (IZ, WA, DIRECTION),
    "L1": SH_LAYERS[:4],
    "L2": SH_LAYERS,
    "SCALAR": (IZ,),
    **CODED,
}


def sampled(mode: str) -> tuple[Channel, ...]:
    """The layers preview kind `mode` ('HHD', 'AHD', 'L1', 'L2', 'SCALAR', or a kind of `CODED`
    such as 'SG9') samples, in input order."""
    return MODES[mode]


def kind_of(mode: str, model: str) -> str | None:
    """The kind (a key of MODES) preview mode `mode` shows for an atlas encoded as `model` (its
    sidecar's encoder model, "hhd" … "sg12"), or None when that mode cannot show it: 'HHD',
    'AHD', 'SCALAR' need the HHD file (hhd, ahd); 'L1', 'L2' read the raw SH file (any model);
    'ENCODED' is the model's own kind ('HHD' for hhd, 'AHD' for ahd)."""
    if mode == ENCODED:
        kind = model.upper()
        return kind if kind in MODES and kind not in ("L1", "L2", "SCALAR") else None
    if mode in ("L1", "L2"):
        return mode
    return mode if model in HHD_MODELS else None


def upgrade_direction(files) -> bool:
    """Rewrite the direction's preview image of the atlas `files` (`lightmap_files.AtlasFiles`)
    from its HHD file when it holds the octahedral pair (written before the preview images held
    the unit vector, `Channel.unpack`), so the node groups of this version read it right. Reads
    the image's header only when it is current. Returns whether it rewrote it."""
    from .. import deps
    from ..encoding.hhd import DIRECTION, FILE
    from ..encoding.spec import FileSpec
    from . import exr, lightmap_files

    path = files.preview_image(DIRECTION.preview)
    if not path.is_file() or not files.hhd.is_file():
        return False
    try:
        image = deps.require("OpenEXR").InputFile(str(path))
        try:
            header = image.header()
        finally:
            image.close()
    except Exception:  # a damaged image: rewritten below as well
        header = {}
    text = lambda value: value.decode("utf-8", "replace") if isinstance(value, bytes) else value
    current = all(text(header.get(k)) == v for k, v in lightmap_files.PREVIEW_UNPACKED.items())
    if current:
        return False
    (h, w), _ = exr.shape_of(files.hhd)
    channels = exr.read_window(files.hhd, DIRECTION.exr_names, (0, h), (0, w))
    with exr.Staging() as staging:
        lightmap_files.stage_preview(staging, files, FileSpec(FILE.key, FILE.suffix, (DIRECTION,)), channels)
        staging.commit()
    return True


#: Layers of the raw SH file whose preview images one read of the file writes (memory: their
#: channels as float32 images of the atlas, 3 layers × 3 colours).
SH_PREVIEW_GROUP = 3


def sh_previews(files) -> bool:
    """Write the preview images of the raw SH file's layers (sh0 … sh8, `raw.SH_LAYERS`) of atlas
    `files` (`lightmap_files.AtlasFiles`) that are missing or older than the SH file: a bake does
    not write them (`lightmap_files.PREVIEWS_ON_DEMAND`), the L1 and L2 preview modes need them.
    The images hold the file's values, as the bake's writer would have written them. Returns
    whether it wrote any (False too without an SH file)."""
    from ..encoding.raw import SH_FILE
    from ..encoding.spec import FileSpec
    from . import exr, lightmap_files

    source = files.sh
    if not source.is_file():
        return False
    written = source.stat().st_mtime
    stale = [
        ch
        for ch in SH_LAYERS
        if not (
            files.preview_image(ch.preview).is_file() and files.preview_image(ch.preview).stat().st_mtime >= written
        )
    ]
    if not stale:
        return False
    (h, w), _ = exr.shape_of(source)
    with exr.Staging() as staging:
        for s in range(0, len(stale), SH_PREVIEW_GROUP):
            group = tuple(stale[s : s + SH_PREVIEW_GROUP])
            channels = exr.read_window(source, [n for ch in group for n in ch.exr_names], (0, h), (0, w))
            lightmap_files.stage_preview(staging, files, FileSpec(SH_FILE.key, SH_FILE.suffix, group), channels)
            del channels
        staging.commit()
    return True


def bspline_image(files, key: str):
    """Path of preview image `key` of atlas `files` (`lightmap_files.AtlasFiles`) as cubic
    B-spline coefficients (`textures.bspline_coefficients`, the texels the atlas covers marked
    filled): what the preview's Filter 'B-spline (prefiltered)' samples. Written beside the image,
    `<key>_bspline.exr`, when missing or older than the image (a re-bake or re-encode rewrites
    the image). The coverage is the atlas's texels file's (a light set's: its parent's); without
    one, a texel is filled where any channel is non-zero."""
    from .. import textures
    from ..encoding.raw import TEXELS_FILE
    from ..errors import BakeError
    from . import exr, lightmap_files

    source = files.preview_image(key)
    target = source.with_name(f"{key}_bspline.exr")
    if target.is_file() and target.stat().st_mtime >= source.stat().st_mtime:
        return target
    channels, _ = exr.read(source)
    image = np.stack([exr.from_exr_rows(channels[c]) for c in "RGB" if c in channels], -1)
    texels = lightmap_files.AtlasFiles(files.folder, files.parent or files.name).texels
    coverage_name = TEXELS_FILE.channels[1].exr_names[0]
    try:
        coverage = exr.from_exr_rows(exr.read(texels)[0][coverage_name]) > 0
        filled = coverage if coverage.shape == image.shape[:2] else None
    except (KeyError, BakeError):
        filled = None
    if filled is None:
        filled = (image != 0).any(axis=-1)
    else:
        filled = filled | (image != 0).any(axis=-1)  # the gutter: dilated texels outside the coverage
    coefficients = textures.bspline_coefficients(image, filled)
    exr.write(target, {c: exr.to_exr_rows(coefficients[..., k]) for k, c in enumerate("RGB"[: image.shape[-1]])})
    return target
