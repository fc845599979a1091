"""The SG encodings' opt-in specular normalisation (`SGBasis(..., specular_norm="uniform")`,
core/encoding/sg.py) against brute-force quadrature of the GGX specular. Core only."""

import numpy as np
import pytest

from hhd_lightmapper.core.encoding import ggx, sg
from quadrature import cap

N = np.array([[0.0, 0.0, 1.0]])


def view(theta_deg: float) -> np.ndarray:
    t = np.radians(theta_deg)
    return np.array([[np.sin(t), 0.0, np.cos(t)]])


def quadrature_specular(count: int, amp: np.ndarray, v: np.ndarray, alpha: float) -> float:
    """∫ Σ_k a_k G_k(ω) f(ω, v) cos dω over n's hemisphere (n = n_v = z), F0 = 1."""
    axes, lam = sg.layout(count)
    d, w = cap(0.0, 160, 320)
    radiance = np.exp(lam * (d @ axes.T - 1.0)) @ amp
    return float(np.sum(w * radiance * ggx.brdf_cos(d, v, N, alpha)))


def test_uniform_radiance_is_near_exact_where_the_warp_loses_a_third():
    """u, the layout's uniform radiance: the warp alone is ≥ 25% low at α = 0.75, 40° (its ASG
    cuts the wide lobe off); normalised it is within 3% of the quadrature."""
    count, alpha, v = 9, 0.75, view(40.0)
    u = sg.uniform_amplitudes(count)
    ref = quadrature_specular(count, u, v, alpha)
    c = np.broadcast_to(u[None, :, None], (1, count, 1))
    plain = sg.SGBasis(count).specular(c, N, N, v, alpha)[0, 0]
    fixed = sg.SGBasis(count, specular_norm="uniform").specular(c, N, N, v, alpha)[0, 0]
    assert plain < 0.75 * ref
    assert abs(fixed / ref - 1.0) < 0.03


def test_random_lobe_sums_improve_at_high_roughness():
    """Non-negative sums of the layout's lobes at α = 0.5625 (Blender Roughness 0.75): the
    normalisation cuts the relative RMS error against quadrature at least in half."""
    count, alpha = 6, 0.5625
    rng = np.random.default_rng(1)
    amps = rng.uniform(0.0, 1.0, (6, count))
    errs = {"none": [], "uniform": []}
    refs = []
    for theta in (0.0, 30.0, 55.0):
        v = view(theta)
        for a in amps:
            refs.append(quadrature_specular(count, a, v, alpha))
            for norm in errs:
                s = sg.SGBasis(count, specular_norm=norm).specular(a[None, :, None], N, N, v, alpha)[0, 0]
                errs[norm].append(s - refs[-1])
    scale = np.sqrt(np.mean(np.square(refs)))
    rms = {k: np.sqrt(np.mean(np.square(e))) / scale for k, e in errs.items()}
    assert rms["uniform"] < 0.5 * rms["none"]


def test_linear_non_negative_and_zero_below_the_horizon():
    rng = np.random.default_rng(2)
    b = sg.SGBasis(5, specular_norm="uniform")
    c = rng.uniform(0.0, 1.0, (4, 5, 3))
    n_v = np.tile(N, (4, 1))
    v = np.concatenate([view(10.0), view(50.0), view(80.0), -view(30.0)])  # the last below n's horizon
    s = b.specular(c, n_v, n_v, v, 0.4, f0=0.04)
    assert np.all(s >= 0.0) and np.all(s[3] == 0.0) and np.all(s[:3] > 0.0)
    assert np.allclose(b.specular(2.5 * c, n_v, n_v, v, 0.4, f0=0.04), 2.5 * s, rtol=1e-12)


def test_unknown_norm_is_refused():
    with pytest.raises(ValueError, match="specular_norm"):
        sg.SGBasis(9, specular_norm="exact")
