"""The light-set blend (`core.light_sets.blend`, the 2024 talk's "Blending HHD" / "HHD and linear
SH") checked against references that do not use its closed forms: lighting of HHD form (a
hemisphere light of radiance C_a around n_v plus a directional light of irradiance C_d along d)
projected to SH by quadrature, the analytic irradiance of that lighting, and a float32 port of
the HLSL in docs/format.md ("Light sets"). Pure numpy, no tracing."""

import re
from pathlib import Path

import numpy as np
import pytest

import quadrature
from hhd_lightmapper.core import hhd, light_sets, octahedral, sh
from hhd_lightmapper.core.errors import BakeError
from scenekit import light_set_reference

FORMAT_DOC = Path(__file__).resolve().parent.parent / "docs" / "format.md"
LUM = np.array([0.2126, 0.7152, 0.0722])


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def hhd_lighting(rng, n, channels=3, min_dz=0.05, n_v=None):
    """Random texels of HHD form: n_v `(n, 3)` (random unless given), C_a `(n, C)` hemisphere
    radiance, C_d `(n, C)` directional irradiance, d `(n, 3)` with d·n_v ≥ min_dz. C_a and C_d
    share one colour ratio per texel (luminance w_a = C_a / I_z is then the w_a of every channel)."""
    n_v = unit(rng.normal(size=(n, 3))) if n_v is None else n_v
    d = unit(rng.normal(size=(n, 3)))
    d = np.where((np.einsum("ni,ni->n", d, n_v) < 0)[:, None], -d, d)
    d = hhd.linear_sh.clamp_to_cone(d, n_v, min_dz)
    colour = rng.uniform(0.2, 1.0, (n, channels))
    scale = rng.uniform(0.0, 3.0, (n, 2))
    return n_v, scale[:, :1] * colour, scale[:, 1:] * colour, d


def params_of(ca, cd, d, n_v):
    """HHDParams of the lighting (luminance w_a), by the model's definition (lobes.py):
    I_z = C_a + C_d d·n_v, w_a = C_a / I_z (1 for black texels, as the encoder writes them)."""
    dz = np.einsum("ni,ni->n", d, n_v)[:, None]
    iz = ca + cd * dz
    weights = hhd.channel_weights(iz.shape[1])
    lum_ca, lum_iz = ca @ weights, iz @ weights
    wa = np.divide(lum_ca, lum_iz, out=np.ones_like(lum_iz), where=lum_iz > 0)  # black: w_a = 1
    return hhd.HHDParams(irradz=iz, ambient_weight=wa, direction=d.copy(), model="hhd")


def quadrature_linear_sh(ca, cd, d, n_v):
    """World linear radiance SH `(N, 4, C)` of the lighting, independently of `to_linear_sh`: the
    hemisphere light by Gauss–Legendre quadrature over n_v's hemisphere, the directional light as
    the delta of radiance π C_d (irradiance C_d facing it) projected exactly, π C_d Y(d)."""
    dirs, weights = quadrature.hemisphere(8, 16)  # exact for bands ≤ 1 times a constant
    frames = sh.tangent_frames(n_v)  # columns t, b, n
    world = np.einsum("nij,sj->nsi", frames, dirs)  # (N, S, 3)
    y = sh.evaluate(world.reshape(-1, 3)).reshape(len(n_v), len(dirs), 9)[:, :, :4]
    hemi = np.einsum("nsk,s->nk", y, weights)[:, :, None] * ca[:, None, :]
    delta = np.pi * sh.evaluate(d)[:, :4, None] * cd[:, None, :]
    return hemi + delta


def exact_irradiance(ca, cd, d, n_v, n):
    """Irradiance (docs/conventions.md#irradiance-units) of the lighting at normals n:
    C_a (1 + n·n_v)/2 + C_d max(n·d, 0)."""
    cos_nv = np.einsum("ni,ni->n", n, n_v)[:, None]
    return ca * 0.5 * (1.0 + cos_nv) + cd * np.maximum(np.einsum("ni,ni->n", n, d), 0.0)[:, None]


def tilted(n_v, degrees, rng):
    """Unit normals at `degrees` from each n_v, random azimuth."""
    frames = sh.tangent_frames(n_v)
    phi = rng.uniform(0, 2 * np.pi, len(n_v))
    t = np.radians(degrees)
    local = np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.full(len(n_v), np.cos(t))], axis=1)
    return np.einsum("nij,nj->ni", frames, local)


# --- the closed forms against quadrature ------------------------------------------------------


def test_to_linear_sh_is_the_projection_of_the_hhd_lighting():
    rng = np.random.default_rng(0)
    n_v, ca, cd, d = hhd_lighting(rng, 500)
    np.testing.assert_allclose(
        hhd.to_linear_sh(params_of(ca, cd, d, n_v), n_v), quadrature_linear_sh(ca, cd, d, n_v), rtol=1e-10, atol=1e-12
    )


@pytest.mark.parametrize("channels", [1, 3])
def test_lighting_of_hhd_form_round_trips_through_linear_sh(channels):
    rng = np.random.default_rng(1)
    n_v, ca, cd, d = hhd_lighting(rng, 2000, channels)
    p = params_of(ca, cd, d, n_v)
    q = hhd.from_linear_sh(quadrature_linear_sh(ca, cd, d, n_v), n_v)
    np.testing.assert_allclose(q.irradz, p.irradz, rtol=1e-10, atol=1e-12)
    # d is undefined without a directional light, and ill-conditioned (through the square root)
    # when it is faint: compare where C_d ≥ 1% of C_a
    has_direction = cd[:, 0] >= 0.01 * ca[:, 0]
    np.testing.assert_allclose(q.ambient_weight, p.ambient_weight, atol=1e-9)
    np.testing.assert_allclose(q.direction[has_direction], d[has_direction], atol=1e-6)


# --- blend properties ---------------------------------------------------------------------------


def two_sets(rng, n=1000, channels=3):
    n_v, ca1, cd1, d1 = hhd_lighting(rng, n, channels)
    _, ca2, cd2, d2 = hhd_lighting_at(rng, n_v, channels)
    return n_v, (ca1, cd1, d1), (ca2, cd2, d2)


def hhd_lighting_at(rng, n_v, channels=3):
    """`hhd_lighting` at given normals."""
    return hhd_lighting(rng, len(n_v), channels, n_v=n_v)


def test_unit_weight_on_one_set_gives_that_set():
    rng = np.random.default_rng(2)
    n_v, s1, s2 = two_sets(rng)
    p1, p2 = params_of(*s1, n_v), params_of(*s2, n_v)
    b = light_sets.blend([p1, p2], n_v, np.array([[1.0] * 3, [0.0] * 3]))
    np.testing.assert_allclose(b.irradz, p1.irradz, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(b.ambient_weight, p1.ambient_weight, atol=1e-9)
    np.testing.assert_allclose(b.direction, p1.direction, atol=1e-6)


def test_a_coloured_weight_on_one_set_tints_i_z_and_keeps_w_a_and_d():
    """Lighting of HHD form times an RGB weight is still of HHD form with the same w_a and d."""
    rng = np.random.default_rng(3)
    n_v, ca, cd, d = hhd_lighting(rng, 1000)
    p = params_of(ca, cd, d, n_v)
    tint = np.array([[2.0, 0.5, 0.25]])
    b = light_sets.blend([p], n_v, tint)
    np.testing.assert_allclose(b.irradz, p.irradz * tint, rtol=1e-12)
    np.testing.assert_allclose(b.ambient_weight, p.ambient_weight, atol=1e-9)
    np.testing.assert_allclose(b.direction, p.direction, atol=1e-6)


def test_i_z_is_linear_in_the_weights():
    """I_z comes from the linear band alone: blended I_z = Σ w_k I_z,k for any weights."""
    rng = np.random.default_rng(4)
    n_v, *sets = two_sets(rng)
    _, ca3, cd3, d3 = hhd_lighting_at(rng, n_v)
    params = [params_of(*s, n_v) for s in sets] + [params_of(ca3, cd3, d3, n_v)]
    for _ in range(10):
        w = rng.uniform(0.0, 3.0, (3, 3)) * (rng.uniform(size=(3, 1)) > 0.2)
        b = light_sets.blend(params, n_v, w)
        np.testing.assert_allclose(b.irradz, sum(wk * p.irradz for wk, p in zip(w, params)), rtol=1e-12, atol=1e-14)


def test_blend_is_the_solve_of_the_summed_projected_lighting():
    """Independent reference: both sets' lighting projected by quadrature, weighted, summed, then
    solved; equal to `blend` of the sets' parameters."""
    rng = np.random.default_rng(5)
    n_v, s1, s2 = two_sets(rng)
    w = np.array([[0.7, 1.0, 1.3], [2.0, 0.5, 1.0]])
    total = w[0] * quadrature_linear_sh(*s1, n_v) + w[1] * quadrature_linear_sh(*s2, n_v)
    ref = hhd.from_linear_sh(total, n_v)
    b = light_sets.blend([params_of(*s1, n_v), params_of(*s2, n_v)], n_v, w)
    np.testing.assert_allclose(b.irradz, ref.irradz, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(b.ambient_weight, ref.ambient_weight, atol=1e-8)
    np.testing.assert_allclose(b.direction, ref.direction, atol=1e-6)


def test_sets_sharing_a_direction_blend_exactly():
    """Two HHD-form sets with the same d sum to HHD-form lighting (C_a and C_d add): the blend
    reconstructs the summed lighting's exact irradiance at every normal of the hemisphere."""
    rng = np.random.default_rng(6)
    n_v, (ca1, cd1, d), (ca2, cd2, _) = two_sets(rng)
    # one colour per texel for all four terms: the summed lighting stays of luminance-w_a HHD form
    colour = ca1 / np.maximum(ca1.max(axis=1, keepdims=True), 1e-30)
    amounts = rng.uniform(0.0, 2.0, (len(n_v), 4))
    ca1, cd1, ca2, cd2 = (amounts[:, k : k + 1] * colour for k in range(4))
    w = np.array([0.3, 1.7])
    b = light_sets.blend([params_of(ca1, cd1, d, n_v), params_of(ca2, cd2, d, n_v)], n_v, np.repeat(w[:, None], 3, 1))
    for degrees in (0, 30, 60, 85):
        n = tilted(n_v, degrees, rng)
        exact = exact_irradiance(w[0] * ca1 + w[1] * ca2, w[0] * cd1 + w[1] * cd2, d, n_v, n)
        np.testing.assert_allclose(hhd.reconstruct(b, n_v, n), exact, rtol=1e-8, atol=1e-10)


def test_monochrome_blend_keeps_the_summed_linear_sh():
    """One channel: HHD and linear SH have the same 4 parameters, so the solve keeps the summed
    linear SH exactly unless the direction cone clamp (d·n_v ≥ MIN_COS) had to act."""
    rng = np.random.default_rng(7)
    n_v, s1, s2 = two_sets(rng, 2000, channels=1)
    params = [params_of(*s1, n_v), params_of(*s2, n_v)]
    b = light_sets.blend(params, n_v, np.ones((2, 1)))
    total = hhd.to_linear_sh(params[0], n_v) + hhd.to_linear_sh(params[1], n_v)
    free = np.einsum("ni,ni->n", b.direction, n_v) > hhd.MIN_COS + 1e-9
    assert free.mean() > 0.8
    np.testing.assert_allclose(hhd.to_linear_sh(b, n_v)[free], total[free], rtol=1e-8, atol=1e-10)


def test_the_linear_sh_blend_beats_the_parameter_blend_on_diverging_lights():
    """The talk's slide in numbers: two sets with diverging directional lights, reconstructed at
    normals tilted 60° from n_v, against the exact irradiance of the summed lighting."""
    rng = np.random.default_rng(8)
    n_v, s1, s2 = two_sets(rng, 4000)
    params = [params_of(*s1, n_v), params_of(*s2, n_v)]
    w = np.ones((2, 3))
    n = tilted(n_v, 60, rng)
    exact = exact_irradiance(*s1, n_v, n) + exact_irradiance(*s2, n_v, n)

    def rmse(p):
        return np.sqrt(np.mean((hhd.reconstruct(p, n_v, n) - exact) ** 2)) / np.mean(exact)

    linear, parameters = rmse(light_sets.blend(params, n_v, w)), rmse(light_set_reference.parameter_blend(params, w))
    assert linear < 0.75 * parameters, (linear, parameters)


# --- weights ------------------------------------------------------------------------------------


def test_weight_array_defaults_broadcasts_and_validates():
    names = ("A", "B")
    np.testing.assert_array_equal(light_sets.weight_array(names, None), np.ones((2, 3)))
    np.testing.assert_array_equal(light_sets.weight_array(names, {"B": 0.5}), [[1, 1, 1], [0.5, 0.5, 0.5]])
    np.testing.assert_array_equal(light_sets.weight_array(names, {"A": (1, 0, 2)}), [[1, 0, 2], [1, 1, 1]])
    for bad in ({"A": -0.1}, {"A": float("nan")}, {"B": float("inf")}, {"B": (1, -1, 1)}, {"C": 1.0}):
        with pytest.raises(BakeError):
            light_sets.weight_array(names, bad)


def test_blend_rejects_mismatched_weights_ahd_and_no_sets():
    rng = np.random.default_rng(9)
    n_v, s1, _ = two_sets(rng, 4)
    p = params_of(*s1, n_v)
    with pytest.raises(BakeError):
        light_sets.blend([p, p], n_v, np.ones((1, 3)))
    with pytest.raises(BakeError):
        light_sets.blend([hhd.HHDParams(p.irradz, p.ambient_weight, p.direction, model="ahd")], n_v, np.ones((1, 3)))
    with pytest.raises(BakeError):
        light_sets.blend([], n_v, np.ones((0, 3)))


# --- extremes -----------------------------------------------------------------------------------


def assert_finite(p):
    for a in (p.irradz, p.ambient_weight, p.direction):
        assert np.isfinite(a).all()
    assert (p.irradz >= 0).all() and ((p.ambient_weight >= 0) & (p.ambient_weight <= 1)).all()
    np.testing.assert_allclose(np.linalg.norm(p.direction, axis=1), 1.0, rtol=1e-12)


def test_black_sets_and_zero_weights_blend_to_finite_black():
    rng = np.random.default_rng(10)
    n_v, s1, _ = two_sets(rng, 100)
    black = hhd.HHDParams(np.zeros((100, 3)), np.ones(100), n_v.copy())
    lit = params_of(*s1, n_v)
    both_black = light_sets.blend([black, black], n_v, np.ones((2, 3)))
    assert_finite(both_black)
    assert (both_black.irradz == 0).all() and (both_black.ambient_weight == 1).all()
    np.testing.assert_allclose(both_black.direction, n_v, atol=1e-15)  # as docs/format.md says
    zero_weights = light_sets.blend([lit, lit], n_v, np.zeros((2, 3)))
    assert_finite(zero_weights)
    assert (zero_weights.irradz == 0).all()
    one_black = light_sets.blend([black, lit], n_v, np.ones((2, 3)))
    np.testing.assert_allclose(one_black.irradz, lit.irradz, rtol=1e-13)
    np.testing.assert_allclose(one_black.direction, lit.direction, atol=1e-6)


def test_grazing_directions_at_the_encoders_floor_blend_finitely():
    """d·n_v = MIN_COS, the encoder's floor: C_d = 50 I_z, still finite and round-tripping."""
    rng = np.random.default_rng(11)
    n_v, ca, cd, d = hhd_lighting(rng, 500, min_dz=1.0)  # d = n_v ...
    tangent = sh.tangent_frames(n_v)[:, :, 0]
    d = hhd.MIN_COS * n_v + np.sqrt(1 - hhd.MIN_COS**2) * tangent  # ... tilted to the floor
    p = params_of(ca, cd, d, n_v)
    b = light_sets.blend([p, p], n_v, np.full((2, 3), 0.5))
    assert_finite(b)
    np.testing.assert_allclose(b.irradz, p.irradz, rtol=1e-12)
    np.testing.assert_allclose(b.direction, d, atol=1e-6)


def test_directions_below_the_floor_blend_like_the_reconstruction_reads_them():
    n_v = np.tile([0.0, 0.0, 1.0], (3, 1))
    d = unit(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, -0.01], [1.0, 0.0, 0.005]]))
    p = hhd.HHDParams(np.ones((3, 3)), np.full(3, 0.5), d)
    with np.errstate(all="ignore"):
        b = light_sets.blend([p], n_v, np.ones((1, 3)))
    assert_finite(b)
    assert (b.direction[:, 0] > 0).all()  # the highlight stays on its side


def test_hdr_values_blend_with_relative_precision():
    rng = np.random.default_rng(12)
    n_v, s1, s2 = two_sets(rng, 500)
    big = [params_of(s1[0] * 1e6, s1[1] * 1e6, s1[2], n_v), params_of(*s2, n_v)]
    w = np.array([[1.0] * 3, [3.0] * 3])
    b = light_sets.blend(big, n_v, w)
    assert_finite(b)
    np.testing.assert_allclose(b.irradz, big[0].irradz + 3 * big[1].irradz, rtol=1e-12)
    small = light_sets.blend([params_of(*s1, n_v)], n_v, np.ones((1, 3)))  # the same set unscaled
    np.testing.assert_allclose(light_sets.blend(big[:1], n_v, w[:1]).direction, small.direction, atol=1e-6)


def test_a_nan_texel_is_blended_black_and_invalid_and_alone():
    """NaN in a set's texel (a damaged file: the encoder never writes one) blends that texel
    black and invalid (I_z 0, w_a 1, d = n_v), as the encoder treats NaN input; no exception,
    no warning, and no other texel changes."""
    rng = np.random.default_rng(13)
    n_v, s1, s2 = two_sets(rng, 50)
    p1, p2 = params_of(*s1, n_v), params_of(*s2, n_v)
    clean = light_sets.blend([p1, p2], n_v, np.ones((2, 3)))
    p1.irradz[7, 0] = np.nan
    b = light_sets.blend([p1, p2], n_v, np.ones((2, 3)))
    others = np.arange(50) != 7
    np.testing.assert_array_equal(b.irradz[others], clean.irradz[others])
    np.testing.assert_array_equal(b.direction[others], clean.direction[others])
    assert (b.irradz[7] == 0.0).all() and b.ambient_weight[7] == 1.0
    np.testing.assert_allclose(b.direction[7], n_v[7] / np.linalg.norm(n_v[7]))
    assert b.invalid[7] and b.invalid.sum() == 1


# --- the HLSL of docs/format.md, ported to float32 numpy ------------------------------------


F = np.float32
MIN_COS = F(0.02)
SQRT_PI, SQRT3 = F(np.sqrt(np.pi)), F(np.sqrt(3.0))


def dot(a, b):
    return (a * b).sum(axis=-1)


def oct_decode(e):
    d = np.concatenate([e, (F(1) - np.abs(e).sum(axis=-1))[:, None]], axis=1).astype(F)
    t = np.clip(-d[:, 2], 0, 1)
    d[:, :2] -= t[:, None] * np.where(d[:, :2] >= 0, F(1), F(-1))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def hlsl_hhd_to_linear_sh(iz, wa, d, nv):
    """HHDToLinearSH: returns (l0, l1m1, l10, l11), each (N, 3)."""
    dz = np.maximum(dot(d, nv), F(0.5) * MIN_COS)[:, None]
    ca = wa[:, None] * iz
    cd = (F(1) - wa[:, None]) * iz / dz
    k = F(0.5) * SQRT_PI
    b = [ca * nv[:, i : i + 1] + cd * d[:, i : i + 1] for i in range(3)]
    return k * (F(2) * ca + cd), -k * SQRT3 * b[1], k * SQRT3 * b[2], -k * SQRT3 * b[0]


def hlsl_tangent_of(nv):
    sign = np.where(nv[:, 2] >= 0, F(1), F(-1))
    a = F(-1) / (sign + nv[:, 2])
    return np.stack([F(1) + sign * nv[:, 0] ** 2 * a, sign * nv[:, 0] * nv[:, 1] * a, -sign * nv[:, 0]], axis=1)


def hlsl_linear_sh_to_hhd(l0, l1m1, l10, l11, nv):
    """LinearSHToHHD: returns (Iz (N, 3), wa (N,), d (N, 3))."""
    lum = LUM.astype(F)
    kb = F(2) / SQRT_PI
    bc, bx, by, bz = kb * l0, -kb / SQRT3 * l11, -kb / SQRT3 * l1m1, kb / SQRT3 * l10
    iz = np.maximum(bx * nv[:, :1] + by * nv[:, 1:2] + bz * nv[:, 2:], F(0))
    bc_l, iz_l = dot(bc, lum), dot(iz, lum)
    b_l = np.stack([dot(bx, lum), dot(by, lum), dot(bz, lum)], axis=1)
    p = F(2) * bc_l - iz_l
    disc = np.maximum(p * p - F(3) * (bc_l * bc_l - dot(b_l, b_l)), F(0))
    ca = np.clip((p - np.sqrt(disc)) / F(3), F(0), iz_l)
    dv = b_l - ca[:, None] * nv
    length = np.linalg.norm(dv, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where((length > F(1e-12) * iz_l)[:, None], dv / length[:, None], nv)
    c = dot(d, nv)
    t = d - c[:, None] * nv
    tl = np.linalg.norm(t, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where((tl > F(1e-12))[:, None], t / tl[:, None], hlsl_tangent_of(nv))
    d = np.where((c < MIN_COS)[:, None], MIN_COS * nv + np.sqrt(F(1) - MIN_COS * MIN_COS) * t, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        wa = np.where(iz_l > 0, np.clip(ca / iz_l, 0, 1), F(1))
    return iz, wa, d


def hlsl_blend(sets, weights, nv):
    """BlendLightSets: sets [(Iz, wa, oct)], weights (K, 3)."""
    total = [np.zeros_like(nv) for _ in range(4)]
    for (iz, wa, e), w in zip(sets, weights.astype(F)):
        for acc, term in zip(total, hlsl_hhd_to_linear_sh(iz, wa, oct_decode(e), nv)):
            acc += w * term
    return hlsl_linear_sh_to_hhd(*total, nv)


def test_the_documented_hlsl_blend_matches_core():
    doc = FORMAT_DOC.read_text()
    section = doc[doc.index("## Light sets") :]
    for name in ("HHDToLinearSH", "LinearSHToHHD", "BlendLightSets", "0.5 * MIN_COS"):
        assert name in section, name
    assert re.search(r"MIN_COS\s*=\s*0\.02", section)
    rng = np.random.default_rng(14)
    n_v, *sets = two_sets(rng, 5000)
    _, ca3, cd3, d3 = hhd_lighting_at(rng, n_v)
    sets.append((ca3 * 0.0, cd3 * 0.0, d3))  # a black set
    params = [params_of(*s, n_v) for s in sets]
    w = np.array([[1.0, 0.5, 2.0], [0.25, 1.0, 0.0], [3.0, 3.0, 3.0]])
    # what the shader reads: the files' float32 normal, half I_z / w_a, half octahedral d
    stored = [(p.irradz.astype(np.float16), p.ambient_weight.astype(np.float16), p.direction) for p in params]
    stored = [(iz.astype(F), wa.astype(F), octahedral.encode(d).astype(np.float16).astype(F)) for iz, wa, d in stored]
    nv32 = n_v.astype(F)
    iz, wa, d = hlsl_blend(stored, w, nv32)
    read = [
        hhd.HHDParams(s[0].astype(float), s[1].astype(float), octahedral.decode(s[2].astype(float))) for s in stored
    ]
    ref = light_sets.blend(read, nv32.astype(float), w)
    scale = ref.irradz.max(axis=1, keepdims=True) + 1e-6
    assert (np.abs(iz - ref.irradz) / scale).max() < 1e-5
    lit = ref.irradz @ LUM > 0.05 * np.median(ref.irradz @ LUM)
    assert np.abs(wa - ref.ambient_weight)[lit].max() < 1e-3
    angle = np.degrees(np.arccos(np.clip(dot(d.astype(float), ref.direction), -1, 1)))
    directional = lit & (ref.ambient_weight < 0.9)  # d is ill-conditioned where C_d is faint
    assert angle[directional].max() < 0.1
    n = tilted(n_v, 45, rng)
    shader = hhd.reconstruct(hhd.HHDParams(iz.astype(float), wa.astype(float), d.astype(float)), n_v, n)
    core = hhd.reconstruct(ref, n_v, n)
    assert np.sqrt(np.mean((shader - core) ** 2)) < 1e-4 * np.mean(core)
