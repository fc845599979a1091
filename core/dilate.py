"""Fill texels outside the charts from their nearest chart texels. No bpy.

Bilinear filtering and mip-mapping average neighbouring texels; an empty (black) texel next to
a chart would darken its border. Dilation copies into every empty texel the value of a nearby
source texel, growing outward one ring per step (8-neighbourhood, so the fill is the chessboard
nearest source). The propagation works on texel indices, so any number of channels costs one
gather at the end. Texels farther than `rings` from every source get the mean of all sources.
"""

from __future__ import annotations

import numpy as np

from . import deps

#: Neighbour offsets (dy, dx), edge neighbours first so they win over diagonal ones.
_NEIGHBOURS = ((0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1))
_DY = np.array([d[0] for d in _NEIGHBOURS], np.int64)
_DX = np.array([d[1] for d in _NEIGHBOURS], np.int64)


#: How far (texels) an invalid texel looks for a valid one of its own chart (`Fill`'s `black`).
CHART_RINGS = 256


def nearest_source(valid: np.ndarray, rings: int, through: np.ndarray | None = None) -> np.ndarray:
    """For an `(H, W)` bool mask of source texels: `(H, W)` int64 flat index of the source each
    texel takes its value from (itself for sources), -1 where none is within `rings`. With
    `through` `(H, W)` bool, the growth only enters those texels (a chart's: the fill stays in it).
    Memory: two index images (int32 below 2³¹ texels) and a neighbour's masks at a time."""
    return _nearest(valid, rings, through).astype(np.int64, copy=False)


def _nearest(valid: np.ndarray, rings: int, through: np.ndarray | None = None) -> np.ndarray:
    """`nearest_source` as int32 below 2³¹ texels (int64 beyond): the compiled front-by-front
    growth (`_grow`, work in proportion to the texels reached), or the numpy rule over whole
    images (`_nearest_images`, rings × the image) where numba is missing; the same result."""
    try:
        kernel = _kernel()
    except deps.DependencyMissing:
        return _nearest_images(valid, rings, through)
    h, w = valid.shape
    dtype = np.int32 if h * w < 2**31 else np.int64
    index = np.where(valid, np.arange(h * w, dtype=dtype).reshape(h, w), dtype(-1)).reshape(-1)
    inside = np.ones(1, bool) if through is None else np.ascontiguousarray(through, bool).reshape(-1)
    kernel(index, h, w, int(rings), inside, through is not None)
    return index.reshape(h, w)


def _grow(index, h, w, rings, through, use_through):  # pragma: no cover - compiled by `_kernel`
    """`_nearest_images`' rule, front by front, in place on the flat `index` (H·W,) (own index at
    the sources, -1 elsewhere): at ring r every texel without a source (and in `through`, if
    `use_through`) next to one reached at ring r − 1 takes the source of its first neighbour in
    _NEIGHBOURS order that had one before ring r. Work: the texels reached and their neighbours."""
    n = h * w
    dy, dx = _DY, _DX
    size = 0
    for t in range(n):
        if index[t] >= 0:
            size += 1
    # a ring queues only texels without a source, each once: its front is never larger than
    # them, nor the first front than the sources (memory: index-sized buffers, not n int64s)
    front = np.empty(max(size, n - size), index.dtype)
    size = 0
    for t in range(n):
        if index[t] >= 0:
            front[size] = t
            size += 1
    queued = np.empty(max(n - size, 1), index.dtype)
    value = np.empty(max(n - size, 1), index.dtype)
    for _ in range(rings):
        if size == 0 or size == n:
            break
        count = 0
        for f in range(size):  # the texels without a source next to the front, once each
            t = front[f]
            y, x = t // w, t % w
            for k in range(8):
                yy, xx = y - dy[k], x - dx[k]  # the texel whose neighbour (dy, dx) t is
                if yy < 0 or yy >= h or xx < 0 or xx >= w:
                    continue
                c = yy * w + xx
                if index[c] != -1 or (use_through and not through[c]):
                    continue
                index[c] = -2  # queued this ring
                queued[count] = c
                count += 1
        for q in range(count):  # their first neighbour with a source from before this ring
            c = queued[q]
            y, x = c // w, c % w
            for k in range(8):
                yy, xx = y + dy[k], x + dx[k]
                if yy < 0 or yy >= h or xx < 0 or xx >= w:
                    continue
                v = index[yy * w + xx]
                if v >= 0:
                    value[q] = v
                    break
        for q in range(count):
            index[queued[q]] = value[q]
            front[q] = queued[q]
        size = count
    return index


_compiled = None


def _kernel():
    """`_grow` compiled (numba, nogil, cached on disk); raises deps.DependencyMissing without numba."""
    global _compiled
    if _compiled is None:
        numba = deps.require("numba")
        _compiled = numba.njit(nogil=True, cache=True)(_grow)
    return _compiled


def _nearest_images(valid: np.ndarray, rings: int, through: np.ndarray | None = None) -> np.ndarray:
    """The ring-by-ring rule over whole images (numpy): each ring, every texel without a
    source takes that of its first neighbour in _NEIGHBOURS order that has one."""
    h, w = valid.shape
    dtype = np.int32 if h * w < 2**31 else np.int64
    index = np.where(valid, np.arange(h * w, dtype=dtype).reshape(h, w), dtype(-1))
    for _ in range(rings):
        if index.min(initial=0) >= 0:  # no texel left without a source
            break
        grown = index.copy()
        for dy, dx in _NEIGHBOURS:
            to, of = _shifted(h, w, dy, dx)
            target, neighbour = grown[to], index[of]
            take = target < 0
            take &= neighbour >= 0
            if through is not None:
                take &= through[to]
            target[take] = neighbour[take]
            del target, neighbour, take
        if np.array_equal(grown, index):
            break
        index = grown
        del grown
    return index


def _shifted(h: int, w: int, dy: int, dx: int) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
    """The slices (rows, columns) of an `(H, W)` image whose texels have a neighbour at (dy, dx)
    inside the image, and those neighbours' slices."""
    to = (slice(max(-dy, 0), h - max(dy, 0)), slice(max(-dx, 0), w - max(dx, 0)))
    of = (slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0)))
    return to, of


#: Texels whose flat indices `_flat_indices` finds at once (bounds its int64 temporaries).
INDEX_BLOCK = 1 << 20


def _flat_indices(mask: np.ndarray, dtype, where: bool = True) -> np.ndarray:
    """`np.flatnonzero(mask == where)` as `dtype`, INDEX_BLOCK texels at a time: no int64 list
    of them all on the way (memory)."""
    flat = mask.reshape(-1)
    parts = []
    for start in range(0, len(flat), INDEX_BLOCK):
        block = flat[start : start + INDEX_BLOCK].astype(bool, copy=False)
        parts.append((np.flatnonzero(block if where else ~block) + start).astype(dtype))
    return np.concatenate(parts) if parts else np.zeros(0, dtype)


class Fill:
    """The dilation of one `(H, W)` mask of source texels, found once and applied to any number
    of images or single channels (each costs one gather). `black` `(H, W)` bool, optional:
    texels `apply(..., keep_black=True)` sets to zero after filling (buried texels). With
    `chart` `(H, W)` bool (the texels of charts), a `black` texel first takes the nearest source
    of its own chart reachable through it (within CHART_RINGS) and only those reaching none stay
    black; the texels outside charts then fill from the sources and those filled texels alike.
    `invalid`: the flat indices of `black`; `black`: those left black. Flat indices (`valid`,
    `invalid`, `black`, `empty` and their `source`) are int32 below 2³¹ texels (memory)."""

    def __init__(
        self, valid: np.ndarray, rings: int = 16, black: np.ndarray | None = None, chart: np.ndarray | None = None
    ):
        self.shape = valid.shape
        dtype = np.int32 if valid.size < 2**31 else np.int64
        self.valid = _flat_indices(valid, dtype)
        self.invalid = _flat_indices(black, dtype) if black is not None else np.zeros(0, dtype)
        self.black = self.invalid
        if chart is not None and len(self.invalid):
            # seeded by the chart's own sources only: a source outside the charts (a stitched
            # gutter texel) must not reach into the invalid texels of a neighbouring chart
            inside = _nearest(valid & chart, CHART_RINGS, through=chart).reshape(-1)
            filled = np.zeros(valid.size, bool)
            filled[self.invalid] = inside[self.invalid] >= 0
            source = _nearest(valid | filled.reshape(valid.shape), rings).reshape(-1)
            via = source >= 0
            via[via] = filled[source[via]]
            source[via] = inside[source[via]]  # an invalid texel's own source, a valid one
            self.black = self.invalid[~filled[self.invalid]]
            del inside, filled, via  # before the lists below are made (memory)
        else:
            source = _nearest(valid, rings).reshape(-1)
        self.empty = _flat_indices(valid, dtype, where=False)
        self.source = source[self.empty].astype(dtype)  # -1: no source within `rings`

    def apply(self, image: np.ndarray, keep_black: bool = False) -> np.ndarray:
        """`image` `(H, W, ...)` filled (same dtype): empty texels take their nearest source's
        value, those out of reach the mean of all sources (0 if there are none); with
        `keep_black`, the `black` texels 0. `image` is this call's (`core.memory`): a contiguous
        one is filled where it is and returned (else a filled copy); its sources are never
        written. A caller that keeps `image` hands over a copy (as `dilate` does)."""
        h, w = self.shape
        out = image.reshape((h * w,) + image.shape[2:])
        reached = self.source >= 0
        out[self.empty[reached]] = out[self.source[reached]]
        if not reached.all():
            fill = out[self.valid].mean(axis=0, dtype=np.float64) if len(self.valid) else 0.0
            out[self.empty[~reached]] = fill
        if keep_black:
            out[self.black] = 0.0
        return out.reshape(image.shape)


def dilate(image: np.ndarray, valid: np.ndarray, rings: int = 16) -> np.ndarray:
    """Copy of `image` `(H, W, ...)` with non-`valid` texels filled from the nearest valid one
    (within `rings`), the rest with the mean of the valid texels (0 if there are none)."""
    return Fill(valid, rings).apply(image.copy())
