"""Incremental bakes: fingerprints of what a bake's lighting depends on, what is stale since the
last bake, which receivers a change influences, and re-tracing a subset of an atlas's receivers
into its existing files. No bpy.

Fingerprints (`Fingerprints`, the sidecar's "fingerprints"): a 128-bit BLAKE2b digest (`digest`)
per mesh object (evaluated geometry, corner normals, world transform, the material inputs: the
bpy side hashes what the bake reads, `bridge/fingerprints.py`), per light (its settings and
transform), of the world, and per atlas of its layout (atlas size, the receivers and their
lightmap UVs). Per object its world bounds (metres) and per light its position and power, which
the influence rule reads. `compare` gives what changed (`Stale`).

A subset bake (`bake_subset`): bake points of the chosen receivers only (same atlas, same
layout), traced with the bake's settings and seed (a texel's own sequences are keyed by its place
in the atlas, `tracer.hemisphere`: it draws what a full bake draws for it, up to the deeper
bounces, which come per work unit), then the atlas's previous SH and texels
files are read whole, the new texels written into them, and the post stages (denoise, stitch)
and the encoder run as a re-encode does (`bake.reencode`), on the region of the touched texels
and of the charts they lie in or fill from (`merge_region`: tiles grown by WINDOW_HALO; every
other texel emptied: the stages' cost follows the region) or, where that region holds more
than WINDOW_SHARE_MAX of the atlas's chart texels, on the whole atlas; on the written texels
the region gives the whole atlas's encode, fill and stitch bit for bit, and the denoiser's
result up to its pages' composition (`_region_encode`); of every file
(raw SH, texels, the encoded file, their preview images, each light set's) only the touched
texels are replaced (`touched_mask`: the re-traced texels, the texels bilinear reads along their
seams take on both sides, and the texels outside charts filled from those), every other texel
keeps its stored value bit for bit. The seams file stays (same layout). Staged: a failure or a
cancel replaces nothing. No earlier bake, a changed layout, other bake settings or other light
sets: `FullBakeNeeded`, nothing written.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from . import encoding, parallel, post, tracer
from .encoding.stage import WINDOW_MARGIN
from .errors import BakeCancelled, FullBakeNeeded
from .files import exr, lightmap_files
from .post.denoise.layout import label_charts

#: Version of the sidecar's "fingerprints" record: a record of another version is "unknown" (full bake).
FINGERPRINT_VERSION = 1
#: The influence rule's margin around a changed object: receivers whose world bounds come within
#: this many times the changed object's bounding-box diagonal of its old or new bounds are
#: influenced (its shadow and its first bounce; measured by bench/incremental.py).
OBJECT_REACH = 1.0
#: A changed point, spot or area light influences receivers where its unoccluded irradiance
#: P / (4π d²) is at least this fraction of the mean irradiance all point-like lights give at
#: the scene's diagonal (their total power / (4π D²)).
LIGHT_REACH = 0.01
#: A subset bake's merge runs its post stages and encoder on the region of the touched texels
#: (`merge_region`) unless it holds more than this share of the atlas's chart texels: then on the
#: whole atlas (measured: bench/results/incremental_merge.md).
WINDOW_SHARE_MAX = 0.6


def digest(*parts) -> str:
    """128-bit BLAKE2b hex digest of `parts`: arrays by dtype, shape and bytes (no copy of a
    contiguous array), anything else by its repr."""
    h = hashlib.blake2b(digest_size=16)
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(memoryview(a).cast("B"))
        else:
            h.update(repr(part).encode())
        h.update(b"\x00")
    return h.hexdigest()


@dataclass
class Fingerprints:
    """What a bake's lighting depends on. objects: per mesh object visible to render, {"hash",
    "bounds": [[x0, y0, z0], [x1, y1, z1]] world metres, "uv": the receiver's lightmap-UV digest
    (receivers only)}; lights: per light {"hash", "position": (3,) metres or None (a sun),
    "power": W (a sun's: its strength, W/m²)}, "emits": bool (an emissive material); world: digest of the world ("" none); layout: per
    atlas the digest of its size, receivers and their lightmap UVs (`layout_digest`)."""

    objects: dict[str, dict] = field(default_factory=dict)
    lights: dict[str, dict] = field(default_factory=dict)
    world: str = ""
    layout: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"version": FINGERPRINT_VERSION, "time": _now(), **asdict(self)}

    @classmethod
    def from_json(cls, doc) -> Fingerprints | None:
        """The record of a sidecar, None when it has none (a bake before fingerprints) or one of
        another version."""
        if not isinstance(doc, dict) or doc.get("version") != FINGERPRINT_VERSION:
            return None
        return cls(dict(doc["objects"]), dict(doc["lights"]), str(doc["world"]), dict(doc["layout"]))


def layout_digest(width: int, height: int, uv: dict[str, str]) -> str:
    """The layout of an atlas: its size and its receivers' lightmap-UV digests {name: digest}."""
    return digest(int(width), int(height), sorted(uv.items()))


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


@dataclass
class Stale:
    """What changed between two Fingerprints: objects (changed, added or removed mesh objects),
    lights (likewise), world, layouts (atlases whose layout changed or that are new)."""

    objects: list[str] = field(default_factory=list)
    lights: list[str] = field(default_factory=list)
    world: bool = False
    layouts: list[str] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.objects or self.lights or self.world or self.layouts)

    def lines(self) -> list[str]:
        """One line per kind of change, for the panel and the console."""
        out = []
        if self.layouts:
            out.append(f"layout changed (full bake needed): {', '.join(self.layouts)}")
        if self.objects:
            out.append(f"objects: {', '.join(self.objects)}")
        if self.lights:
            out.append(f"lights: {', '.join(self.lights)}")
        if self.world:
            out.append("world")
        return out or ["nothing changed since the last bake"]


def compare(old: Fingerprints, new: Fingerprints) -> Stale:
    """What changed from `old` (the last bake's) to `new` (the scene's now): sorted names."""

    def changed(a: dict, b: dict) -> list[str]:
        return sorted(k for k in set(a) | set(b) if (a.get(k) or {}).get("hash") != (b.get(k) or {}).get("hash"))

    layouts = sorted(k for k in new.layout if old.layout.get(k) != new.layout[k])
    return Stale(changed(old.objects, new.objects), changed(old.lights, new.lights), old.world != new.world, layouts)


def changed_receivers(stale: Stale, receivers: list[str]) -> list[str]:
    """The receivers whose own fingerprint changed (geometry, transform, material)."""
    mine = set(stale.objects)
    return [r for r in receivers if r in mine]


def _bounds(entry: dict | None) -> np.ndarray | None:
    if not entry or entry.get("bounds") is None:
        return None
    return np.asarray(entry["bounds"], dtype=np.float64)


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance (m) between two axis-aligned boxes (2, 3); 0 where they overlap."""
    d = np.maximum(0.0, np.maximum(a[0] - b[1], b[0] - a[1]))
    return float(np.linalg.norm(d))


def influenced(stale: Stale, old: Fingerprints, new: Fingerprints, receivers: list[str]) -> list[str]:
    """The receivers to re-trace so that every change of `stale` is baked (the "changed +
    influenced" rule; conservative, measured by bench/incremental.py):
      * every receiver that changed itself;
      * a changed world, or a changed sun, or a light without a position, or a changed object whose
        materials emit (before or after the change): every receiver;
      * a changed (added, removed, moved, edited) object: receivers whose world bounds come within
        OBJECT_REACH × its bounding-box diagonal of its old or its new bounds (its shadow, its
        bounce light and the light it no longer blocks);
      * a changed point, spot or area light: receivers within its reach, the distance at which
        its irradiance P / (4π d²) falls to LIGHT_REACH of the mean that all point-like lights
        give at the scene's diagonal D (their total power / (4π D²)), from its old and its new
        position, taking the larger power.
    Second and later bounces beyond those distances are left stale: the rule's error."""
    if stale.world or any(_is_global(old.lights.get(n)) or _is_global(new.lights.get(n)) for n in stale.lights):
        return list(receivers)
    if any((old.objects.get(n) or {}).get("emits") or (new.objects.get(n) or {}).get("emits") for n in stale.objects):
        return list(receivers)  # an emitter changed: its light may reach anywhere
    boxes = {r: _bounds(new.objects.get(r)) for r in receivers}
    out = set(changed_receivers(stale, receivers))
    for name in stale.objects:
        for box in (_bounds(old.objects.get(name)), _bounds(new.objects.get(name))):
            if box is None:
                continue
            reach = OBJECT_REACH * float(np.linalg.norm(box[1] - box[0]))
            out |= {r for r, b in boxes.items() if b is None or _gap(b, box) <= reach}
    if stale.lights:
        scene = [b for b in boxes.values() if b is not None]
        diagonal = (
            float(np.linalg.norm(np.max([b[1] for b in scene], 0) - np.min([b[0] for b in scene], 0))) if scene else 0.0
        )
        total = sum(float(e["power"]) for fp in (new,) for e in fp.lights.values() if e.get("position") is not None)
        for name in stale.lights:
            entries = [e for e in (old.lights.get(name), new.lights.get(name)) if e]
            power = max(float(e["power"]) for e in entries)
            reach = diagonal * np.sqrt(power / max(LIGHT_REACH * total, 1e-30)) if total > 0 else np.inf
            for e in entries:
                p = np.asarray(e["position"], np.float64)
                point = np.stack([p, p])
                out |= {r for r, b in boxes.items() if b is None or _gap(b, point) <= reach}
    return [r for r in receivers if r in out]


def _is_global(entry: dict | None) -> bool:
    return entry is not None and entry.get("position") is None


# ---------------------------------------------------------------------------------------------
# the last bake's record


def folder_state(out_dir, atlases: list[str]) -> tuple[Fingerprints | None, dict[str, dict]]:
    """The fingerprints of the last bake into `out_dir` of the atlases named (None when any has
    no sidecar or no record: no earlier bake to compare with), and each atlas's sidecar. A
    receiver's entry comes from its own atlas's sidecar, everything else from the newest record."""
    sidecars: dict[str, dict] = {}
    records = []
    for name in atlases:
        path = lightmap_files.AtlasFiles(Path(out_dir), name).sidecar
        if not path.is_file():
            return None, sidecars
        doc = lightmap_files.read_sidecar(path)
        sidecars[name] = doc
        record = doc.get("fingerprints")
        found = Fingerprints.from_json(record)
        if found is None:
            return None, sidecars
        records.append((str((record or {}).get("time", "")), name, found))
    if not records:
        return None, sidecars
    records.sort(key=lambda r: r[0])
    _, _, newest = records[-1]
    state = Fingerprints(dict(newest.objects), dict(newest.lights), newest.world, {})
    for _, name, found in records:
        state.layout[name] = found.layout.get(name, "")
        for receiver in _receivers_of(sidecars[name]):
            if receiver in found.objects:
                state.objects[receiver] = found.objects[receiver]
    return state, sidecars


def _receivers_of(sidecar: dict) -> list[str]:
    return [o["name"] for o in sidecar.get("objects", [])]


def consumed(old: Fingerprints, new: Fingerprints, names: list[str], everything: bool) -> Fingerprints:
    """The record a subset bake writes: `new` where `everything` (changed + influenced: every
    change is baked), else `old` with the objects `names` (re-traced) taken from `new`; the
    layout is `new`'s (checked equal)."""
    if everything:
        return new
    objects = dict(old.objects)
    for n in names:
        if n in new.objects:
            objects[n] = new.objects[n]
    return Fingerprints(objects, dict(old.lights), old.world, dict(new.layout))


# ---------------------------------------------------------------------------------------------
# the subset bake


@dataclass
class SubsetResult:
    """One atlas re-traced in part: its name, the objects re-traced, texels re-traced, texels
    written (re-traced + seam partners + their fill), all texels of the atlas's bake, seconds per
    stage."""

    name: str
    objects: list[str]
    texels: int
    written: int
    atlas_texels: int
    seconds: dict
    warnings: list[str] = field(default_factory=list)


def check_settings(sidecar: dict, settings, name: str) -> None:
    """FullBakeNeeded when the bake settings the texels depend on differ from the last bake's."""
    was = sidecar.get("bake", {})
    now = asdict(settings.trace)
    for key in ("samples", "pass_samples", "bounces", "noise_target", "light_sets"):
        if key in was and was[key] != now[key]:
            raise FullBakeNeeded(
                f"atlas '{name}' was baked with {key} = {was[key]}, the settings now give {now[key]}: "
                "bake all (a part baked otherwise would not match the rest)"
            )
    encoder = dict(encoding.for_settings(settings.encoder).settings)
    for key, value in sidecar.get("encoder", {}).items():
        if key in encoder and encoder[key] != value:
            raise FullBakeNeeded(
                f"atlas '{name}' was encoded with {key} = {value!r}, the settings now give {encoder[key]!r}: "
                "bake all, or re-encode first"
            )
    records = sidecar.get("post", {})
    for key, on in (("denoise", settings.denoise), ("stitch", settings.stitch_seams)):
        if key in records and bool(records[key].get("enabled")) != bool(on):
            raise FullBakeNeeded(
                f"atlas '{name}' was baked with {key} {'on' if records[key].get('enabled') else 'off'}, "
                f"it is {'on' if on else 'off'} now: bake all, or re-encode first"
            )


def _subset_surface(surface, rows: np.ndarray):
    """The SurfaceTriangles of `surface`'s triangles `rows` (object indices kept)."""
    out = replace(
        surface,
        positions=surface.positions[rows],
        normals=surface.normals[rows],
        uv=surface.uv[rows],
        object_index=surface.object_index[rows],
        albedo=surface.albedo[rows],
    )
    for key in ("texture_index", "texture_uv", "polygon"):
        value = getattr(surface, key)
        if value is not None:
            setattr(out, key, value[rows])
    return out


def touched_mask(
    texels: np.ndarray, shape: tuple[int, int], atlas_seams, baked: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """The texels a subset bake writes back and the seam samples it stitches: (`(H, W)` bool,
    rows bottom-up; `(S,)` bool or None without seams). `texels`: flat indices (y·W + x)
    re-traced; `atlas_seams` (`seams.Seams` or None): a seam sample whose bilinear footprint (the
    2×2 texels around each side's position) holds a marked texel marks both sides' footprints
    (stitching moves both), repeated until no sample is added (a chain of seams sharing texels is
    stitched together); `baked` `(H, W)` bool, the dilation sources: the texels outside them whose
    nearest source (`dilate.nearest_source`) is marked are marked too (their fill changes)."""
    from . import dilate
    from .encoding.stage import DILATE_RINGS

    h, w = shape
    mask = np.zeros(h * w, bool)
    mask[texels] = True
    hit = None
    if atlas_seams is not None and len(atlas_seams):
        feet = [_footprint(atlas_seams.a, h, w), _footprint(atlas_seams.b, h, w)]
        hit = np.zeros(len(atlas_seams), bool)
        while True:
            now = mask[feet[0]].any(axis=1) | mask[feet[1]].any(axis=1)
            if (now == hit).all():
                break
            hit = now
            for foot in feet:
                mask[foot[hit].reshape(-1)] = True
    source = dilate.nearest_source(baked, DILATE_RINGS).reshape(-1)
    outside = np.flatnonzero(~baked.reshape(-1))
    reached = source[outside] >= 0
    mask[outside[reached]] |= mask[source[outside[reached]]]
    return mask.reshape(h, w), hit


def _footprint(pos: np.ndarray, h: int, w: int) -> np.ndarray:
    """(S, 4) flat indices of the 2×2 texels a bilinear read at texel-space `pos` (S, 2) takes
    (texel (i, j) centred at (i + ½, j + ½)), clamped to the atlas."""
    x0 = np.floor(pos[:, 0] - 0.5).astype(np.int64)
    y0 = np.floor(pos[:, 1] - 0.5).astype(np.int64)
    xs = np.clip(np.stack([x0, x0 + 1, x0, x0 + 1], 1), 0, w - 1)
    ys = np.clip(np.stack([y0, y0, y0 + 1, y0 + 1], 1), 0, h - 1)
    return ys * w + xs


def bake_subset(
    atlases: list,
    only: dict[str, list[str]],
    scene,
    settings,
    out_dir,
    record: Callable[[str, list[str]], dict] | None = None,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> list[SubsetResult]:
    """Re-trace the receivers `only[atlas name]` of each atlas of `atlases` (`bake.AtlasInput`,
    every object of the atlas: the layout) and write their texels into the atlas's files in
    `out_dir` (module doc). `record(atlas, objects)` gives the sidecar keys to set (the
    fingerprints and the objects' bake times). Raises FullBakeNeeded (nothing written) when an
    atlas has no earlier bake, its files are of another size or other receivers, a re-traced
    texel lies outside the earlier bake's charts (the layout changed), or the settings differ."""
    from . import bake as core_bake

    threads = parallel.resolve_threads(settings.trace.threads)
    settings = replace(settings, trace=replace(settings.trace, threads=threads))
    exr.set_threads(threads)
    chosen = [(a, only[a.name]) for a in atlases if only.get(a.name)]
    if not chosen:
        raise FullBakeNeeded("nothing to bake: none of the named objects is a receiver of a baked atlas")
    out_dir = Path(out_dir)
    previous = [_previous(a, names, settings, out_dir) for a, names in chosen]  # refuse before any work
    atlases_in, found, scene = core_bake.check_inward([a for a, _ in chosen], scene, settings.inward_faces)
    ray_scene = core_bake.ray_scene_of(scene)
    results = []
    report = progress or (lambda f, m: None)
    with exr.Staging() as staging:
        for k, ((_, names), atlas, sidecar) in enumerate(zip(chosen, atlases_in, previous)):
            base, share = k / len(chosen), 1.0 / len(chosen)
            results.append(
                _bake_atlas(
                    staging,
                    atlas,
                    names,
                    sidecar,
                    scene,
                    ray_scene,
                    settings,
                    out_dir,
                    record,
                    lambda f, m, base=base, share=share: report(base + share * f, m),
                    cancel,
                )
            )
        if cancel is not None and cancel():
            raise BakeCancelled("bake cancelled")
        staging.commit()
    report(1.0, "written")
    return results


def _previous(atlas, names: list[str], settings, out_dir: Path) -> dict:
    """The atlas's last sidecar, after checking a subset bake can go into its files."""
    files = lightmap_files.AtlasFiles(out_dir, atlas.name)
    if not files.sidecar.is_file() or not files.sh.is_file() or not files.texels.is_file():
        raise FullBakeNeeded(f"atlas '{atlas.name}' has no earlier bake in {out_dir}: bake all first")
    sidecar = lightmap_files.read_sidecar(files.sidecar)
    if (sidecar.get("width"), sidecar.get("height")) != (atlas.width, atlas.height):
        raise FullBakeNeeded(
            f"atlas '{atlas.name}' was baked at {sidecar.get('width')}×{sidecar.get('height')}, it is "
            f"{atlas.width}×{atlas.height} now (unwrapped again): bake all"
        )
    before = set(_receivers_of(sidecar))
    if before != set(atlas.objects):
        added, gone = sorted(set(atlas.objects) - before), sorted(before - set(atlas.objects))
        raise FullBakeNeeded(
            f"atlas '{atlas.name}' holds other receivers than at its last bake (new: {', '.join(added) or 'none'}; "
            f"gone: {', '.join(gone) or 'none'}): bake all"
        )
    missing = [n for n in names if n not in atlas.objects]
    if missing:
        raise FullBakeNeeded(f"{', '.join(missing)}: not in atlas '{atlas.name}'")
    check_settings(sidecar, settings, atlas.name)
    return sidecar


def _bake_atlas(staging, atlas, names, sidecar, scene, ray_scene, settings, out_dir, record, report, cancel):
    """Re-trace `names` of one atlas and stage its merged files (`bake_subset`)."""
    from . import bake as core_bake
    from . import light_sets as _ls

    t0 = time.perf_counter()
    files = lightmap_files.AtlasFiles(out_dir, atlas.name)
    indices = [atlas.objects.index(n) for n in names]
    rows = np.flatnonzero(np.isin(atlas.surface.object_index, indices))
    part = replace(atlas, surface=_subset_surface(atlas.surface, rows))
    report(0.0, f"bake points of {', '.join(names)}")
    points = core_bake.points_of(part, ray_scene, settings.trace.threads, cancel)
    t_points = time.perf_counter() - t0
    old = lightmap_files.read_texel_data(files)
    h, w = old.coverage.shape
    if not (old.coverage.reshape(-1)[points.texel] != 0.0).all():
        raise FullBakeNeeded(
            f"atlas '{atlas.name}': {', '.join(names)} cover texels outside the last bake's charts "
            "(the layout changed: unwrapped again?): bake all"
        )
    set_names = [e["name"] for e in sidecar.get("light_sets", [])]
    t = time.perf_counter()
    traced = tracer.bake(
        points,
        scene,
        settings.trace,
        progress=lambda f, m: report(0.8 * f, m),
        cancel=cancel,
        ray_scene=ray_scene,
        compact=True,
    )
    if list(traced.sets) != set_names:
        raise FullBakeNeeded(
            f"atlas '{atlas.name}' was baked with light sets {set_names or 'none'}, the scene now has "
            f"{list(traced.sets) or 'none'}: bake all"
        )
    t_trace = time.perf_counter() - t
    t = time.perf_counter()
    report(0.8, "merging into the atlas's files")
    atlas_seams = lightmap_files.read_seams(files, (h, w))
    fresh = encoding.TexelData.from_points(points, traced.sh, noise=traced.noise())
    merged = _merge(old, fresh, points.texel)
    mask, hit = touched_mask(points.texel, (h, w), atlas_seams, merged.baked)
    if atlas_seams is not None and hit is not None:
        atlas_seams = atlas_seams.select(hit)  # stitch the seams of the touched charts only
    when = _now()
    keys = record(atlas.name, names) if record else {}
    baked = {**sidecar.get("baked", {}), **{n: when for n in names}}
    total = int((merged.coverage != 0.0).sum())  # before the merge empties texels outside its region
    update = {
        **keys,
        "baked": baked,
        "incremental": {
            "time": when,
            "objects": list(names),
            "texels_traced": int(len(points.texel)),
            "texels_written": int(mask.sum()),
            "rays": int(traced.rays),
        },
    }
    warnings = _merge_files(staging, files, merged, sidecar, settings, atlas_seams, mask, update, cancel)
    for k, set_name in enumerate(set_names):
        set_files = lightmap_files.AtlasFiles(out_dir, _ls.set_atlas_name(atlas.name, set_name), atlas.name)
        set_sidecar = lightmap_files.read_sidecar(set_files.sidecar)
        set_fresh = encoding.TexelData.from_points(points, traced.light_set(k).sh, noise=traced.light_set(k).noise())
        set_merged = _merge(lightmap_files.read_texel_data(set_files), set_fresh, points.texel)
        warnings += _merge_files(
            staging, set_files, set_merged, set_sidecar, settings, atlas_seams, mask, update, cancel
        )
    seconds = {"bake_points": t_points, "trace": t_trace, "merge": time.perf_counter() - t}
    return SubsetResult(atlas.name, list(names), int(len(points.texel)), int(mask.sum()), total, seconds, warnings)


def _merge(old, fresh, texels: np.ndarray):
    """`old` (a bake's TexelData, whole atlas) with the texels `texels` (flat) of `fresh` (the
    subset's, whole atlas) written into it: SH, n_v, coverage and noise."""
    h, w = old.coverage.shape

    def put(a, b):
        flat_a, flat_b = a.reshape((h * w,) + a.shape[2:]), b.reshape((h * w,) + b.shape[2:])
        flat_a[texels] = flat_b[texels]

    put(old.sh, fresh.sh)
    put(old.normal, fresh.normal)
    put(old.coverage, fresh.coverage)
    if old.noise is not None and fresh.noise is not None:
        put(old.noise, fresh.noise)
    return old


def _merge_files(staging, files, data, sidecar, settings, atlas_seams, mask, update, cancel) -> list[str]:
    """Raw files → post stages → encode of the merged `data` (whole atlas), each file staged with
    only the `mask` texels taken from it (`_stage_merged`). The raw files are of the whole atlas;
    the post stages and the encoder run on the region of the `mask` texels (`_region_encode`),
    or on the whole atlas (as a re-encode) where the region would hold more than
    WINDOW_SHARE_MAX of its chart texels or cannot give the same fill. The sidecar's
    `incremental.merge` says which ran, and why."""

    def check():
        if cancel is not None and cancel():
            raise BakeCancelled("bake cancelled")

    fill = data.fill()
    tables = {}
    with encoding.raw_files(data, fill) as images_of:
        for key, (spec, images) in images_of.items():
            tables[key] = _stage_merged(staging, files, spec, images, mask)
            check()
    doc = dict(sidecar)
    region = _region_encode(data, fill, settings, atlas_seams, mask, check)
    if isinstance(region, str):
        data, records = post.apply(data, settings, seams=atlas_seams)
        encoded = encoding.encode_atlas(data, encoding.for_settings(settings.encoder), raw=False)
        encoded = post.stitch_encoded(encoded, data.coverage, settings, atlas_seams, records)
        doc["stats"] = encoded.stats
        merge: dict = {"over": "atlas", "why": region}
    else:
        encoded, records, merge = region
    check()
    for key, (encoded_spec, layers) in encoded.files.items():
        tables[key] = _stage_merged(staging, files, encoded_spec, layers, mask)
    doc.update(update)
    doc["incremental"] = {**doc.get("incremental", {}), "merge": merge}
    doc["channels"] = {**doc.get("channels", {}), **tables}
    doc["post"] = records
    staging.write_json(files.sidecar, doc, indent=2, ensure_ascii=False)
    return post.warnings(records)


# ---------------------------------------------------------------------------------------------
# the merge's post stages and encoder on the region of the touched texels

#: Texels around the touched texels and their charts that a region merge's stages see
#: (`merge_region`): an almost empty atlas's window margin (`encoding.stage.WINDOW_MARGIN`:
#: beyond the dilation's reach from a stitched gutter texel and the denoiser's page margin). The
#: denoiser needs no more: it filters each chart with its own texels only, and the region holds
#: every touched chart whole (`_region_encode`).
WINDOW_HALO = WINDOW_MARGIN
#: Side in texels of the tiles whose touched texels' bounding boxes, grown by WINDOW_HALO, make
#: the region.
WINDOW_TILE = 64


def merge_region(held: np.ndarray, halo: int = WINDOW_HALO, tile: int = WINDOW_TILE) -> np.ndarray:
    """The region `(H, W)` bool of an atlas the merge's stages run on: per `tile` × `tile` tile
    holding texels of `held` `(H, W)` bool (the touched texels and their charts), the bounding
    box of those grown by `halo` texels (clipped to the atlas). Every `held` texel lies in it
    with at least `halo` texels of it around (or the atlas's edge)."""
    h, w = held.shape
    ty, tx = -(-h // tile), -(-w // tile)
    padded = np.zeros((ty * tile, tx * tile), bool)
    padded[:h, :w] = held
    tiles = padded.reshape(ty, tile, tx, tile)
    rows_any, cols_any = tiles.any(axis=3), tiles.any(axis=1)  # (ty, tile, tx), (ty, tx, tile)
    region = np.zeros((h, w), bool)
    for i, j in zip(*np.nonzero(rows_any.any(axis=1))):
        r, c = np.flatnonzero(rows_any[i, :, j]), np.flatnonzero(cols_any[i, j])
        y0, x0 = max(i * tile + r[0] - halo, 0), max(j * tile + c[0] - halo, 0)
        region[y0 : i * tile + r[-1] + 1 + halo, x0 : j * tile + c[-1] + 1 + halo] = True
    return region


def _region_encode(data, fill, settings, atlas_seams, mask, check):
    """The post stages and encoder of `_merge_files` on `data` (the merged atlas; spent: its
    texels outside the region are emptied in place) with every texel outside `merge_region`
    empty (no chart, no value): their cost follows the region's charts and texels, not the
    atlas's, and on the `mask` texels they give the whole atlas's values: the encoder, the fill
    (checked: every `mask` texel fills from the same texel) and the stitch (the same seams and
    unknowns) exactly; the denoiser filters each touched chart whole and alone, its pages
    (shared with other charts, each page's exposure and energy scale) hold fewer charts than
    the whole atlas's: bench/results/incremental_merge.md measures the difference. Returns (the
    EncodedAtlas, the post records, the sidecar's `incremental.merge`), or why the whole atlas
    must run instead (then `data` is untouched). The sidecar's stats stay the last full
    encode's (the region's are in `incremental.merge`)."""
    labels, n = label_charts(data.coverage != 0.0)  # the denoiser's charts
    reads = _fill_reads(fill)[mask.reshape(-1)]
    seeds = mask.copy()  # the touched texels and the texels they fill from (a buried texel's: far in its chart)
    seeds.reshape(-1)[reads[reads >= 0]] = True
    touched = np.zeros(n + 1, bool)
    touched[labels[seeds] + 1] = True
    touched[0] = False  # texels outside charts
    region = merge_region(seeds | touched[labels + 1], WINDOW_HALO, WINDOW_TILE)
    del labels
    covered = data.coverage != 0.0
    share = np.count_nonzero(covered & region) / float(max(int(np.count_nonzero(covered)), 1))
    if share > WINDOW_SHARE_MAX:
        return f"the region holds {100 * share:.0f}% of the atlas's chart texels (over {100 * WINDOW_SHARE_MAX:.0f}%)"
    outside = ~region
    coverage = data.coverage[outside]
    data.coverage[outside] = 0.0
    flat = mask.reshape(-1)
    if not np.array_equal(_fill_reads(fill)[flat], _fill_reads(data.fill())[flat]):
        data.coverage[outside] = coverage
        return "a touched texel fills from beyond the region"  # (a buried texel far into a cut chart)
    del coverage
    data.sh[outside] = 0.0
    data.normal[outside] = 0.0
    if data.noise is not None:
        data.noise[outside] = np.nan
    check()
    data, records = post.apply(data, settings, seams=atlas_seams)  # as the whole atlas's (`_merge_files`)
    check()
    encoded = encoding.encode_atlas(data, encoding.for_settings(settings.encoder), raw=False)
    encoded = post.stitch_encoded(encoded, data.coverage, settings, atlas_seams, records)
    texels = int(np.count_nonzero(region))
    merge = {"over": "region", "texels": texels, "share": share, "halo": WINDOW_HALO, "stats": encoded.stats}
    return encoded, records, merge


def _fill_reads(fill) -> np.ndarray:
    """`(H·W,)` int64: what `fill.apply(..., keep_black=True)` puts in each texel: its own value
    (its index), its source's (that index), the mean of the sources (-1) or 0 (-2: black)."""
    out = np.arange(fill.shape[0] * fill.shape[1], dtype=np.int64)
    out[fill.empty] = fill.source
    out[fill.black] = -2
    return out


def _stage_merged(staging, files, spec, images: dict, mask: np.ndarray) -> dict:
    """Stage one file of `spec`: the previous file's channels with the `mask` texels (rows
    bottom-up) taken from `images` (the merged atlas's, bottom-up); a channel stored as half
    before and needing float now (or the reverse) is stored as float, so no old value changes.
    Its preview images follow from the merged channels. Returns its channel table."""
    channels = lightmap_files.exr_channels(spec, images)
    path = files.path(spec)
    old, _ = exr.read(path)
    rows = exr.to_exr_rows(mask, copy=False)
    merged = {}
    for name, new in channels.items():
        before = old.get(name)
        if before is None or before.shape != new.shape:
            raise FullBakeNeeded(f"{path} lacks channel {name} or is of another size: bake all")
        dtype = np.float32 if np.float32 in (before.dtype, new.dtype) else np.float16
        out = before.astype(dtype)  # half → float is exact
        out[rows] = np.asarray(new).astype(dtype)[rows]
        merged[name] = out
    attributes = {
        "hhdFormat": lightmap_files.FORMAT,
        "hhdFormatVersion": lightmap_files.FORMAT_VERSION,
        "hhdAtlas": files.name,
    }
    exr.write_file(staging.stage(path), merged, attributes)
    lightmap_files.stage_preview(staging, files, spec, merged)
    return lightmap_files.channel_table(spec, merged)
