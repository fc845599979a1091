"""The encoder's compiled θ search (core/hhd/search_kernels.py) against the vectorised search it
replaced, written here from `search.golden` over `FitAtPhi.evaluate`: the same θ and w bit for
bit on texels of every kind (black, huge, tiny, grazing normals, sanitised NaN), for each model,
Gram matrix and fitted channels."""

import numpy as np
import pytest

from hhd_lightmapper.core.hhd import encoder, search
from hhd_lightmapper.core.hhd.fit import prepare
from hhd_lightmapper.core.hhd.lobes import MIN_COS, ambient_lobe

THETA_MAX = float(np.arccos(MIN_COS))


def reference_search_theta(at, theta_start, iterations=search.GOLDEN_ITERATIONS):
    """The vectorised search: a scan, golden sections in the best bracket, the best of them,
    the scan's best and the start (first of equals); and the fit's w there."""
    n = len(theta_start)
    grid = np.linspace(0.0, THETA_MAX, search.SCAN_STEPS)
    scan = np.stack([at.evaluate(np.full(n, t))[0] for t in grid], axis=1)
    k = np.argmin(scan, axis=1)
    step = grid[1] - grid[0]
    lo, hi = np.clip(grid[k] - step, 0.0, THETA_MAX), np.clip(grid[k] + step, 0.0, THETA_MAX)
    theta, err = search.golden(lambda t: at.evaluate(t)[0], lo, hi, iterations)
    candidates = np.stack([theta, grid[k], theta_start], axis=1)
    errors = np.stack([err, scan[np.arange(n), k], at.evaluate(theta_start)[0]], axis=1)
    chosen = candidates[np.arange(n), np.argmin(errors, axis=1)]
    return chosen, at.evaluate(chosen)[1]


def texels(count=6000, seed=3):
    """Radiance SH `(N, 9, 3)` of mixed kinds and normals `(N, 3)`."""
    rng = np.random.default_rng(seed)
    sh = rng.normal(size=(count, 9, 3)) * 0.3
    sh[:, 0] = np.abs(sh[:, 0]) + 0.5  # mostly positive radiance, some ringing
    n = rng.normal(size=(count, 3))
    n[:, 2] = np.abs(n[:, 2]) + 0.2
    k = count // 8
    sh[:k] = 0.0  # black
    sh[k : 2 * k] *= 1e30
    sh[2 * k : 3 * k] *= 1e-30
    n[3 * k : 4 * k] = [1.0, 0.0, 1e-9]  # grazing
    sh[4 * k, 2, 1] = np.nan  # sanitised to black
    sh[4 * k + 1 : 5 * k, 1:] = 0.0  # all ambient
    return sh, n


@pytest.mark.parametrize("model", ["hhd", "ahd"])
@pytest.mark.parametrize("gram", ["hemisphere", "sphere"])
@pytest.mark.parametrize("luminance", [True, False])
def test_the_compiled_search_gives_the_vectorised_searchs_bits(model, gram, luminance):
    sh, n = texels()
    world, unit_n, _ = encoder.sanitise(sh, n)
    fit, _, local, _, _, lum_fit = prepare(
        world, unit_n, a=ambient_lobe(model), g=encoder.gram_matrix(gram), luminance=luminance, hemisphere_sampled=True
    )
    start, phi = search.optimal_linear_angles(local, lum_fit, THETA_MAX)
    at = fit.at_phi(phi)
    theta, err, w = search.search_theta(fit, phi, start, THETA_MAX, at=at)
    ref_theta, ref_w = reference_search_theta(at, start)
    assert theta.tobytes() == ref_theta.tobytes()
    assert w.tobytes() == ref_w.tobytes()
    # the objective at the chosen θ: a weighted sum over the channels (numpy's may round it apart)
    np.testing.assert_allclose(err, at.evaluate(theta)[0], rtol=1e-12, atol=1e-300)
    assert np.isfinite(theta).all() and ((w >= 0.0) & (w <= 1.0)).all()


def test_the_search_takes_no_texel():
    fit, _, local, _, _, lum_fit = prepare(
        np.zeros((0, 9, 3)), np.zeros((0, 3)), a=ambient_lobe("hhd"), g=encoder.gram_matrix("hemisphere"),
        luminance=True, hemisphere_sampled=True,
    )  # fmt: skip
    start, phi = search.optimal_linear_angles(local, lum_fit, THETA_MAX)
    theta, err, w = search.search_theta(fit, phi, start, THETA_MAX)
    assert theta.shape == err.shape == (0,) and w.shape == (0, 1)
    p = encoder.encode(np.zeros((0, 9, 3)), np.zeros((0, 3)))
    assert p.irradz.shape == (0, 3) and p.ambient_weight.shape == (0,) and p.direction.shape == (0, 3)
