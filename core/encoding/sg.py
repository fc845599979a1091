"""Spherical Gaussian lightmaps (Baking Lab's SG5 / SG6 / SG9 / SG12): fixed lobes, three
solves, irradiance and GGX specular per lobe. The math the `sg5` … `sg12` modules share. No bpy.

A lobe is G(ω) = a exp(λ (μ·ω − 1)): amplitude a (RGB radiance, stored), axis μ and sharpness
λ fixed per layout, in the tangent frame of n_v (`basis.frames`). **Layout** (`layout(K)`,
Baking Lab's `GenerateUniformSGs`): 2K points of a Fibonacci sphere, z_k = (k + ½)/K − 1,
φ_k = k π (3 − √5), (x, y) = √(1 − z²)(cos φ, sin φ); the K with z ≥ 0 (k = K … 2K − 1) are the
axes; λ = K ln(0.65) / (μ_0·h − 1), h = normalize(μ_0 + μ_1) (the two first axes).

**Samples.** The texel's radiance is not kept per sample by the tracer: the solves fit the
radiance *reconstructed from the traced L2 SH* at SAMPLES fixed directions of the hemisphere
(`basis.fibonacci_hemisphere`, equal solid angle 2π/SAMPLES each), b = Y s. So an SG fit can
hold no more angular detail than L2 SH holds: it re-shapes L2's information (no ringing below
zero with NNLS, a cheaper specular) rather than adding to it. Baking Lab fits the path tracer's
own samples instead.

**Solves** (`EncoderSettings.solve`), each linear in the SH except NNLS:
  * "adhoc": Baking Lab's projection as if the lobes were orthogonal,
    a_k = c_K ∫_{Ω+} L G_k [μ_k·ω > 0] dω (by the samples), times c_K: Baking Lab's raw sum is
    not normalised (uniform radiance 1 gives I(n_v) of 2.0 (SG5) … 1.09 (SG12)), so c_K makes
    uniform radiance reconstruct I(n_v) = 1 exactly (`adhoc_scale`);
  * "ls": least squares over the samples, a = A⁺ b (A_sk = exp(λ(μ_k·ω_s − 1)));
  * "nnls": the same with a ≥ 0 (per texel and colour; `nnls`: vectorised projected
    coordinate descent, then the exact solution on the found active set, checked by its KKT
    conditions).

**Reconstruction** (Baking Lab's defaults): irradiance per lobe by Stephen Hill's fitted
cosine-lobe convolution (`SGIrradianceFitted`), divided by π for the project's unit; specular per
lobe by the anisotropic-warp approximation (`SpecularTermASGWarp`): the GGX NDF as an SG
(λ = 2/α², a = 1/(π α²)), warped to an ASG around the reflection of v, convolved with the lobe,
times Smith visibility, Schlick Fresnel and n·l at the warped axis.

**Specular normalisation** (opt-in, `SGBasis(..., specular_norm="uniform")`; the default "none"
is Baking Lab's sum above). With w_k ≥ 0 the warp's weight of lobe k at (n, v) (the specular
of lobe k with amplitude 1) and u the layout's uniform radiance (`uniform_amplitudes`: the least-squares
amplitudes of radiance 1 at the sample directions), the sum is rescaled so that u reflects
exactly the GGX directional albedo E(n·v, α, F0) (`ggx` table, the GgxAlbedo table HHD's
specular reads):

    S = Σ_k max(w_k a_k, 0) · E / Σ_k w_k u_k          (0 where Σ_k w_k u_k = 0)

i.e. the warp serves only as the filter that averages the radiance over the lobe (a split sum)
and E gives the magnitude. Its error against quadrature: bench/results/sg_specular.md.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from .. import sh as _sh
from . import ggx
from .basis import CoefficientEncoding, fibonacci_hemisphere, frames, layers
from .spec import FileSpec

SOLVES = ("adhoc", "ls", "nnls")
#: Specular normalisations (module docstring): Baking Lab's plain sum, or rescaled by uniform radiance.
SPECULAR_NORMS = ("none", "uniform")
#: Radiance samples per texel the solves fit (from the L2 SH).
SAMPLES = 256
#: NNLS: coordinate-descent sweeps between active-set polishes, and polish rounds at most.
NNLS_SWEEPS, NNLS_ROUNDS = 8, 40


@cache
def layout(count: int) -> tuple[np.ndarray, float]:
    """Axes `(count, 3)` (tangent frame, unit, z ≥ 0) and the sharpness λ of Baking Lab's layout."""
    n = 2 * count
    k = np.arange(n)
    z = (k + 0.5) * (2.0 / n) - 1.0
    r = np.sqrt(1.0 - z * z)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    pts = np.stack([np.cos(phi) * r, np.sin(phi) * r, z], -1)
    axes = pts[z >= 0.0]
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    h = axes[0] + axes[1]
    h = h / np.linalg.norm(h)
    return axes, float(count * np.log(0.65) / (h @ axes[0] - 1.0))


def sample_directions() -> np.ndarray:
    return fibonacci_hemisphere(SAMPLES)


@cache
def design(count: int) -> np.ndarray:
    """A `(SAMPLES, count)`: lobe k (amplitude 1) at sample direction s."""
    axes, lam = layout(count)
    return np.exp(lam * (sample_directions() @ axes.T - 1.0))


@cache
def sample_sh() -> np.ndarray:
    """Y `(SAMPLES, 9)`: the SH basis at the sample directions (b = Y s)."""
    return _sh.evaluate(sample_directions())


def _hill_irradiance(cos_mu_n: np.ndarray, lam: float) -> np.ndarray:
    """∫ exp(λ(μ·ω − 1)) max(n·ω, 0) dω (Hill's fit, Baking Lab `SGIrradianceFitted`), unit amplitude."""
    c0 = 0.36
    c1 = 1.0 / (4.0 * c0)
    eml = np.exp(-lam)
    em2l = eml * eml
    rl = 1.0 / lam
    scale = 1.0 + 2.0 * em2l - rl
    bias = (eml - em2l) * rl - em2l
    x = np.sqrt(1.0 - scale)
    x0 = c0 * cos_mu_n
    x1 = c1 * x
    y = np.where(np.abs(x0) <= x1, (x0 + x1) ** 2 / x, np.clip(cos_mu_n, 0.0, 1.0))
    return (scale * y + bias) * 2.0 * np.pi / lam


@cache
def adhoc_matrix(count: int) -> np.ndarray:
    """`(count, 9)`: SH -> ad-hoc amplitudes (normalised by ADHOC_SCALE)."""
    axes, lam = layout(count)
    a = design(count) * (sample_directions() @ axes.T > 0.0)
    raw = (2.0 * np.pi / SAMPLES) * a.T
    return adhoc_scale(count) * raw @ sample_sh()


@cache
def adhoc_scale(count: int) -> float:
    """c_K: 1 / I(n_v) of Baking Lab's raw projection of uniform radiance 1 (its samples)."""
    axes, lam = layout(count)
    a = design(count) * (sample_directions() @ axes.T > 0.0)
    amp = (2.0 * np.pi / SAMPLES) * a.sum(axis=0)
    return float(1.0 / (amp @ _hill_irradiance(axes[:, 2], lam) / np.pi))


@cache
def uniform_amplitudes(count: int) -> np.ndarray:
    """u `(count,)`: the least-squares amplitudes of uniform radiance 1 at the sample directions
    (A⁺ 1), what the specular normalisation rescales by (module docstring)."""
    return np.linalg.pinv(design(count)) @ np.ones(SAMPLES)


@cache
def ls_matrix(count: int) -> np.ndarray:
    """`(count, 9)`: SH -> least-squares amplitudes, A⁺ Y."""
    return np.linalg.pinv(design(count)) @ sample_sh()


def nnls(q: np.ndarray, c: np.ndarray, start: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """min_a ½ aᵀ q a − cᵀ a subject to a ≥ 0, for each row of c `(B, K)` with one positive
    definite q `(K, K)` (the Gram form of min |A a − b|², q = AᵀA, c = Aᵀb) -> a `(B, K)` and
    the count of rows whose KKT check failed after NNLS_ROUNDS (their a is the last projected
    coordinate-descent iterate). Vectorised over rows."""
    b, k = c.shape
    a = np.zeros((b, k)) if start is None else np.maximum(start, 0.0)
    out = np.zeros((b, k))
    todo = np.arange(b)
    diag = np.diag(q).copy()
    tol = 1e-9 * (np.abs(c).max(axis=1) + 1e-300)
    for _ in range(NNLS_ROUNDS):
        x, cc = a[todo], c[todo]
        for _sweep in range(NNLS_SWEEPS):
            for j in range(k):
                x[:, j] = np.maximum(0.0, x[:, j] + (cc[:, j] - x @ q[:, j]) / diag[j])
        polished, ok = _polish(q, cc, x > 0.0, tol[todo])
        out[todo[ok]] = polished[ok]
        a[todo] = np.where(ok[:, None], polished, x)
        todo = todo[~ok]
        if not len(todo):
            break
    out[todo] = a[todo]
    return out, len(todo)


def _polish(q: np.ndarray, c: np.ndarray, active: np.ndarray, tol: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unconstrained minimum over each row's active set (solved once per distinct set) and
    whether it satisfies NNLS's KKT conditions (a ≥ 0, gradient ≥ −tol where a = 0)."""
    out = np.zeros_like(c)
    keys = active @ (1 << np.arange(c.shape[1]))
    for key in np.unique(keys):
        rows = keys == key
        p = active[np.argmax(rows)]
        if p.any():
            out[np.ix_(rows, p)] = np.linalg.solve(q[np.ix_(p, p)], c[rows][:, p].T).T
    grad = out @ q - c
    ok = np.all(out >= 0.0, axis=1) & np.all((out > 0.0) | (grad >= -tol[:, None]), axis=1)
    return out, ok


def _world_axes(count: int, n_v: np.ndarray) -> np.ndarray:
    axes, _ = layout(count)
    return np.einsum("nij,kj->nki", frames(n_v), axes)  # (N, K, 3)


class SGBasis:
    """SG`count` with the solve `solve` (only the encoding depends on it)."""

    SPECULAR = True

    def __init__(self, count: int, solve: str = "nnls", specular_norm: str = "none"):
        if solve not in SOLVES:
            raise ValueError(f"SG solve must be one of {', '.join(SOLVES)}, not {solve!r}")
        if specular_norm not in SPECULAR_NORMS:
            raise ValueError(f"SG specular_norm must be one of {', '.join(SPECULAR_NORMS)}, not {specular_norm!r}")
        self.count, self.solve, self.specular_norm = count, solve, specular_norm
        self.name = f"sg{count}"

    def coefficients(self, sh: np.ndarray, n_v: np.ndarray) -> np.ndarray:
        """Amplitudes `(N, K, 3)` of the texels' lobes."""
        return self.solve_coefficients(sh, n_v)[0]

    def solve_coefficients(self, sh: np.ndarray, n_v: np.ndarray) -> tuple[np.ndarray, int]:
        """Amplitudes `(N, K, 3)` and the count of (texel, colour) NNLS problems not solved
        exactly (`nnls`; 0 for the linear solves)."""
        local = _sh.to_local(np.asarray(sh, np.float64), frames(n_v))  # (N, 9, C)
        if self.solve == "adhoc":
            return np.einsum("kj,njc->nkc", adhoc_matrix(self.count), local), 0
        ls = np.einsum("kj,njc->nkc", ls_matrix(self.count), local)
        if self.solve == "ls":
            return ls, 0
        a = design(self.count)
        c = np.einsum("kj,njc->nck", a.T @ sample_sh(), local).reshape(-1, self.count)  # Aᵀ b per (texel, colour)
        x, unconverged = nnls(a.T @ a, c, start=np.moveaxis(ls, 1, 2).reshape(-1, self.count))
        return np.moveaxis(x.reshape(len(local), local.shape[2], self.count), 2, 1), unconverged

    def irradiance(self, c: np.ndarray, n_v: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Σ_k Hill's fit of lobe k at n, / π."""
        _, lam = layout(self.count)
        cos = np.einsum("nki,ni->nk", _world_axes(self.count, n_v), np.asarray(n, np.float64))
        return np.einsum("nk,nkc->nc", _hill_irradiance(cos, lam), c) / np.pi

    def specular(self, c, n_v, n, v, alpha, f0=1.0) -> np.ndarray:
        """Σ_k ASG-warp specular of lobe k (Baking Lab `SpecularTermASGWarp`), ≥ 0 per lobe;
        with specular_norm "uniform", rescaled (module docstring)."""
        _, lam = layout(self.count)
        axes, c = _world_axes(self.count, n_v), np.asarray(c, np.float64)
        if self.specular_norm == "none":
            return asg_specular(axes, lam, c, n, v, alpha, f0)
        return normalised_specular(axes, lam, c, uniform_amplitudes(self.count), n, v, alpha, f0)


def normalised_specular(axes: np.ndarray, lam: float, amp: np.ndarray, u: np.ndarray, n, v, alpha, f0=1.0):
    """`asg_specular` rescaled so that the amplitudes u `(K,)` reflect E(n·v, α, F0) exactly:
    Σ_k max(w_k a_k, 0) · E / Σ_k w_k u_k `(N, C)` (F0 scalar; module docstring)."""
    n, v = np.asarray(n, np.float64), np.asarray(v, np.float64)
    w = asg_weights(axes, lam, n, v, alpha, f0)  # (N, K, 1)
    s = np.maximum(w * amp, 0.0).sum(axis=1)
    su = w[:, :, 0] @ np.asarray(u, np.float64)
    nv = np.clip(np.sum(n * v, -1), 0.0, 1.0)
    albedo = ggx.lobe_sh(nv, np.broadcast_to(np.asarray(alpha, np.float64), nv.shape), f0)[:, 0] / _sh.Y00
    gain = np.where(su > 0.0, albedo / np.where(su > 0.0, su, 1.0), 0.0)
    return s * gain[:, None]


def asg_specular(axes: np.ndarray, lam: float, amp: np.ndarray, n, v, alpha, f0=1.0) -> np.ndarray:
    """Specular of SG lights (axes `(N, K, 3)`, sharpness λ, amplitudes `(N, K, C)`) at unit n,
    v `(N, 3)`, GGX α (scalar or `(N,)`) -> `(N, C)` (see the module docstring)."""
    return np.maximum(asg_weights(axes, lam, n, v, alpha, f0) * amp, 0.0).sum(axis=1)


def asg_weights(axes: np.ndarray, lam: float, n, v, alpha, f0=1.0) -> np.ndarray:
    """w `(N, K, 1)`: the ASG-warp specular of each SG light of amplitude 1 (axes `(N, K, 3)`,
    sharpness λ) at unit n, v `(N, 3)`, GGX α (scalar or `(N,)`), F0 scalar (module docstring)."""
    n, v = np.asarray(n, np.float64), np.asarray(v, np.float64)
    alpha = np.broadcast_to(np.asarray(alpha, np.float64), (len(n),))[:, None]
    m2 = alpha * alpha
    ndf_lam, ndf_amp = 2.0 / m2, 1.0 / (np.pi * m2)
    nv_raw = np.sum(n * v, -1)[:, None]
    z = 2.0 * nv_raw * n - v  # reflect(-v, n)
    x = np.cross(n, z)
    length = np.linalg.norm(x, axis=-1, keepdims=True)
    x = np.where(length > 1e-8, x / np.maximum(length, 1e-300), _sh.tangent_frames(z)[:, :, 0])
    y = np.cross(z, x)
    dot_o = np.maximum(nv_raw, 1e-4)
    lx, ly = ndf_lam / (8.0 * dot_o * dot_o), ndf_lam / 8.0
    nu = 0.5 * lam
    cx, cy = nu * lx / (nu + lx), nu * ly / (nu + ly)
    camp = np.pi / np.sqrt((nu + lx) * (nu + ly))
    dz, dx, dy = (np.einsum("nki,ni->nk", axes, w) for w in (z, x, y))
    conv = camp * np.maximum(dz, 0.0) * np.exp(-cx * dx * dx - cy * dy * dy) * ndf_amp  # (N, K)
    nl = np.clip(np.sum(n * z, -1), 0.0, 1.0)[:, None]
    nv = np.clip(nv_raw, 0.0, 1.0)

    def v1(x_):
        return 1.0 / (x_ + np.sqrt(m2 + (1.0 - m2) * x_ * x_))

    h = z + v
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    fres = f0 + (1.0 - f0) * (1.0 - np.clip(np.sum(z * h, -1), 0.0, 1.0))[:, None] ** 5
    scale = v1(nl) * v1(nv) * fres * nl  # (N, 1)
    return conv[:, :, None] * scale[:, :, None]


MEANING = "amplitude of SG lobe k (fixed axis in n_v's tangent frame, fixed sharpness: docs/format.md), radiance, RGB"


def file_of(count: int) -> FileSpec:
    return FileSpec(f"sg{count}", f"_sg{count}.exr", layers("SG", count, MEANING, f"sg{count}"))


def encoding_of(count: int, file: FileSpec, settings) -> CoefficientEncoding:
    basis = SGBasis(count, settings.solve)
    return CoefficientEncoding(basis, file, {"model": settings.model, "solve": settings.solve})
