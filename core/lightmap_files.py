"""The files a bake writes per lightmap atlas, and reading them back. No bpy.

Per atlas `<name>` in the output folder (docs/format.md is the contract):
  <name>_hhd.exr     the encoded lightmap: Iz.R/G/B (I_z, linear RGB irradiance at n_v, DESIGN.md
                     units), Wa.V (w_a, luminance mode) or Wa.R/G/B (RGB mode), Direction.X/Y (the
                     highlight direction d, world space, octahedral in [-1, 1]²). Half floats when
                     every value fits, float32 otherwise (I_z above 65504): never clipped.
  <name>_sh.exr      the raw L2 radiance SH, 27 float32 channels SH0.R … SH8.B (DESIGN order),
                     world space: re-encode or blend without re-tracing.
  <name>_texels.exr  what the encoder needs besides the SH: Normal.X/Y/Z (n_v, world, float32)
                     and Coverage.V (fraction of the texel covered by triangles; 0 outside
                     charts, -1 for buried texels, whose hemisphere is closed by geometry).
  <name>.json        the sidecar: format version, channel meanings, conventions, settings,
                     per-object texel rectangles, timings, statistics.
Texels outside charts are filled by dilation (`dilate`) in every image, so bilinear filtering and
mip-maps never pull in black; buried texels stay black (I_z = 0).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import dilate as _dilate
from . import exr, hhd, octahedral
from .bakepoints import BakePoints
from .errors import BakeError

FORMAT = "hhd-lightmap"
FORMAT_VERSION = 1
SH_CHANNELS = [f"SH{k}.{c}" for k in range(9) for c in "RGB"]
#: Dilation reach in texels: enough for bilinear filtering down several mip levels; farther
#: empty texels take the atlas mean.
DILATE_RINGS = 16

CONVENTIONS = {
    "world": "Blender world space: right-handed, Z up, metres",
    "uv": "lightmap UV (0,0) is the bottom-left texel corner; EXR scanline 0 is the top row (v = 1); "
          "texel (x, y) counted from the bottom sits in scanline height-1-y",
    "sh_basis": "real L2 SH, order (0,0),(1,-1),(1,0),(1,1),(2,-2),(2,-1),(2,0),(2,1),(2,2); "
                "Y1 ∝ (-y, z, -x), Y2 ∝ (xy, -yz, 3z²-1, -xz, x²-y²); orthonormal over the sphere",
    "sh_quantity": "incident radiance over the hemisphere of n_v (zero below it), linear RGB",
    "irradiance": "I(n) = (1/π) ∫ L(ω) max(n·ω, 0) dω, so diffuse outgoing radiance = albedo × I",
    "hhd": "I(n) = Iz · [ wa·(1 + n·nv)/2 + (1 − wa)·max(n·d, 0)/(d·nv) ]",
    "ahd": "I(n) = Iz · [ wa + (1 − wa)·max(n·d, 0)/(d·nv) ]",
    "self_bounce": "optional: + albedo · Iz · (1 − n·nv)/2",
    "direction": "d in world space, octahedral: encode p = d.xy/(|x|+|y|+|z|); if d.z < 0: "
                 "p = (1 − |p.yx|)·sign(p); d·nv ≥ 0.02 guaranteed",
    "luminance": "Rec.709 (0.2126, 0.7152, 0.0722)",
}


@dataclass
class AtlasFiles:
    """Paths of one atlas's files (they share `folder` and `name`)."""
    folder: Path
    name: str

    @property
    def hhd(self) -> Path:
        return self.folder / f"{self.name}_hhd.exr"

    @property
    def sh(self) -> Path:
        return self.folder / f"{self.name}_sh.exr"

    @property
    def texels(self) -> Path:
        return self.folder / f"{self.name}_texels.exr"

    @property
    def sidecar(self) -> Path:
        return self.folder / f"{self.name}.json"

    @property
    def preview(self) -> Path:
        """Folder of the RGB images the EEVEE preview samples (Blender cannot sample a pass of a
        multi-channel EXR): iz, wa, dir (octahedral X, Y in R, G), sh0 … sh8."""
        return self.folder / f"{self.name}_preview"

    def preview_image(self, key: str) -> Path:
        return self.preview / f"{key}.exr"


@dataclass
class TexelData:
    """An atlas's per-texel inputs to the encoder, as float32 images `(H, W, ...)` (rows
    bottom-up): sh (9, 3) radiance SH, normal (3,) n_v, coverage (0 outside charts, -1 buried).
    float32 as in the files, so encoding a fresh bake and re-encoding its files agree exactly."""
    sh: np.ndarray
    normal: np.ndarray
    coverage: np.ndarray

    @property
    def baked(self) -> np.ndarray:
        """Texels with a bake value of their own (covered, not buried): the dilation sources."""
        return self.coverage > 0.0

    @classmethod
    def from_points(cls, points: BakePoints, sh: np.ndarray) -> "TexelData":
        coverage = np.where(points.buried, -1.0, points.coverage)
        return cls(sh=points.image(sh, dtype=np.float32), normal=points.image(points.normal, dtype=np.float32),
                   coverage=points.image(coverage, dtype=np.float32))

    def fill(self) -> _dilate.Fill:
        """The dilation of this atlas: empty texels from the baked ones, buried texels black."""
        return _dilate.Fill(self.baked, DILATE_RINGS, black=self.coverage < 0.0)


#: Texels encoded per call of hhd.encode: bounds the float64 copy it makes of its input.
ENCODE_CHUNK = 1 << 17


def encode_image(data: TexelData, encoder: dict, fill: _dilate.Fill | None = None) -> tuple[dict, dict]:
    """Encode the baked texels with `hhd.encode(**encoder)`, ENCODE_CHUNK at a time; returns the
    HHD EXR channels (dilated, EXR rows: top-down) and statistics of the baked texels."""
    h, w = data.coverage.shape
    fill = fill or data.fill()
    baked = fill.valid
    sh, normal = data.sh.reshape(h * w, 9, -1), data.normal.reshape(h * w, 3)
    rgb_weight = encoder.get("ambient", "luminance") == "rgb"
    iz = np.zeros((h * w, 3), np.float32)
    wa = np.ones((h * w, 3 if rgb_weight else 1), np.float32)
    direction = np.zeros((h * w, 3), np.float32)
    direction[:, 2] = 1.0
    invalid, iz_max, lum_sum = 0, 0.0, 0.0
    for s in range(0, len(baked), ENCODE_CHUNK):
        rows = baked[s:s + ENCODE_CHUNK]
        params = hhd.encode(sh[rows], normal[rows], **encoder)
        iz[rows], direction[rows] = params.irradz, params.direction
        wa[rows] = params.ambient_weight.reshape(len(rows), -1)
        invalid += params.n_invalid
        iz_max = max(iz_max, float(params.irradz.max(initial=0.0)))
        lum_sum += float((params.irradz @ hhd.LUMINANCE).sum())
    iz = fill.apply(iz.reshape(h, w, 3), keep_black=True)
    wa = fill.apply(wa.reshape(h, w, -1))
    oct_uv = octahedral.encode(fill.apply(direction.reshape(h, w, 3)).reshape(-1, 3)).reshape(h, w, 2)
    iz_type = np.float16 if exr.fits_half(iz) else np.float32
    channels = {f"Iz.{name}": exr.to_exr_rows(iz[..., c]).astype(iz_type) for c, name in enumerate("RGB")}
    channels.update({f"Wa.{name}": exr.to_exr_rows(wa[..., c]).astype(np.float16)
                     for c, name in enumerate("RGB" if rgb_weight else "V")})
    channels["Direction.X"] = exr.to_exr_rows(oct_uv[..., 0]).astype(np.float16)
    channels["Direction.Y"] = exr.to_exr_rows(oct_uv[..., 1]).astype(np.float16)
    stats = {"texels_baked": int(len(baked)), "texels_buried": int(len(fill.black)), "texels_invalid": invalid,
             "irradz_max": iz_max, "irradz_mean_luminance": lum_sum / len(baked) if len(baked) else 0.0}
    return channels, stats


def sh_channels(data: TexelData, fill: _dilate.Fill | None = None) -> dict:
    """The SH EXR's 27 float32 channels (dilated, buried texels black, EXR rows), one at a time."""
    fill = fill or data.fill()
    h, w = data.coverage.shape
    flat = data.sh.reshape(h, w, 27)
    return {name: exr.to_exr_rows(fill.apply(flat[..., k], keep_black=True)).astype(np.float32, copy=False)
            for k, name in enumerate(SH_CHANNELS)}


def texel_channels(data: TexelData) -> dict:
    out = {f"Normal.{a}": exr.to_exr_rows(data.normal[..., k]).astype(np.float32, copy=False)
           for k, a in enumerate("XYZ")}
    out["Coverage.V"] = exr.to_exr_rows(data.coverage).astype(np.float32, copy=False)
    return out


def channel_table(channels: dict, meanings: dict) -> dict:
    return {name: {"type": "half" if a.dtype == np.float16 else "float", "meaning": meanings[name.split(".")[0]]}
            for name, a in channels.items()}


MEANINGS = {
    "Iz": "I_z: irradiance at the vertex normal n_v, linear RGB, DESIGN.md units (albedo × I = radiance)",
    "Wa": "w_a: ambient weight in [0, 1] (luminance mode: one channel V; RGB mode: per channel)",
    "Direction": "highlight direction d, world space, octahedral X/Y in [-1, 1]",
    "SH0": "radiance SH coefficient k (SHk.R/G/B), world space", "Normal": "vertex normal n_v, world space, unit",
    "Coverage": "fraction of the texel covered by triangles; 0 outside charts (dilated), -1 buried",
}
MEANINGS.update({f"SH{k}": MEANINGS["SH0"] for k in range(9)})


def stage_atlas(staging: exr.Staging, files: AtlasFiles, data: TexelData, encoder: dict,
                sidecar: dict, write_sh: bool = True) -> dict:
    """Encode and stage every file of one atlas (nothing is replaced until `staging.commit()`).
    `sidecar` carries the bake's settings/objects/timings; channel tables and encoder settings
    are added here. Returns the statistics of the encoded texels (also in the sidecar).
    Memory: the images of `data` plus one SH file's worth of channels (~110 bytes per texel)."""
    fill = data.fill()
    hhd_ch, stats = encode_image(data, encoder, fill)
    h, w = data.coverage.shape
    attributes = {"hhdFormat": FORMAT, "hhdFormatVersion": FORMAT_VERSION, "hhdAtlas": files.name}
    exr.write_file(staging.stage(files.hhd), hhd_ch, attributes)
    tables = {"hhd": channel_table(hhd_ch, MEANINGS)}
    sh_ch = None
    if write_sh:
        sh_ch, tx_ch = sh_channels(data, fill), texel_channels(data)
        exr.write_file(staging.stage(files.sh), sh_ch, attributes)
        exr.write_file(staging.stage(files.texels), tx_ch, attributes)
        tables.update(sh=channel_table(sh_ch, MEANINGS), texels=channel_table(tx_ch, MEANINGS))
    else:
        tables.update({k: v for k, v in sidecar.get("channels", {}).items() if k != "hhd"})
    doc = dict(sidecar)
    doc.update({
        "format": FORMAT, "format_version": FORMAT_VERSION, "atlas": files.name, "width": w, "height": h,
        "files": {"hhd": files.hhd.name, "sh": files.sh.name, "texels": files.texels.name},
        "channels": tables, "conventions": CONVENTIONS,
        "encoder": {k: v for k, v in encoder.items()},
        "stats": stats,
    })
    staging.write_text(files.sidecar, json.dumps(doc, indent=2, ensure_ascii=False))
    stage_preview(staging, files, hhd_ch, sh_ch)
    return stats


def _rgb(channels: list[np.ndarray]) -> dict:
    """R, G, B channels of a preview image (missing ones zero), float32 so nothing clips."""
    channels = list(channels) + [np.zeros_like(channels[0])] * (3 - len(channels))
    return {c: np.asarray(a, np.float32) for c, a in zip("RGB", channels)}


def stage_preview(staging: exr.Staging, files: AtlasFiles, hhd_ch: dict, sh_ch: dict | None) -> None:
    """Stage the preview's plain RGB EXRs from the channels of the HHD and (if given) SH files
    (EXR rows, as every file here): I_z, w_a (three equal channels in luminance mode), the
    octahedral direction, and the SH."""
    wa = [hhd_ch[f"Wa.{c}"] for c in "RGB"] if "Wa.R" in hhd_ch else [hhd_ch["Wa.V"]] * 3
    images = {"iz": _rgb([hhd_ch[f"Iz.{c}"] for c in "RGB"]), "wa": _rgb(wa),
              "dir": _rgb([hhd_ch["Direction.X"], hhd_ch["Direction.Y"]])}
    for key, channels in images.items():
        exr.write_file(staging.stage(files.preview_image(key)), channels)
    for k in range(9 if sh_ch is not None else 0):
        exr.write_file(staging.stage(files.preview_image(f"sh{k}")), _rgb([sh_ch[f"SH{k}.{c}"] for c in "RGB"]))


def read_sidecar(path) -> dict:
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BakeError(f"no bake found: {path} does not exist (bake first)") from None
    except (OSError, ValueError) as exc:
        raise BakeError(f"cannot read the bake sidecar {path}: {exc}") from exc
    if doc.get("format") != FORMAT or doc.get("format_version", 0) > FORMAT_VERSION:
        raise BakeError(f"{path} is not an HHD lightmap sidecar of format version ≤ {FORMAT_VERSION}")
    return doc


def read_texel_data(files: AtlasFiles) -> TexelData:
    """The SH and texel EXRs of a finished bake, as the encoder's input."""
    sh_ch, _ = exr.read(files.sh)
    tx_ch, _ = exr.read(files.texels)
    missing = [n for n in SH_CHANNELS if n not in sh_ch]
    if missing:
        raise BakeError(f"{files.sh} lacks SH channels {missing[:3]}…")
    sh = np.stack([exr.from_exr_rows(sh_ch[n]) for n in SH_CHANNELS], axis=-1).astype(np.float32, copy=False)
    h, w = sh.shape[:2]
    normal = np.stack([exr.from_exr_rows(tx_ch[f"Normal.{a}"]) for a in "XYZ"], axis=-1).astype(np.float32, copy=False)
    coverage = exr.from_exr_rows(tx_ch["Coverage.V"]).astype(np.float32, copy=False)
    return TexelData(sh=sh.reshape(h, w, 9, 3), normal=normal, coverage=coverage)


def object_rects(points: BakePoints, names: list[str]) -> list[dict]:
    """Per object: its texel rectangle in the atlas (x0, y0 inclusive, x1, y1 exclusive, y from
    the bottom), the same as a UV rectangle, and its number of baked texels."""
    x = points.texel % points.width
    y = points.texel // points.width
    out = []
    for index, name in enumerate(names):
        mine = points.object_index == index
        if not mine.any():
            out.append({"name": name, "texels": 0, "rect": None, "uv_rect": None})
            continue
        x0, x1, y0, y1 = int(x[mine].min()), int(x[mine].max()) + 1, int(y[mine].min()), int(y[mine].max()) + 1
        out.append({"name": name, "texels": int(mine.sum()), "rect": [x0, y0, x1, y1],
                    "uv_rect": [x0 / points.width, y0 / points.height, x1 / points.width, y1 / points.height]})
    return out
