"""The compiled (numba) running statistics of `tracer.statistics`: one pass's SH estimate into
every texel's Welford sums (`add_pass`). No bpy. Nothing compiles until `get()` (`core.compiled`).
"""

from __future__ import annotations

from .. import compiled, sh

_IRRADZ_FROM_R10 = sh.IRRADZ_FROM_R10
#: I_z's band-1 factor along a normal, `sh.zonal_band1`; `get()` rebinds it to its compiled version.
zonal_band1 = sh.zonal_band1


def add_pass(idx, estimate, normals, luminance, total, m2, iz, iz_sq, passes):
    """One pass's SH estimate (len(idx), 9, C) into the running statistics of the texels idx
    (unique), in place: total += estimate; m2 (float32) += (x - mean before)·(x - mean after)
    (Welford, per coefficient; the first pass adds 0); iz / iz_sq += the estimate's I_z (`sh`:
    IRRADZ_FROM_R10 · zonal_band1) weighted by `luminance` (3,) and its square; passes += 1.
    C = 3 per light set: I_z is that of the sets' sum."""
    cols = estimate.shape[2]
    for j in range(idx.shape[0]):
        t = idx[j]
        k = passes[t]
        for m in range(9):
            for c in range(cols):
                x = estimate[j, m, c]
                before = total[t, m, c] / k if k > 0 else x
                total[t, m, c] += x
                m2[t, m, c] += (x - before) * (x - total[t, m, c] / (k + 1))
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        lum = 0.0
        for c in range(cols):
            r10 = zonal_band1(estimate[j, 1, c], estimate[j, 2, c], estimate[j, 3, c], nx, ny, nz)
            lum += luminance[c % 3] * _IRRADZ_FROM_R10 * r10
        iz[t] += lum
        iz_sq[t] += lum * lum
        passes[t] = k + 1


KERNELS = compiled.KernelSet(__name__, kernels=("add_pass",), helpers=("zonal_band1",))
get = KERNELS.get
