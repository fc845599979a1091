"""core.hhd is a package split by job; its public API stays importable from the package."""

import numpy as np

from hhd_lightmapper.core import colour, hhd


def test_public_names_are_exported_from_the_package():
    for name in (
        "encode",
        "HHDParams",
        "irradz",
        "reconstruct",
        "hemispherical_rmse",
        "hemisphere_quadrature",
        "fit_error",
        "to_linear_sh",
        "from_linear_sh",
        "optimal_linear_angles",
        "ambient_lobe",
        "directional_lobe",
        "LUMINANCE",
        "MIN_COS",
        "GOLDEN_ITERATIONS",
        "IRRADZ_FROM_R10",
        "CHUNK",
    ):
        assert hasattr(hhd, name), name
    assert hhd.LUMINANCE is colour.LUMINANCE  # defined once
    assert hhd.IRRADZ_FROM_R10 == 2.0 / np.sqrt(3.0 * np.pi)
    from hhd_lightmapper.core.hhd import encoder, fit, linear_sh, lobes, metrics, search  # noqa: F401


def test_optimal_linear_angles_point_along_the_linear_band():
    local = np.zeros((2, 9, 1))
    local[0, 2, 0] = 1.0  # +z
    local[1, 3, 0] = -1.0  # -r_1^1 = +x
    theta, phi = hhd.optimal_linear_angles(local, np.ones(1), np.arccos(hhd.MIN_COS))
    np.testing.assert_allclose(theta, [0.0, np.arccos(hhd.MIN_COS)])
    np.testing.assert_allclose(phi[1], 0.0)
