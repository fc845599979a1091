"""The compiled (numba) recursion of `textures.bspline_coefficients`: a symmetric FIR kernel's
inverse along each row of an image, one first-order causal and anti-causal pass per pole. No
bpy. Nothing compiles until `get()` (`core.compiled`)."""

from __future__ import annotations

from . import compiled


def deconvolve_rows(x, first, last, poles, horizons, gain):
    """Rows `first` … `last − 1` of `x` `(N, M)` float64, in place, convolved along the row with
    the inverse of the symmetric kernel whose poles (|z| < 1) are `poles` `(P,)` and whose gain
    is `gain` (Π (1 − z)(1 − 1/z)), the row mirrored (whole-sample) at both ends; the causal
    start sums `horizons` `(P,)` terms (z^horizon below the float64 epsilon)."""
    m = x.shape[1]
    for j in range(first, last):
        row = x[j]
        for k in range(m):
            row[k] *= gain
        if m == 1:
            continue
        for p in range(poles.shape[0]):
            z = poles[p]
            s, zk = 0.0, 1.0
            for k in range(horizons[p]):
                s += zk * row[k]
                zk *= z
            row[0] = s
            for k in range(1, m):
                row[k] += z * row[k - 1]
            row[m - 1] = (z / (z * z - 1.0)) * (row[m - 1] + z * row[m - 2])
            for k in range(m - 2, -1, -1):
                row[k] = z * (row[k + 1] - row[k])


def deconvolve_columns(x, first, last, poles, horizons, gain):
    """`deconvolve_rows` along the columns `first` … `last − 1` of `x` `(N, M)`: the recursion
    steps down the rows, each step over the columns' stretch of a row (contiguous)."""
    n = x.shape[0]
    for k in range(n):
        for j in range(first, last):
            x[k, j] *= gain
    if n == 1:
        return
    for p in range(poles.shape[0]):
        z = poles[p]
        for j in range(first, last):
            s, zk = 0.0, 1.0
            for k in range(horizons[p]):
                s += zk * x[k, j]
                zk *= z
            x[0, j] = s
        for k in range(1, n):
            for j in range(first, last):
                x[k, j] += z * x[k - 1, j]
        for j in range(first, last):
            x[n - 1, j] = (z / (z * z - 1.0)) * (x[n - 1, j] + z * x[n - 2, j])
        for k in range(n - 2, -1, -1):
            for j in range(first, last):
                x[k, j] = z * (x[k + 1, j] - x[k, j])


KERNELS = compiled.KernelSet(__name__, kernels=("deconvolve_rows", "deconvolve_columns"))
get = KERNELS.get
