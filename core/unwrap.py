"""Lightmap UVs with xatlas: chart and pack meshes into one shared atlas or one per object. No bpy.

Input meshes are triangle lists in world space (metres), so texel density is per metre of the
object as it stands in the scene (object scale included; negative scale is fine: only lengths
and areas matter), with the polygon (quad, n-gon) each triangle comes from. Output UVs are per
triangle corner in [0, 1]² of the object's atlas, with texel centres at (i + 0.5)/width; the
triangles of one polygon are always in one chart and the corners of one polygon that share a
vertex always get the same UV, so the UVs can be written per loop exactly. Polygons with no area
get no chart (UV (0, 0), skipped by the rasteriser).

Two stages, each in child processes (`xatlas_worker`, so a crash in xatlas's threads is a retry,
not a lost session): charting, once per mesh content and cached (`chart_key`), in parallel
processes when there is enough work; then packing of the cached charts, re-packed with a smaller
density (never re-charted) until they fit the atlas.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field

import numpy as np

from . import atlas_limits, deps, instances, xatlas_worker
from .errors import BakeCancelled, BakeError

MIN_RESOLUTION, MAX_RESOLUTION = 256, 8192
#: xatlas runs in child processes (`xatlas_worker`): tries before giving up, and the time after
#: which a child counts as hung (generous: several times the measured charting time, see
#: bench/results/unwrap.md).
XATLAS_ATTEMPTS = 3
XATLAS_TIMEOUT_BASE, XATLAS_TIMEOUT_PER_TRIANGLE = 120.0, 2e-4
#: Seconds between checks of `cancel()` while a child runs: a cancelled unwrap stops this soon.
CANCEL_POLL = 0.1
_WORKER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "xatlas_worker.py")
#: Objects below this many covered texels get a warning: too few to show any lighting detail.
FEW_TEXELS = 64
#: Charting child processes run at once, never more than the cores this process may use. Each
#: charts some of the meshes, or of the connected parts of a large one. xatlas has threads of
#: its own, but they leave cores idle (small meshes, one mesh's last charts), and its Python
#: binding holds the GIL, so threads of ours could not chart side by side: measured gains are
#: in bench/results/unwrap.md.
CHART_PROCESSES = 4
#: Charting work below this many triangles per process stays in fewer processes (starting one
#: costs a Python start-up and the imports of numpy and xatlas; below it, xatlas's own threads
#: did as well).
TRIANGLES_PER_PROCESS = 100_000
#: Bytes of charts kept for re-unwrapping unchanged meshes (least recently used dropped first):
#: 28 bytes or less per triangle, so several million triangles.
CHART_CACHE_BYTES = 256 << 20
#: Part of the cache key: bump when the charting (xatlas options, polygon rule) changes.
CHART_VERSION = b"charts-1"
#: Packed atlases kept for re-unwrapping the same charts with the same settings: at most this
#: many, and this many bytes of UVs (24 per triangle).
PACK_CACHE_ENTRIES, PACK_CACHE_BYTES = 8, 128 << 20
#: Fitting packs below this many triangles run in one child, one after another (starting a
#: child costs more than such a pack); larger ones are packed two at a time in parallel children
#: when there are two cores or more (`xatlas_worker.fit`).
ONE_CHILD_TRIANGLES = 50_000


class AtlasFull(BakeError):
    """The charts of these objects do not fit one atlas at the chosen resolution (or, with a
    texel density, within MAX_RESOLUTION²): `unwrap` then spreads the objects over several."""


@dataclass
class UnwrapMesh:
    """name: object name (for messages); positions (V, 3) world space, metres; triangles (T, 3)
    vertex indices; resolution / texel_density: per-object overrides (None = the settings');
    polygons: (T,) index ≥ 0 of the polygon each triangle belongs to (its triangles stay in one
    chart, its corners on one vertex share one UV); None: every triangle is its own polygon.
    instance_of: the name of the mesh (datablock) the object uses; objects naming the same mesh
    share one lightmap UV layer and become instances (`core.instances`); None: never shared.
    bundle: (collection, instancer, member) for a mesh a collection instance shows: the object
    `member` of `collection` as the Empty `instancer` places it (positions in world space through
    the instancer); it is an instance of `instance_of` even when no other object shares it, and
    the collection's members are placed together per instancer (`core.instances.Bundle`)."""

    name: str
    positions: np.ndarray
    triangles: np.ndarray
    resolution: int | None = None
    texel_density: float | None = None
    polygons: np.ndarray | None = None
    instance_of: str | None = None
    bundle: tuple[str, str, str] | None = None


@dataclass
class UnwrapSettings:
    """resolution: atlas size in texels (square), used when texel_density is None.
    texel_density: texels per metre; the atlas size is then chosen to fit (≤ MAX_RESOLUTION).
    padding: texels between charts (≥ 2 for bilinear filtering; 2^k more per mip level).
    per_object: one atlas per object instead of one shared atlas."""

    resolution: int = 1024
    texel_density: float | None = None
    padding: int = 4
    per_object: bool = False


@dataclass
class ObjectUV:
    """uv (T, 3, 2) float32 per triangle corner in [0, 1]² of atlas `atlas`; texels: texels its
    charts cover (UV area × width × height); rect: (x0, y0, x1, y1) texel bounds in the atlas.
    An instance (`core.instances`) also has layer_uv (T, 3, 2), the UVs its mesh's lightmap
    layer holds (shared by every instance of the mesh), and instance = (scale u, scale v,
    offset u, offset v): uv = layer_uv · scale + offset. For other objects layer_uv is uv. A mesh
    of a collection instance also has inner (its rectangle in the collection's bundle) and outer
    (the instancer's copy of the bundle in the atlas): instance = outer ∘ inner."""

    name: str
    uv: np.ndarray
    atlas: int
    texels: float
    rect: tuple
    charts: int
    layer_uv: np.ndarray | None = None
    instance: tuple[float, float, float, float] | None = None
    inner: tuple[float, float, float, float] | None = None
    outer: tuple[float, float, float, float] | None = None

    @property
    def layer(self) -> np.ndarray:
        """What the object's lightmap UV layer holds (T, 3, 2)."""
        return self.uv if self.layer_uv is None else self.layer_uv


@dataclass
class UnwrapResult:
    """stats: how the unwrap went ("charted" / "cached" meshes, "chart_s" / "pack_s" seconds,
    "chart_processes", "packs": packs summed over atlases, "tries": per atlas, the densities
    packed and whether they fitted [(texels per metre, fitted)])."""

    objects: list[ObjectUV]
    atlas_sizes: list[tuple[int, int]]  # (width, height) per atlas
    utilisation: list[float]  # fraction of each atlas covered by charts (padding included)
    charts: int
    warnings: list[str] = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    #: per atlas: whether it holds objects of the shared atlas (not an object's own), and its
    #: number among the atlases one group spilled into (0: the first or only one)
    shared: list[bool] = field(default_factory=list)
    part: list[int] = field(default_factory=list)
    #: per atlas: whether it holds instances (`core.instances`)
    instanced: list[bool] = field(default_factory=list)


@dataclass(frozen=True)
class Charts:
    """One mesh cut into charts, in metres (see `xatlas_worker`): chart (T,) int32 chart id per
    triangle (-1: no area); corner (T, 3) int32 index into uv of each corner (-1 likewise), one
    per (chart, vertex); uv (U, 2) float32 chart-local coordinates; folded: polygons that overlap
    themselves however they are flattened (e.g. self-intersecting n-gons). Read-only (shared by
    the cache)."""

    chart: np.ndarray
    corner: np.ndarray
    uv: np.ndarray
    folded: int = 0

    @property
    def nbytes(self) -> int:
        return self.chart.nbytes + self.corner.nbytes + self.uv.nbytes


def padding_for_mips(mip_levels: int, base: int = 2) -> int:
    """Padding (texels) keeping charts apart down to the given mip level: base · 2^levels."""
    return base * (1 << max(0, mip_levels))


def validate(mesh: UnwrapMesh) -> None:
    """Raise BakeError naming the object if its geometry cannot be unwrapped."""
    p = np.asarray(mesh.positions)
    t = np.asarray(mesh.triangles)
    if t.size == 0:
        raise BakeError(f"'{mesh.name}' has no faces to unwrap")
    if p.ndim != 2 or p.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3:
        raise BakeError(f"'{mesh.name}': positions must be (V, 3) and triangles (T, 3), got {p.shape} and {t.shape}")
    if not np.isfinite(p).all():
        raise BakeError(f"'{mesh.name}' has NaN or infinite vertex coordinates")
    if t.min() < 0 or t.max() >= len(p):
        raise BakeError(f"'{mesh.name}' has faces that reference missing vertices")
    if mesh.polygons is not None:
        poly = np.asarray(mesh.polygons)
        if poly.shape != (len(t),) or not np.issubdtype(poly.dtype, np.integer) or poly.min() < 0:
            raise BakeError(
                f"'{mesh.name}': polygons must give one polygon index ≥ 0 per triangle "
                f"({len(t)}), got an array of shape {poly.shape} and type {poly.dtype}"
            )
    if not (triangle_areas(p, t) > 0).any():
        raise BakeError(f"'{mesh.name}' has only zero-area faces: nothing to bake")


def triangle_areas(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area `(T,)` of each triangle (same units as positions, squared)."""
    p = np.asarray(positions, dtype=np.float64)[np.asarray(triangles)]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def unwrap(
    meshes: list[UnwrapMesh],
    settings: UnwrapSettings,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> UnwrapResult:
    """Chart and pack `meshes`: one shared atlas, or one per object when settings.per_object or
    an object overrides resolution/density (overridden objects get their own atlas).

    progress(fraction in [0, 1], message) is called from the calling thread only (charting up to
    0.8, packing the rest, 1.0 at the end). cancel() may be called from any thread, every
    CANCEL_POLL seconds while a child runs: once it returns True the running children are killed
    and BakeCancelled is raised; nothing of a cancelled unwrap enters the caches."""
    for m in meshes:
        validate(m)
    inst_groups = instances.instance_groups(
        [m.instance_of for m in meshes], {m.instance_of for m in meshes if m.bundle and m.instance_of}
    )
    reps = _representatives(meshes, inst_groups)
    held = {i for g in inst_groups for i in g}
    groups = _group(meshes, settings, held)
    for _, resolution, density, _ in groups:
        _check_scale(resolution, density)
    atlas_limits.check_density(meshes, settings.texel_density, MAX_RESOLUTION)  # before xatlas meets it
    deps.require("xatlas")  # a missing wheel is a clear message here, not in the child
    stats: dict = {"packs": 0, "tries": []}
    t0 = time.perf_counter()
    charted = [i for i in range(len(meshes)) if i not in held] + reps  # an instanced mesh once
    keys: list[bytes] = [b""] * len(meshes)
    for i in charted:
        keys[i] = chart_key(meshes[i])
    _check(cancel)
    charts: list = [None] * len(meshes)
    done = chart_meshes(
        [meshes[i] for i in charted], stats, _stage(progress, 0.0, 0.8), [keys[i] for i in charted], cancel
    )
    for i, c in zip(charted, done):
        charts[i] = c
    for g, r in zip(inst_groups, reps):
        for i in g:
            charts[i] = charts[r]
    stats["chart_s"] = time.perf_counter() - t0
    result = UnwrapResult([None] * len(meshes), [], [], 0, stats=stats)  # type: ignore[list-item]  # filled below
    for gi, (indices, resolution, density, shared) in enumerate(groups):
        stage = _stage(progress, 0.8 + 0.2 * gi / len(groups), 0.2 / len(groups))
        if stage:
            stage(0.0, f"xatlas: packing atlas {gi + 1} of {len(groups)}")

        def pack(part, stage=stage, resolution=resolution, density=density):
            _check(cancel)
            return _pack(
                [meshes[i] for i in part],
                [charts[i] for i in part],
                [keys[i] for i in part],
                resolution,
                density,
                settings.padding,
                stage,
                cancel,
            )

        for k, (part, atlas) in enumerate(_spill(indices, pack, charts, resolution, density, settings.padding)):
            # a density-driven atlas is xatlas's own size; a fixed one is resolution² (charts fit in it)
            turn = _upright(atlas)
            w, h = (atlas["width"], atlas["height"]) if density is not None else (resolution, resolution)
            if turn:
                w, h = h, w
            _add_atlas(result, atlas, (w, h), shared, k)
            for j, i in enumerate(part):
                result.objects[i] = _object_uv(meshes[i], atlas, j, len(result.atlas_sizes) - 1, w, h, turn)
    for part_groups, resolution, density in _instance_atlases(inst_groups, reps, settings, meshes):
        _check(cancel)
        _add_instances(result, meshes, charts, part_groups, resolution, density, settings.padding, cancel)
    stats["pack_s"] = time.perf_counter() - t0 - stats["chart_s"]
    if progress:
        progress(1.0, "xatlas: done")
    result.warnings = _warnings(meshes, charts, result.objects)
    return result


def _check(cancel) -> None:
    """Raise BakeCancelled if `cancel` (or None) says so."""
    if cancel is not None and cancel():
        raise BakeCancelled("unwrap cancelled")


def _add_atlas(result: UnwrapResult, atlas: dict, size, shared: bool, part: int) -> None:
    result.atlas_sizes.append(size)
    result.utilisation.append(atlas["utilisation"])
    result.shared.append(shared)
    result.part.append(part)
    result.instanced.append(False)
    result.charts += atlas["charts"]
    result.stats["packs"] += atlas["packs"]
    result.stats["tries"].append(atlas.get("tries", []))


#: Share of an atlas that the padded chart boxes of one spilled group may take at zero density
#: (padding alone) when choosing how many atlases to start with: the rest is for the charts.
SPILL_PADDING_SHARE = 0.5


def _spill(indices, pack, charts, resolution, density, padding):
    """[(mesh indices, pack result)]: one atlas if the charts of `indices` fit one (`pack`
    raises AtlasFull when not), else the objects spread over the fewest atlases that each fit:
    objects are dealt largest first to the least loaded atlas (by padded chart-box area), so
    every object stays whole in one atlas. An object that alone does not fit is an error."""
    try:
        return [(indices, pack(indices))]
    except AtlasFull:
        if len(indices) == 1:
            raise
    boxes = [xatlas_worker.chart_boxes([(c.chart, c.corner, c.uv)])[1] for c in (charts[i] for i in indices)]
    count = _first_spill_count(boxes, resolution, density, padding)
    while True:
        packed = []
        for part in _deal(indices, boxes, count, resolution, density, padding):
            try:
                packed.append((part, pack(part)))
            except AtlasFull:
                if len(part) == 1:  # one object alone: more atlases cannot help
                    raise
                break
        else:
            return packed
        count += 1


def _area_density(boxes, resolution, density, padding):
    """Texels per metre at which to weigh the objects' chart boxes: the given density, or the
    one at which all the boxes would fill one resolution² atlas (none if padding alone does)."""
    if density is not None:
        return density
    t = xatlas_worker.box_density(np.concatenate(boxes), resolution, padding, 1.0)
    return t or 0.0


def _first_spill_count(boxes, resolution, density, padding) -> int:
    """Atlases to try first: enough that each holds its share of the padded boxes at the density
    the objects are weighed at, and that padding alone takes at most SPILL_PADDING_SHARE of each."""
    q = 2.0 * padding + 2.0
    all_boxes = np.concatenate(boxes)
    size = resolution if density is None else MAX_RESOLUTION
    padding_only = len(all_boxes) * q * q / (SPILL_PADDING_SHARE * size * size)
    t = density if density is not None else 0.0
    at_density = xatlas_worker.box_area(all_boxes, padding, t) / (size * size)
    return int(min(len(boxes), max(2, np.ceil(max(padding_only, at_density)))))


def _deal(indices, boxes, count, resolution, density, padding):
    """`indices` dealt into `count` groups, heaviest object first to the lightest group, by the
    area of their padded chart boxes; each group keeps the input order."""
    t = _area_density(boxes, resolution, density, padding)
    weight = [xatlas_worker.box_area(b, padding, t) for b in boxes]
    load = [0.0] * count
    parts: list[list[int]] = [[] for _ in range(count)]
    for k in sorted(range(len(indices)), key=lambda k: -weight[k]):
        g = min(range(count), key=load.__getitem__)
        load[g] += weight[k]
        parts[g].append(k)
    return [[indices[k] for k in sorted(p)] for p in parts if p]


def _warnings(meshes, charts, objects) -> list[str]:
    """Objects with polygons that fold over themselves, and objects with too few texels."""
    out = [
        f"'{m.name}': {c.folded} polygon(s) overlap themselves when flattened (twisted or "
        "self-intersecting faces), so their lightmap texels overlap: triangulate them (Face > "
        "Triangulate Faces) or fix their shape"
        for m, c in zip(meshes, charts)
        if c.folded
    ]
    return out + [
        f"'{o.name}' gets only {o.texels:.0f} lightmap texels: raise the resolution or its texel "
        "density to see lighting detail on it"
        for o in objects
        if o.texels < FEW_TEXELS
    ]


def _stage(progress, start, span):
    """A progress callback mapping [0, 1] onto [start, start + span] of `progress` (or None)."""
    if progress is None:
        return None
    return lambda f, msg: progress(start + span * f, msg)


def _group(meshes, settings, held=frozenset()):
    """[(mesh indices, resolution, density, shared)] per atlas to build (before any spill):
    the shared atlas first, then one per object with its own (shared False). Instances (`held`)
    are in none: they get atlases of their own (`_instance_atlases`)."""
    shared = [
        i
        for i, m in enumerate(meshes)
        if not settings.per_object and m.resolution is None and m.texel_density is None and i not in held
    ]
    groups = [(shared, settings.resolution, settings.texel_density, True)] if shared else []
    for i, m in enumerate(meshes):
        if i not in shared and i not in held:
            groups.append(
                (
                    [i],
                    m.resolution or settings.resolution,
                    m.texel_density
                    if m.texel_density is not None
                    else (None if m.resolution is not None else settings.texel_density),
                    False,
                )
            )
    return groups


def _check_scale(resolution, density):
    if density is None and not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION:
        raise BakeError(f"lightmap resolution {resolution} is outside {MIN_RESOLUTION}–{MAX_RESOLUTION}")
    if density is not None and not density > 0:
        raise BakeError(f"texel density must be positive, got {density}")


# --- charting: once per mesh content, cached, in parallel child processes ---
_CACHE: OrderedDict[bytes, Charts] = OrderedDict()  # chart_key → charts
_PACKED: OrderedDict[tuple, dict] = OrderedDict()  # (keys, settings) → pack result


def clear_chart_cache() -> None:
    """Forget every cached chart set and packed atlas (the next unwrap charts every mesh again)."""
    _CACHE.clear()
    _PACKED.clear()


def chart_key(mesh: UnwrapMesh) -> bytes:
    """Cache key of a mesh's charts: a hash of its vertex positions (float32, centred on their
    mean, so moving an object keeps its charts; rotating or scaling it does not), its triangles,
    its polygon indices and CHART_VERSION. The packing settings (resolution, density, padding)
    play no part: charts are in metres and re-packed for any atlas."""
    h = hashlib.blake2b(CHART_VERSION, digest_size=20)
    for a in (_centred(mesh.positions).astype(np.float32), np.ascontiguousarray(mesh.triangles, dtype=np.uint32)):
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    if mesh.polygons is not None:
        h.update(np.ascontiguousarray(mesh.polygons, dtype=np.int64).tobytes())
    return h.digest()


def _centred(positions) -> np.ndarray:
    """Positions (V, 3) float64 minus their mean: charted in float32 by xatlas, a mesh far from
    the origin would lose its small details (and xatlas's choices change with them)."""
    p = np.asarray(positions, dtype=np.float64)
    return p - p.mean(axis=0)


def chart_meshes(
    meshes: list[UnwrapMesh],
    stats: dict | None = None,
    progress: Callable[[float, str], None] | None = None,
    keys: list[bytes] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> list[Charts]:
    """Charts of every mesh: from the cache when a mesh with the same content was charted
    before in this session, else charted now (identical meshes once), in up to CHART_PROCESSES
    child processes at once. keys: the meshes' `chart_key`s, if already computed; cancel: as in
    `unwrap` (the cache is only filled once every child has finished)."""
    keys = keys if keys is not None else [chart_key(m) for m in meshes]
    todo: dict = {}
    for key, m in zip(keys, meshes):
        if key not in _CACHE:
            todo.setdefault(key, m)
    if stats is not None:
        stats.update(charted=len(todo), cached=len(meshes) - sum(k in todo for k in keys))
    if todo:
        for key, charts in zip(todo, _chart_uncached(list(todo.values()), stats, progress, cancel)):
            _remember(key, charts)
    out = []
    for key in keys:
        _CACHE.move_to_end(key)
        out.append(_CACHE[key])
    return out


def _remember(key, charts):
    for a in (charts.chart, charts.corner, charts.uv):
        a.flags.writeable = False
    _CACHE[key] = charts
    total = sum(c.nbytes for c in _CACHE.values())
    while total > CHART_CACHE_BYTES and len(_CACHE) > 1:
        total -= _CACHE.popitem(last=False)[1].nbytes


def _chart_uncached(meshes, stats, progress, cancel=None):
    """Chart `meshes` in parallel children: [Charts] in order."""
    jobs = _chart_jobs(meshes)
    if stats is not None:
        stats["chart_processes"] = len(jobs)

    def run(job):
        payload = [(_centred(meshes[i].positions)[used], tri, poly) for i, _, used, tri, poly in job]
        names = [meshes[i].name for i, *_ in job]
        triangles = sum(len(tri) for *_, tri, _ in job)
        return _run_worker({"task": "chart", "meshes": payload}, names, triangles, cancel)["charts"]

    if progress:
        progress(0.0, f"xatlas: charting {sum(len(m.triangles) for m in meshes)} triangles")
    results: list = [None] * len(jobs)
    with ThreadPoolExecutor(max_workers=len(jobs)) as pool:
        futures = {pool.submit(run, job): k for k, job in enumerate(jobs)}
        for done, future in enumerate(as_completed(futures), 1):  # progress from this thread only
            results[futures[future]] = future.result()
            if progress:
                progress(done / len(jobs), f"xatlas: charted {done} of {len(jobs)} parts")
    pieces: dict[int, list] = {}
    for job, result in zip(jobs, results):
        for (i, rows, *_), charts in zip(job, result):
            pieces.setdefault(i, []).append((rows, charts))
    return [_join(pieces[i], len(m.triangles)) for i, m in enumerate(meshes)]


def _chart_jobs(meshes):
    """Work for each charting child: [[(mesh index, triangle rows (t,) or None, vertices used
    (v,), triangles (t, 3) uint32 renumbered, polygons (t,) or None)]], balanced by triangles.
    A mesh larger than one child's share is split between its connected parts (charts never
    cross from one connected part to another, so this gives the same kind of charts)."""
    total = sum(len(m.triangles) for m in meshes)
    n = max(1, min(CHART_PROCESSES, _cores(), -(-total // TRIANGLES_PER_PROCESS)))
    share = total / n
    items = []
    for i, m in enumerate(meshes):
        tri = np.asarray(m.triangles, dtype=np.int64)
        pieces = _connected_pieces(tri, len(m.positions), share) if n > 1 and len(tri) > share else [None]
        for rows in pieces:
            items.append(_piece(i, m, tri, rows))
    bins: list[list] = [[] for _ in range(n)]
    load = [0] * n
    for item in sorted(items, key=lambda it: -len(it[3])):
        k = load.index(min(load))
        bins[k].append(item)
        load[k] += len(item[3])
    return [b for b in bins if b]


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def _piece(i, mesh, tri, rows):
    """(mesh index, rows, vertices used, renumbered triangles uint32, polygons) of a piece."""
    sub = tri if rows is None else tri[rows]
    used, inverse = np.unique(sub, return_inverse=True)
    poly = None if mesh.polygons is None else np.asarray(mesh.polygons, dtype=np.int64)
    if poly is not None and rows is not None:
        poly = poly[rows]
    return i, rows, used, inverse.reshape(-1, 3).astype(np.uint32), poly


def _connected_pieces(triangles, n_vertices, share):
    """Triangle rows of the connected parts of a mesh, gathered into pieces of about `share`
    triangles (largest parts first); a single connected part stays whole."""
    label = connected_parts(triangles, n_vertices)
    ids, inverse, counts = np.unique(label, return_inverse=True, return_counts=True)
    k = max(1, min(len(ids), int(round(len(triangles) / share))))
    if k == 1:
        return [None]
    piece_of, load = np.zeros(len(ids), dtype=np.int64), np.zeros(k)
    for c in np.argsort(-counts, kind="stable"):
        piece_of[c] = int(np.argmin(load))
        load[piece_of[c]] += counts[c]
    tri_piece = piece_of[inverse.ravel()]
    return [np.nonzero(tri_piece == p)[0] for p in range(k) if load[p] > 0]


def connected_parts(triangles: np.ndarray, n_vertices: int) -> np.ndarray:
    """Label (T,) per triangle, equal for triangles connected through shared vertices (the
    smallest vertex index of the part). Union by hooking roots onto smaller roots, then
    pointer jumping, until no triangle edge joins two roots."""
    parent = np.arange(n_vertices)
    a, b = triangles.ravel(), np.roll(triangles, 1, axis=1).ravel()
    while True:
        ra, rb = parent[a], parent[b]
        join = ra != rb
        if not join.any():
            return parent[triangles[:, 0]]
        np.minimum.at(parent, np.maximum(ra[join], rb[join]), np.minimum(ra[join], rb[join]))
        while True:
            nxt = parent[parent]
            if (nxt == parent).all():
                break
            parent = nxt


def _join(pieces, n_triangles):
    """One mesh's Charts from its pieces' worker results [(rows or None, (chart, corner, uv))]."""
    if len(pieces) == 1 and pieces[0][0] is None:
        return Charts(*pieces[0][1])
    chart = np.full(n_triangles, -1, dtype=np.int32)
    corner = np.full((n_triangles, 3), -1, dtype=np.int32)
    uvs, n_charts, n_uv, folded = [], 0, 0, 0
    for rows, (c, k, uv, f) in pieces:
        chart[rows] = np.where(c >= 0, c + n_charts, -1)
        corner[rows] = np.where(k >= 0, k + n_uv, -1)
        n_charts += int(c.max()) + 1 if len(c) else 0
        n_uv += len(uv)
        uvs.append(uv)
        folded += f
    return Charts(chart, corner, np.concatenate(uvs), folded)


# --- packing ---
def _pack(meshes, charts, keys, resolution, density, padding, progress=None, cancel=None):
    """Pack the charts of `meshes` into one atlas (see `xatlas_worker.pack`); returns the
    worker's result dict plus "texels_per_metre" and "packs" (pack runs). A fixed density is
    packed once into an atlas of the size it needs; a fixed resolution is fitted by `_fit`.
    The same charts packed with the same settings before in this session are not packed again."""
    cache_key = (tuple(keys), int(resolution), density, int(padding))
    if cache_key in _PACKED:
        _PACKED.move_to_end(cache_key)
        return dict(_PACKED[cache_key], packs=0)
    if density is not None:
        result = _pack_at([density], charts, meshes, 0, padding, density * xatlas_worker.PACK_UNITS_PER_TEXEL, cancel)[
            0
        ]
        if max(result["width"], result["height"]) > MAX_RESOLUTION:
            raise AtlasFull(
                f"texel density {density:g}/m needs a {result['width']}×{result['height']} atlas for "
                f"{_names(meshes)}, larger than {MAX_RESOLUTION}²: lower the density or give some "
                "objects their own atlas"
            )
        result.update(texels_per_metre=density, packs=1)
    else:
        result = _fit(meshes, charts, resolution, padding, progress, cancel)
    _PACKED[cache_key] = result
    while len(_PACKED) > 1 and (
        len(_PACKED) > PACK_CACHE_ENTRIES
        or sum(sum(u.nbytes for u in r["uv"]) for r in _PACKED.values()) > PACK_CACHE_BYTES
    ):
        _PACKED.popitem(last=False)
    return result


def _fit(meshes, charts, resolution, padding, progress=None, cancel=None):
    """Pack at the largest density found that fits one resolution² atlas (`xatlas_worker.fit`):
    in one child when the charts are few or there is one core, else driven from here with two
    densities packed side by side in parallel children each round."""
    payload = [(c.chart, c.corner, c.uv) for c in charts]
    _, boxes = xatlas_worker.chart_boxes(payload)
    q, fill = 2 * padding + 2, min(xatlas_worker.FIRST_FILL)
    if xatlas_worker.box_density(boxes, resolution, padding, fill) is None:
        raise AtlasFull(
            f"{_names(meshes)}: {len(boxes)} charts with padding {padding} need at least "
            f"{len(boxes) * q * q:.0f} texels for their padding alone, more than {fill:.0%} of a "
            f"{resolution}² atlas: raise the resolution, lower the padding, or give some objects "
            "their own atlas"
        )
    triangles = sum(len(m.triangles) for m in meshes)
    if _cores() < 2 or triangles <= ONE_CHILD_TRIANGLES:
        job = {
            "task": "fit",
            "charts": payload,
            "resolution": int(resolution),
            "padding": int(padding),
            "fills": (float(np.mean(xatlas_worker.FIRST_FILL)),),
        }
        result = _run_worker(job, [m.name for m in meshes], triangles, cancel)
    else:

        def pack_at(densities, units):
            return _pack_at(densities, charts, meshes, resolution, padding, units, cancel)

        result = xatlas_worker.fit(pack_at, boxes, resolution, padding, xatlas_worker.FIRST_FILL, True, progress)
    if not result["fits"]:
        raise AtlasFull(
            f"could not fit the {len(boxes)} charts of {_names(meshes)} into one {resolution}² atlas "
            f"with padding {padding}: raise the resolution, lower the padding, or give some objects "
            "their own atlas"
        )
    return result


def _pack_at(densities, charts, meshes, resolution, padding, units, cancel=None):
    """Worker pack results, one per density (texels per metre), packed in parallel children."""
    payload = [(c.chart, c.corner, c.uv) for c in charts]
    names = [m.name for m in meshes]
    triangles = sum(len(m.triangles) for m in meshes)

    def run(density):
        job = {
            "task": "pack",
            "charts": payload,
            "texels_per_metre": float(density),
            "resolution": int(resolution),
            "padding": int(padding),
            "units": float(units),
        }
        return _run_worker(job, names, triangles, cancel)

    if len(densities) == 1:
        return [run(densities[0])]
    with ThreadPoolExecutor(max_workers=len(densities)) as pool:
        return list(pool.map(run, densities))


def _names(meshes) -> str:
    shown = ", ".join(f"'{m.name}'" for m in meshes[:5])
    return shown + (f" and {len(meshes) - 5} more" if len(meshes) > 5 else "")


def _run_worker(job, names, triangles, cancel=None):
    """Run one xatlas_worker task in a child process; a crashed or hung child is retried.
    cancel() True (checked every CANCEL_POLL seconds): the child is killed and reaped, then
    BakeCancelled is raised."""
    payload = pickle.dumps(list(sys.path)) + pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
    timeout = XATLAS_TIMEOUT_BASE + XATLAS_TIMEOUT_PER_TRIANGLE * triangles
    failures = []
    for _ in range(XATLAS_ATTEMPTS):
        _check(cancel)
        run = _run_child(payload, timeout, cancel)
        _check(cancel)  # a Ctrl-C on the terminal also reaches the child: not a crash
        if run is None:
            failures.append(f"no answer after {timeout:.0f} s")
            continue
        if run.returncode == 0 and run.stdout:
            result = pickle.loads(run.stdout)
            if "error" in result:
                raise BakeError(result["error"])
            return result
        failures.append(_describe_failure(run))
    shown = ", ".join(f"'{n}'" for n in names[:5]) + (" …" if len(names) > 5 else "")
    raise BakeError(f"xatlas failed {XATLAS_ATTEMPTS} times unwrapping {shown}: {'; '.join(failures)}")


def _run_child(payload: bytes, timeout: float, cancel=None):
    """Run the worker on `payload`: a CompletedProcess, or None if it gave no answer within
    `timeout` seconds (then killed). Raises BakeCancelled, the child killed and reaped, once
    cancel() returns True. The pipes are served by a helper thread (`communicate` cannot be
    retried after a timeout while input remains to be written), this one only waits."""
    proc = subprocess.Popen(
        [sys.executable, "-I", _WORKER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    streams = []
    talker = threading.Thread(target=lambda: streams.append(proc.communicate(payload)), daemon=True)
    talker.start()
    deadline = time.monotonic() + timeout
    try:
        while talker.is_alive():
            talker.join(max(0.0, min(CANCEL_POLL, deadline - time.monotonic())))
            if talker.is_alive() and cancel is not None and cancel():
                raise BakeCancelled("unwrap cancelled")
            if talker.is_alive() and time.monotonic() >= deadline:
                return None
        stdout, stderr = streams[0] if streams else (b"", b"")
        return subprocess.CompletedProcess(proc.args, proc.wait(), stdout, stderr)
    finally:
        if talker.is_alive():
            proc.kill()
            talker.join()  # the pipes close with the child: communicate returns and reaps it
        proc.wait()


def _describe_failure(run) -> str:
    """One line on how the xatlas child ended: the signal that killed it or its last error line."""
    if run.returncode < 0:
        try:
            return f"crashed ({signal.Signals(-run.returncode).name})"
        except ValueError:
            return f"crashed (signal {-run.returncode})"
    lines = run.stderr.decode(errors="replace").strip().splitlines()
    return f"exit code {run.returncode}" + (f": {lines[-1]}" if lines else "")


def _upright(atlas) -> bool:
    """Whether the charts xatlas packed span more rows than columns of its atlas (`_object_uv`
    turns such an atlas a quarter)."""
    placed = [u[u.any(axis=(1, 2))].reshape(-1, 2) for u in atlas["uv"]]  # placed triangles' corners
    corners = np.concatenate(placed).astype(np.float64) if placed else np.zeros((0, 2))
    if not len(corners):
        return False
    corners *= [atlas["width"], atlas["height"]]
    span = corners.max(axis=0) - corners.min(axis=0)
    return bool(span[1] > span[0])


def _object_uv(mesh, atlas, k, atlas_index, w, h, turn=False):
    """ObjectUV of mesh k of a packed `atlas` in the final w × h atlas. The worker's UVs are
    normalised by xatlas's atlas size; they are rescaled to the final size, and with `turn`
    (xatlas's atlas taller than wide; w, h are already the turned sizes) turned a quarter,
    (u, v) → (v, 1 − u): texel centres land on texel centres and charts keep their handedness,
    and the texels lie in few rows, which is what the files' writers and the post stages'
    windows are cheapest for (a long thin strip packed upright would touch every row)."""
    if turn:
        scale = np.array([atlas["width"] / h, atlas["height"] / w], dtype=np.float64)
        uv = atlas["uv"][k] * scale
        unplaced = ~uv.any(axis=(1, 2))  # triangles without area keep UVs 0, turned or not
        uv = np.stack([uv[..., 1], 1.0 - uv[..., 0]], axis=-1).astype(np.float32)
        uv[unplaced] = 0.0
    else:
        scale = np.array([atlas["width"] / w, atlas["height"] / h], dtype=np.float64)
        uv = (atlas["uv"][k] * scale).astype(np.float32)  # (T, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    areas = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * w * h  # texels²
    live = areas > 0
    if live.any():
        px = uv[live].reshape(-1, 2) * [w, h]
        rect = (
            int(np.floor(px[:, 0].min())),
            int(np.floor(px[:, 1].min())),
            int(np.ceil(px[:, 0].max())),
            int(np.ceil(px[:, 1].max())),
        )
    else:
        rect = (0, 0, 0, 0)
    return ObjectUV(mesh.name, uv, atlas_index, float(areas.sum()), rect, atlas["mesh_charts"][k])


# --- instances: linked duplicates sharing one lightmap UV layer (core.instances) ---
def _representatives(meshes, groups) -> list[int]:
    """The mesh index charted for each instance group (its largest instance), after checking
    that no instance asks for an atlas of its own (its layer is its mesh's, shared)."""
    reps = []
    for g in groups:
        own = [meshes[i].name for i in g if meshes[i].resolution is not None or meshes[i].texel_density is not None]
        if own:
            raise BakeError(
                f"{', '.join(repr(n) for n in own)} share the mesh '{meshes[g[0]].instance_of}' with other objects "
                "and override the resolution or texel density: instances share their mesh's lightmap UVs, so "
                "they cannot have an atlas of their own; clear the override or make the object single user"
            )
        areas = [float(triangle_areas(meshes[i].positions, meshes[i].triangles).sum()) for i in g]
        reps.append(g[instances.representative(areas)])
    return reps


def _instance_atlases(groups, reps, settings, meshes):
    """[(groups [(member indices, representative)], resolution, density)] per instance atlas:
    one for all instanced meshes, or, when every object has its own atlas, one per mesh and
    collection (the meshes of one collection's instances share theirs)."""
    pairs = list(zip(groups, reps))
    if not pairs:
        return []
    if not settings.per_object:
        return [(pairs, settings.resolution, settings.texel_density)]
    root = list(range(len(pairs)))

    def find(a):
        while root[a] != a:
            a = root[a]
        return a

    first: dict[str, int] = {}
    for k, (members, _) in enumerate(pairs):
        for i in members:
            if meshes[i].bundle is not None:
                root[find(k)] = find(first.setdefault(meshes[i].bundle[0], k))
    parts: dict[int, list] = {}
    for k, pair in enumerate(pairs):
        parts.setdefault(find(k), []).append(pair)
    return [(part, settings.resolution, settings.texel_density) for part in parts.values()]


@dataclass
class _Units:
    """What an instance atlas places: per mesh group its plain instances (linked duplicates,
    mesh indices), then per collection its instancers (sorted) and each instancer's members
    (mesh indices, by member name), and per collection the group index of each member."""

    plain: list[list[int]]
    collections: list[dict[str, list[int]]]
    member_groups: list[list[int]]

    @property
    def counts(self) -> list[int]:
        """Copies per unit: each mesh group's block, then each collection's bundle."""
        return [len(p) for p in self.plain] + [len(c) for c in self.collections]


def _units(meshes, groups) -> _Units:
    """Sort the instance groups' meshes into plain instances and collection instances; raises
    BakeError when two instancers of one collection show different members."""
    group_of = {i: gi for gi, (members, _) in enumerate(groups) for i in members}
    plain: list[list[int]] = [[] for _ in groups]
    by_collection: dict[str, dict[str, list[int]]] = {}
    for gi, (members, _) in enumerate(groups):
        for i in members:
            b = meshes[i].bundle
            if b is None:
                plain[gi].append(i)
            else:
                by_collection.setdefault(b[0], {}).setdefault(b[1], []).append(i)
    collections, member_groups = [], []
    for name, by_instancer in by_collection.items():
        ordered = {e: sorted(idx, key=lambda i: meshes[i].bundle[2]) for e, idx in sorted(by_instancer.items())}
        shown = {tuple(meshes[i].bundle[2] for i in idx) for idx in ordered.values()}
        if len(shown) > 1:
            raise BakeError(
                f"the instances of collection '{name}' show different objects ({', '.join(sorted(ordered))}): "
                "unwrap them together again"
            )
        collections.append(ordered)
        member_groups.append([group_of[i] for i in next(iter(ordered.values()))])
    return _Units(plain, collections, member_groups)


def _add_instances(result, meshes, charts, groups, resolution, density, padding, cancel) -> None:
    """Pack the instance groups [(member indices, representative)] into one new atlas of `result`
    and fill in their ObjectUVs (`core.instances`): a block per linked duplicate, a bundle per
    collection instance."""
    _check_scale(resolution, density)
    rep_charts = [charts[r] for _, r in groups]
    names = [meshes[r].name for _, r in groups]
    triangles = sum(len(meshes[r].triangles) for _, r in groups)
    units = _units(meshes, groups)
    counts = units.counts

    def pack_blocks(t):
        job = {
            "task": "each",
            "charts": [(c.chart, c.corner, c.uv) for c in rep_charts],
            "texels_per_metre": float(t),
            "padding": int(padding),
            "units": float(t) * xatlas_worker.PACK_UNITS_PER_TEXEL,
        }
        out = _run_worker(job, names, triangles, cancel)["blocks"]
        blocks = [
            instances.Block(b["uv"][0], b["width"], b["height"], b["mesh_charts"][0], b["utilisation"]) for b in out
        ]
        return blocks + [instances.bundle(blocks, m, padding) for m in units.member_groups]

    first = None
    if density is None:
        boxes = [xatlas_worker.chart_boxes([(c.chart, c.corner, c.uv)])[1] for c in rep_charts]
        boxes += [np.concatenate([boxes[g] for g in m]) for m in units.member_groups]
        first = instances.first_density(boxes, counts, resolution, padding)
    w, h, t, placed, corners, packs = instances.layout(
        pack_blocks, counts, resolution, density, padding, MAX_RESOLUTION, first
    )
    atlas_index = len(result.atlas_sizes)
    result.atlas_sizes.append((w, h))
    covered = sum(n * b.utilisation * b.width * b.height for n, b in zip(counts, placed))
    result.utilisation.append(float(covered / (w * h)))
    result.shared.append(False)
    result.part.append(0)
    result.instanced.append(True)
    result.charts += sum(n * b.charts for n, b in zip(counts, placed))
    result.stats["packs"] += packs
    result.stats["tries"].append([(float(t), True)])
    blocks = placed[: len(groups)]
    copies = iter(corners)
    for gi, members in enumerate(units.plain):
        for i in members:
            result.objects[i] = _instance_uv(meshes, i, groups[gi][1], blocks[gi], next(copies), atlas_index, (w, h))
    for ci, by_instancer in enumerate(units.collections):
        bundle = placed[len(groups) + ci]
        assert isinstance(bundle, instances.Bundle)
        for members in by_instancer.values():
            x0, y0 = (int(v) for v in next(copies))
            outer = instances.rectangle(bundle, (x0, y0), w, h)
            for i, (g, (x, y)) in zip(members, bundle.parts):
                ouv = _instance_uv(meshes, i, groups[g][1], blocks[g], (x0 + x, y0 + y), atlas_index, (w, h))
                ouv.inner = instances.rectangle(blocks[g], (x, y), bundle.width, bundle.height)
                ouv.outer = outer
                result.objects[i] = ouv


def _instance_uv(meshes, i, r, block, corner, atlas_index, size) -> ObjectUV:
    """The ObjectUV of instance `i` (representative `r`) for its block's copy at lower-left texel
    `corner` of atlas `atlas_index` of `size` (width, height)."""
    w, h = size
    reversed_ = instances.corner_map(meshes[i].triangles, meshes[r].triangles, meshes[i].name, meshes[r].instance_of)
    layer = block.uv[:, ::-1] if reversed_ else block.uv
    x, y = (int(v) for v in corner)
    rect = instances.rectangle(block, (x, y), w, h)
    uv = instances.atlas_uv(layer, rect)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    texels = float((0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])).sum() * w * h)
    return ObjectUV(
        meshes[i].name,
        uv,
        atlas_index,
        texels,
        (x, y, x + block.width, y + block.height),
        block.charts,
        np.ascontiguousarray(layer, dtype=np.float32),
        rect,
    )
