"""Fill texels outside the charts from their nearest chart texels. No bpy.

Bilinear filtering and mip-mapping average neighbouring texels; an empty (black) texel next to
a chart would darken its border. Dilation copies into every empty texel the value of a nearby
source texel, growing outward one ring per step (8-neighbourhood, so the fill is the chessboard
nearest source). The propagation works on texel indices, so any number of channels costs one
gather at the end. Texels farther than `rings` from every source get the mean of all sources.
"""

from __future__ import annotations

import numpy as np

#: Neighbour offsets (dy, dx), edge neighbours first so they win over diagonal ones.
_NEIGHBOURS = ((0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1))


#: How far (texels) an invalid texel looks for a valid one of its own chart (`Fill`'s `black`).
CHART_RINGS = 256


def nearest_source(valid: np.ndarray, rings: int, through: np.ndarray | None = None) -> np.ndarray:
    """For an `(H, W)` bool mask of source texels: `(H, W)` int flat index of the source each
    texel takes its value from (itself for sources), -1 where none is within `rings`. With
    `through` `(H, W)` bool, the growth only enters those texels (a chart's: the fill stays in it)."""
    h, w = valid.shape
    index = np.where(valid, np.arange(h * w).reshape(h, w), -1)
    for _ in range(rings):
        empty = index < 0
        if not empty.any():
            break
        padded = np.pad(index, 1, constant_values=-1)
        grown = index.copy()
        for dy, dx in _NEIGHBOURS:
            neighbour = padded[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
            take = (grown < 0) & (neighbour >= 0)
            if through is not None:
                take &= through
            grown[take] = neighbour[take]
        if np.array_equal(grown, index):
            break
        index = grown
    return index


class Fill:
    """The dilation of one `(H, W)` mask of source texels, found once and applied to any number
    of images or single channels (each costs one gather). `black` `(H, W)` bool, optional:
    texels `apply(..., keep_black=True)` sets to zero after filling (buried texels). With
    `chart` `(H, W)` bool (the texels of charts), a `black` texel first takes the nearest source
    of its own chart reachable through it (within CHART_RINGS) and only those reaching none stay
    black; the texels outside charts then fill from the sources and those filled texels alike.
    `invalid`: the flat indices of `black`; `black`: those left black."""

    def __init__(
        self, valid: np.ndarray, rings: int = 16, black: np.ndarray | None = None, chart: np.ndarray | None = None
    ):
        self.shape = valid.shape
        self.valid = np.flatnonzero(valid)
        self.invalid = np.flatnonzero(black) if black is not None else np.zeros(0, np.int64)
        self.black = self.invalid
        if chart is not None and len(self.invalid):
            # seeded by the chart's own sources only: a source outside the charts (a stitched
            # gutter texel) must not reach into the invalid texels of a neighbouring chart
            inside = nearest_source(valid & chart, CHART_RINGS, through=chart).reshape(-1)
            filled = np.zeros(valid.size, bool)
            filled[self.invalid] = inside[self.invalid] >= 0
            source = nearest_source(valid | filled.reshape(valid.shape), rings).reshape(-1)
            via = source >= 0
            via[via] = filled[source[via]]
            source[via] = inside[source[via]]  # an invalid texel's own source, a valid one
            self.black = self.invalid[~filled[self.invalid]]
        else:
            source = nearest_source(valid, rings).reshape(-1)
        self.empty = np.flatnonzero(~valid.reshape(-1))
        self.source = source[self.empty]  # -1: no source within `rings`

    def apply(self, image: np.ndarray, keep_black: bool = False, in_place: bool = False) -> np.ndarray:
        """Filled copy of `image` `(H, W, ...)` (same dtype): empty texels take their nearest
        source's value, those out of reach the mean of all sources (0 if there are none).
        `in_place`: fill `image` itself (a contiguous array) and return it (sources are never
        written, so the result is the same)."""
        h, w = self.shape
        flat = image.reshape((h * w,) + image.shape[2:])
        out = flat if in_place else flat.copy()
        reached = self.source >= 0
        out[self.empty[reached]] = flat[self.source[reached]]
        if not reached.all():
            fill = flat[self.valid].mean(axis=0, dtype=np.float64) if len(self.valid) else 0.0
            out[self.empty[~reached]] = fill
        if keep_black:
            out[self.black] = 0.0
        return out.reshape(image.shape)


def dilate(image: np.ndarray, valid: np.ndarray, rings: int = 16) -> np.ndarray:
    """Copy of `image` `(H, W, ...)` with non-`valid` texels filled from the nearest valid one
    (within `rings`), the rest with the mean of the valid texels (0 if there are none)."""
    return Fill(valid, rings).apply(image)
