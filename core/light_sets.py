"""Light sets: one bake, one lightmap per set of lights, blended the way the 2024 talk blends them.
No bpy.

A light set is one of Blender's Light Groups (`Object.lightgroup` of lamps and emissive meshes,
`World.lightgroup`); the emitters in no group form the set `scene.DEFAULT_LIGHT_SET`
(`scene.light_set_names`). A bake of a scene that uses
light groups credits every contribution to its emitter's set inside the same paths (the tracer's
`TraceScene.sets`), so K sets cost one bake's rays; the atlas's ordinary files hold the sum of the
sets (the bake without sets, same seed) and each set is written as an ordinary atlas of its own,
`<atlas>.<set>` (`set_atlas_name`), listed in the atlas's sidecar under `light_sets`.

Blending (2024 paper, "Blending HHD", "HHD and linear SH"): blending HHD *parameters* is wrong
(I_z adds, but w_a and d do not); instead each set's HHD is turned into world-space linear SH
(`hhd.to_linear_sh`), the SH are summed with RGB weights ≥ 0, and the sum is solved back to HHD in
closed form (`hhd.from_linear_sh`). `blend` is that, per texel; a shader does the same per pixel
(docs/format.md, the EEVEE live blend node group).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np

from .errors import BakeError
from .hhd import HHDParams, from_linear_sh, to_linear_sh

#: The largest blend weight: 1 is the set as baked; far larger weights only overflow the HHD
#: file's numbers (1e300 made most texels infinite), so they are refused.
MAX_WEIGHT = 1000.0

_NAME = re.compile(r"[^A-Za-z0-9_\-]")


def set_atlas_name(atlas: str, light_set: str) -> str:
    """The file stem of one set's lightmap of `atlas`: `<atlas>.<set>`, the set's name reduced to
    letters, digits, '_' and '-' (Blender already restricts light group names to those)."""
    return f"{atlas}.{_NAME.sub('_', light_set)}"


def weight_array(names: Sequence[str], weights: Mapping[str, object] | None) -> np.ndarray:
    """`(K, 3)` float64 RGB weights of the sets `names` from {set: weight} (a number or an RGB
    triple; sets not given weigh 1). Raises BakeError for an unknown set or a weight that is
    negative, non-finite or above MAX_WEIGHT."""
    weights = dict(weights or {})
    unknown = sorted(set(weights) - set(names))
    if unknown:
        raise BakeError(
            f"unknown light set(s) {', '.join(map(repr, unknown))}: the bake has {', '.join(map(repr, names)) or 'none'}"
        )
    out = np.ones((len(names), 3))
    for k, name in enumerate(names):
        if name in weights:
            try:
                out[k] = np.broadcast_to(np.asarray(weights[name], dtype=np.float64), (3,))
            except (TypeError, ValueError):
                raise BakeError(
                    f"light set '{name}': weight {weights[name]!r} is not a number or R,G,B triple"
                ) from None
    bad = ~(np.isfinite(out) & (out >= 0.0) & (out <= MAX_WEIGHT)).all(axis=1)
    if bad.any():
        name = names[int(np.argmax(bad))]
        raise BakeError(
            f"light set '{name}': weight {_format_weight(out[int(np.argmax(bad))])} is out of range: give 0–{MAX_WEIGHT:g} "
            "(1 = as baked, 0 = off)"
        )
    return out


def _format_weight(rgb) -> str:
    r, g, b = (float(v) for v in rgb)
    return f"{r:g}" if r == g == b else f"{r:g},{g:g},{b:g}"


def blend(params: Sequence[HHDParams], n_v: np.ndarray, weights: np.ndarray) -> HHDParams:
    """The blended HHD `(N,)` of the sets' HHD `params` (K of them, same texels) at RGB
    `weights` `(K, 3)` ≥ 0, as the talk does it at runtime: Σ_k w_k · to_linear_sh(params_k),
    solved back to HHD in closed form (`from_linear_sh`: luminance w_a). n_v `(N, 3)`. A texel
    with a non-finite value in any set (a damaged file) is blended black and `invalid`, as the
    encoder treats such input (I_z 0, w_a 1, d = n_v)."""
    if len(params) != len(weights):
        raise BakeError(f"{len(params)} light sets but {len(weights)} weights")
    if any(p.model != "hhd" for p in params):
        raise BakeError("light sets blend through linear SH only as HHD: encode with model 'hhd', not 'ahd'")
    total = None
    for p, w in zip(params, np.asarray(weights, dtype=np.float64)):
        term = to_linear_sh(p, n_v) * w[None, None, :]
        total = term if total is None else total + term
    if total is None:
        raise BakeError("no light sets to blend")
    bad = ~np.isfinite(total).all(axis=(1, 2))
    total[bad] = 0.0
    out = from_linear_sh(total, n_v)
    if bad.any():
        unit = np.asarray(n_v, dtype=np.float64)[bad]
        out.direction[bad] = unit / np.linalg.norm(unit, axis=1, keepdims=True)
        out.ambient_weight[bad] = 1.0
    out.invalid = bad
    return out


def blend_atlas(files, weights: Mapping[str, object] | None) -> dict:
    """Write the blended state of an atlas's light sets into its ordinary lightmap: the atlas's
    HHD file and preview images become `blend` of its sets' HHD files at `weights` ({set: number
    or RGB}, sets not given weigh 1), texel by texel over the whole image (the sets' files are
    filled alike, so the fill blends too), the sidecar records the weights under `blend`. The
    sets' files and the raw SH are untouched (Re-encode restores the plain sum). files:
    `lightmap_files.AtlasFiles` of the atlas. Returns the sidecar's `blend` record. Raises
    BakeError for an atlas baked without light sets, one encoded in another model than HHD, or bad weights."""
    from .files import exr, lightmap_files

    sidecar = lightmap_files.read_sidecar(files.sidecar)
    entries = sidecar.get("light_sets", [])
    if not entries:
        raise BakeError(
            f"atlas '{files.name}' was baked without light sets: put lights in Blender Light Groups and bake again"
        )
    model = sidecar.get("encoder", {}).get("model", "hhd")
    if model != "hhd":
        raise BakeError(
            f"atlas '{files.name}' is encoded as {model}: light sets blend as HHD (through linear SH); "
            "re-encode the atlas as HHD (Re-encode, or `encode --model hhd`) and blend again"
        )
    names = [entry["name"] for entry in entries]
    w = weight_array(names, weights)
    normal, window = _texel_normals(files)
    h, wid = normal.shape[:2] if window is None else window.atlas
    for f in files.light_sets(sidecar):
        if window is not None and exr.shape_of(f.hhd)[0] != (h, wid):
            raise BakeError(_not_of_atlas(f, files, h, wid))
    layers = [read_hhd(f, window) for f in files.light_sets(sidecar)]
    for f, (p, _) in zip(files.light_sets(sidecar), layers):
        if window is None and len(p.irradz) != h * wid:
            raise BakeError(_not_of_atlas(f, files, h, wid))
    blended = blend([p for p, _ in layers], normal.reshape(-1, 3), w)
    record = {"method": "linear_sh", "weights": {n: w[k].tolist() for k, n in enumerate(names)}}
    sidecar["blend"] = record
    with exr.Staging() as staging:
        write_hhd(staging, files, blended, (h, wid), layers[0][1], sidecar, window)
        staging.commit()
    return record


def _not_of_atlas(f, files, h: int, w: int) -> str:
    return (
        f"{f.hhd} is not of the {w}×{h} atlas of {files.texels.name}: the files come from different bakes; bake again"
    )


def read_hhd(files, window=None) -> tuple[HHDParams, list[str]]:
    """The HHD parameters of every texel `(H·W,)` of an atlas's HHD file (rows bottom-up) and
    the file's Wa channel names (["Wa.V"] or ["Wa.R", "Wa.G", "Wa.B"]). With a `window`
    (`stages.Window`: an almost empty atlas's, `lightmap_files.texel_window`), those of its
    texels `(h·w,)` only, then one more: a texel outside it (every one there holds the same
    fill), the only part of the file read besides the window's ZIP blocks."""
    from . import octahedral
    from .encoding import hhd as spec
    from .files import exr

    if window is None:
        channels, _ = exr.read(files.hhd)
        stored = list(channels)
    else:
        stored = list(exr.shape_of(files.hhd)[1])
    required = spec.IZ.exr_names + spec.DIRECTION.exr_names
    for name in required:
        if name not in stored:
            raise BakeError(f"{files.hhd} is not an HHD lightmap (no channel {name!r}): encode with model 'hhd'")
    wa_names: list[str] = [n for n in spec.WA.exr_names + spec.WA_RGB.exr_names if n in stored]
    names = [*required, *wa_names]
    if window is not None:
        channels = _window_and_one(files.hhd, names, window)
    if not wa_names or len({channels[n].shape for n in names}) != 1:
        raise BakeError(f"{files.hhd} is damaged (its channels are missing or differ in size): bake again")
    iz = np.stack([exr.from_exr_rows(channels[n]) for n in spec.IZ.exr_names], axis=-1).astype(np.float64)
    oct_xy = np.stack([exr.from_exr_rows(channels[n]) for n in spec.DIRECTION.exr_names], axis=-1)
    wa = np.stack([exr.from_exr_rows(channels[n]) for n in wa_names], axis=-1).astype(np.float64)
    n = iz.shape[0] * iz.shape[1]
    params = HHDParams(
        irradz=iz.reshape(n, 3),
        ambient_weight=wa.reshape(n) if wa.shape[-1] == 1 else wa.reshape(n, 3),
        direction=octahedral.decode(oct_xy.reshape(n, 2).astype(np.float64)),
        model="hhd",
    )
    return params, wa_names


def _window_and_one(path, names: list[str], window) -> dict[str, np.ndarray]:
    """Channels `names` of EXR `path` as `(h·w + 1, 1)` images in EXR order: turned by
    `exr.from_exr_rows`, `window`'s texels (rows bottom-up), then one texel outside it."""
    from .files import exr

    h, w = window.atlas
    rows, cols = (h - window.y0 - window.h, h - window.y0), (window.x0, window.x0 + window.w)
    inner = exr.read_window(path, names, rows, cols)
    if window.h < h:  # a row outside the window's
        y = 0 if rows[0] > 0 else h - 1
        one = exr.read_window(path, names, (y, y + 1), (0, 1))
    else:  # a column outside
        x = 0 if cols[0] > 0 else w - 1
        one = exr.read_window(path, names, (0, 1), (x, x + 1))
    # reversed, as `from_exr_rows` turns them back: the window's texels bottom-up, then the outside one
    return {n: np.concatenate([inner[n][::-1].reshape(-1), one[n].reshape(1)])[::-1, None] for n in names}


def _texel_normals(files):
    """n_v `(H, W, 3)` of the atlas's texels file, unit, and None; texels without one (outside
    the charts) take their nearest chart texel's, as the encoded layers were filled, else +z.
    An almost empty atlas's (`lightmap_files.texel_window`): n_v `(h·w + 1, 3)` of its window's
    texels, then of those outside it (all alike: the fill's mean), and the window."""
    from .encoding.stage import background
    from .files import lightmap_files

    data = lightmap_files.read_texel_data(files, crop=True)
    fill = data.fill()
    normal = data.normal.astype(np.float64)
    if data.window is not None:
        outside = background(fill, normal)
        normal = np.concatenate([fill.apply(normal).reshape(-1, 3), outside.reshape(1, 3)])
    else:
        normal = fill.apply(normal)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    return np.where(length > 1e-6, normal / np.maximum(length, 1e-300), [0.0, 0.0, 1.0]), data.window


def write_hhd(
    staging, files, p: HHDParams, shape: tuple[int, int], wa_names: list[str], sidecar: dict, window=None
) -> None:
    """Stage an atlas's HHD file (Iz, Wa as `wa_names`, octahedral Direction; the HHD file's
    storage types), its preview images and `sidecar`. `window`: `p` is of its texels and one
    outside it (`read_hhd`'s), written as the whole atlas's (`stages.PlacedImage`)."""
    from . import octahedral
    from .encoding import hhd as hhd_spec
    from .files import exr, lightmap_files
    from .stages import placed

    h, w = shape if window is None else (window.h, window.w)

    def image(values: np.ndarray):
        if window is None:
            return values.reshape(h, w)
        return placed(values[:-1].reshape(h, w), window, values[-1])

    images = {n: image(p.irradz[:, k]) for k, n in enumerate(hhd_spec.IZ.exr_names)}
    images.update({name: image(p.ambient_weight) for name in wa_names})
    oct_xy = octahedral.encode(p.direction)
    images.update({n: image(oct_xy[:, k]) for k, n in enumerate(hhd_spec.DIRECTION.exr_names)})
    spec = hhd_spec.FILE.for_settings(_Ambient("luminance" if wa_names == hhd_spec.WA.exr_names else "rgb"))
    channels = lightmap_files.exr_channels(spec, images)
    attributes = {"hhdFormat": lightmap_files.FORMAT, "hhdFormatVersion": lightmap_files.FORMAT_VERSION}
    exr.write_file(staging.stage(files.hhd), channels, {**attributes, "hhdAtlas": files.name})
    lightmap_files.stage_preview(staging, files, spec, channels)
    sidecar.setdefault("channels", {})["hhd"] = lightmap_files.channel_table(spec, channels)
    staging.write_json(files.sidecar, sidecar, indent=2, ensure_ascii=False)


class _Ambient:
    """The one encoder setting `Channel.when` asks of the HHD file's layers."""

    def __init__(self, ambient: str):
        self.ambient = ambient
