"""Running statistics of the pass estimates per texel, for the mean, its standard error and the
noise target. No bpy."""

from __future__ import annotations

import numpy as np

from ..colour import LUMINANCE
from ..memory import releasable_zeros
from . import statistics_kernels as _kernels
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
        compiled (`statistics_kernels.add_pass`): runs on the scheduling thread beside the tracing workers,
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

    def view(self, first: int, end: int) -> Statistics:
        """The statistics of texels first..end as views of these arrays (writing to it writes here)."""
        part = Statistics.__new__(Statistics)
        part.normals = self.normals[first:end]
        for key in ("total", "m2", "iz", "iz_sq", "passes"):
            setattr(part, key, getattr(self, key)[first:end])
        part.texel_passes = 0
        return part

    def result(self, chunk: int = 1 << 16):
        """(mean (N, 9, C) float64, its standard error (N, 9, C) float32), computed in place over
        the running statistics (spent afterwards), a chunk of texels at a time."""
        for s in range(0, len(self.passes), chunk):
            k = np.maximum(self.passes[s : s + chunk], 1).astype(np.float64)[:, None, None]
            self.total[s : s + chunk] /= k
            self.m2[s : s + chunk] /= k * np.maximum(k - 1.0, 1.0)  # variance of the mean
            np.sqrt(self.m2[s : s + chunk], out=self.m2[s : s + chunk])
        return self.total, self.m2


def finished(stats: Statistics, buried: np.ndarray, sets: bool):
    """The traced SH of finished statistics `stats` (spent: computed in place): (sh (N, 9, 3)
    float64, 0 where `buried`; its standard error (N, 9, 3) float32; with light `sets` (C = 3K
    channels), set_sh (K, N, 9, 3) float64 and set_sh_error (K, N, 9, 3) float32, else None, None).
    With sets, sh is their sum and sh_error the sum of their errors (as if fully correlated: they
    share their paths). Per texel: the same numbers for a whole atlas or any part of it."""
    sh, sh_error = stats.result()
    sh[buried] = 0.0
    set_sh = set_sh_error = None
    if sets:
        set_sh, set_sh_error = _per_set(sh), _per_set(sh_error)
        sh, sh_error = set_sh.sum(axis=0), set_sh_error.sum(axis=0)
    return sh, sh_error, set_sh, set_sh_error


def _per_set(a: np.ndarray) -> np.ndarray:
    """`(N, 9, 3K)` statistics → `(K, N, 9, 3)`, one block per light set."""
    n, m, c = a.shape
    return np.ascontiguousarray(a.reshape(n, m, c // 3, 3).transpose(2, 0, 1, 3))


class Reduced:
    """Finished statistics reduced to what an atlas's files take (`TracedAtlas` compact), filled
    a part at a time (`take`) so that full statistics need exist only for that part: per texel
    the SH mean as float32 (sh (N, 9, 3); the files hold float32 of the float64 mean, so these are
    their bits), the standard error of band 0 only (sh_error (N, 1, 3) float32: the luminance
    L0's, `TracedAtlas.noise`, is all the files and the denoiser read) and the passes (int32); with
    light sets the same per set (set_sh (K, N, 9, 3), set_sh_error (K, N, 1, 3)). 124 bytes per
    texel without sets, against the 348 of `Statistics`. normals (N, 3), channels, buried (N,) bool:
    as `Statistics` and `finished` take them."""

    def __init__(self, normals: np.ndarray, channels: int, buried: np.ndarray, sets: bool):
        n = len(normals)
        self.normals, self.channels, self.buried, self.sets = normals, channels, buried, sets
        # the atlas's SH and error freed a part at a time as they are imaged (`TexelData.from_traced`)
        self.sh = releasable_zeros((n, 9, 3), np.float32)
        self.sh_error = releasable_zeros((n, 1, 3), np.float32)
        k = channels // 3
        # plain memory: the sets' SH is only read (`bake.finishing.finish_atlas`, a farm worker's fallback)
        self.set_sh = np.zeros((k, n, 9, 3), np.float32) if sets else None
        self.set_sh_error = np.zeros((k, n, 1, 3), np.float32) if sets else None
        self.passes = np.zeros(n, dtype=np.int32)  # the files' texel samples: 4 bytes are plenty
        self.texel_passes = 0

    def statistics(self, first: int, end: int) -> Statistics:
        """Empty running statistics for texels first..end (indices from 0 = texel `first`)."""
        return Statistics(end - first, self.normals[first:end], self.channels)

    def take(self, first: int, stats: Statistics) -> None:
        """Reduce the finished statistics `stats` of texels first..first + len (spent) into these."""
        end = first + len(stats.passes)
        self.passes[first:end] = stats.passes
        self.texel_passes += stats.texel_passes
        sh, sh_error, set_sh, set_sh_error = finished(stats, self.buried[first:end], self.sets)
        self.sh[first:end] = sh
        self.sh_error[first:end] = sh_error[:, :1]
        if self.set_sh is not None and self.set_sh_error is not None:
            assert set_sh is not None and set_sh_error is not None
            self.set_sh[:, first:end] = set_sh
            self.set_sh_error[:, first:end] = set_sh_error[:, :, :1]

    def take_all(self, stats: Statistics, chunk: int = 1 << 16) -> None:
        """Reduce the finished statistics of every texel (spent), a chunk of texels at a time."""
        for s in range(0, len(stats.passes), chunk):
            self.take(s, stats.view(s, s + chunk))
        self.texel_passes = stats.texel_passes
