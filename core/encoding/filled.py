"""A raw file's filled channels made a band of rows at a time, for the EXR writer. No bpy.

The raw SH file holds the SH dilated (`dilate.Fill.apply`): every texel outside the charts takes
its nearest source's value. Filling the TexelData's SH itself would write every empty texel of
the atlas (the pages of an almost empty image become resident, ~108 bytes per atlas texel) and
would have to be undone before the post stages. The EXR writer takes its channels a band of
rows at a time (`exr.write_file`), so a `FilledChannel` computes only the band asked for, from
the unchanged layer: the writer's memory is a band of every channel, whatever the atlas size.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import dilate as _dilate
from ..stages import BandedImage


@dataclass(eq=False)
class FilledLayer:
    """The layer `(H, W, K)` (rows bottom-up; any strides: a view of a TexelData's SH) as
    `fill.apply(layer[..., k], keep_black)` fills each of its K channels, made a band of rows at
    a time (`band`). The layer is only read. The last band is kept, since the writer asks for it
    once per channel (and once more to check it is finite)."""

    layer: np.ndarray
    fill: _dilate.Fill
    keep_black: bool
    _rows: tuple[int, int] | None = field(default=None, init=False)
    _band: np.ndarray | None = field(default=None, init=False)
    _means: np.ndarray | None = field(default=None, init=False)

    @property
    def flat(self) -> np.ndarray:
        """The layer as `(H·W, K)` rows (a view)."""
        h, w, k = self.layer.shape
        return self.layer.reshape(h * w, k)

    def band(self, a: int, b: int) -> np.ndarray:
        """Rows a … b (bottom-up) filled, `(b - a, W, K)`, a new array."""
        if self._rows != (a, b):
            self._band = None  # freed before the next one exists
            self._band, self._rows = self._filled(a, b), (a, b)
        assert self._band is not None
        return self._band

    def _filled(self, a: int, b: int) -> np.ndarray:
        """`Fill.apply`'s steps on the band's empty texels: the reached ones take their source's
        value (read from the unchanged layer, wherever it lies), the others the mean of all
        sources, then the black ones 0."""
        w, k = self.layer.shape[1], self.layer.shape[2]
        out = np.array(self.layer[a:b])
        rows = out.reshape(-1, k)
        lo, hi = _span(self.fill.empty, a * w, b * w)
        empty, source = self.fill.empty[lo:hi] - a * w, self.fill.source[lo:hi]
        reached = source >= 0
        rows[empty[reached]] = self.flat[source[reached]]
        if not reached.all():
            rows[empty[~reached]] = self.means()
        if self.keep_black:
            lo, hi = _span(self.fill.black, a * w, b * w)
            rows[self.fill.black[lo:hi] - a * w] = 0.0
        return out

    def means(self) -> np.ndarray:
        """Per channel the mean of the sources, float64 `(K,)` (0 without any): the value of the
        texels out of every source's reach, taken as `Fill.apply` takes it (a contiguous gather
        of one channel, then its mean)."""
        if self._means is None:
            k = self.layer.shape[2]
            valid = self.fill.valid
            self._means = np.array(
                [self.flat[:, c][valid].mean(dtype=np.float64) if len(valid) else 0.0 for c in range(k)]
            )
        return self._means


def _span(indices: np.ndarray, start: int, stop: int) -> tuple[int, int]:
    """Where the flat indices start … stop lie in the sorted `indices` (a `Fill`'s, made by
    flatnonzero). The bounds take the indices' dtype: numpy would otherwise convert the whole
    array to compare it (milliseconds per band at 4096²)."""
    lo, hi = np.searchsorted(indices, np.array([start, stop], indices.dtype))
    return int(lo), int(hi)


@dataclass(frozen=True, eq=False)
class FilledChannel(BandedImage):
    """Channel `k` of a `FilledLayer` as an `(H, W)` `BandedImage` for `exr.write_file`
    (`flipped`: rows reversed)."""

    layer: FilledLayer
    k: int
    flipped: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.layer.layer.shape[:2]
        return (h, w)

    @property
    def dtype(self) -> np.dtype:
        return self.layer.layer.dtype

    def _rows(self, a: int, b: int) -> np.ndarray:
        if not self.flipped:
            return self.layer.band(a, b)[:, :, self.k]
        h = self.shape[0]
        return self.layer.band(h - b, h - a)[::-1, :, self.k]


def filled_channels(layer: np.ndarray, fill: _dilate.Fill, keep_black: bool) -> list[FilledChannel]:
    """The K channels of `layer` `(H, W, K)` filled as `fill.apply` fills each, made a band at a
    time (one `FilledLayer` shared by them)."""
    shared = FilledLayer(layer, fill, keep_black)
    return [FilledChannel(shared, k) for k in range(layer.shape[2])]
