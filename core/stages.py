"""The data handed from one bake stage to the next. No bpy.

    bake points ─trace─▶ TracedAtlas ─image─▶ TexelData ─[post stages]─▶ TexelData ─encode─▶ EncodedAtlas ─write─▶ files

Every hand-off is plain numpy data (picklable, no live Embree object), so a stage can run in
another process or on another machine. The post stages (a denoiser, seam stitching; `core.post`)
work on the texel images, so a re-encode from the raw SH file can run them too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from .colour import LUMINANCE

if TYPE_CHECKING:  # bakepoints imports the compiled kernels; the data types need no import at run time
    from .bakepoints import BakePoints


#: Passes before a texel's spread counts as its noise (`TracedAtlas.noise`): the spread of fewer
#: is too often a small fraction of the true error (tracer.settings.MIN_ADAPTIVE_PASSES has the figures);
#: at least 4: `TracedAtlas.noise` widens the spread by √(ν / (ν − 2)), ν = passes − 1.
NOISE_PASSES = 4


@dataclass
class TracedAtlas:
    """One atlas's traced radiance, compact over its P covered texels (order of `points.texel`).

    points: the BakePoints it was traced at (per-texel and per-triangle arrays, picklable);
    sh (P, 9, 3) float64: world-space radiance L2 SH over the hemisphere of n_v
    (docs/conventions.md#what-the-sh-store),
    0 for buried texels; sh_error (P, 9, 3) float32: standard error of `sh` from the spread
    between passes (0 where every pass agrees, or after a single pass); texel_samples (P,) int:
    hemisphere samples each texel took (they differ under a noise target or a time budget).
    Light sets (`core.light_sets`): sets, the set names (() without light groups); set_sh
    (K, P, 9, 3) float64 and set_sh_error (K, P, 9, 3) float32, each set's SH and its standard
    error (None without sets); `sh` is then their sum, `sh_error` the sum of their errors.
    Run statistics: samples (the most a texel took), passes, rays traced, seconds of wall time,
    stopped_by ("samples", "noise_target": every texel converged, "time_budget"), threads.

    Compact (`tracer.bake(..., compact=True)`, as `bake.run` traces): sh and set_sh are float32
    (the float32 of the float64 mean: the bits the files hold) and sh_error, set_sh_error hold
    band 0 only, (P, 1, 3) and (K, P, 1, 3): all that `noise` and the files read."""

    points: BakePoints
    sh: np.ndarray
    sh_error: np.ndarray
    texel_samples: np.ndarray
    samples: int = 0
    passes: int = 0
    rays: int = 0
    seconds: float = 0.0
    stopped_by: str = "samples"
    threads: int = 1
    sets: tuple[str, ...] = ()
    set_sh: np.ndarray | None = None
    set_sh_error: np.ndarray | None = None

    @property
    def valid(self) -> np.ndarray:
        """(P,) bool: texels with a bake value of their own (not buried under geometry)."""
        return np.logical_not(self.points.buried)

    @property
    def mean_samples(self) -> float:
        return float(self.texel_samples.mean()) if len(self.texel_samples) else 0.0

    def noise(self) -> np.ndarray:
        """(P,) float32: the standard error of each texel's luminance L0 (radiance), the colours'
        standard errors summed with the luminance weights (as if fully correlated: they share
        their paths), widened for the uncertainty of its own estimate: the spread of a texel's
        p passes estimates it with ν = p − 1 degrees of freedom, the traced value's error over
        that estimate is Student-t distributed, and its standard deviation is √(ν / (ν − 2))
        times the estimate (1.73 at NOISE_PASSES passes, 1.07 at 16). NaN for texels of fewer
        than NOISE_PASSES passes."""
        per_pass = self.samples // self.passes if self.passes else 1
        error = self.sh_error[:, 0, :].astype(np.float64) @ LUMINANCE
        dof = self.texel_samples // max(per_pass, 1) - 1.0
        known = dof >= NOISE_PASSES - 1
        nu = np.maximum(dof, NOISE_PASSES - 1.0)  # > 2 (the unknown texels' value is not used)
        return np.where(known, error * np.sqrt(nu / (nu - 2.0)), np.nan).astype(np.float32)

    def with_sh(self, sh: np.ndarray, sh_error: np.ndarray | None = None) -> TracedAtlas:
        """A copy carrying new SH (and standard error) for the same texels, without light sets."""
        error = self.sh_error if sh_error is None else sh_error
        return replace(self, sh=sh, sh_error=error, sets=(), set_sh=None, set_sh_error=None)

    def light_set(self, k: int) -> TracedAtlas:
        """The atlas as traced for light set k alone (`sets[k]`): its SH and standard error."""
        assert self.set_sh is not None and self.set_sh_error is not None, "an atlas traced without light sets"
        return self.with_sh(self.set_sh[k], self.set_sh_error[k])


@dataclass(frozen=True)
class Window:
    """Where an atlas's texel images lie when they are not the whole atlas (`TexelData.window`):
    rows y0 … y0 + h and columns x0 … x0 + w (rows bottom-up) of an `atlas` (height, width) whose
    every texel outside them holds one value per image (an almost empty atlas: memory and time
    follow its texels, not its area; `encoding.stage.window_of`)."""

    y0: int
    x0: int
    h: int
    w: int
    atlas: tuple[int, int]

    def local(self, texel: np.ndarray) -> np.ndarray:
        """Flat atlas indices (row · width + column) → flat indices in the window."""
        width = self.atlas[1]
        return (texel // width - self.y0) * self.w + (texel % width - self.x0)


#: Largest finite half-float value.
HALF_MAX = 65504.0


def fits_half(values: np.ndarray) -> bool:
    """True when every finite value is within the half-float range (so nothing would clip to
    infinity). Values below half's precision lose bits but not range: that is not clipping.
    An image that knows (`stages.PlacedImage`: an almost empty atlas's) is asked."""
    if hasattr(values, "fits_half"):
        return values.fits_half()
    finite = np.asarray(values)[np.isfinite(values)]
    return finite.size == 0 or float(np.abs(finite).max()) <= HALF_MAX


class BandedImage:
    """An `(H, W)` image the EXR writer (`exr.write_file`) takes a band of rows at a time, without
    the whole image ever existing: `[a:b]` gives those rows (an ndarray), `[::-1]` the image with
    its rows reversed (EXR's top-down order), `astype` to its own dtype without a copy is itself,
    `np.asarray` makes it whole. Each kind is a dataclass with a field `flipped` (rows reversed)
    and gives `shape`, `dtype` and `_rows`."""

    flipped: bool

    @property
    def shape(self) -> tuple[int, int]:
        raise NotImplementedError

    @property
    def dtype(self) -> np.dtype:
        raise NotImplementedError

    def _rows(self, a: int, b: int) -> np.ndarray:
        """Rows a … b (a ≤ b) in this image's order, `(b - a, W)`: a new array or a view of one."""
        raise NotImplementedError

    @property
    def ndim(self) -> int:
        return 2

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    def __len__(self) -> int:
        return self.shape[0]

    def astype(self, dtype, copy: bool = True):
        if np.dtype(dtype) == self.dtype and not copy:
            return self
        return np.asarray(self).astype(dtype)

    def __getitem__(self, key):
        """`[::-1]` (this image, rows reversed) or `[a:b]` (those rows, an ndarray)."""
        kind = type(self).__name__
        if not isinstance(key, slice):
            raise TypeError(f"a {kind} takes a slice of rows, not {key!r}")
        if key == slice(None, None, -1):
            return replace(self, flipped=not self.flipped)  # type: ignore[type-var]  # every kind is a dataclass
        start, stop, step = key.indices(self.shape[0])
        if step != 1:
            raise ValueError(f"a {kind} gives rows in order or reversed only")
        return self._rows(start, max(stop, start))

    def __array__(self, dtype=None, copy=None):
        whole = np.ascontiguousarray(self[0 : self.shape[0]])
        return whole if dtype is None else whole.astype(dtype, copy=False)


@dataclass
class PlacedImage(BandedImage):
    """A full-size `(H, W)` image of one value, `background`, but for the rows and columns of
    `window`, which hold `inner` `(h, w)` (any strides: a view of a TexelData's or a layer's
    window image). What the files of an almost empty atlas are made of: a `BandedImage`, whose
    `astype` stores it as small. `flipped`: rows reversed (row 0 is the atlas's top)."""

    inner: np.ndarray
    window: Window
    background: np.ndarray  # 0-d, of inner's dtype
    flipped: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        return self.window.atlas

    @property
    def dtype(self) -> np.dtype:
        return self.inner.dtype

    def astype(self, dtype, copy: bool = True) -> PlacedImage:
        if np.dtype(dtype) == self.dtype and not copy:
            return self
        background = np.asarray(self.background).astype(dtype)
        return replace(self, inner=self.inner.astype(dtype, copy=copy), background=background)

    def zeros(self) -> PlacedImage:
        """An image of zeros of this one's shape and dtype (as np.zeros_like), as small."""
        z = np.zeros((), self.dtype)
        return PlacedImage(np.broadcast_to(z, self.inner.shape), self.window, z, self.flipped)

    def fits_half(self) -> bool:
        """Whether every finite value fits a half float (`fits_half`)."""
        return fits_half(self.inner) and fits_half(np.asarray(self.background).reshape(1))

    def _rows(self, a: int, b: int) -> np.ndarray:
        out = np.full((b - a, self.shape[1]), self.background, self.dtype)
        w = self.window
        # the window's rows in this image's order (flipped: atlas row y is row h - 1 - y)
        first = self.shape[0] - w.y0 - w.h if self.flipped else w.y0
        lo, hi = max(a, first), min(b, first + w.h)
        if lo < hi:
            rows = (
                self.inner[lo - first : hi - first] if not self.flipped else self.inner[::-1][lo - first : hi - first]
            )
            out[lo - a : hi - a, w.x0 : w.x0 + w.w] = rows
        return out


def placed(inner: np.ndarray, window: Window | None, background) -> np.ndarray | PlacedImage:
    """`inner` itself without a window (it is the whole atlas), else the `PlacedImage` of it with
    `background` (cast to its dtype) everywhere else."""
    if window is None:
        return inner
    return PlacedImage(inner, window, np.asarray(background).astype(inner.dtype))
