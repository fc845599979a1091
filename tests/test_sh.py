"""SH basis, projection, cosine convolution and rotation against independent references."""

import numpy as np
import pytest

import quadrature as quad
import sh_reference
from hhd_lightmapper.core import sh


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_basis_matches_legendre_reference(rng):
    dirs = np.vstack([quad.random_dirs(rng, 200), np.eye(3), -np.eye(3)])
    ref = np.array([sh_reference.basis(d) for d in dirs])
    np.testing.assert_allclose(sh.evaluate(dirs), ref, atol=1e-13)


def test_basis_is_orthonormal_over_the_sphere():
    dirs, w = quad.sphere()
    y = sh.evaluate(dirs)
    np.testing.assert_allclose(y.T @ (y * w[:, None]), np.eye(9), atol=1e-12)


def test_project_then_evaluate_round_trips(rng):
    coeffs = rng.normal(size=(9, 3))
    dirs, w = quad.sphere()
    values = sh.evaluate(dirs) @ coeffs
    np.testing.assert_allclose(sh.project(dirs, values, w), coeffs, atol=1e-12)


def test_cosine_convolution_matches_quadrature_of_clamped_cosine(rng):
    """E(n) = (1/π)∫ L(ω) max(n·ω,0) dω for band-limited L; the kink limits accuracy to ~1e-5."""
    r = rng.normal(size=(1, 9, 3))
    r[0, 0] += 4.0
    dirs, w = quad.sphere(n_z=400, n_phi=800)
    radiance = sh.evaluate(dirs) @ r[0]
    normals = quad.random_dirs(rng, 6)
    for n in normals:
        expected = (w * np.maximum(dirs @ n, 0.0)) @ radiance / np.pi
        got = sh.irradiance(r, n[None])[0]
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-4 * np.abs(radiance).max())


def test_unit_radiance_gives_unit_irradiance():
    r = np.zeros((1, 9, 3))
    r[0, 0] = 1.0 / sh.Y00  # constant radiance 1 (= 2√π on Y00)
    np.testing.assert_allclose(sh.irradiance(r, np.array([[0.3, -0.4, np.sqrt(0.75)]])), 1.0)


def test_rotation_agrees_with_rotating_the_argument(rng):
    n = 50
    coeffs = rng.normal(size=(n, 9, 3))
    m = quad.random_rotations(rng, n)
    w = quad.random_dirs(rng, n)
    rotated = sh.rotate(coeffs, m)
    np.testing.assert_allclose(
        sh.evaluate_sh(rotated, w), sh.evaluate_sh(coeffs, np.einsum("nij,nj->ni", m, w)), atol=1e-12
    )
    np.testing.assert_allclose(sh.rotate(coeffs[:, :, 0], m), rotated[:, :, 0], atol=1e-12)


def test_rotation_preserves_band_energy(rng):
    coeffs = rng.normal(size=(20, 9, 3))
    rotated = sh.rotate(coeffs, quad.random_rotations(rng, 20))
    for band in (slice(0, 1), slice(1, 4), slice(4, 9)):
        np.testing.assert_allclose((rotated[:, band] ** 2).sum(1), (coeffs[:, band] ** 2).sum(1), rtol=1e-12)


@pytest.mark.parametrize("normal", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, -1, 0), (1e-9, 0, -1), (0.6, 0.0, 0.8)])
def test_tangent_frames_are_right_handed_orthonormal_with_z_on_the_normal(normal):
    n = np.array([normal], dtype=np.float64)
    n /= np.linalg.norm(n)
    f = sh.tangent_frames(n)[0]
    np.testing.assert_allclose(f.T @ f, np.eye(3), atol=1e-12)
    assert np.linalg.det(f) == pytest.approx(1.0)
    np.testing.assert_allclose(f[:, 2], n[0], atol=1e-15)


def test_local_frame_round_trip_and_zenith_value(rng):
    n = quad.random_dirs(rng, 30)
    coeffs = rng.normal(size=(30, 9, 3))
    frames = sh.tangent_frames(n)
    local = sh.to_local(coeffs, frames)
    np.testing.assert_allclose(sh.to_world(local, frames), coeffs, atol=1e-12)
    z = np.tile([0.0, 0.0, 1.0], (30, 1))
    np.testing.assert_allclose(sh.evaluate_sh(local, z), sh.evaluate_sh(coeffs, n), atol=1e-12)
