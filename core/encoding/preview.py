"""What each EEVEE preview mode samples: layers of the channel spec. No bpy.

Each layer is shown through its preview image (`Channel.preview`, an RGB EXR the writer stages
beside the files) and feeds the node-group input of the same name (`Channel.name`):
shaders/node_groups.py names its inputs from here, shaders/preview.py links image to input.
"""

from __future__ import annotations

from .hhd import DIRECTION, IZ, WA
from .raw import SH_LAYERS
from .spec import Channel

MODES: dict[str, tuple[Channel, ...]] = {
    "HHD": (IZ, WA, DIRECTION),
    "AHD": (IZ, WA, DIRECTION),
    "L1": SH_LAYERS[:4],
    "L2": SH_LAYERS,
    "SCALAR": (IZ,),
}


def sampled(mode: str) -> tuple[Channel, ...]:
    """The layers preview mode `mode` ('HHD', 'AHD', 'L1', 'L2', 'SCALAR') samples, in input order."""
    return MODES[mode]


def upgrade_direction(files) -> bool:
    """Rewrite the direction's preview image of the atlas `files` (`lightmap_files.AtlasFiles`)
    from its HHD file when it holds the octahedral pair (written before the preview images held
    the unit vector, `Channel.unpack`), so the node groups of this version read it right. Reads
    the image's header only when it is current. Returns whether it rewrote it."""
    from .. import deps, exr, lightmap_files
    from .hhd import DIRECTION, FILE
    from .spec import FileSpec

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
