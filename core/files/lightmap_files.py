"""The files of an atlas: laying out and writing already-encoded channels, and reading them back. No bpy.

Per atlas `<name>` in the output folder (docs/format.md is the contract; `core.encoding`'s spec
says which channels each file holds):
  <name>_hhd.exr     the encoded lightmap (`encoding.hhd`)
  <name>_sh.exr      the raw L2 radiance SH (`encoding.raw.SH_FILE`): re-encode or blend without tracing
  <name>_texels.exr  n_v and coverage (`encoding.raw.TEXELS_FILE`): what re-encoding needs besides the SH
  <name>.json        the sidecar: format version, channel meanings, conventions, settings,
                     per-object texel rectangles, timings, statistics
  <name>.<set>…      with light sets (`core.light_sets`): each set's own files as above (its
                     sidecar says which set it is; it shares the atlas's seams file)
  <name>_seams.npz   the atlas's seam sample pairs (`seams.Seams`): what stitching needs on a
                     re-encode besides the SH (internal to re-encoding, not for engines)
  <name>_preview/    plain RGB EXRs the EEVEE preview samples (one per layer with a preview key;
                     the raw SH file's, sh0 … sh8, only when a preview asks for them:
                     `encoding.preview.sh_previews`)
Writing (`write_atlas`) takes the encode stage's `EncodedAtlas`: it turns rows to EXR order
(top-down), stores each layer as its Channel's dtype says (HALF_OR_FLOAT: half when every value
fits, else float32: never clipped), writes the sidecar and the preview images. It encodes nothing.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..bakepoints import BakePoints
from ..encoding import (
    CONVENTIONS,
    FLOAT,
    HALF,
    HALF_OR_FLOAT,
    HHD_FILE,
    RAW_FILES,
    SH_FILE,
    TEXELS_FILE,
    EncodedAtlas,
    FileSpec,
    TexelData,
)
from ..errors import BakeError
from ..progress import Tick, ticker
from ..stages import Window, fits_half
from . import exr

if TYPE_CHECKING:
    from ..post.seams.geometry import Seams

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "SH_CHANNELS",
    "AtlasFiles",
    "channel_table",
    "exr_channels",
    "object_rects",
    "read_seams",
    "read_sidecar",
    "read_texel_data",
    "texel_window",
    "stage_preview",
    "stage_seams",
    "write_atlas",
]

FORMAT = "hhd-lightmap"
FORMAT_VERSION = 1
SH_CHANNELS = SH_FILE.exr_names


@dataclass
class AtlasFiles:
    """Paths of one atlas's files (they share `folder` and `name`). parent: for one light set's
    files (`core.light_sets`), the name of the atlas whose seams file it shares ("" otherwise)."""

    folder: Path
    name: str
    parent: str = ""

    def path(self, spec: FileSpec) -> Path:
        """The EXR of `spec`: `<folder>/<name><suffix>`."""
        return self.folder / f"{self.name}{spec.suffix}"

    @property
    def hhd(self) -> Path:
        return self.path(HHD_FILE)

    @property
    def sh(self) -> Path:
        return self.path(SH_FILE)

    @property
    def texels(self) -> Path:
        return self.path(TEXELS_FILE)

    @property
    def sidecar(self) -> Path:
        return self.folder / f"{self.name}.json"

    @property
    def seams(self) -> Path:
        """The atlas's seam sample pairs (`seams.Seams.save`), for stitching on a re-encode
        (a light set's atlas shares its parent's)."""
        return self.folder / f"{self.parent or self.name}_seams.npz"

    def light_sets(self, sidecar: dict) -> list[AtlasFiles]:
        """The files of each light set listed in this atlas's `sidecar` (none without sets)."""
        return [AtlasFiles(self.folder, entry["atlas"], self.name) for entry in sidecar.get("light_sets", [])]

    @property
    def preview(self) -> Path:
        """Folder of the RGB images the EEVEE preview samples (Blender cannot sample a pass of a
        multi-channel EXR), one per layer with a preview key (`Channel.preview`: iz, wa, dir,
        sh0 … sh8)."""
        return self.folder / f"{self.name}_preview"

    def preview_image(self, key: str) -> Path:
        return self.preview / f"{key}.exr"


def storage_type(dtype: str, images: list[np.ndarray]) -> type:
    """np.float16 or np.float32 for a layer of spec dtype HALF, FLOAT or HALF_OR_FLOAT (half when
    every finite value of its `images` fits)."""
    if dtype == HALF_OR_FLOAT:
        return np.float16 if all(fits_half(a) for a in images) else np.float32
    return {HALF: np.float16, FLOAT: np.float32}[dtype]


def exr_channels(spec: FileSpec, images: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """One file's EXR channels `(H, W)` in spec order: EXR rows (top-down), stored as each
    Channel's dtype says. Takes the images out of `images` (bottom-up rows); a channel already
    of its stored type stays a view of its image (rows reversed: `exr.write_file` writes views
    a band of rows at a time), others are converted copies."""
    out: dict[str, np.ndarray] = {}
    for ch in spec.channels:
        names = [n for n in ch.exr_names if n in images]
        if names:
            dtype = storage_type(ch.dtype, [images[n] for n in names])
            for name in names:
                out[name] = exr.to_exr_rows(images.pop(name), copy=False).astype(dtype, copy=False)
    return out


def channel_table(spec: FileSpec, channels: dict[str, np.ndarray]) -> dict:
    """The sidecar's table of one file: EXR channel → {type: "half" | "float", meaning}."""
    meanings = {n: ch.meaning for ch in spec.channels for n in ch.exr_names}
    return {
        name: {"type": "half" if a.dtype == np.float16 else "float", "meaning": meanings[name]}
        for name, a in channels.items()
    }


def write_atlas(
    staging: exr.Staging, files: AtlasFiles, encoded: EncodedAtlas, sidecar: dict, tick: Tick | None = None
) -> None:
    """Stage every file of `encoded` (nothing is replaced until `staging.commit()`): its EXRs,
    their preview images and the sidecar. `sidecar` carries the bake's settings/objects/timings
    and the channel tables of files staged before (`stage_files`: a bake's raw files) or not
    written now (after a re-encode, the previous sidecar's); format, files, channel tables,
    conventions, encoder settings and statistics are added here. Consumes `encoded`'s images;
    memory: one file's EXR channels at a time. `tick` (`core.progress`): progress and cancel per
    band of rows written (`stage_files`)."""
    tables = stage_files(staging, files, encoded.files, tick)
    tables.update({k: v for k, v in sidecar.get("channels", {}).items() if k not in tables})
    doc = dict(sidecar)
    doc.update(
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "atlas": files.name,
            "width": encoded.width,
            "height": encoded.height,
            "files": {spec.key: files.path(spec).name for spec in (encoded.encoding_file, *RAW_FILES)},
            "channels": tables,
            "conventions": CONVENTIONS,
            "encoder": dict(encoded.settings),
            "stats": encoded.stats,
        }
    )
    staging.write_json(files.sidecar, doc, indent=2, ensure_ascii=False)


#: Files whose preview images a bake does not write: the raw SH file's nine (sh0 … sh8) would
#: compress the atlas's SH a second time for the L1/L2 preview modes only; those modes write them
#: from the file when they need them (`encoding.preview.sh_previews`).
PREVIEWS_ON_DEMAND = frozenset({SH_FILE.key})


def stage_files(staging: exr.Staging, files: AtlasFiles, images_of: dict, tick: Tick | None = None) -> dict:
    """Stage the EXRs of `images_of` ({sidecar key: (FileSpec, {EXR channel name: `(H, W)`
    image, rows bottom-up})}, as `EncodedAtlas.files`) and their preview images (none for
    PREVIEWS_ON_DEMAND), one file's channels at a time (consumed); returns their channel tables
    for the sidecar. `tick`
    (`core.progress.Tick`): each file's and preview's share of it in proportion to the texels
    it compresses (`write_cost`), reported (and cancellable) per band of rows."""
    attributes = {"hhdFormat": FORMAT, "hhdFormatVersion": FORMAT_VERSION, "hhdAtlas": files.name}
    tables = {}
    tick = ticker(tick)
    parts = tick.split([write_cost(images) * (1 + _preview_share(spec)) for spec, images in images_of.values()])
    for part, (key, (spec, images)) in zip(parts, images_of.items()):
        channels = exr_channels(spec, images)
        path = files.path(spec)
        own, previews = part.split([1.0, _preview_share(spec)])
        exr.write_file(staging.stage(path), channels, attributes, _rows_done(own, f"writing {path.name}"))
        tables[key] = channel_table(spec, channels)
        if spec.key not in PREVIEWS_ON_DEMAND:
            stage_preview(staging, files, spec, channels, previews)
        del channels
    return tables


def write_cost(images) -> int:
    """The texels an EXR of `images` (a dict or list of `(H, W)` images) compresses: per channel
    its image's, or a `stages.PlacedImage`'s window's (`sparse_exr` compresses only that)."""
    values = images.values() if isinstance(images, dict) else images
    total = 0
    for a in values:
        inner = getattr(a, "inner", None)
        total += int(np.prod(np.shape(inner if inner is not None else a)))
    return total


def _preview_share(spec: FileSpec) -> float:
    """A file's preview images' cost beside the file's own (1): their RGB channels over its channels."""
    if spec.key in PREVIEWS_ON_DEMAND:
        return 0.0
    exr_count = sum(len(ch.exr_names) for ch in spec.channels) or 1
    return 3.0 * sum(1 for ch in spec.channels if ch.preview is not None) / exr_count


def _rows_done(tick: Tick, what: str):
    """`exr.write_file`'s `rows_done` reporting to `tick` ("writing <file>: rows 64 of 1024")."""
    if not tick.reports:
        return lambda done, of: tick()
    return lambda done, of: tick.at(done / max(of, 1), f"{what}: rows {done} of {of}")


def _rgb(channels: list[np.ndarray]) -> dict:
    """R, G, B of a preview image, each stored as its file channel is (half or float: the values
    the file holds, and half the bytes to compress for a half layer): one channel repeated, or up
    to three with the missing ones zero. An almost empty atlas's images (`stages.PlacedImage`)
    stay as small."""
    if len(channels) == 1:  # one array for the three (memory)
        return dict.fromkeys("RGB", _stored(channels[0]))
    channels = [_stored(a) for a in channels]
    zero = channels[0].zeros() if hasattr(channels[0], "zeros") else np.zeros_like(channels[0])
    channels += [zero] * (3 - len(channels))
    return dict(zip("RGB", channels))


def _stored(image):
    """`image` as an EXR channel: float16 and float32 as they are, any other float as float32."""
    return image if image.dtype in (np.float16, np.float32) else image.astype(np.float32, copy=False)


def stage_preview(staging: exr.Staging, files: AtlasFiles, spec: FileSpec, channels: dict, tick=None) -> None:
    """Stage the preview images of one file's layers that have a preview key, from its EXR
    channels (EXR rows, as every file here); `tick` (`core.progress.Tick`): progress and cancel."""
    shown = [ch for ch in spec.channels if ch.preview is not None and all(n in channels for n in ch.exr_names)]
    for part, ch in zip(ticker(tick).split([1.0] * len(shown)), shown):
        path = files.preview_image(str(ch.preview))
        images = [channels[n] for n in ch.exr_names]
        rgb = dict(zip("RGB", _unpacked(ch.unpack, images))) if ch.unpack else _rgb(images)
        attributes = PREVIEW_UNPACKED if ch.unpack else None
        exr.write_file(staging.stage(path), rgb, attributes, _rows_done(part, f"preview {path.name}"))


#: Header attribute of a packed layer's preview image (the direction's): it holds the unpacked
#: value (x, y, z), which the preview's bilinear filter may blend; images written before it was
#: added hold the octahedral pair (`files.preview.upgrade_direction`).
PREVIEW_UNPACKED = {"hhdPreviewValue": "unpacked"}
#: Rows unpacked at a time (the memory of a band's float64 temporaries, not the atlas's).
_UNPACK_ROWS = 256


def _unpacked(unpack, images: list) -> list:
    """The components of a packed layer's value, half floats, from its EXR channel images
    (`Channel.unpack`: the direction's unit vector from its octahedral pair), a band of rows at a
    time; an almost empty atlas's (`stages.PlacedImage`) stay as small."""
    from dataclasses import replace

    if hasattr(images[0], "inner"):
        inner = _unpacked(unpack, [a.inner for a in images])
        outside = unpack(np.array([[float(a.background) for a in images]]))[0].astype(np.float16)
        return [replace(images[0], inner=a, background=np.asarray(b)) for a, b in zip(inner, outside)]
    h, w = images[0].shape
    out = None
    for y in range(0, h, _UNPACK_ROWS):
        value = unpack(np.stack([a[y : y + _UNPACK_ROWS].reshape(-1) for a in images], axis=-1))
        if out is None:
            out = np.empty((value.shape[1], h, w), np.float16)
        out[:, y : y + _UNPACK_ROWS] = value.T.reshape(value.shape[1], -1, w)
    return list(out) if out is not None else [np.zeros((h, w), np.float16)] * 3


def stage_seams(staging: exr.Staging, files: AtlasFiles, seams: Seams) -> None:
    """Stage the atlas's seams file (replaced with its other files at `staging.commit()`)."""
    with open(staging.stage(files.seams), "wb") as f:
        seams.save(f)


def read_seams(files: AtlasFiles, shape: tuple[int, int]) -> Seams | None:
    """The seams of a finished bake of an atlas of `shape` (height, width) texels; None when the
    bake has no seams file (it was made before they were written). Raises BakeError for a file
    that cannot be read or is of another atlas size."""
    if not files.seams.is_file():
        return None
    from ..post.seams.geometry import Seams

    try:
        seams = Seams.load(files.seams)
    except (OSError, ValueError, KeyError, EOFError, TypeError) as exc:
        # numpy's own messages ("allow_pickle", zip errors) mean nothing to an artist
        raise BakeError(
            f"the seams file {files.seams} is damaged or not a seams file: bake again, or re-encode with "
            "Stitch Seams off (--no-stitch)"
        ) from exc
    if (seams.height, seams.width) != tuple(shape):
        raise BakeError(
            f"the seams file {files.seams} is of a {seams.width}×{seams.height} atlas, the bake's files of "
            f"{shape[1]}×{shape[0]}: bake again"
        )
    return seams


def read_sidecar(path) -> dict:
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BakeError(f"no bake found: {path} does not exist (bake first)") from None
    except UnicodeDecodeError:
        raise BakeError(f"the bake sidecar {path} is damaged (not UTF-8 text): bake again") from None
    except ValueError as exc:
        raise BakeError(f"the bake sidecar {path} is damaged (invalid JSON: {exc}): bake again") from None
    except OSError as exc:
        raise BakeError(f"cannot read the bake sidecar {path}: {exc.strerror or exc}") from None
    if not isinstance(doc, dict):
        raise BakeError(
            f"the bake sidecar {path} is damaged (valid JSON, but a {type(doc).__name__}, not an object): bake again"
        )
    version = doc.get("format_version", 0)
    if doc.get("format") != FORMAT or not isinstance(version, int) or version > FORMAT_VERSION:
        raise BakeError(f"{path} is not an HHD lightmap sidecar of format version ≤ {FORMAT_VERSION}: bake again")
    if not isinstance(doc.get("light_sets", []), list) or not all(
        isinstance(e, dict) and isinstance(e.get("name"), str) and isinstance(e.get("atlas"), str)
        for e in doc.get("light_sets", [])
    ):
        raise BakeError(f"the bake sidecar {path} is damaged (its light_sets list): bake again")
    return doc


def read_texel_data(files: AtlasFiles, crop: bool = False) -> TexelData:
    """The SH and texel EXRs of a finished bake, as the encoder's input. Raises BakeError for a
    missing or damaged file, or files of different atlas sizes (of different bakes).
    `crop`: an almost empty atlas's are read as the window of its texels (`texel_window`: the
    window its bake's stages worked on, `TexelData.window`), only the ZIP blocks of the files
    that hold it decompressed; the whole atlas where that is all of it."""
    if crop:
        (h, w), _ = _raw_shapes(files)
        window = texel_window(files, (h, w))
        if window is not None:
            return _read_window(files, window)
    sh = read_sh(files.sh)
    h, w = sh.shape[:2]
    tx_ch, _ = exr.read(files.texels)
    normal_layer, coverage_layer, noise_layer = TEXELS_FILE.channels
    missing = [n for layer in (normal_layer, coverage_layer) for n in layer.exr_names if n not in tx_ch]
    if missing:
        raise BakeError(f"{files.texels} lacks the channels {missing}: it is not a texels file; bake again")
    sizes = {a.shape for a in tx_ch.values()}
    if sizes != {(h, w)}:
        (th, tw) = next(iter(sizes)) if len(sizes) == 1 else (0, 0)
        _different_bakes(files, (th, tw), (h, w))
    normal = np.stack([exr.from_exr_rows(tx_ch[n]) for n in normal_layer.exr_names], axis=-1).astype(
        np.float32, copy=False
    )
    coverage = exr.from_exr_rows(tx_ch[coverage_layer.exr_names[0]]).astype(np.float32, copy=False)
    noise_name = noise_layer.exr_names[0]  # absent from bakes made before it was kept
    noise = exr.from_exr_rows(tx_ch[noise_name]).astype(np.float32, copy=False) if noise_name in tx_ch else None
    if noise is not None:  # unknown: NOISE_UNKNOWN in the file (NaN in bakes made before), NaN in memory
        noise[~(noise >= 0.0)] = np.nan
    return TexelData(sh=sh, normal=normal, coverage=coverage, noise=noise)


def _different_bakes(files: AtlasFiles, texels: tuple[int, int], sh: tuple[int, int]):
    (th, tw), (h, w) = texels, sh
    raise BakeError(
        f"{files.texels} is of a {tw}×{th} atlas but {files.sh.name} of {w}×{h}: the files come from "
        "different bakes; bake again"
    )


def _raw_shapes(files: AtlasFiles) -> tuple[tuple[int, int], list[str]]:
    """The atlas (height, width) of a bake's SH and texels files, from their headers, and the
    texels file's channels; BakeError as `read_texel_data` for files that are not those (their
    channels) or of different sizes."""
    shape, sh_types = exr.shape_of(files.sh)
    missing = [n for n in SH_CHANNELS if n not in sh_types]
    if missing:
        raise BakeError(f"{files.sh} lacks SH channels {missing[:3]}…: it is not an SH file; bake again")
    texels_shape, tx_types = exr.shape_of(files.texels)
    normal_layer, coverage_layer, _ = TEXELS_FILE.channels
    missing = [n for layer in (normal_layer, coverage_layer) for n in layer.exr_names if n not in tx_types]
    if missing:
        raise BakeError(f"{files.texels} lacks the channels {missing}: it is not a texels file; bake again")
    if texels_shape != shape:
        _different_bakes(files, texels_shape, shape)
    return shape, list(tx_types)


def texel_window(files: AtlasFiles, shape: tuple[int, int]) -> Window | None:
    """The window of an atlas of `shape` (height, width) that its bake's stages worked on
    (`encoding.stage.window_of` of its texels: those of Coverage ≠ 0 in the texels file, every
    bake point's), found decompressing only the texels file's ZIP blocks that are not its
    background (`sparse_exr.uniform_blocks`; the background's, one block, is checked to hold
    no texel). None for the whole atlas: when at most half its blocks are background (a dense
    atlas: read whole, as before), or the file cannot be scanned so (read whole, which reports
    a damaged file)."""
    from ..encoding.stage import window_of
    from . import sparse_exr

    scan = sparse_exr.uniform_blocks(files.texels)
    if scan is None or scan[0] != tuple(shape) or 2 * scan[1].sum() <= len(scan[1]):
        return None
    (h, w), same = scan
    coverage = TEXELS_FILE.channels[1].exr_names[0]
    rows = sparse_exr.BLOCK_ROWS
    first = int(np.argmax(same)) * rows
    if exr.read_window(files.texels, [coverage], (first, min(first + rows, h)), (0, w))[coverage].any():
        return None
    lo, hi = [h, w], [-1, -1]  # EXR rows and columns of the texels
    edges = np.flatnonzero(np.diff(np.concatenate([[0], (~same).astype(np.int8), [0]])))
    for a, b in zip(edges[::2] * rows, np.minimum(edges[1::2] * rows, h)):  # runs of other blocks
        held = exr.read_window(files.texels, [coverage], (int(a), int(b)), (0, w))[coverage] != 0.0
        ys, xs = np.flatnonzero(held.any(axis=1)), np.flatnonzero(held.any(axis=0))
        if len(ys):
            lo = [min(lo[0], int(a + ys[0])), min(lo[1], int(xs[0]))]
            hi = [max(hi[0], int(a + ys[-1])), max(hi[1], int(xs[-1]))]
    if hi[0] < 0:
        return None
    top, bottom = h - 1 - lo[0], h - 1 - hi[0]  # texel rows (bottom-up) of the first and last EXR rows
    return window_of(np.array([bottom * w + lo[1], top * w + hi[1]]), h, w)


def _read_window(files: AtlasFiles, window: Window) -> TexelData:
    """`read_texel_data` of the rows and columns of `window` only (rows bottom-up, as the
    whole's)."""
    h, _ = window.atlas
    rows, cols = (h - window.y0 - window.h, h - window.y0), (window.x0, window.x0 + window.w)
    sh_ch = exr.read_window(files.sh, list(SH_CHANNELS), rows, cols)
    sh = np.stack([exr.from_exr_rows(sh_ch.pop(n)) for n in SH_CHANNELS], axis=-1).astype(np.float32, copy=False)
    sh = sh.reshape(sh.shape[:2] + (9, 3))
    normal_layer, coverage_layer, noise_layer = TEXELS_FILE.channels
    noise_name = noise_layer.exr_names[0]
    _, tx_types = exr.shape_of(files.texels)
    names = [*normal_layer.exr_names, coverage_layer.exr_names[0]] + ([noise_name] if noise_name in tx_types else [])
    tx_ch = exr.read_window(files.texels, names, rows, cols)
    normal = np.stack([exr.from_exr_rows(tx_ch[n]) for n in normal_layer.exr_names], axis=-1).astype(
        np.float32, copy=False
    )
    coverage = exr.from_exr_rows(tx_ch[coverage_layer.exr_names[0]]).astype(np.float32, copy=False)
    noise = exr.from_exr_rows(tx_ch[noise_name]).astype(np.float32, copy=False) if noise_name in tx_ch else None
    if noise is not None:
        noise[~(noise >= 0.0)] = np.nan
    return TexelData(sh=sh, normal=normal, coverage=coverage, noise=noise, window=window)


#: EXR rows of a raw SH file decompressed at a time by `read_sh` (memory: this many rows of its
#: channels beside the SH image).
SH_READ_ROWS = 256


def read_sh(path: Path) -> np.ndarray:
    """The SH image `(H, W, 9, 3)` float32 (rows bottom-up) of a raw SH file, read SH_READ_ROWS
    scanlines at a time into it (memory: the image once, not its channels and then the image)."""
    (h, w), types = exr.shape_of(path)
    missing = [n for n in SH_CHANNELS if n not in types]
    if missing:
        raise BakeError(f"{path} lacks SH channels {missing[:3]}…: it is not an SH file; bake again")
    sh = np.empty((h, w, len(SH_CHANNELS)), np.float32)
    for a in range(0, h, SH_READ_ROWS):  # EXR rows a … b: texel rows h - b … h - a, reversed
        b = min(a + SH_READ_ROWS, h)
        band = exr.read_window(path, list(SH_CHANNELS), (a, b), (0, w))
        for k, n in enumerate(SH_CHANNELS):
            sh[h - b : h - a, :, k] = band.pop(n)[::-1]
    return sh.reshape((h, w, 9, 3))


def object_rects(points: BakePoints, names: list[str], instances: dict | None = None) -> list[dict]:
    """Per object: its texel rectangle in the atlas (x0, y0 inclusive, x1, y1 exclusive, y from
    the bottom), the same as a UV rectangle, and its number of baked texels; an instance
    (`instances[name]`: {"mesh", "scale", "offset"}, `core.unwrap.instances`) also its "instance"."""
    instances = instances or {}
    x = points.texel % points.width
    y = points.texel // points.width
    out = []
    for index, name in enumerate(names):
        mine = points.object_index == index
        if not mine.any():
            out.append({"name": name, "texels": 0, "rect": None, "uv_rect": None})
            if name in instances:
                out[-1]["instance"] = instances[name]
            continue
        x0, x1, y0, y1 = int(x[mine].min()), int(x[mine].max()) + 1, int(y[mine].min()), int(y[mine].max()) + 1
        out.append(
            {
                "name": name,
                "texels": int(mine.sum()),
                "rect": [x0, y0, x1, y1],
                "uv_rect": [x0 / points.width, y0 / points.height, x1 / points.width, y1 / points.height],
            }
        )
        if name in instances:
            out[-1]["instance"] = instances[name]
    return out
