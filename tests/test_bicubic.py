"""core.textures.sample_bicubic against independent references: Catmull-Rom reproduces quadratic
fields exactly and interpolates the texels, the B-spline reproduces linear fields and has the
known weights (1, 4, 1)/6 at a texel centre, both sum to one; black stays black, HDR stays
finite, the clamp reads the edge texel, and the Catmull-Rom overshoot is clamped when asked."""

import numpy as np
import pytest

from hhd_lightmapper.core.textures import bspline_weights, catmull_rom_weights, sample_bicubic, sample_bilinear

RNG = np.random.default_rng(7)


def field_image(f, h=12, w=16):
    """(H, W, 1) image of f(x, y) at texel centres, x, y in texel units (row 0 at v = 0)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    return f(x, y)[..., None]


def interior_uv(n, h=12, w=16):
    """uv whose 4 × 4 footprint stays inside the image (no clamping)."""
    x = RNG.uniform(1.5, w - 2.5, n)
    y = RNG.uniform(1.5, h - 2.5, n)
    return np.column_stack([(x + 0.5) / w, (y + 0.5) / h]), x, y


def test_weights_sum_to_one_and_match_the_kernels():
    t = np.linspace(0.0, 1.0, 101)
    for weights in (catmull_rom_weights, bspline_weights):
        assert np.allclose(weights(t).sum(-1), 1.0, atol=1e-15)
    assert np.allclose(catmull_rom_weights(0.0), [0, 1, 0, 0])
    assert np.allclose(catmull_rom_weights(0.5), [-1 / 16, 9 / 16, 9 / 16, -1 / 16])
    assert np.allclose(bspline_weights(0.0), [1 / 6, 4 / 6, 1 / 6, 0])
    assert np.allclose(bspline_weights(0.5), [1 / 48, 23 / 48, 23 / 48, 1 / 48])
    assert (bspline_weights(t) >= 0).all() and (catmull_rom_weights(t) < 0).any()


def test_catmull_rom_reproduces_quadratics_and_interpolates():
    def f(x, y):
        return 0.3 + 0.2 * x - 0.1 * y + 0.05 * x * x + 0.02 * x * y - 0.03 * y * y

    image = field_image(f)
    uv, x, y = interior_uv(500)
    assert np.allclose(sample_bicubic(image, uv)[:, 0], f(x, y), atol=1e-12)
    # at the texel centres: the texels themselves, whatever they hold
    noise = RNG.uniform(0.0, 5.0, (12, 16, 3))
    j, i = np.mgrid[2:10, 2:14]
    centres = np.column_stack([(i.ravel() + 0.5) / 16, (j.ravel() + 0.5) / 12])
    assert np.allclose(sample_bicubic(noise, centres), noise[j.ravel(), i.ravel()], atol=1e-12)


def test_bspline_reproduces_linear_fields_but_blurs_a_texel():
    def f(x, y):
        return 1.0 + 0.25 * x - 0.5 * y

    uv, x, y = interior_uv(500)
    assert np.allclose(sample_bicubic(field_image(f), uv, kernel="bspline")[:, 0], f(x, y), atol=1e-12)
    spike = np.zeros((9, 9, 1))
    spike[4, 4] = 1.0
    centre = np.array([[4.5 / 9, 4.5 / 9]])
    assert sample_bicubic(spike, centre, kernel="bspline")[0, 0] == pytest.approx(16 / 36)
    assert sample_bicubic(spike, centre)[0, 0] == pytest.approx(1.0)


def test_black_huge_and_the_clamp():
    uv = RNG.uniform(0.0, 1.0, (300, 2))
    assert not sample_bicubic(np.zeros((8, 8, 3)), uv).any()
    huge = np.full((8, 8, 3), np.finfo(np.float32).max, np.float32)
    huge[::2] = 0.0  # a step of the largest float32 at every other row: the overshoot is finite
    for kernel in ("catmull_rom", "bspline"):
        out = sample_bicubic(huge, uv, clamp=True, kernel=kernel)
        assert np.isfinite(out).all()
    # clamped: outside the image the edge texels repeat, as if the image were padded with them
    image = RNG.uniform(0.0, 1.0, (6, 7, 2))
    padded = np.pad(image, ((3, 3), (3, 3), (0, 0)), mode="edge")
    edge = np.column_stack([RNG.uniform(0.0, 1.0, 200), RNG.uniform(0.0, 1.0, 200)])
    edge[:20, 0], edge[20:40, 1] = 0.0, 1.0
    inner = (edge * [7, 6] + 3) / [13, 12]
    assert np.allclose(sample_bicubic(image, edge, clamp=True), sample_bicubic(padded, inner), atol=1e-12)
    ramp = field_image(lambda x, y: x + 0 * y, 8, 8)
    assert sample_bicubic(ramp, np.array([[0.0, 0.5]]))[0, 0] > 0.5  # repeat: the last column's 7 takes part
    assert sample_bilinear(ramp, np.array([[0.0, 0.5]]))[0, 0] > 0.5


def test_overshoot_is_clamped_for_irradiance():
    step = np.zeros((8, 8, 1))
    step[:, 4:] = 1.0
    uv = np.column_stack([np.linspace(0.3, 0.7, 200), np.full(200, 0.5)])
    raw = sample_bicubic(step, uv)[:, 0]
    assert raw.min() < -0.05 and raw.max() > 1.05  # Catmull-Rom's lobes next to a step
    clamped = sample_bicubic(step, uv, nonnegative=True)[:, 0]
    assert clamped.min() == 0.0 and np.array_equal(clamped, np.maximum(raw, 0.0))
    with pytest.raises(ValueError):
        sample_bicubic(step, uv, kernel="lanczos")


def test_the_nine_tap_runtime_listing_is_catmull_rom():
    """docs/format.md's SampleCatmullRom (9 bilinear taps, the middle texels merged) ported line
    by line, the bilinear taps by sample_bilinear with clamp: it equals the 16-texel sum."""
    image = RNG.uniform(0.0, 1.0, (20, 24, 3))
    size = np.array([24.0, 20.0])
    t = RNG.uniform(0.0, 1.0, (1000, 2))
    p = t * size - 0.5
    i = np.floor(p)
    f = p - i
    w0, w3 = f * (-0.5 + f * (1.0 - 0.5 * f)), f * f * (-0.5 + 0.5 * f)
    w1, w2 = 1.0 + f * f * (-2.5 + 1.5 * f), f * (0.5 + f * (2.0 - 1.5 * f))
    w12 = w1 + w2
    c0, c12, c3 = (i - 0.5) / size, (i + 0.5 + w2 / w12) / size, (i + 2.5) / size
    taps = ((c0, w0), (c12, w12), (c3, w3))
    out = sum(
        sample_bilinear(image, np.column_stack([cx[:, 0], cy[:, 1]]), clamp=True) * (wx[:, 0] * wy[:, 1])[:, None]
        for cy, wy in taps
        for cx, wx in taps
    )
    assert np.allclose(out, sample_bicubic(image, t, clamp=True), atol=1e-12)
