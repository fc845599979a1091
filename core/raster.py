"""Conservative rasterisation of triangles in lightmap UV space. No bpy.

Every texel that a triangle overlaps with positive area is found (thin slivers and chart
borders included), with the exact overlap area (the triangle clipped against the texel square)
and the overlap's centroid, a point inside both, used as the texel's sample point. All steps
are vectorised over (triangle, texel) pairs; triangles are processed in chunks to bound memory.

Texel space: x = u · width, y = v · height; texel (i, j) is the square [i, i+1] × [j, j+1] and
its flat index is j · width + i.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from . import parallel

#: Candidate (triangle, texel) pairs per chunk: bounds the temporaries; larger chunks were not faster.
PAIRS_PER_CHUNK = 1 << 18


@dataclass
class Coverage:
    """One row per (triangle, texel) pair with positive overlap.

    triangle (P,) int, texel (P,) int flat index, area (P,) overlap in texel units (≤ 1),
    point (P, 2) overlap centroid in texel space."""

    triangle: np.ndarray
    texel: np.ndarray
    area: np.ndarray
    point: np.ndarray


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


def _signed_area(p):
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


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
