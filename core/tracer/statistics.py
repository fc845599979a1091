"""Running statistics of the pass estimates per texel, for the mean, its standard error and the
noise target. No bpy."""

from __future__ import annotations

import numpy as np

from .. import kernels as _kernels
from ..colour import LUMINANCE
from .settings import NOISE_FLOOR


class Statistics:
    """Per texel (each may have its own pass count): the SH sum (N, 9, C) float64, the SH's sum
    of squared deviations from the running mean (Welford; float32 is enough, being a sum of
    squares, not a difference of two), and the sum and square sum of I_z's luminance for the
    noise target: 336 bytes per texel and light set. normals (N, 3): the texels' n_v (I_z is
    taken along it); channels C: 3 per light set (the noise target takes the sets' sum)."""

    def __init__(self, n: int, normals: np.ndarray, channels: int = 3):
        self.normals = normals
        self.total = np.zeros((n, 9, channels))
        self.m2 = np.zeros((n, 9, channels), np.float32)
        self.iz = np.zeros(n)
        self.iz_sq = np.zeros(n)
        self.passes = np.zeros(n, dtype=np.int64)
        self.texel_passes = 0

    def add(self, idx: np.ndarray, estimate: np.ndarray) -> None:
        """Add one pass's estimate (len(idx), 9, C) for the texels idx (unique: a work unit's);
        compiled (`kernels.add_pass`): runs on the scheduling thread beside the tracing workers,
        where numpy was several times slower (the README has the figures)."""
        self.texel_passes += len(idx)
        _kernels.get().add_pass(
            np.asarray(idx, dtype=np.int64),
            estimate,
            self.normals,
            LUMINANCE,
            self.total,
            self.m2,
            self.iz,
            self.iz_sq,
            self.passes,
        )

    def converged(self, idx: np.ndarray, target: float, floor: float | None = None) -> np.ndarray:
        """(len(idx),) bool: the texels idx whose standard error of I_z is below the target
        (see BakeSettings.noise_target); `floor`: the I_z below which the target is absolute
        (default `self.floor()`)."""
        k = self.passes[idx].astype(np.float64)
        mean = self.iz[idx] / k
        var = np.maximum(self.iz_sq[idx] / k - mean * mean, 0.0) / np.maximum(k - 1.0, 1.0)
        if floor is None:
            floor = self.floor()
        ok = np.sqrt(var) <= target * np.maximum(mean, floor)
        return ok & np.isfinite(var)

    def floor(self) -> float:
        """NOISE_FLOOR × the mean I_z of the texels sampled so far (0 before any pass)."""
        sampled = self.passes > 0
        if not sampled.any():
            return 0.0
        return NOISE_FLOOR * max(float((self.iz[sampled] / self.passes[sampled]).mean()), 0.0)

    def result(self, chunk: int = 1 << 16):
        """(mean (N, 9, C) float64, its standard error (N, 9, C) float32), computed in place over
        the running statistics (spent afterwards), a chunk of texels at a time."""
        for s in range(0, len(self.passes), chunk):
            k = np.maximum(self.passes[s : s + chunk], 1).astype(np.float64)[:, None, None]
            self.total[s : s + chunk] /= k
            self.m2[s : s + chunk] /= k * np.maximum(k - 1.0, 1.0)  # variance of the mean
            np.sqrt(self.m2[s : s + chunk], out=self.m2[s : s + chunk])
        return self.total, self.m2
