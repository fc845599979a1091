"""HLSH against an independent least-squares fit, and the paper's exact constants."""

import numpy as np
import pytest

import quadrature as quad
import sh_reference
from hhd_lightmapper.core import hlsh, sh

# Cosine-convolution factors per band up to l = 4 (E = (1/π)∫ L max(n·ω,0)): 1, 2/3, 1/4, 0, -1/24.
A_L4 = [1.0, 2.0 / 3.0, 0.25, 0.0, -1.0 / 24.0]


def basis_l4(dirs):
    return np.array([sh_reference.basis(d, lmax=4) for d in dirs])


def reference_fit(r_local, cos_alpha):
    """Fit HLSH in the local frame (N = z) by least squares, independently of the shader code:
    mask the radiance r·Y to the cone, project to SH up to l = 4, convolve with the clamped
    cosine, then fit [z, 1-z, x, y] over the hemisphere (not the cone: that is what reproduces
    the shader's polynomials) with the z weight fixed to the exact occluded irradiance at z.
    Returns (I_z, C_a, c_x, c_y)."""
    dirs, w = quad.cap(cos_alpha, n_z=24, n_phi=48)
    radiance = sh.evaluate(dirs) @ r_local
    proj = basis_l4(dirs).T @ (w * radiance)  # masked, projected to l ≤ 4
    iz = (w * radiance) @ dirs[:, 2] / np.pi  # exact occluded irradiance at z
    hemi, hw = quad.hemisphere(n_z=24, n_phi=48)
    bands = np.repeat(np.arange(5), [1, 3, 5, 7, 9])
    irr = basis_l4(hemi) @ (proj * np.array(A_L4)[bands])  # band-limited irradiance
    design = np.column_stack([1.0 - hemi[:, 2], hemi[:, 0], hemi[:, 1]])
    rhs = irr - iz * hemi[:, 2]
    sw = np.sqrt(hw)
    coef, *_ = np.linalg.lstsq(design * sw[:, None], rhs * sw, rcond=None)
    return iz, coef[0], coef[1], coef[2]


@pytest.mark.parametrize("cos_alpha", [0.0, 0.3, 0.7])
def test_hlsh_is_the_constrained_least_squares_fit(cos_alpha):
    rng = np.random.default_rng(3)
    for _ in range(5):
        r = rng.normal(size=9)
        r[0] += 3.0
        got = hlsh.project(r[None, :, None], np.array([[0.0, 0.0, 1.0]]), cos_alpha)
        iz, ca, cx, cy = reference_fit(r, cos_alpha)
        assert got.irradz[0, 0] == pytest.approx(iz, abs=1e-12)
        assert got.ambient[0, 0] == pytest.approx(ca, abs=1e-12)
        # c = c_t + (I_z - C_a) N; in the local frame c_x, c_y are the tangent weights.
        np.testing.assert_allclose(got.vector[0, :, 0], [cx, cy, iz - ca], atol=1e-12)


def test_hemisphere_matrix_constants_are_exact():
    """At cos α = 0 the fit's matrix is the slide's: C_a row [1/(4√π), 0, 2203/(8192√(3π)), 0, 0, 0,
    -7√5/(128√π), 0, 0] and c_x, c_y rows with -2573/(4096√(3π)) and -11√15/(128√π)."""
    z = np.array([[0.0, 0.0, 1.0]])
    rows = np.array(
        [
            [
                v[0, 0]
                for v in (lambda p: (p.ambient, p.vector[:, 0], p.vector[:, 1]))(
                    hlsh.project(np.eye(9)[k][None, :, None], z)
                )
            ]
            for k in range(9)
        ]
    ).T
    sp, s3p = np.sqrt(np.pi), np.sqrt(3 * np.pi)
    expected = np.zeros((3, 9))
    expected[0, [0, 2, 6]] = [1 / (4 * sp), 2203 / (8192 * s3p), -7 * np.sqrt(5) / (128 * sp)]
    expected[1, [3, 7]] = [-2573 / (4096 * s3p), -11 * np.sqrt(15) / (128 * sp)]
    expected[2, [1, 5]] = [-2573 / (4096 * s3p), -11 * np.sqrt(15) / (128 * sp)]
    np.testing.assert_allclose(rows, expected, atol=1e-15)
    # ... and the independent least-squares fit reproduces them exactly.
    fitted = np.array([reference_fit(np.eye(9)[k], 0.0)[1:] for k in range(9)]).T
    np.testing.assert_allclose(fitted, expected, atol=1e-12)


def test_world_space_projection_equals_local_frame_projection():
    rng = np.random.default_rng(5)
    n = quad.random_dirs(rng, 40)
    coeffs = rng.normal(size=(40, 9, 3))
    frames = sh.tangent_frames(n)
    world = hlsh.project(coeffs, n, 0.2)
    local = hlsh.project(sh.to_local(coeffs, frames), np.tile([0.0, 0.0, 1.0], (40, 1)), 0.2)
    np.testing.assert_allclose(np.einsum("nij,njc->nic", frames, local.vector), world.vector, atol=1e-12)
    np.testing.assert_allclose(world.ambient, local.ambient, atol=1e-12)
    np.testing.assert_allclose(world.evaluate(n), world.irradz, atol=1e-12)  # exact at N


def test_cone_angle_from_visibility():
    alpha = np.radians([10.0, 45.0, 80.0])
    for cos_theta in (1.0, 0.7):
        v = np.sin(alpha) ** 2 * cos_theta
        np.testing.assert_allclose(hlsh.cone_cos_from_visibility(v, cos_theta), np.cos(alpha), atol=1e-12)
