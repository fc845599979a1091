"""xatlas charting and packing, run in child processes by `unwrap`. No bpy, no package imports.

Why a child process: xatlas's worker threads are not robust on small machines. On 2 cores we have
seen, rarely, a SIGSEGV inside Atlas.generate() and a hang in its TaskScheduler's destructor
(both in CI, both gone on re-run; xatlas users report the same on 2-core CI machines). In a child
a crash costs one retry instead of Blender and the artist's unsaved work, and the child leaves
with os._exit() as soon as its result is written, so no destructor ever runs (every Atlas is kept
alive until then).

Two tasks, each a separate run:

- "chart": cut meshes into charts (`chart`). xatlas charts the triangles; a polygon (quad,
  n-gon) whose triangles xatlas put in different charts, or that has a triangle xatlas left out
  (zero area), becomes a chart of its own, flattened onto the plane of its area vector. A chart
  whose triangles overlap (xatlas can lay out a ring whose inner edge falls inside its own outer
  part) is broken up the same way, one polygon per chart. Every chart is then scaled to metres
  (its u and v scales fitted to its 3D edge lengths, then its UV area made its 3D area), so
  charts depend on no atlas size and can be cached and re-packed.
- "pack": place the charts of several meshes at a given density with xatlas's UV-mesh packer
  (`xatlas_packing.pack`); the parent (`packing._fit`) chooses the densities.

Charts are stored per mesh as (chart (T,) int32 chart id per triangle, -1 for a polygon with no
area; corner (T, 3) int32 index of each triangle corner into uv, -1 likewise; uv (U, 2) float32
chart-local coordinates in metres). A corner index stands for one (chart, vertex) pair, so all
the loops of a vertex in one polygon share one UV vertex: the UVs written per loop are exact.

This file runs as a script (`python -I xatlas_worker.py`), so it imports only numpy, xatlas and
`xatlas_packing` (the packing half, from this file's folder).
Protocol: stdin = two pickles, the parent's sys.path (a plain list, read before anything is
imported) and a job dict: {"task": "chart", "meshes": [(positions (V, 3) float64, triangles
(T, 3) uint32, polygons (T,) int64 or None)]} → {"charts": [(chart, corner, uv, folded)]}, or
{"task": "pack", "charts": [(chart, corner, uv)], "texels_per_metre", "resolution", "padding",
"units"} → `pack`'s result, or {"task": "each", "charts", "texels_per_metre", "padding", "units"} →
{"blocks": [`pack`'s result of each mesh's charts alone]}; stdout = pickle of the result.
"""

import os
import pickle
import sys
from typing import TYPE_CHECKING

if __package__ or TYPE_CHECKING:  # imported by the unwrap (`packing`, the tests), or read by mypy
    from .xatlas_packing import _ATLASES, _NONE, _signed_area, chart_boxes, fit, pack
else:  # run as a script: no package, its folder is not on sys.path (-I)
    sys.path.append(os.path.dirname(os.path.abspath(__file__)))
    from xatlas_packing import _ATLASES, _NONE, _signed_area, chart_boxes, fit, pack

#: The charting pass packs each mesh into an atlas of about this many texels across; only its
#: chart shapes are kept (rescaled to metres), so it only needs to be fine enough for float32.
CHART_PASS_RESOLUTION = 1024
#: xatlas's ChartOptions.max_iterations (its default: 1).
CHART_ITERATIONS = 1
#: Area (in xatlas's input units, squared) below which triangles are scaled up for charting
#: (`_chart_scale`): well above FLT_EPSILON, xatlas's zero-area threshold.
SMALL_TRIANGLE = 1e-5
#: Candidate pairs tested at once when checking charts for overlaps (bounds the memory used).
MAX_PAIRS = 1 << 22


def chart(meshes):
    """Charts of each mesh: [(chart, corner, uv, folded)] (see the module docstring and
    `_finish_charts`)."""
    import numpy as np
    import xatlas

    out = []
    for positions, triangles, polygons in meshes:
        positions = np.asarray(positions, dtype=np.float64)
        triangles = np.ascontiguousarray(triangles, dtype=np.uint32)
        scaled = np.ascontiguousarray(positions * _chart_scale(positions, triangles), dtype=np.float32)
        atlas = xatlas.Atlas()
        _ATLASES.append((atlas, scaled, triangles))
        tri_chart, corner_uv, corner_vertex = _xatlas_charts(atlas, scaled, triangles)
        if polygons is None:
            polygons = np.arange(len(triangles), dtype=np.int64)
        else:  # numbered 0 … P-1
            polygons = np.unique(np.asarray(polygons, dtype=np.int64), return_inverse=True)[1].ravel()
        out.append(_finish_charts(positions, triangles.astype(np.int64), polygons, tri_chart, corner_uv, corner_vertex))
    return out


def _chart_scale(positions, triangles):
    """Factor to scale a mesh by for xatlas. Its zero-area test is absolute (FLT_EPSILON in its
    input units: in metres, triangles under about half a millimetre square would get no chart)
    and its charts change a little with the scale, so meshes keep their size (in metres) unless
    their smaller triangles (the 1st percentile by area) are under SMALL_TRIANGLE: then they are
    scaled up to that size."""
    import numpy as np

    areas = _areas(positions, triangles.astype(np.int64))
    areas = areas[areas > 0]
    small = float(np.percentile(areas, 1)) if len(areas) else SMALL_TRIANGLE
    return float(np.sqrt(SMALL_TRIANGLE / small)) if small < SMALL_TRIANGLE else 1.0


def _xatlas_charts(atlas, positions, triangles):
    """Chart one mesh with xatlas: (chart (T,) int64, -1 where xatlas made none or its chart is
    invalid; corner UVs (T, 3, 2) float64 in the charting pass's texels; corner output vertex
    (T, 3) int64, one per (chart, vertex))."""
    import numpy as np
    import xatlas

    atlas.add_mesh(positions, triangles)
    area = _areas(positions.astype(np.float64), triangles.astype(np.int64)).sum()
    options = xatlas.PackOptions()
    options.padding, options.bilinear, options.rotate_charts = 0, False, False
    options.resolution = 0
    options.texels_per_unit = float(np.sqrt(0.75 * CHART_PASS_RESOLUTION**2 / max(area, 1e-30)))
    chart_options = xatlas.ChartOptions()
    chart_options.max_iterations = CHART_ITERATIONS
    atlas.generate(chart_options=chart_options, pack_options=options)
    _, indices, uvs = atlas[0]
    _, vertex_chart = atlas.get_mesh_vertex_assignment(0)
    vertex_chart = np.where(vertex_chart == _NONE, -1, vertex_chart.astype(np.int64))
    invalid = [
        c for c in range(atlas.get_mesh_chart_count(0)) if atlas.get_mesh_chart(0, c).type == xatlas.ChartType.Invalid
    ]
    tri_chart = vertex_chart[indices[:, 0]]
    if invalid:
        tri_chart[np.isin(tri_chart, invalid)] = -1  # overlapping: redone per polygon
    corner_uv = uvs.astype(np.float64)[indices] * [atlas.width, atlas.height]
    return tri_chart, corner_uv, indices.astype(np.int64)


def _finish_charts(positions, triangles, polygons, tri_chart, corner_uv, corner_vertex):
    """Give polygons xatlas split, and charts that fold over themselves, one chart per polygon;
    scale every chart to metres; number the UV vertices. Returns (chart (T,) int32, corner
    (T, 3) int32, uv (U, 2) float32, folded: polygons that overlap themselves even flattened
    alone, e.g. self-intersecting n-gons)."""
    import numpy as np

    bad_poly = _split_polygons(triangles, polygons, tri_chart, corner_vertex)
    while True:
        chart, key, uv, planar = _assemble(
            positions, triangles, polygons, tri_chart, corner_uv, corner_vertex, bad_poly
        )
        invalid = _invalid_charts(uv, chart, key, len(planar))
        redo = invalid & ~planar
        if not redo.any():
            break
        bad_poly[polygons[(chart >= 0) & redo[np.maximum(chart, 0)]]] = True
    chart, corner, uv_vertices = _uv_vertices(chart, key, uv)
    return chart, corner, uv_vertices, int((invalid & planar).sum())


def _assemble(positions, triangles, polygons, tri_chart, corner_uv, corner_vertex, bad_poly):
    """xatlas's charts, with the polygons flagged in bad_poly (P,) flattened one per chart.
    Returns (chart (T,) numbered from 0, -1 for no area; corner key (T, 3), one per (chart,
    vertex); corner UVs (T, 3, 2) in metres; planar (C,) bool: the chart is one polygon)."""
    import numpy as np

    bad = bad_poly[polygons]
    chart = tri_chart.copy()
    uv = corner_uv.copy()
    key = np.where(bad[:, None], -1, corner_vertex)  # xatlas's (chart, vertex)
    first = int(tri_chart.max()) + 1 if (tri_chart >= 0).any() else 0
    if bad.any():
        p_chart, p_uv = _planar_charts(positions, triangles[bad], polygons[bad])
        chart[bad] = np.where(p_chart >= 0, p_chart + first, -1)
        uv[bad] = p_uv
        # (polygon, vertex) pairs numbered after xatlas's output vertices
        pv = polygons[bad][:, None] * (int(triangles.max()) + 1) + triangles[bad]
        _, pv_index = np.unique(pv.ravel(), return_inverse=True)
        key[bad] = int(corner_vertex.max()) + 1 + pv_index.reshape(-1, 3)
    live = chart >= 0
    key[~live] = -1
    ids, chart = _renumber(chart)
    uv[live] = _to_metres(positions[triangles[live]], uv[live], chart[live], len(ids))
    return chart, key, uv, ids >= first


def _invalid_charts(uv, chart, key, n_charts):
    """(C,) bool: charts whose triangles overlap. A chart is valid when its triangles all wind
    one way, no edge has more than two triangles, no two boundary edges cross, and next to
    every boundary loop, on its triangles' side, the boundary winds once around (twice: a
    second layer, e.g. a ring whose inner edge xatlas laid inside its own outer part)."""
    import numpy as np

    live = chart >= 0
    uv, chart, key = uv[live], chart[live], key[live]
    invalid = np.zeros(n_charts, dtype=bool)
    signed = _signed_area(uv)
    total = np.bincount(chart, weights=signed, minlength=n_charts)
    size = np.bincount(chart, weights=np.abs(signed), minlength=n_charts)
    against = signed * np.sign(total)[chart] < -1e-9 * size[chart]
    invalid[chart[against]] = True
    directed = np.stack([key, np.roll(key, -1, axis=1)], axis=-1).reshape(-1, 2)
    ends = np.stack([uv, np.roll(uv, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    undirected = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(
        undirected[:, 0] * (int(key.max()) + 1) + undirected[:, 1], return_inverse=True, return_counts=True
    )
    counts = counts[inverse.ravel()]
    edge_chart = np.repeat(chart, 3)
    invalid[edge_chart[counts > 2]] = True
    boundary = counts == 1
    ends, directed, edge_chart = ends[boundary], directed[boundary], edge_chart[boundary]
    invalid[_crossing_charts(ends, directed, edge_chart, n_charts)] = True
    invalid[_layered_charts(ends, directed, edge_chart, np.sign(total))] = True
    return invalid


def _layered_charts(ends, directed, chart, orientation):
    """Chart ids where, beside some boundary loop on its triangles' side, the chart's boundary
    winds around more or less than once. Boundary edges (ends (E, 2, 2), vertex ids (E, 2),
    chart (E,)) are linked into loops; one point per loop is tested against its chart's whole
    boundary. orientation (C,): +1 counter-clockwise charts, -1 mirrored ones."""
    import numpy as np

    if len(ends) == 0:
        return np.zeros(0, dtype=np.int64)
    # pair each vertex's incoming edges with its outgoing ones: a permutation of the edges
    out_order = np.lexsort((directed[:, 0], chart))
    in_order = np.lexsort((directed[:, 1], chart))
    if not (directed[out_order, 0] == directed[in_order, 1]).all():
        return np.unique(chart)  # ragged boundary: check every chart
    succ = np.empty(len(ends), dtype=np.int64)
    succ[in_order] = out_order
    loop = np.arange(len(ends))
    step = succ.copy()
    for _ in range(int(np.ceil(np.log2(len(ends) + 1)))):  # smallest edge index per loop
        loop = np.minimum(loop, loop[step])
        step = step[step]
    sample = np.unique(loop)
    several = np.bincount(chart[sample])[chart[sample]] > 1  # one simple loop winds once
    sample = sample[several]
    if len(sample) == 0:
        return np.zeros(0, dtype=np.int64)
    a, b = ends[sample, 0], ends[sample, 1]
    left = np.stack([-(b - a)[:, 1], (b - a)[:, 0]], axis=1)
    point = 0.5 * (a + b) + 1e-6 * orientation[chart[sample]][:, None] * left  # triangles' side
    edges = np.nonzero(np.isin(chart, chart[sample]))[0]
    wind = np.zeros(len(sample))
    for who, edge in _rows_at_height(chart[sample], point[:, 1], chart[edges], ends[edges, :, 1]):
        np.add.at(wind, who, _winding(point[who], ends[edges[edge], 0], ends[edges[edge], 1]))
    c = chart[sample]
    return np.unique(c[wind * orientation[c] != 1])


def _rows_at_height(point_chart, y, edge_chart, edge_y):
    """(point, edge) index pairs of the same chart where min(edge y) ≤ point y < max(edge y):
    the only edges that can add to a point's winding number, in chunks (see `_chunks`).
    edge_y (E, 2)."""
    import numpy as np

    lo, hi = edge_y.min(axis=1), edge_y.max(axis=1)
    rank = np.unique(np.concatenate([y, lo, hi]), return_inverse=True)[1].ravel()
    n = len(rank) + 1
    key = point_chart * n + rank[: len(y)]
    order = np.argsort(key, kind="stable")
    start = np.searchsorted(key[order], edge_chart * n + rank[len(y) : len(y) + len(lo)])
    stop = np.searchsorted(key[order], edge_chart * n + rank[len(y) + len(lo) :])
    count = stop - start
    for rows in _chunks(count):
        edge = np.repeat(rows, count[rows])
        first = np.repeat(start[rows], count[rows])
        yield order[first + np.arange(len(edge)) - np.repeat(np.cumsum(count[rows]) - count[rows], count[rows])], edge


def _winding(p, a, b):
    """Winding contributions (n,) of edges a→b around points p (each (n, 2)): ±1 where the
    edge crosses the horizontal line through p on p's right, upwards or downwards (Sunday's
    rule). Summed over a closed boundary: its winding number around p."""
    import numpy as np

    side = _orient(a, b, p)
    up = (a[:, 1] <= p[:, 1]) & (b[:, 1] > p[:, 1]) & (side > 0)
    down = (a[:, 1] > p[:, 1]) & (b[:, 1] <= p[:, 1]) & (side < 0)
    return up.astype(np.float64) - down


def _crossing_charts(ends, vertices, chart, n_charts):
    """Chart ids in which two of the given edges (ends (E, 2, 2), vertex ids (E, 2), chart
    (E,)) properly cross. Edges are binned into a grid per chart (cells about one mean edge
    long, or 1/√E of the chart's size if larger, doubled while the bins would hold too many
    entries); edges sharing a cell and no vertex are tested with strict orientation signs."""
    import numpy as np

    if len(ends) < 2:
        return np.zeros(0, dtype=np.int64)
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    count = np.maximum(np.bincount(chart, minlength=n_charts), 1)
    extent = np.zeros(n_charts)
    np.maximum.at(extent, chart, ends.max(axis=(1, 2)))
    cell = np.maximum(np.bincount(chart, weights=length, minlength=n_charts) / count, extent / np.sqrt(count))
    cell = np.maximum(cell, 1e-12)[chart]
    while True:
        lo = np.floor(ends.min(axis=1) / cell[:, None]).astype(np.int64)
        hi = np.floor(ends.max(axis=1) / cell[:, None]).astype(np.int64)
        nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
        if (nx * ny).sum() <= max(MAX_PAIRS, 8 * len(ends)):
            break
        cell = cell * 2.0
    count = nx * ny
    edge = np.repeat(np.arange(len(ends)), count)
    k = np.arange(len(edge)) - np.repeat(np.cumsum(count) - count, count)
    cx, cy = lo[edge, 0] + k % nx[edge], lo[edge, 1] + k // nx[edge]
    cell_key = (chart[edge] << 42) + ((cx & 0x1FFFFF) << 21) + (cy & 0x1FFFFF)
    order = np.argsort(cell_key, kind="stable")
    edge, cell_key = edge[order], cell_key[order]
    found = []
    for i, j in _pairs_in_runs(cell_key):
        a, b = edge[i], edge[j]
        shared = (vertices[a][:, :, None] == vertices[b][:, None, :]).any(axis=(1, 2))
        a, b = a[~shared], b[~shared]
        p1, q1, p2, q2 = ends[a, 0], ends[a, 1], ends[b, 0], ends[b, 1]
        cross = (_orient(p1, q1, p2) * _orient(p1, q1, q2) < 0) & (_orient(p2, q2, p1) * _orient(p2, q2, q1) < 0)
        found.append(np.unique(chart[a[cross]]))
    return np.unique(np.concatenate(found)) if found else np.zeros(0, dtype=np.int64)


def _pairs_in_runs(keys):
    """Index pairs (i, j), i < j, of entries in the same run of equal sorted `keys`, yielded in
    chunks of about MAX_PAIRS pairs (memory stays bounded whatever the runs' sizes)."""
    import numpy as np

    start = np.concatenate([[True], keys[1:] != keys[:-1]])
    run_start = np.maximum.accumulate(np.where(start, np.arange(len(keys)), 0))
    run_id = np.cumsum(start) - 1
    run_end = np.bincount(run_id) + run_start[start]  # exclusive, per run
    after = run_end[run_id] - np.arange(len(keys)) - 1  # partners after i
    for rows in _chunks(after):
        i = np.repeat(rows, after[rows])
        j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(after[rows]) - after[rows], after[rows])
        yield i, j


def _chunks(counts):
    """Consecutive index ranges (as arrays) of `counts` each summing to about MAX_PAIRS at most
    (a single larger count is a chunk of its own)."""
    import numpy as np

    total = np.cumsum(counts)
    start = 0
    while start < len(counts):
        base = total[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(total, base + MAX_PAIRS, side="right")))
        yield np.arange(start, stop)
        start = stop


def _orient(a, b, c):
    """Twice the signed area (n,) of triangles (a, b, c), each (n, 2)."""
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def _split_polygons(triangles, polygons, tri_chart, corner_vertex):
    """(P,) bool: polygons xatlas did not keep whole: a triangle without a chart, or a vertex
    that is two different chart vertices (different charts or a seam) inside the polygon."""
    import numpy as np

    n_poly = int(polygons.max()) + 1
    bad = np.zeros(n_poly, dtype=bool)
    bad[polygons[tri_chart < 0]] = True
    lo, hi = np.full(n_poly, np.iinfo(np.int64).max), np.full(n_poly, -1)
    np.minimum.at(lo, polygons, tri_chart)
    np.maximum.at(hi, polygons, tri_chart)
    bad |= (hi >= 0) & (lo != hi)
    pv = np.repeat(polygons, 3) * (int(triangles.max()) + 1) + triangles.ravel()
    order = np.argsort(pv, kind="stable")
    pv_sorted, out_sorted = pv[order], corner_vertex.ravel()[order]
    differs = (pv_sorted[1:] == pv_sorted[:-1]) & (out_sorted[1:] != out_sorted[:-1])
    bad[np.repeat(polygons, 3)[order][1:][differs]] = True
    return bad


def _planar_charts(positions, triangles, polygons):
    """One chart per polygon, flattened onto the plane of its area vector (as Blender
    triangulates it). Returns (chart (t,) int64 numbered from 0, -1 for polygons without area;
    corner UVs (t, 3, 2) in metres)."""
    import numpy as np

    p = positions[triangles]  # (t, 3, 3)
    ids, poly_index = np.unique(polygons, return_inverse=True)
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal = np.zeros((len(ids), 3))
    np.add.at(normal, poly_index, cross)
    length = np.linalg.norm(normal, axis=1)
    flat = length <= 1e-12 * np.maximum(_extent(p, poly_index, len(ids)) ** 2, 1e-300)
    n = normal / np.where(flat, 1.0, length)[:, None]
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    v = np.cross(n, u)
    origin = np.zeros((len(ids), 3))
    origin[poly_index[::-1]] = p[::-1, 0]  # a vertex of each polygon
    local = p - origin[poly_index][:, None, :]
    uv = np.stack(
        [np.einsum("tki,ti->tk", local, u[poly_index]), np.einsum("tki,ti->tk", local, v[poly_index])], axis=-1
    )
    chart = np.where(flat[poly_index], -1, poly_index)
    return chart, uv


def _extent(p, index, n):
    """Bounding-box diagonal (n,) of the triangles `p (t, 3, 3)` grouped by `index`."""
    import numpy as np

    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    np.minimum.at(lo, index, p.min(axis=1))
    np.maximum.at(hi, index, p.max(axis=1))
    return np.linalg.norm(hi - lo, axis=1)


def _renumber(chart):
    """Chart ids made consecutive from 0 (-1 kept): (old id (C,) of each new id, chart (T,))."""
    import numpy as np

    ids, inverse = np.unique(chart, return_inverse=True)
    inverse = inverse.reshape(chart.shape)
    if len(ids) and ids[0] < 0:
        return ids[1:], np.where(chart < 0, -1, inverse - 1)
    return ids, inverse


def _to_metres(p, uv, chart, n_charts):
    """Corner UVs `(t, 3, 2)` rescaled per chart so that one UV unit is one metre: u and v
    scales fitted (least squares) to the 3D lengths of the chart's edges, which undoes the
    stretch xatlas's charting pass gives small charts, then a uniform scale making the chart's
    UV area its 3D area. Charts are moved to start at (0, 0)."""
    import numpy as np

    d_uv = np.roll(uv, -1, axis=1) - uv  # (t, 3, 2) edges
    d_p = np.roll(p, -1, axis=1) - p
    d_len2 = np.einsum("tki,tki->tk", d_p, d_p)
    ok = d_len2 > 0
    # a·du² + b·dv² ≈ length² for every edge, relative: a·x + b·y ≈ 1
    x = np.where(ok, d_uv[..., 0] ** 2 / np.where(ok, d_len2, 1.0), 0.0)
    y = np.where(ok, d_uv[..., 1] ** 2 / np.where(ok, d_len2, 1.0), 0.0)
    edge_chart = np.repeat(chart, 3)

    def total(w):
        return np.bincount(edge_chart, weights=w.ravel(), minlength=n_charts)

    sxx, sxy, syy, sx, sy = total(x * x), total(x * y), total(y * y), total(x), total(y)
    det = sxx * syy - sxy * sxy
    solvable = det > 1e-9 * np.maximum(sxx * syy, 1e-300)
    safe = np.where(solvable, det, 1.0)
    a, b = (syy * sx - sxy * sy) / safe, (sxx * sy - sxy * sx) / safe
    iso = total(x + y) / np.maximum(total((x + y) ** 2), 1e-300)  # one scale for both
    fit = solvable & (a > 0) & (b > 0)
    a, b = np.where(fit, a, iso), np.where(fit, b, iso)
    scaled = uv * np.stack([np.sqrt(a), np.sqrt(b)], axis=1)[chart][:, None, :]
    area_uv = np.bincount(chart, weights=np.abs(_signed_area(scaled)), minlength=n_charts)
    area_3d = np.bincount(chart, weights=_areas3(p), minlength=n_charts)
    has_area = (area_uv > 0) & (area_3d > 0)  # a needle: its edge lengths only
    factor = np.sqrt(np.where(has_area, area_3d, 1.0) / np.where(has_area, area_uv, 1.0))
    scaled *= factor[chart][:, None, None]
    lo = np.full((n_charts, 2), np.inf)
    np.minimum.at(lo, chart, scaled.min(axis=1))
    return scaled - lo[chart][:, None, :]


def _uv_vertices(chart, key, uv):
    """Number the UV vertices: one per distinct corner key. Returns (chart (T,) int32, corner
    (T, 3) int32, -1 on triangles without a chart; uv (U, 2) float32 of each UV vertex)."""
    import numpy as np

    live = key >= 0
    ids, first, inverse = np.unique(key[live], return_index=True, return_inverse=True)
    corner = np.full(key.shape, -1, dtype=np.int64)
    corner[live] = inverse.ravel()
    return (chart.astype(np.int32), corner.astype(np.int32), np.ascontiguousarray(uv[live][first], dtype=np.float32))


def _areas(positions, triangles):
    """Area (T,) of each triangle of a mesh."""
    return _areas3(positions[triangles])


def _areas3(p):
    """Area (t,) of triangles given by their corners `(t, 3, 3)`."""
    import numpy as np

    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def main():
    stdin = sys.stdin.buffer
    sys.path[:0] = [p for p in pickle.load(stdin) if p not in sys.path]
    job = pickle.load(stdin)
    if job["task"] == "chart":
        result = {"charts": chart(job["meshes"])}
    elif job["task"] == "fit":
        charts, resolution, padding = job["charts"], job["resolution"], job["padding"]
        _, boxes = chart_boxes(charts)
        result = fit(
            lambda densities, units: [pack(charts, t, resolution, padding, units) for t in densities],
            boxes,
            resolution,
            padding,
            job["fills"],
        )
    elif job["task"] == "each":  # every mesh's charts alone, each into its own atlas (core.instances)
        t, padding, units = job["texels_per_metre"], job["padding"], job["units"]
        result = {"blocks": [pack([c], t, 0, padding, units) for c in job["charts"]]}
    else:
        result = pack(job["charts"], job["texels_per_metre"], job["resolution"], job["padding"], job["units"])
    sys.stdout.buffer.write(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
    sys.stdout.buffer.flush()
    os._exit(0)  # skip xatlas's destructors (see the module docstring)


if __name__ == "__main__":
    main()
