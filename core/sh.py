"""Real L2 spherical harmonics in the project's convention. No bpy.

Basis (docs/conventions.md#sh-basis): 9 coefficients in (l, m) order
    (0,0),(1,-1),(1,0),(1,1),(2,-2),(2,-1),(2,0),(2,1),(2,2),
    Y1 ∝ (-y, z, -x),  Y2 ∝ (xy, -yz, 3z²-1, -xz, x²-y²),
orthonormal over the sphere: the real SH with the Condon–Shortley phase (`sh_reference` builds
them from associated Legendre functions and the tests compare).

Array conventions: directions `(N, 3)` unit vectors; SH `(N, 9, C)` (C colour channels, usually
3) or `(N, 9)`; the coefficient axis is axis 1. Stored SH is *radiance*; irradiance uses the
normalisation of docs/conventions.md#irradiance-units, E(n) = (1/π) ∫ L(ω) max(n·ω, 0) dω, so
that a white diffuse surface under radiance 1 has E = 1, and radiance SH becomes irradiance SH by
scaling bands by 1, 2/3, 1/4.
"""

from __future__ import annotations

import numpy as np

N_COEFFS = 9
#: band l of each coefficient
BAND = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])

# Normalisation constants, from ∫_S Y² = 1.
Y00 = 0.5 / np.sqrt(np.pi)  # 0.282095
C1 = np.sqrt(3.0 / (4.0 * np.pi))  # 0.488603  (band 1)
C2 = 0.5 * np.sqrt(15.0 / np.pi)  # 1.092548  (xy, yz, xz)
C20 = 0.25 * np.sqrt(5.0 / np.pi)  # 0.315392  (3z² - 1)
C22 = 0.25 * np.sqrt(15.0 / np.pi)  # 0.546274  (x² - y²)

#: Per-band factors turning radiance SH into irradiance SH (normalised clamped-cosine
#: convolution, Ramamoorthi & Hanrahan 2001 divided by π): 1, 2/3, 1/4.
COSINE_BAND_FACTORS = (1.0, 2.0 / 3.0, 0.25)
COSINE_KERNEL = np.array([COSINE_BAND_FACTORS[l] for l in BAND])


#: I_z of radiance SH sampled over the hemisphere of n only (zero below): I_z = (1/π)∫_{Ω+} L cosθ dω
#: = 2/√(3π) · r_1^0, r_1^0 the zonal band-1 coefficient in n's frame (`zonal_band1`); exact
#: whatever the truncation, cosθ lying in band 1's span.
IRRADZ_FROM_R10 = 2.0 / np.sqrt(3.0 * np.pi)


def basis(x, y, z):
    """The 9 basis values at the unit direction (x, y, z), as a tuple. Plain arithmetic on its
    arguments (floats, or arrays of one shape, the first value then being a float), so numba
    compiles it for the tracer's kernels (`hemisphere_kernels.sh_basis`) and `evaluate` uses it on arrays."""
    return (
        Y00,
        -C1 * y,
        C1 * z,
        -C1 * x,
        C2 * x * y,
        -C2 * y * z,
        C20 * (3.0 * z * z - 1.0),
        -C2 * x * z,
        C22 * (x * x - y * y),
    )


def zonal_band1(s1m1, s10, s11, nx, ny, nz):
    """r_1^0 in the frame whose z is the unit n: v·n with v = (-r_1^1, -r_1^-1, r_1^0), from the
    world-space band-1 coefficients r_1^-1, r_1^0, r_1^1. Plain arithmetic (floats or arrays;
    numba compiles it for `statistics_kernels.add_pass`)."""
    return -s11 * nx - s1m1 * ny + s10 * nz


def hemisphere_irradz(sh: np.ndarray, n: np.ndarray) -> np.ndarray:
    """I_z at unit n `(N, 3)` of world-space radiance SH `(N, 9, C)` sampled over n's hemisphere
    only: IRRADZ_FROM_R10 · r_1^0 -> `(N, C)`."""
    return IRRADZ_FROM_R10 * zonal_band1(sh[:, 1], sh[:, 2], sh[:, 3], n[:, 0:1], n[:, 1:2], n[:, 2:3])


def evaluate(dirs: np.ndarray) -> np.ndarray:
    """Basis values Y(ω) for unit directions `dirs (N, 3)` -> `(N, 9)` float64 (`basis`)."""
    d = np.asarray(dirs, dtype=np.float64)
    return np.stack(np.broadcast_arrays(*basis(d[..., 0], d[..., 1], d[..., 2])), axis=-1)


def _as_nkc(sh: np.ndarray) -> np.ndarray:
    """View `(N, 9)` SH as `(N, 9, 1)`; `(N, 9, C)` passes through."""
    sh = np.asarray(sh)
    return sh[..., None] if sh.ndim == 2 else sh


def project(dirs: np.ndarray, values: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Σ_k w_k v_k Y(ω_k): project weighted samples onto the basis.

    dirs `(S, 3)`, values `(S,)` or `(S, C)`, weights `(S,)` (e.g. 1/(S·pdf) for a Monte Carlo
    estimate of ∫ v Y dω). Returns `(9,)` or `(9, C)`.
    """
    y = evaluate(dirs)
    w = np.ones(len(y)) if weights is None else np.asarray(weights, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    return np.einsum("sk,s...->k...", y * w[:, None], v)


def convolve_cosine(sh: np.ndarray) -> np.ndarray:
    """Radiance SH -> irradiance SH (bands × 1, 2/3, 1/4). Same shape as the input."""
    sh = np.asarray(sh, dtype=np.float64)
    kernel = COSINE_KERNEL if sh.ndim == 1 else COSINE_KERNEL.reshape((1, 9) + (1,) * (sh.ndim - 2))
    return sh * kernel


def evaluate_sh(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Value of the SH function at one direction per row: `(N,9,C), (N,3) -> (N,C)`."""
    return np.einsum("nk,nkc->nc", evaluate(dirs), _as_nkc(sh))


def irradiance(radiance_sh: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance E(n) (docs/conventions.md#irradiance-units) of radiance SH at normals:
    `(N,9,C), (N,3) -> (N,C)`."""
    return evaluate_sh(convolve_cosine(_as_nkc(radiance_sh)), normals)


def tangent_frames(normals: np.ndarray) -> np.ndarray:
    """Orthonormal frames `(N, 3, 3)` whose columns are (t, b, n), right-handed, z = n.

    Branchless construction of Duff et al. 2017 ("Building an Orthonormal Basis, Revisited"):
    continuous everywhere except n = -z, exact for n = ±z.
    """
    n = np.asarray(normals, dtype=np.float64)
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=-1)
    bt = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=-1)
    return np.stack([t, bt, n], axis=-1)


# Band 2 as quadratic forms: Σ_m s_m Y2m(ω) = ωᵀ Q ω with Q traceless symmetric.
def _band2_to_quadratic(s) -> dict:
    """Band-2 coefficients (5 arrays) -> entries of the traceless symmetric Q with
    Σ_m s_m Y2m(ω) = ωᵀ Q ω, as {(i, j): array} for i ≤ j."""
    return {
        (0, 1): 0.5 * C2 * s[0],
        (1, 2): -0.5 * C2 * s[1],
        (0, 2): -0.5 * C2 * s[3],
        (0, 0): -C20 * s[2] + C22 * s[4],
        (1, 1): -C20 * s[2] - C22 * s[4],
        (2, 2): 2.0 * C20 * s[2],
    }


def rotate(sh: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Coefficients of g(ω) = f(M ω) for per-row rotations M `(N, 3, 3)`; sh `(N, 9, C)` or `(N, 9)`.

    Band 1 is a linear form C1·v·ω with v = (-s₃, -s₁, s₂), so v' = Mᵀv; band 2 is a quadratic
    form ωᵀQω, so Q' = MᵀQM. Exact for any orthogonal M, vectorised over rows. The sums over
    the 3×3 indices are written out on contiguous per-coefficient arrays: numpy's batched 3×3
    products and strided slices are several times slower.
    """
    sh = np.asarray(sh, dtype=np.float64)
    s = np.ascontiguousarray(np.moveaxis(_as_nkc(sh), 1, 0))  # (9, N, C)
    mt = np.ascontiguousarray(np.asarray(m, dtype=np.float64).transpose(1, 2, 0))[..., None]  # (3,3,N,1)
    v = (-s[3], -s[1], s[2])
    v2 = [mt[0, j] * v[0] + mt[1, j] * v[1] + mt[2, j] * v[2] for j in range(3)]  # Mᵀ v
    qd = _band2_to_quadratic(s[4:9])
    q = [[qd[(min(a, b), max(a, b))] for b in range(3)] for a in range(3)]
    mq = [[q[a][0] * mt[0, j] + q[a][1] * mt[1, j] + q[a][2] * mt[2, j] for j in range(3)] for a in range(3)]

    def q2(i, j):  # (MᵀQM)_ij
        return mt[0, i] * mq[0][j] + mt[1, i] * mq[1][j] + mt[2, i] * mq[2][j]

    out = np.stack(
        [
            s[0],
            -v2[1],
            v2[2],
            -v2[0],
            2.0 * q2(0, 1) / C2,
            -2.0 * q2(1, 2) / C2,
            q2(2, 2) / (2.0 * C20),
            -2.0 * q2(0, 2) / C2,
            (q2(0, 0) - q2(1, 1)) / (2.0 * C22),
        ],
        axis=1,
    )
    return out[..., 0] if sh.ndim == 2 else out


def to_local(sh: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """World-space SH -> SH in each row's frame (columns t, b, n of `frames (N,3,3)`; z = n)."""
    return rotate(sh, frames)


def to_world(sh_local: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Inverse of `to_local`."""
    return rotate(sh_local, np.swapaxes(frames, 1, 2))
