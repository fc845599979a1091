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
#: is too often a small fraction of the true error (tracer.settings.MIN_ADAPTIVE_PASSES has the figures).
NOISE_PASSES = 4


@dataclass
class TracedAtlas:
    """One atlas's traced radiance, compact over its P covered texels (order of `points.texel`).

    points: the BakePoints it was traced at (per-texel and per-triangle arrays, picklable);
    sh (P, 9, 3) float64: world-space radiance L2 SH over the hemisphere of n_v (DESIGN.md),
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
        their paths); NaN for texels of fewer than NOISE_PASSES passes."""
        per_pass = self.samples // self.passes if self.passes else 1
        error = self.sh_error[:, 0, :].astype(np.float64) @ LUMINANCE
        return np.where(self.texel_samples >= NOISE_PASSES * per_pass, error, np.nan).astype(np.float32)

    def release_sh(self) -> None:
        """Drop `sh` and `sh_error` (they become empty `(0, 9, 3)` arrays) once imaged: a bake's
        largest arrays, freed before the post stages unless another reference holds them."""
        self.sh = np.zeros((0, 9, 3))
        self.sh_error = np.zeros((0, 9, 3), np.float32)

    def release_points(self) -> None:
        """Drop `points` (None from then on) once the atlas's last image is made (`bake.finish_atlas`
        with `release`): the bake points are as large as the traced SH."""
        self.points = None  # type: ignore[assignment]

    def with_sh(self, sh: np.ndarray, sh_error: np.ndarray | None = None) -> TracedAtlas:
        """A copy carrying new SH (and standard error) for the same texels, without light sets."""
        error = self.sh_error if sh_error is None else sh_error
        return replace(self, sh=sh, sh_error=error, sets=(), set_sh=None, set_sh_error=None)

    def light_set(self, k: int) -> TracedAtlas:
        """The atlas as traced for light set k alone (`sets[k]`): its SH and standard error."""
        assert self.set_sh is not None and self.set_sh_error is not None, "an atlas traced without light sets"
        return self.with_sh(self.set_sh[k], self.set_sh_error[k])
