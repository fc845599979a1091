"""SG specular (Baking Lab's anisotropic warp, `core.encoding.sg`) against quadrature, the warp's
own error apart from the fit's: bench/results/sg_specular.md. Core only (numpy).

    .venv/bin/python bench/sg_specular.py

The radiance is what an SG layout holds exactly, so no fit (and no L2 SH) is involved: one lobe
of the layout (amplitude 1, the layout's sharpness λ), sums of the layout's lobes with random
amplitudes in [0, 1], and u, the layout's least-squares uniform radiance (`sg.uniform_amplitudes`).
n = n_v = z, v in the xz plane at n·v = NV; the layout is turned about n by AZIMUTHS angles, so
each statistic spans the view's azimuth relative to the lobes. Reference: S = ∫ L f cos dω (GGX,
F0 = 1, `ggx.brdf_cos`) by a product Gauss-Legendre rule in polar coordinates around the mirror
direction, graded towards it (`polar_grid`), checked against a finer grid and against
`ggx.half_vector_quadrature` (an independent rule, sampling GGX's half vectors). The warp: the
per-lobe weights w_k of `sg.asg_weights` (the lights' specular is w·a, exactly `asg_specular`
for a ≥ 0).

The decomposition (uniform radiance u and single lobes) replaces one approximation of the warp
at a time, each integral by the same quadrature: the GGX NDF by Baking Lab's SG NDF
(λ = 2/α², amplitude 1/(πα²)) in the exact integrand; that lobe, a function of ω through h, by
the warped ASG without, then with, its smooth term max(z·ω, 0); visibility, Fresnel and n·l
taken at the mirror direction; the horizon n·ω > 0 dropped; the ASG-SG convolution in closed
form (Xu et al.), which is the warp. The fix rows: `SGBasis(..., specular_norm="uniform")`.
Last, every SG row of bench/encodings_basis.py's fields with and without the fix.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import sh
from hhd_lightmapper.core.encoding import EncoderSettings, ggx, registry, sg

ROOT = Path(__file__).resolve().parents[1]
COUNTS = (5, 6, 9, 12)
ALPHAS = (0.0625, 0.25, 0.5, 0.5625, 0.75)
NV = (1.0, float(np.cos(np.radians(40.0))), 0.5, float(np.cos(np.radians(75.0))))
AZIMUTHS = 8
RANDOM_SUMS = 64
#: quadrature: Gauss-Legendre nodes per polar panel, azimuth steps (the check doubles both)
PANEL, PHI = 24, 384


def polar_grid(axis: np.ndarray, alpha: float, panel: int = PANEL, phi: int = PHI) -> tuple[np.ndarray, np.ndarray]:
    """Directions `(M, 3)` and weights `(M,)` over the whole sphere: θ from `axis` in panels
    [0, α/16, 1.6 α/16, …, π] of `panel` Gauss-Legendre nodes each, `phi` uniform azimuths."""
    edges = [0.0]
    t = alpha / 16.0
    while t < np.pi:
        edges.append(t)
        t *= 1.6
    edges.append(np.pi)
    x, w = np.polynomial.legendre.leggauss(panel)
    th = np.concatenate([0.5 * (b - a) * x + 0.5 * (b + a) for a, b in zip(edges[:-1], edges[1:])])
    wt = np.concatenate([0.5 * (b - a) * w for a, b in zip(edges[:-1], edges[1:])])
    ph = (np.arange(phi) + 0.5) * 2.0 * np.pi / phi
    f = sh.tangent_frames(np.asarray(axis, np.float64)[None])[0]
    st, ct = np.sin(th)[:, None], np.cos(th)[:, None]
    local = np.stack([st * np.cos(ph), st * np.sin(ph), np.broadcast_to(ct, (len(th), phi))], -1)
    weights = (wt * np.sin(th))[:, None] * np.full(phi, 2.0 * np.pi / phi)
    return local.reshape(-1, 3) @ f.T, weights.reshape(-1)


N = np.array([0.0, 0.0, 1.0])


def view(nv: float) -> np.ndarray:
    return np.array([np.sqrt(max(1.0 - nv * nv, 0.0)), 0.0, nv])


def mirror(nv: float) -> np.ndarray:
    return 2.0 * nv * N - view(nv)


def turned_axes(count: int, j: int) -> np.ndarray:
    """The layout's axes turned about n by the j-th azimuth `(K, 3)`."""
    a = (j + 0.5) * 2.0 * np.pi / AZIMUTHS
    c, s = np.cos(a), np.sin(a)
    return sg.layout(count)[0] @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def lobes_at(d: np.ndarray, axes: np.ndarray, lam: float) -> np.ndarray:
    return np.exp(lam * (d @ axes.T - 1.0))  # (M, K)


def exact(axes: np.ndarray, lam: float, nv: float, alpha: float, **grid) -> np.ndarray:
    """∫ G_k f cos dω per lobe `(K,)` (F0 = 1)."""
    d, w = polar_grid(mirror(nv), alpha, **grid)
    return (w * ggx.brdf_cos(d, view(nv)[None], N[None], alpha)) @ lobes_at(d, axes, lam)


def warp(axes: np.ndarray, lam: float, nv: float, alpha: float) -> np.ndarray:
    return sg.asg_weights(axes[None], lam, N[None], view(nv)[None], alpha)[0, :, 0]


def albedo(nv: float, alpha: float) -> float:
    return float(ggx.lobe_sh(np.array([nv]), np.array([alpha]), 1.0)[0, 0] / sh.Y00)


def measure_lobes() -> dict:
    """(K, α, n·v) -> (e, w) `(AZIMUTHS, K)` each: exact and warp per lobe."""
    out = {}
    for k in COUNTS:
        lam = sg.layout(k)[1]
        for a in ALPHAS:
            for nv in NV:
                e = np.stack([exact(turned_axes(k, j), lam, nv, a) for j in range(AZIMUTHS)])
                w = np.stack([warp(turned_axes(k, j), lam, nv, a) for j in range(AZIMUTHS)])
                out[(k, a, nv)] = (e, w)
    return out


def quadrature_check() -> tuple[float, float]:
    """Largest change of the exact per-lobe integrals (SG12, azimuth 0), relative to the
    largest of them, on doubling the grid, and against `ggx.half_vector_quadrature` (whose
    midpoint rule in tan²θ_h is the slower to converge in GGX's tail at small α)."""
    lam = sg.layout(12)[1]
    axes = turned_axes(12, 0)
    fine, other = 0.0, 0.0
    for a in ALPHAS:
        for nv in NV:
            e = exact(axes, lam, nv, a)
            e2 = exact(axes, lam, nv, a, panel=2 * PANEL, phi=2 * PHI)
            d, wt = ggx.half_vector_quadrature(nv, a, 512, 512)
            # that rule's frame is z = n, v = (√(1 − nv²), 0, nv): this bench's frame
            e3 = wt.sum(axis=1) @ lobes_at(d, axes, lam)
            fine = max(fine, float(np.max(np.abs(e - e2)) / e2.max()))
            other = max(other, float(np.max(np.abs(e3 - e2)) / e2.max()))
    return fine, other


def rel_rms(est: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((est - ref) ** 2)) / np.sqrt(np.mean(ref**2)))


def fixed(w: np.ndarray, amp: np.ndarray, u: np.ndarray, e_alb: float) -> np.ndarray:
    """The normalised specular (`sg.normalised_specular`) from per-lobe weights `(A, K)` and
    amplitudes `(R, K)` -> `(A, R)`."""
    return (w @ amp.T) * (e_alb / (w @ u))[:, None]


def cell(rms: float, bias: float) -> str:
    return f"{rms:.3f} ({bias:.2f})"


def lobe_tables(res: dict) -> list[str]:
    rng = np.random.default_rng(59)
    head = "| K | α | " + " | ".join(f"n·v={nv:.2f}" for nv in NV) + " |"
    rule = "|---|---|" + "---|" * len(NV)
    single, sums, sums_fix, uni = [head, rule], [head, rule], [head, rule], [head, rule]
    for k in COUNTS:
        amp = rng.uniform(0.0, 1.0, (RANDOM_SUMS, k))
        u = sg.uniform_amplitudes(k)
        for a in ALPHAS:
            c1, c2, c3, c4 = [], [], [], []
            for nv in NV:
                e, w = res[(k, a, nv)]
                c1.append(cell(rel_rms(w, e), w.sum() / e.sum()))
                se, sw = e @ amp.T, w @ amp.T
                c2.append(cell(rel_rms(sw, se), sw.sum() / se.sum()))
                sf = fixed(w, amp, u, albedo(nv, a))
                c3.append(cell(rel_rms(sf, se), sf.sum() / se.sum()))
                eu, wu = e @ u, w @ u
                alb = albedo(nv, a)
                c4.append(f"{np.mean(eu) / alb:.3f} / {np.mean(wu) / alb:.3f} / {np.mean(alb / eu):.3f}")
            for table, cells in ((single, c1), (sums, c2), (sums_fix, c3), (uni, c4)):
                table.append(f"| {k} | {a:g} | " + " | ".join(cells) + " |")
    return [
        "## One lobe: the warp alone",
        "",
        "Each of the layout's K lobes (amplitude 1, the layout's λ) as the only radiance, at 8 azimuths of the",
        "layout about n: relative RMS error of the warp over those K × 8 lights (RMS of warp − exact over RMS of",
        "exact) and, in brackets, the bias Σ warp / Σ exact.",
        "",
        *single,
        "",
        "## Sums of the layout's lobes: the warp alone, and with the normalisation",
        "",
        f"{RANDOM_SUMS} amplitude vectors uniform in [0, 1]^K × 8 azimuths; relative RMS error (bias). Baking Lab's warp:",
        "",
        *sums,
        "",
        'The same radiance with `specular_norm="uniform"`:',
        "",
        *sums_fix,
        "",
        "## Uniform radiance",
        "",
        "u = the layout's least-squares fit of radiance 1 (`sg.uniform_amplitudes`), mean over the 8 azimuths:",
        "exact S(u) / E, the warp's S(u) / E, and E / exact S(u) (what the normalisation makes of u, relative",
        "to its exact specular). E = the GGX directional albedo ∫ f cos dω (F0 = 1, the `ggx` table).",
        "",
        *uni,
        "",
    ]


def chain(axes: np.ndarray, lam: float, amp: np.ndarray, nv: float, alpha: float) -> list[float]:
    """The integrals of the decomposition (module docstring), exact first, the warp last."""
    v, z = view(nv), mirror(nv)
    d, wq = polar_grid(z, alpha)
    light = lobes_at(d, axes, lam) @ amp
    m2 = alpha * alpha
    nl = d @ N
    up = nl > 0.0
    h = d + v
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    g = ggx.g1(nl, alpha) * ggx.g1(np.array(nv), alpha) / (4.0 * nv)
    sg_ndf = np.exp(2.0 / m2 * (h @ N - 1.0)) / (np.pi * m2)
    x = np.cross(N, z)  # the warp's frame (`sg.asg_weights`)
    x = x / np.linalg.norm(x) if nv < 1.0 else sh.tangent_frames(z[None])[0][:, 0]
    y = np.cross(z, x)
    lx, ly = (2.0 / m2) / (8.0 * nv * nv), (2.0 / m2) / 8.0
    gauss = np.exp(-lx * (d @ x) ** 2 - ly * (d @ y) ** 2) / (np.pi * m2)
    asg_rough = gauss * (d @ z > 0.0)
    asg = gauss * np.clip(d @ z, 0.0, 1.0)

    def v1(t):
        return 1.0 / (t + np.sqrt(m2 + (1.0 - m2) * t * t))

    rest = v1(np.clip(nl, 0.0, 1.0)) * v1(nv) * np.clip(nl, 0.0, 1.0)  # G1 G1 / (4 n·v) at ω, F = 1
    centre = v1(max(z @ N, 0.0)) * v1(nv) * max(z @ N, 0.0)
    return [
        float(np.sum(wq * light * ggx.ndf(h @ N, alpha) * g * up)),
        float(np.sum(wq * light * sg_ndf * g * up)),
        float(np.sum(wq * light * asg_rough * rest)),
        float(np.sum(wq * light * asg * rest)),
        float(np.sum(wq * light * asg * up) * centre),
        float(np.sum(wq * light * asg) * centre),
        float(warp(axes, lam, nv, alpha) @ amp),
    ]


CHAIN_HEAD = "| SG NDF | ASG, no smooth term | ASG | V, F, n·l at the mirror direction | no horizon | closed-form convolution (the warp) |"


def chain_tables() -> list[str]:
    out = [
        "## Which approximation: the decomposition",
        "",
        "Each column replaces one more of the warp's approximations (module docstring) and gives the result over",
        "the exact specular; the last column is Baking Lab's warp. Uniform radiance u, mean over the 8 azimuths:",
        "",
    ]
    rule = "|---|---|---|" + "---|" * 6
    for k in (5, 9, 12):
        lam, u = sg.layout(k)[1], sg.uniform_amplitudes(k)
        out += [f"SG{k}:", "", "| α | n·v | exact / E " + CHAIN_HEAD, rule]
        for a in ALPHAS:
            for nv in NV[:3]:
                rows = np.array([chain(turned_axes(k, j), lam, u, nv, a) for j in range(AZIMUTHS)])
                ratio = (rows[:, 1:] / rows[:, :1]).mean(axis=0)
                e_ratio = rows[:, 0].mean() / albedo(nv, a)
                out.append(f"| {a:g} | {nv:.2f} | {e_ratio:.3f} | " + " | ".join(f"{r:.3f}" for r in ratio) + " |")
        out.append("")
    out += [
        "One SG9 lobe (amplitude 1) in the plane of incidence, θ from n towards the mirror direction's side,",
        "n·v = 0.77 (the mirror direction at θ = 40°):",
        "",
        "| α | θ of the lobe | exact " + CHAIN_HEAD,
        "|---|---|---|" + "---|" * 6,
    ]
    lam = sg.layout(9)[1]
    for a in (0.0625, 0.25, 0.5625, 0.75):
        for th in (0.0, 40.0, 70.0):
            t = np.radians(th)
            axis = np.array([[-np.sin(t), 0.0, np.cos(t)]])
            r = chain(axis, lam, np.ones(1), NV[1], a)
            out.append(f"| {a:g} | {th:.0f}° | {r[0]:.4f} | " + " | ".join(f"{x / r[0]:.3f}" for x in r[1:]) + " |")
    return out + [""]


def _test_helper(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tests" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def field_tables() -> list[str]:
    _test_helper("quadrature")
    f = _test_helper("encoding_fields")
    n = f.normals()
    v = f.views(n)
    n_v = np.broadcast_to(f.N_V, n.shape)
    out = [
        "## The encodings_basis fields, with and without the normalisation",
        "",
        "bench/encodings_basis.py's fields and views (tests/encoding_fields.py: the SG fit of the field's L2 SH,",
        "so the fit's error is included): relative RMS specular error without → with `specular_norm=\"uniform\"`,",
        "over the 5 shading normals (n_v and four tilted by 30° and 60°), and in brackets at n = n_v alone.",
        "",
    ]
    head = "| field | encoding | " + " | ".join(f"α={a:g}" for a in ALPHAS) + " |"
    out += [head, "|---|---|" + "---|" * len(ALPHAS)]
    for field in f.fields():
        s = np.broadcast_to(field.sh(), (len(n), 9, 3))
        refs = {a: field.specular(n, v, a) for a in ALPHAS}
        for k in COUNTS:
            for solve in ("adhoc", "ls", "nnls"):
                plain = registry.basis_of(EncoderSettings(model=f"sg{k}", solve=solve))
                norm = sg.SGBasis(k, solve, specular_norm="uniform")
                c = plain.coefficients(s, n_v)
                cells = []
                for a in ALPHAS:
                    p, q = plain.specular(c, n_v, n, v, a), norm.specular(c, n_v, n, v, a)
                    ref = refs[a]
                    cells.append(
                        f"{f.relative_rms(p, ref):.3f} → {f.relative_rms(q, ref):.3f} "
                        f"({f.relative_rms(p[:1], ref[:1]):.3f} → {f.relative_rms(q[:1], ref[:1]):.3f})"
                    )
                out.append(f"| {field.name} | sg{k} ({solve}) | " + " | ".join(cells) + " |")
    return out + [""]


def main() -> None:
    fine, other = quadrature_check()
    lines = [
        "# SG specular: the anisotropic warp against quadrature",
        "",
        "`bench/sg_specular.py` (module docstring: radiance, quadrature, decomposition). GGX, F0 = 1, α = GGX α",
        "(Blender Roughness r: α = r²; the compare's r = 0.25, 0.5, 0.75 are α = 0.0625, 0.25, 0.5625), n = n_v.",
        f"Quadrature check (SG12's lobes, every α and n·v): the exact per-lobe integrals change by at most {fine:.1e}",
        f"of the largest on doubling the grid, and differ from `ggx.half_vector_quadrature` (512 × 512) by at most {other:.1e}.",
        "",
    ]
    lines += lobe_tables(measure_lobes())
    lines += chain_tables()
    lines += field_tables()
    text = "\n".join(lines)
    path = ROOT / "bench" / "results" / "sg_specular.md"
    path.write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
