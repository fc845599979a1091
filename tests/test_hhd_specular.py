"""HHD / AHD specular (core/encoding/hhd_specular.py) against independent quadrature. Core only, no bpy.

Exact where the model is exact (AHD: a directional light plus uniform radiance; the directional
light of HHD), bounded where it approximates (HHD's hemisphere visibility V; the fitted
parameters on the analytic fields of tests/encoding_fields.py, next to L2 SH on the same fields:
bench/results/encodings_basis.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from encoding_fields import N_V, dense_sphere, fields, normals, relative_rms, unit, views
from hhd_lightmapper.core import hhd
from hhd_lightmapper.core.encoding import ggx, sh_l2
from hhd_lightmapper.core.encoding.hhd_specular import directional_albedo, hemisphere_visibility, specular

ROUGHNESS = (0.25, 0.5, 0.75)  # Blender Roughness r; GGX α = r²


def _pairs(count: int = 8, seed: int = 3):
    """Shading normals in n_v's hemisphere (≤ 60° from it) and views in theirs."""
    rng = np.random.default_rng(seed)
    n = unit(N_V + 0.7 * unit(rng.normal(size=(count, 3))))
    v = unit(n + 0.9 * unit(rng.normal(size=(count, 3))))
    return n, v


def _params(model: str, c_a: float, c_d: float, d: np.ndarray, count: int) -> hhd.HHDParams:
    """The parameters of ambient C_a plus a light of irradiance C_d along d (grey)."""
    i_z = c_a + c_d * float(d @ N_V)
    return hhd.HHDParams(
        irradz=np.full((count, 1), i_z),
        ambient_weight=np.full(count, c_a / i_z),
        direction=np.broadcast_to(d, (count, 3)).copy(),
        model=model,
    )


def _quadrature(n, v, alpha, radiance: np.ndarray) -> np.ndarray:
    d, w = dense_sphere()
    return np.array([w * (ggx.brdf_cos(d, vi[None], ni[None], alpha) @ radiance) for ni, vi in zip(n, v)])


@pytest.mark.parametrize("r", ROUGHNESS)
def test_directional_albedo_is_the_integral_of_the_lobe(r):
    n, v = _pairs()
    d, w = dense_sphere()
    for f0 in (1.0, 0.04):
        ref = np.array([w * ggx.brdf_cos(d, vi[None], ni[None], r * r, f0).sum() for ni, vi in zip(n, v)])
        np.testing.assert_allclose(directional_albedo(np.sum(n * v, -1), r * r, f0), ref, rtol=0.01)


@pytest.mark.parametrize("r", ROUGHNESS)
def test_ahd_specular_equals_quadrature_of_its_lights(r):
    """AHD = uniform radiance C_a + a directional light C_d: exact up to the table's interpolation."""
    n, v = _pairs()
    light = unit(N_V + np.array([0.5, 0.3, 0.0]))
    p = _params("ahd", 0.3, 1.2, light, len(n))
    d, _ = dense_sphere()
    ref = _quadrature(n, v, r * r, np.full(len(d), 0.3)) + 1.2 * np.pi * ggx.brdf_cos(
        np.broadcast_to(light, n.shape), v, n, r * r
    )
    np.testing.assert_allclose(specular(p, np.broadcast_to(N_V, n.shape), n, v, r * r)[:, 0], ref, rtol=0.01)


@pytest.mark.parametrize("r", ROUGHNESS)
def test_hhd_specular_against_quadrature_of_its_lights(r):
    """HHD = a hemisphere light C_a around n_v + a directional light: the directional part is
    exact, the hemisphere part off by V's approximation only (measured ≤ 0.06 of C_a·E)."""
    n, v = _pairs()
    n_v = np.broadcast_to(N_V, n.shape)
    light = unit(N_V + np.array([-0.4, 0.6, 0.0]))
    p = _params("hhd", 0.5, 0.8, light, len(n))
    d, _ = dense_sphere()
    hemi = _quadrature(n, v, r * r, 0.5 * (d @ N_V > 0.0))
    direct = 0.8 * np.pi * ggx.brdf_cos(np.broadcast_to(light, n.shape), v, n, r * r)
    got = specular(p, n_v, n, v, r * r)[:, 0]
    e = 0.5 * directional_albedo(np.sum(n * v, -1), r * r)
    assert np.abs(got - direct - hemi).max() <= 0.08 * e.max()
    assert np.abs(hemisphere_visibility(n, v, n_v, r * r) - hemi / e).max() < 0.08  # V alone


#: Relative RMS error of HHD specular on the fields (bench/results/encodings_basis.md, section
#: "HHD / AHD specular"), with a margin; a wrong π, C_d or E gives errors of order 1 at every α.
HHD_BOUNDS = {
    "narrow lobe": (0.6, 0.2, 0.05),
    "sky gradient": (0.6, 0.25, 0.1),
    "two lights": (4.5, 1.3, 0.45),
}


def test_hhd_specular_on_the_fields_next_to_l2_sh():
    n = normals()
    v = views(n)
    n_v = np.broadcast_to(N_V, n.shape)
    for field in fields():
        s = np.broadcast_to(field.sh(), (len(n), 9, 3))
        p = hhd.encode(s, n_v, model="hhd")
        for r, bound in zip(ROUGHNESS, HHD_BOUNDS[field.name]):
            ref = field.specular(n, v, r * r)
            err = relative_rms(specular(p, n_v, n, v, r * r), ref)
            assert err < bound, (field.name, r, err)
            if field.name == "narrow lobe":  # one lobe: HHD's light beats L2 SH's ringing
                assert err < relative_rms(sh_l2.BASIS.specular(s, n_v, n, v, r * r), ref)


def test_specular_is_zero_behind_the_view_and_scales_with_f0():
    n, v = _pairs(4)
    n_v = np.broadcast_to(N_V, n.shape)
    p = _params("hhd", 0.4, 1.0, unit(N_V + np.array([0.2, 0.0, 0.0])), len(n))
    assert np.all(specular(p, n_v, n, -v, 0.3) == 0.0)
    one, zero = specular(p, n_v, n, v, 0.3, 1.0), specular(p, n_v, n, v, 0.3, 0.0)
    half = specular(p, n_v, n, v, 0.3, 0.5)
    np.testing.assert_allclose(half, 0.5 * (one + zero), rtol=1e-12)
    with pytest.raises(ValueError):
        specular(p, n_v, n, v, 0.3, model="hl2")
