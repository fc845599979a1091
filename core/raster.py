"""Conservative rasterisation of triangles in lightmap UV space. No bpy.

Every texel that a triangle overlaps with positive area is found (thin slivers and chart
borders included), with the exact overlap area (the triangle clipped against the texel square)
and the overlap's centroid, a point inside both, used as the texel's sample point. The
per-triangle set-up is numpy; the loop over each triangle's (triangle, texel) pairs and the
choice per texel are compiled (`raster_kernels`, numba, `nogil`), over chunks of triangles on
the bake's threads (bounded memory; the result does not depend on the thread count).

Texel space: x = u · width, y = v · height; texel (i, j) is the square [i, i+1] × [j, j+1] and
its flat index is j · width + i.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from . import parallel, progress, raster_kernels

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


def rasterise(uv: np.ndarray, width: int, height: int, check=None, threads: int = 0) -> Coverage:
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

    # Edge functions of the CCW triangles: e(c) = m·(c - a) ≥ 0 inside, m the inward normal.
    edge = np.roll(p, -1, axis=1) - p  # edges a→b, (T, 3, 2)
    m = np.stack([-edge[..., 1], edge[..., 0]], axis=-1)
    off = np.einsum("tki,tki->tk", m, p)  # m·a
    kernel = raster_kernels.get().rasterise_chunk

    def chunk(bound: tuple[int, int]) -> Coverage:
        a, b = bound
        return Coverage(*kernel(p[a:b], m[a:b], off[a:b], lo[a:b], hi[a:b], counts[a:b], live[a:b], width))

    parts: list[Coverage] = []
    workers = parallel.resolve_threads(threads)
    tick = progress.ticker(check)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures: deque = deque()
        try:
            for bound in bounds:  # at most `workers` chunks ahead (memory: their temporaries)
                futures.append(pool.submit(chunk, bound))
                if len(futures) > workers:
                    tick.at(len(parts) / len(bounds))
                    parts.append(futures.popleft().result())
            while futures:
                tick.at(len(parts) / len(bounds))
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


def choose_per_texel(cov: Coverage):
    """Deterministically pick one pair per texel: the largest overlap, ties to the lowest
    triangle index. Returns (order: indices into cov for the chosen pairs sorted by texel,
    total coverage per chosen texel clipped to 1)."""
    if len(cov.texel) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    texel, texels = texel_ranks(cov.texel)  # a scratch image of the texels up to the last covered one
    return raster_kernels.get().choose_per_texel(texel, cov.triangle, cov.area, texels)


#: Flat texel ids reach this many times the pairs' count before the compiled kernels' scratch
#: images index the covered texels' ranks instead (`texel_ranks`): an almost empty atlas.
SPARSE_TEXELS = 4


def texel_ranks(texel: np.ndarray) -> tuple[np.ndarray, int]:
    """Ids for the pairs' flat texel ids `texel` (N,) that a scratch image of every id below a
    bound can index, and that bound: the ids themselves (bound: the last + 1) or, when that
    image would be SPARSE_TEXELS times larger than the pairs (an almost empty atlas: memory
    follows its texels, not its area), each id's rank among the covered texels (the same order,
    so the kernels' results are the same)."""
    texels = int(texel.max()) + 1 if len(texel) else 0
    if texels <= SPARSE_TEXELS * len(texel):
        return texel, texels
    covered, rank = np.unique(texel, return_inverse=True)
    return rank.reshape(-1).astype(np.int64, copy=False), len(covered)
