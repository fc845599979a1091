"""The numpy bake-point code as it was before issue 23 part 5 compiled it: the reference the
compiled rasteriser, probe points, footprint triangles and settle spokes are checked against
(tests/test_raster_compiled.py) and the old path `bench/bake_points.py --compare` times. Not
shipped; copied unchanged from core/raster.py and core/bakepoints/ (only module prefixes
added). `_barycentric`, `_normalise` and `_texel_world_size`, which only this reference uses, moved
here from core/bakepoints/ (issue 55)."""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from hhd_lightmapper.core import parallel
from hhd_lightmapper.core.bakepoints import (
    FOOTPRINT_MIN_COS,
    FOOTPRINT_TRIANGLES,
    BakePoints,
    SurfaceTriangles,
    _albedo,
    _barycentric_grouped,
)
from hhd_lightmapper.core.bakepoints.covers import CoverProbe
from hhd_lightmapper.core.bakepoints.data import FOOTPRINT
from hhd_lightmapper.core.bakepoints.flags import BURIED_FRACTION, BURIED_PROBES, _probe_directions
from hhd_lightmapper.core.bakepoints.settling import _SPOKES, _push_out, _Spokes
from hhd_lightmapper.core.raster import PAIRS_PER_CHUNK, Coverage
from hhd_lightmapper.core.rays import RayScene


def _signed_area(p):
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def rasterise(uv: np.ndarray, width: int, height: int, check=None, threads: int = 1) -> Coverage:
    """All positive-area overlaps of triangles `uv (T, 3, 2)` (in [0, 1]²) with texels.
    `check()`, if given, is called between chunks (it raises to stop, e.g. on cancel).
    `threads`: workers over the chunks (0 = every core, `parallel.resolve_threads`); the chunks
    are independent and joined in order, so the result does not depend on it."""
    p = np.asarray(uv, dtype=np.float64) * np.array([width, height], dtype=np.float64)
    signed = _signed_area(p)
    live = np.nonzero(np.abs(signed) > 0.0)[0]
    p = p[live]
    # Counter-clockwise winding so the inside of every edge is on its left.
    flip = signed[live] < 0
    p[flip] = p[flip][:, ::-1]
    lo = np.clip(np.floor(p.min(axis=1)).astype(np.int64), 0, [width - 1, height - 1])
    hi = np.clip(np.ceil(p.max(axis=1)).astype(np.int64) - 1, 0, [width - 1, height - 1])
    hi = np.maximum(hi, lo)
    counts = (hi[:, 0] - lo[:, 0] + 1) * (hi[:, 1] - lo[:, 1] + 1)
    bounds = []
    start = 0
    while start < len(p):
        stop = start + max(1, int(np.searchsorted(np.cumsum(counts[start:]), PAIRS_PER_CHUNK)))
        bounds.append((start, stop))
        start = stop

    def chunk(bound: tuple[int, int]) -> Coverage:
        a, b = bound
        return _rasterise_chunk(p[a:b], lo[a:b], hi[a:b], counts[a:b], live[a:b], width)

    parts = []
    workers = parallel.resolve_threads(threads)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures: deque = deque()
        try:
            for bound in bounds:  # at most `workers` chunks ahead (memory: their temporaries)
                futures.append(pool.submit(chunk, bound))
                if len(futures) > workers:
                    if check is not None:
                        check()
                    parts.append(futures.popleft().result())
            while futures:
                if check is not None:
                    check()
                parts.append(futures.popleft().result())
        finally:
            for future in futures:
                future.cancel()
    if not parts:
        return Coverage(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2)))
    return Coverage(*(np.concatenate(x) for x in zip(*[(c.triangle, c.texel, c.area, c.point) for c in parts])))


def _rasterise_chunk(p, lo, hi, counts, tri_ids, width):
    """Candidate pairs from each triangle's texel bounding box; separating-axis rejection; fast
    paths for texels inside a triangle and triangles inside a texel; exact clipping otherwise."""
    tri = np.repeat(np.arange(len(p)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    k = np.arange(len(tri)) - first
    span_x = (hi[:, 0] - lo[:, 0] + 1)[tri]
    ix = lo[tri, 0] + k % span_x
    iy = lo[tri, 1] + k // span_x
    x0, y0 = ix.astype(np.float64), iy.astype(np.float64)
    # Edge functions of the CCW triangle: e(c) = m·(c - a) ≥ 0 inside, m the inward normal.
    a, b = p, np.roll(p, -1, axis=1)  # edges a→b, (T, 3, 2)
    m = np.stack([-(b - a)[..., 1], (b - a)[..., 0]], axis=-1)  # (T, 3, 2)
    off = np.einsum("tki,tki->tk", m, a)  # m·a
    mt, offt = m[tri], off[tri]  # (P, 3, 2), (P, 3)
    base = mt[..., 0] * x0[:, None] + mt[..., 1] * y0[:, None] - offt  # e at corner (x0, y0)
    e_max = base + np.maximum(mt[..., 0], 0) + np.maximum(mt[..., 1], 0)
    e_min = base + np.minimum(mt[..., 0], 0) + np.minimum(mt[..., 1], 0)
    overlap = (e_max > 0).all(axis=1)  # no separating edge axis
    full = overlap & (e_min >= 0).all(axis=1)  # whole texel inside
    pt = p[tri]
    inside_texel = (
        overlap
        & ~full
        & (
            (pt[..., 0] >= x0[:, None])
            & (pt[..., 0] <= x0[:, None] + 1)
            & (pt[..., 1] >= y0[:, None])
            & (pt[..., 1] <= y0[:, None] + 1)
        ).all(axis=1)
    )
    area = np.zeros(len(tri))
    centroid = np.zeros((len(tri), 2))
    area[full] = 1.0
    centroid[full] = np.stack([x0[full] + 0.5, y0[full] + 0.5], axis=1)
    area[inside_texel] = np.abs(_signed_area(pt[inside_texel]))
    centroid[inside_texel] = pt[inside_texel].mean(axis=1)
    clip = overlap & ~full & ~inside_texel  # partial overlaps: exact integrals
    area[clip], centroid[clip] = _overlap_with_texels(pt[clip], x0[clip], y0[clip])
    keep = area > 0.0
    return Coverage(tri_ids[tri[keep]], (iy * width + ix)[keep], area[keep], centroid[keep])


def _overlap_with_texels(tri, x0, y0):
    """Exact overlap area `(P,)` and centroid `(P, 2)` of CCW triangles `(P, 3, 2)` with the
    squares [x0, x0+1] × [y0, y0+1].

    Green's theorem with the vertical extent clamped to the square: for a CCW polygon,
        area = -∮ g(y) dx,  ∫∫ x = -∮ x g(y) dx,  ∫∫ y = -∮ g(y)²/2 dx,  g(y) = clamp(y, 0, 1),
    with each edge's x range clipped to [0, 1] (texel-local coordinates). Between the points
    where an edge crosses y = 0 and y = 1 the integrands are polynomials of degree ≤ 2 in x, so
    Simpson's rule on each of the (at most 3) pieces is exact. Branch-free and vectorised.
    """
    t = tri - np.stack([x0, y0], axis=1)[:, None, :]
    area = np.zeros(len(t))
    mx = np.zeros(len(t))
    my = np.zeros(len(t))
    for k in range(3):
        a, b = t[:, k], t[:, (k + 1) % 3]
        dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        slope = np.divide(dy, dx, out=np.zeros_like(dx), where=dx != 0.0)
        lo = np.clip(np.minimum(a[:, 0], b[:, 0]), 0.0, 1.0)
        hi = np.clip(np.maximum(a[:, 0], b[:, 0]), 0.0, 1.0)
        cuts = [lo, hi]
        for level in (0.0, 1.0):
            x_cross = a[:, 0] + np.divide(level - a[:, 1], slope, out=np.full_like(dx, -1.0), where=slope != 0.0)
            cuts.append(np.clip(x_cross, lo, hi))
        xs = np.sort(np.stack(cuts, axis=1), axis=1)  # (P, 4)
        direction = np.sign(dx)

        def g(x, a=a, slope=slope):
            return np.clip(a[:, 1] + (x - a[:, 0]) * slope, 0.0, 1.0)

        for u, v in ((xs[:, 0], xs[:, 1]), (xs[:, 1], xs[:, 2]), (xs[:, 2], xs[:, 3])):
            m = 0.5 * (u + v)
            gu, gm, gv = g(u), g(m), g(v)
            w = (v - u) / 6.0 * direction
            area -= w * (gu + 4.0 * gm + gv)
            mx -= w * (u * gu + 4.0 * m * gm + v * gv)
            my -= w * 0.5 * (gu * gu + 4.0 * gm * gm + gv * gv)
    good = area > 1e-14
    safe = np.where(good, area, 1.0)
    centroid = np.stack([x0 + mx / safe, y0 + my / safe], axis=1)
    return np.where(good, area, 0.0), centroid


def choose_per_texel(cov: Coverage):
    """Deterministically pick one pair per texel: the largest overlap, ties to the lowest
    triangle index. Returns (order: indices into cov for the chosen pairs sorted by texel,
    total coverage per chosen texel clipped to 1)."""
    if len(cov.texel) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    order = np.lexsort((cov.triangle, -cov.area, cov.texel))
    texels_sorted = cov.texel[order]
    first = np.concatenate([[True], texels_sorted[1:] != texels_sorted[:-1]])
    chosen = order[first]
    total = np.bincount(np.searchsorted(texels_sorted[first], cov.texel), weights=cov.area, minlength=len(chosen))
    return chosen, np.minimum(total, 1.0)


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates `(P, 3)` of 2D points in 2D triangles `(P, 3, 2)`, clamped to
    the triangle (the centroid is inside up to rounding)."""
    bary = np.clip(_barycentric_grouped(p[:, None, :], tri)[:, 0], 0.0, 1.0)
    return bary / bary.sum(axis=1, keepdims=True)


def _normalise(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=1, keepdims=True)


def _texel_world_size(pos: np.ndarray, texel_uv: np.ndarray) -> np.ndarray:
    """World-space edge length of one texel on each triangle `pos (n, 3, 3)` whose UVs in texel
    units are `texel_uv (n, 3, 2)`: √(world area / texel area)."""
    world = 0.5 * np.linalg.norm(np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0]), axis=1)
    t = texel_uv
    texels = 0.5 * np.abs(
        (t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1]) - (t[:, 2, 0] - t[:, 0, 0]) * (t[:, 1, 1] - t[:, 0, 1])
    )
    return np.sqrt(world / np.maximum(texels, 1e-12))


def texel_points(self: BakePoints, idx: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Ray origins `(len(idx), k, 3)` at `offsets` (k, 2) texel units from each texel's corner,
    clamped into the texel's triangle."""
    corner = np.stack([self.texel[idx] % self.width, self.texel[idx] // self.width], 1)
    tri = self.triangle[idx]
    bary = np.clip(_barycentric_grouped(corner[:, None, :] + offsets[None], self.mesh.texel_uv[tri]), 0.0, None)
    bary /= np.maximum(bary.sum(axis=-1, keepdims=True), 1e-300)
    return np.matmul(bary, self.mesh.positions[tri]) + self.face_normal[idx][:, None, :] * self.offset


def _fill_points(points: BakePoints, surface: SurfaceTriangles, rows: slice, centroid: np.ndarray) -> None:
    """Position, n_v, face normal, albedo and texel size of the texels `rows`, whose overlap
    centroids (texel space) are `centroid`."""
    tri = points.triangle[rows]
    pos = points.mesh.positions[tri]  # (n, 3, 3)
    bary = _barycentric(centroid, points.mesh.texel_uv[tri])
    points.position[rows] = np.einsum("pk,pki->pi", bary, pos)
    normal = _normalise(np.einsum("pk,pki->pi", bary, points.mesh.normals[tri]))
    face = _normalise(np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0]))
    # A vertex normal of zero length (degenerate input) falls back to the face normal.
    bad = ~np.isfinite(normal).all(axis=1) | (np.linalg.norm(normal, axis=1) < 0.5)
    normal[bad] = face[bad]
    face *= np.where(np.einsum("pi,pi->p", face, normal) < 0.0, -1.0, 1.0)[:, None]
    points.normal[rows], points.face_normal[rows] = normal, face
    points.albedo[rows] = _albedo(surface, tri, bary)
    points.texel_size[rows] = _texel_world_size(pos, points.mesh.texel_uv[tri])


def find_near_cover(
    points: BakePoints, probe: CoverProbe, check=None, chunk: int = 1 << 15, threads: int = 0
) -> np.ndarray:
    """Texels part of whose samples may start under a coplanar face (core.bakepoints.covers): the bake point,
    the footprint's corners and the texel's corners (where the samples' fallback can reach),
    mapped into the texel's triangle, are probed. The tracer probes every sample of the texels
    flagged here, so the flag only has to be conservative at the scale of a texel. (P,) bool."""
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    offsets = np.concatenate([0.5 + FOOTPRINT * (corners - 0.5), corners])  # texel units from its corner
    flags = np.zeros(len(points.texel), bool)

    def probe_chunk(rows: slice):
        idx = np.arange(rows.start, rows.stop)
        origins = np.concatenate([points.origins(idx)[:, None, :], points.texel_points(idx, offsets)], axis=1)
        normals = np.repeat(points.face_normal[idx], origins.shape[1], axis=0)
        flags[idx] = probe.covered(origins.reshape(-1, 3), normals).reshape(len(idx), -1).any(axis=1)

    _for_chunks(probe_chunk, len(flags), chunk, check, threads)
    return flags


def _for_chunks(work, n: int, chunk: int, check=None, threads: int = 0) -> None:
    """work(rows) for consecutive slices of range(n), `chunk` long, on `threads` workers (0 = every
    core; Embree releases the GIL); `check()` before each chunk's result is taken (it raises to
    stop: the chunks not started are dropped). Each chunk writes only its own rows, so the result
    does not depend on the thread count."""
    with ThreadPoolExecutor(max_workers=parallel.resolve_threads(threads)) as pool:
        futures = [pool.submit(work, slice(s, min(s + chunk, n))) for s in range(0, n, chunk)]
        try:
            for future in futures:
                if check is not None:
                    check()
                future.result()
        finally:
            for future in futures:
                future.cancel()


def find_buried(
    points: BakePoints, scene: RayScene, probes: int = BURIED_PROBES, check=None, chunk: int = 1 << 15, threads: int = 0
) -> np.ndarray:
    """Texels whose hemisphere is closed by nearby geometry seen from behind (the inside of a
    box pushed into the floor): at least BURIED_FRACTION of short probe rays (length 4 texels)
    hit back faces. Such texels are invalid: the traced SH is 0 there, never a dilation source,
    and the files fill them from the nearest valid texel of their chart (`TexelData.fill`). (Deeper inside a closed volume texels are dark anyway: all
    their rays end on the volume's inner faces.) Returns (P,) bool. Works in chunks of texels
    (bounded memory) on `threads` workers (0 = every core), calling `check()` between chunks. Every texel gets
    the first probes − need + 1 probes, only those with a back-face hit among them the rest:
    the same answer (the others cannot reach `need`) for most of the rays on open surfaces."""
    from hhd_lightmapper.core.sh import tangent_frames

    buried = np.zeros(len(points.texel), bool)
    local = _probe_directions(probes)
    need = int(np.ceil(BURIED_FRACTION * probes))  # back-face hits that make a texel buried
    first = probes - need + 1  # with none in these, the rest cannot add up to `need`: not buried

    def back_hits(sl, rows, directions):
        """Back-face hits (len(rows),) of the probes `directions` from the texels sl[rows]."""
        frames = tangent_frames(points.face_normal[sl][rows])
        dirs = np.einsum("pij,kj->pki", frames, directions).reshape(-1, 3)
        k = len(directions)
        origins = np.repeat(points.origins(sl)[rows], k, axis=0)
        reach = np.repeat(4.0 * points.texel_size[sl][rows] + 4.0 * points.offset, k)
        t, prim, ng = scene.intersect(origins, dirs, reach)
        return ((prim >= 0) & (np.einsum("ri,ri->r", dirs, ng) > 0.0)).reshape(-1, k).sum(axis=1)

    def probe_chunk(sl: slice):
        hits = back_hits(sl, slice(None), local[:first])
        rows = np.flatnonzero(hits > 0)  # most texels (open surfaces) stop here
        hits[rows] += back_hits(sl, rows, local[first:])
        buried[sl] = hits >= need

    _for_chunks(probe_chunk, len(buried), chunk, check, threads)
    return buried


def other_triangles(
    cov: Coverage, chosen: np.ndarray, face_normals: np.ndarray | None = None, threads: int = 0
) -> np.ndarray:
    """(P, FOOTPRINT_TRIANGLES - 1) int32: for each chosen pair's texel (`chosen`, sorted by
    texel as `raster.choose_per_texel` returns them) the other triangles overlapping it, largest
    overlap first (ties: lowest index), -1 where there are fewer. All lie in the texel's own
    chart: charts never share a texel. `face_normals` (T, 3) unit (0 for degenerate triangles):
    if given, only triangles within FOOTPRINT_MIN_COS of the texel's own triangle count.
    (`threads`, unused, only to be called as the compiled one is: this runs on one.)"""
    m = FOOTPRINT_TRIANGLES - 1
    out = np.full((len(chosen), m), -1, np.int32)
    if len(chosen) == 0 or m == 0:
        return out
    triangle, area, texel = cov.triangle, cov.area, cov.texel
    if face_normals is not None:
        own = cov.triangle[chosen][np.searchsorted(cov.texel[chosen], texel)]
        cos = np.einsum("ij,ij->i", face_normals[triangle], face_normals[own])
        keep = (cos >= FOOTPRINT_MIN_COS) | (triangle == own)
        triangle, area, texel = triangle[keep], area[keep], texel[keep]
    order = np.lexsort((triangle, -area, texel))
    texel = texel[order]
    start = np.flatnonzero(np.concatenate([[True], texel[1:] != texel[:-1]]))
    rank = np.arange(len(order)) - np.repeat(start, np.diff(np.append(start, len(order))))
    row = np.repeat(np.arange(len(start)), np.diff(np.append(start, len(order))))
    take = (rank >= 1) & (rank <= m)
    out[row[take], rank[take] - 1] = triangle[order[take]]
    return out


def settle(
    points: BakePoints, scene: RayScene, probe: CoverProbe, check=None, chunk: int = 1 << 15, threads: int = 0
) -> np.ndarray:
    """Bake points moved out from under back faces (`bakepoints.settle`, its spokes built with
    numpy). Updates `points.position` in place; returns (P,) bool: crossed."""
    crossed = np.zeros(len(points.texel), bool)
    k = len(_SPOKES)

    def settle_chunk(sl: slice):
        idx = np.arange(sl.start, sl.stop)
        anchor = points.origins(idx)
        target = _spoke_targets(points, idx, _SPOKES * FOOTPRINT + 0.5 * (1.0 - FOOTPRINT))
        ray = target - anchor[:, None, :]
        length = np.linalg.norm(ray, axis=2)
        direction = ray / np.maximum(length, 1e-300)[..., None]
        reach = np.maximum(length, points.texel_size[idx][:, None])
        origin = np.repeat(anchor, k, axis=0)
        near = scene.occluded(origin, direction.reshape(-1, 3), reach.reshape(-1)).reshape(-1, k)
        rows = np.flatnonzero((near & (length > 0.0)).any(axis=1))  # the few texels near geometry
        if len(rows) == 0:
            return
        spokes = _Spokes(scene, anchor[rows], direction[rows], reach[rows])
        moved = _push_out(points, idx[rows], spokes, probe)
        crossed[idx[rows]] = (spokes.t < length[rows]).any(axis=1) | moved

    _for_chunks(settle_chunk, len(crossed), chunk, check, threads)
    return crossed


def _spoke_targets(points: BakePoints, idx: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Ray origins (len(idx), k, 3) at `offsets` (k, 2) texel units from each texel's corner: on
    the first of the texel's triangles holding the point (its own, then `BakePoints.others`,
    whose parts of the footprint its samples cover too), else clamped into its own triangle
    (`BakePoints.texel_points`)."""
    target = points.texel_points(idx, offsets)
    if points.others is None:
        return target
    rows = np.flatnonzero((points.others[idx] >= 0).any(axis=1))
    if len(rows) == 0:
        return target
    sub = idx[rows]
    corner = np.stack([points.texel[sub] % points.width, points.texel[sub] // points.width], 1)
    at = corner[:, None, :] + offsets[None]
    done = np.zeros(at.shape[:2], bool)
    lift = points.face_normal[sub][:, None, :] * points.offset
    for tri in np.concatenate([points.triangle[sub, None], points.others[sub]], axis=1).T:
        bary = _barycentric_grouped(at, points.mesh.texel_uv[np.maximum(tri, 0)])
        take = (bary.min(axis=-1) >= 0.0) & (tri >= 0)[:, None] & ~done
        here = np.matmul(bary, points.mesh.positions[np.maximum(tri, 0)]) + lift
        target[rows] = np.where(take[..., None], here, target[rows])
        done |= take
    return target
