"""The coefficient encodings' math (Baking Lab's set: SH, HL2, H-basis, SG) against independent
quadrature on analytic radiance fields. Core only, no bpy.

Exact where the math is exact (H-basis orthonormality and its SH matrix, HL2 from band 1,
SH specular of band-limited radiance, I(n_v) of the HL2 encoding, the SG solves against
a dense lstsq / Lawson–Hanson on the same samples); bounded where it approximates (the per-field
errors of bench/results/encodings_basis.md, with margins well below what a wrong factor gives).
"""

from __future__ import annotations

import numpy as np
import pytest

from encoding_fields import N_V, dense_sphere, fields, normals, relative_rms, unit, views
from hhd_lightmapper.core import sh
from hhd_lightmapper.core.encoding import EncoderSettings, ggx, hbasis, hl2, registry, sg
from quadrature import cap, hemisphere

NEW_MODELS = ("sh_l1", "sh_l2", "hl2", "hbasis_l1", "hbasis_l2", "sg5", "sg6", "sg9", "sg12")


def test_hbasis_is_orthonormal_over_the_hemisphere_and_its_sh_matrix_matches_quadrature():
    d, w = hemisphere(24, 48)
    h = hbasis.evaluate(d)
    np.testing.assert_allclose((h * w[:, None]).T @ h, np.eye(6), atol=1e-12)
    np.testing.assert_allclose(hbasis.sh_to_h(), (h * w[:, None]).T @ sh.evaluate(d), atol=1e-12)


def test_hl2_coefficients_are_the_projection_of_the_field_and_exact_at_n_v():
    field = fields()[0]
    frame = sh.tangent_frames(N_V[None])
    c = hl2.BASIS.coefficients(field.sh()[None], N_V[None])[0]
    d, w = cap(0.0, 96, 192)
    d = d @ frame[0].T
    direct = np.stack([(w * (d @ (frame[0] @ b))) @ field.masked(d) for b in hl2.DIRECTIONS]) / np.pi
    np.testing.assert_allclose(c, direct, rtol=1e-9, atol=1e-12)
    i_z = hl2.BASIS.irradiance(c[None], N_V[None], N_V[None])[0]
    np.testing.assert_allclose(i_z, field.irradiance(N_V[None])[0], rtol=2e-4)


@pytest.mark.parametrize("alpha", [0.25, 0.5, 0.75])
def test_sh_specular_is_exact_for_radiance_band_limited_to_l2(alpha):
    """For radiance inside L2 (whole sphere), Σ g_k s_k = ∫ L f cos dω: only the table's
    interpolation separates them."""
    rng = np.random.default_rng(4)
    s = rng.normal(scale=0.3, size=(9, 1))
    s[0] = 2.0
    n = unit(rng.normal(size=(4, 3)))
    v = unit(n + unit(rng.normal(size=(4, 3))) * 0.8)
    d, w = dense_sphere()
    radiance = sh.evaluate(d) @ s[:, 0]
    ref = np.stack([w * (ggx.brdf_cos(d, vi[None], ni[None], alpha) @ radiance) for ni, vi in zip(n, v)])
    est = ggx.sh_specular(np.broadcast_to(s, (4, 9, 1)), n, v, alpha)[:, 0]
    np.testing.assert_allclose(est, ref, rtol=0.02)


def _texel_sh(count: int = 6) -> tuple[np.ndarray, np.ndarray]:
    sh_rows = np.stack([f.sh() for f in fields()])
    rng = np.random.default_rng(1)
    extra = rng.normal(scale=0.4, size=(count - len(sh_rows), 9, 3))
    extra[:, 0] += 1.5
    normals_ = np.concatenate([np.broadcast_to(N_V, (len(sh_rows), 3)), unit(rng.normal(size=(len(extra), 3)))])
    return np.concatenate([sh_rows, extra]), normals_


def _samples(sh_rows, n_v):
    """b `(T, S, 3)`: each texel's radiance from its SH at the SG sample directions."""
    local = sh.to_local(sh_rows, sh.tangent_frames(n_v))
    return np.einsum("sj,tjc->tsc", sg.sample_sh(), local)


@pytest.mark.parametrize("count", [5, 9, 12])
def test_sg_least_squares_equals_a_dense_lstsq_on_the_same_samples(count):
    sh_rows, n_v = _texel_sh()
    a = sg.design(count)
    got = sg.SGBasis(count, "ls").coefficients(sh_rows, n_v)
    for t, b in enumerate(_samples(sh_rows, n_v)):
        want = np.linalg.lstsq(a, b, rcond=None)[0]
        np.testing.assert_allclose(got[t], want, atol=1e-8 * np.abs(want).max())


def _lawson_hanson(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Reference NNLS (Lawson & Hanson 1974) on the dense samples, one right-hand side."""
    m, k = a.shape
    x, passive = np.zeros(k), np.zeros(k, bool)
    for _ in range(10 * k):
        grad = a.T @ (b - a @ x)
        if passive.all() or grad[~passive].max() <= 1e-12 * np.abs(a.T @ b).max():
            break
        passive[np.argmax(np.where(passive, -np.inf, grad))] = True
        while True:
            z = np.zeros(k)
            z[passive] = np.linalg.lstsq(a[:, passive], b, rcond=None)[0]
            if z[passive].min() > 0:
                x = z
                break
            neg = passive & (z <= 0)
            step = np.min(x[neg] / (x[neg] - z[neg]))
            x = x + step * (z - x)
            passive &= x > 1e-15
    return x


@pytest.mark.parametrize("count", [5, 9, 12])
def test_sg_nnls_equals_lawson_hanson_on_the_same_samples(count):
    sh_rows, n_v = _texel_sh()
    a = sg.design(count)
    got, unsolved = sg.SGBasis(count, "nnls").solve_coefficients(sh_rows, n_v)
    assert unsolved == 0
    assert got.min() >= 0.0
    for t, b in enumerate(_samples(sh_rows, n_v)):
        for ch in range(3):
            want = _lawson_hanson(a, b[:, ch])
            np.testing.assert_allclose(got[t, :, ch], want, atol=1e-7 * max(np.abs(want).max(), 1e-3))


def test_sg_adhoc_reconstructs_uniform_radiance_at_n_v():
    uniform = np.zeros((1, 9, 3))
    uniform[0, 0] = 2.0 * np.sqrt(np.pi)  # radiance 1 on the whole sphere
    for count in (5, 6, 9, 12):
        b = sg.SGBasis(count, "adhoc")
        i = b.irradiance(b.coefficients(uniform, N_V[None]), N_V[None], N_V[None])
        np.testing.assert_allclose(i, 1.0, rtol=1e-9)


def test_sg_lobe_approximations_against_quadrature():
    """Hill's irradiance fit and the ASG-warp specular for one SG light (SG9's sharpness) stay
    within their known approximation error (measured: ≤ 3 % of the peak, ≤ 18 %)."""
    _, lam = sg.layout(9)
    mu = unit([0.3, 0.0, 1.0])
    d, w = dense_sphere()
    light = np.exp(lam * (d @ mu - 1.0))
    n = unit(np.array([[0, 0, 1.0], [1, 0, 0.5], [-1, 0.2, 0.3], [0, 1, 0.1]]))
    ref = np.array([w * (np.maximum(d @ m, 0) @ light) for m in n])
    est = sg._hill_irradiance(n @ mu, lam)
    assert np.abs(est - ref).max() <= 0.03 * ref.max()
    v = unit(np.array([[-0.5, 0.1, 1.0]] * 4))
    n4 = np.broadcast_to([0.0, 0.0, 1.0], (4, 3))
    for i, alpha in enumerate((0.25, 0.5, 0.75)):
        s_ref = w * (ggx.brdf_cos(d, v[i : i + 1], n4[:1], alpha) @ light)
        s_est = sg.asg_specular(mu[None, None], lam, np.ones((1, 1, 1)), n4[:1], v[i : i + 1], alpha)[0, 0]
        assert abs(s_est / s_ref - 1.0) < 0.18


#: Bounds on the relative RMS error vs the field's quadrature (irradiance over 5 normals;
#: specular at α = 0.25, 0.5, 0.75): the measured values (bench/results/encodings_basis.md)
#: with a margin; a wrong π, band factor or frame gives errors of order 1.
IRRADIANCE_BOUND = 0.25
SPECULAR_BOUND = 0.9


def test_every_encoding_against_the_fields():
    n = normals()
    v = views(n)
    n_v = np.broadcast_to(N_V, n.shape)
    for field in fields():
        s = np.broadcast_to(field.sh(), (len(n), 9, 3))
        i_ref = field.irradiance(n)
        spec_ref = {a: field.specular(n, v, a) for a in (0.25, 0.75)}
        for model in NEW_MODELS:
            for solve in ("adhoc", "ls", "nnls") if model.startswith("sg") else ("nnls",):
                b = registry.basis_of(EncoderSettings(model=model, solve=solve))
                c = b.coefficients(s, n_v)
                i = b.irradiance(c, n_v, n)
                assert relative_rms(i, i_ref) < IRRADIANCE_BOUND, (field.name, model, solve)
                if model == "hl2":  # from band 1 only, where I_z lies: exact at n_v
                    np.testing.assert_allclose(i[0], i_ref[0], rtol=2e-3)
                if not b.SPECULAR:
                    with pytest.raises(NotImplementedError):
                        b.specular(c, n_v, n, v, 0.5)
                    continue
                for a, ref in spec_ref.items():
                    assert relative_rms(b.specular(c, n_v, n, v, a), ref) < SPECULAR_BOUND, (field.name, model, a)


def test_encodings_write_their_layers_and_leave_the_hhd_settings_alone():
    sh_rows, n_v = _texel_sh()
    for model in NEW_MODELS:
        enc = registry.for_settings(EncoderSettings(model=model))
        out = enc.encode(sh_rows, n_v)
        assert list(out.values) == [ch.name for ch in enc.file.channels]
        assert all(v.shape == (len(sh_rows), 3) and np.isfinite(v).all() for v in out.values.values())
        assert enc.summary([out.stats], len(sh_rows))["solve_unsolved"] == 0
    assert "solve" not in EncoderSettings().kwargs()
    assert EncoderSettings(model="sg9", solve="ls").kwargs()["solve"] == "ls"
    with pytest.raises(ValueError):
        registry.for_settings(EncoderSettings(model="sg9", solve="svd"))
