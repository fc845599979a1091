"""Charting: each mesh cut into charts once per content (`chart_key`), cached, in parallel
child processes (`xatlas_worker.chart`), a large mesh split into its connected parts. No bpy."""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

import numpy as np

from . import worker_runs
from .data import Charts, UnwrapMesh
from .worker_runs import _cores, _run_worker

#: Charting child processes run at once, never more than the cores this process may use. Each
#: charts some of the meshes, or pieces of a large one. xatlas has threads of its own, but they
#: leave cores idle (small meshes, one mesh's last charts), and its Python binding holds the GIL,
#: so threads of ours could not chart side by side: measured gains are in bench/results/unwrap.md.
CHART_PROCESSES = 4
#: Charting work below this many triangles per process stays in fewer processes (starting one
#: costs a Python start-up and the imports of numpy and xatlas; below it, xatlas's own threads
#: did as well). A mesh with more triangles than this is charted in pieces of about this many
#: (its connected parts gathered, `_connected_pieces`), each piece alone: the pieces depend on the
#: mesh alone, not on the cores nor on the other meshes charted with it, so its charts do too.
TRIANGLES_PER_PROCESS = 100_000
#: Bytes of charts kept for re-unwrapping unchanged meshes (least recently used dropped first):
#: 28 bytes or less per triangle, so several million triangles.
CHART_CACHE_BYTES = 256 << 20
#: Part of the cache key: bump when the charting (xatlas options, polygon rule) changes.
CHART_VERSION = b"charts-1"


# --- charting: once per mesh content, cached, in parallel child processes ---
_CACHE: OrderedDict[bytes, Charts] = OrderedDict()  # chart_key → charts


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
    start, done = time.monotonic(), 0
    with ThreadPoolExecutor(max_workers=len(jobs)) as pool:
        futures = {pool.submit(run, job): k for k, job in enumerate(jobs)}
        pending = set(futures)
        while pending:  # progress from this thread only: a line per part, and while none ends
            finished, pending = wait(pending, timeout=worker_runs.HEARTBEAT, return_when=FIRST_COMPLETED)
            for future in finished:
                results[futures[future]] = future.result()
                done += 1
                if progress:
                    progress(done / len(jobs), f"xatlas: charted {done} of {len(jobs)} parts")
            if progress and not finished:
                seconds = time.monotonic() - start
                progress(done / len(jobs), f"xatlas: charting, {done} of {len(jobs)} parts done, {seconds:.0f} s")
    pieces: dict[int, list] = {}
    for job, result in zip(jobs, results):
        for (i, rows, *_), charts in zip(job, result):
            pieces.setdefault(i, []).append((rows, charts))
    return [_join(pieces[i], len(m.triangles)) for i, m in enumerate(meshes)]


def _chart_jobs(meshes):
    """Work for each charting child: [[(mesh index, triangle rows (t,) or None, vertices used
    (v,), triangles (t, 3) uint32 renumbered, polygons (t,) or None)]], balanced by triangles.
    A mesh larger than TRIANGLES_PER_PROCESS is split between its connected parts (charts never
    cross from one connected part to another, so this gives the same kind of charts); how the
    pieces are dealt to children plays no part in the charts (each piece is charted alone)."""
    total = sum(len(m.triangles) for m in meshes)
    n = max(1, min(CHART_PROCESSES, _cores(), -(-total // TRIANGLES_PER_PROCESS)))
    items = []
    for i, m in enumerate(meshes):
        tri = np.asarray(m.triangles, dtype=np.int64)
        large = len(tri) > TRIANGLES_PER_PROCESS
        pieces = _connected_pieces(tri, len(m.positions), TRIANGLES_PER_PROCESS) if large else [None]
        for rows in pieces:
            items.append(_piece(i, m, tri, rows))
    bins: list[list] = [[] for _ in range(n)]
    load = [0] * n
    for item in sorted(items, key=lambda it: -len(it[3])):
        k = load.index(min(load))
        bins[k].append(item)
        load[k] += len(item[3])
    return [b for b in bins if b]


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
