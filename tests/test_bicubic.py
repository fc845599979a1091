"""core.textures.sample_bicubic against independent references: Catmull-Rom reproduces quadratic
fields exactly and interpolates the texels, the B-spline reproduces linear fields and has the
known weights (1, 4, 1)/6 at a texel centre, both sum to one; black stays black, HDR stays
finite, the clamp reads the edge texel, and the Catmull-Rom overshoot is clamped when asked.
core.textures.bspline_coefficients: the B-spline of the coefficients keeps every texel's mean
(Gauss-Legendre over each texel), is closer than Catmull-Rom to an exact hard edge, fills the
unmarked texels instead of ringing with them, stays finite; the documented 4-tap listing."""

import numpy as np
import pytest

from hhd_lightmapper.core.textures import (
    AREA_KERNEL,
    bspline_coefficients,
    bspline_weights,
    catmull_rom_weights,
    sample_bicubic,
    sample_bilinear,
)

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


def texel_means(coefficients: np.ndarray) -> np.ndarray:
    """The mean of the B-spline of `coefficients` `(H, W, C)` over every texel: Gauss-Legendre,
    2 points per half texel and axis (exact: the spline is cubic between texel centres)."""
    h, w = coefficients.shape[:2]
    g = np.array([-1.0, 1.0]) / np.sqrt(3.0)
    offsets = np.concatenate([0.25 + 0.25 * g, 0.75 + 0.25 * g])  # within a texel, in texels
    j, i = np.mgrid[0:h, 0:w]
    total = 0.0
    for dy in offsets:
        for dx in offsets:
            uv = np.column_stack([(i.ravel() + dx) / w, (j.ravel() + dy) / h])
            total = total + sample_bicubic(coefficients, uv, clamp=True, kernel="bspline")
    return (total / len(offsets) ** 2).reshape(coefficients.shape)


def test_bspline_coefficients_keep_every_texels_mean():
    """The prefiltered B-spline's mean over each texel is the texel (the bake's texel is its
    footprint's mean), away from the image's border (mirrored there, clamped by the sampler)."""
    image = RNG.uniform(0.0, 4.0, (20, 24, 3))
    c = bspline_coefficients(image).astype(np.float64)
    assert np.abs(texel_means(c) - image)[2:-2, 2:-2].max() < 1e-5
    assert np.abs(texel_means(image) - image)[2:-2, 2:-2].max() > 0.1  # the unfiltered B-spline blurs
    # one channel; a linear field is its own coefficients (the kernel is symmetric), away from
    # the mirrored border (its error decays by the pole, ≈ 0.36, per texel)
    ramp = field_image(lambda x, y: 0.5 + 0.1 * x + 0.2 * y, 40, 40)[..., 0]
    assert np.abs(bspline_coefficients(ramp) - ramp)[12:-12, 12:-12].max() < 1e-5


def test_prefiltered_bspline_draws_a_step_closer_than_catmull_rom_and_bilinear():
    """Texel means of a shadow's hard edge (exact: the area of the texel past the edge line),
    sampled three ways against the edge itself, within one texel of it."""
    h, w = 24, 24
    angle, offset = np.radians(20.0), 12.3  # the edge: x cos + y sin = offset (texel units)
    normal = np.array([np.cos(angle), np.sin(angle)])
    fine = (np.arange(64) + 0.5) / 64
    fx, fy = np.meshgrid(fine, fine)
    j, i = np.mgrid[0:h, 0:w]
    inside = (i[..., None, None] + fx) * normal[0] + (j[..., None, None] + fy) * normal[1] > offset
    image = inside.mean(axis=(-1, -2))[..., None]
    t = np.random.default_rng(3).uniform(6.0, 18.0, (20000, 2))
    t = t[np.abs(t @ normal - offset) < 1.0]
    truth = (t @ normal > offset).astype(np.float64)
    uv = t / [w, h]
    c = bspline_coefficients(image)
    rms = {
        "bilinear": sample_bilinear(image, uv, clamp=True)[:, 0],
        "catmull_rom": sample_bicubic(image, uv, clamp=True)[:, 0],
        "prefiltered": sample_bicubic(c, uv, clamp=True, kernel="bspline")[:, 0],
    }
    rms = {k: float(np.sqrt(np.mean((v - truth) ** 2))) for k, v in rms.items()}
    assert rms["prefiltered"] < 0.97 * rms["catmull_rom"] < 0.97 * rms["bilinear"], rms


def test_bspline_coefficients_fill_the_gutter_and_stay_finite():
    """A chart of constant I_z beside unfilled (zero) texels: with the chart marked filled the
    coefficients inside are the constant (no ringing from the zeros); NaN texels count as
    unfilled; a step of float32's largest value stays finite; black stays black."""
    image = np.zeros((16, 16, 3))
    image[4:12, 4:12] = 2.0
    filled = image[..., 0] > 0
    c = bspline_coefficients(image, filled)
    assert np.abs(c[4:12, 4:12] - 2.0).max() < 1e-5
    assert np.abs(bspline_coefficients(image)[4:12, 4:12] - 2.0).max() > 0.05  # unmarked: the zeros ring in
    image[6, 6] = np.nan
    c = bspline_coefficients(image, filled)
    assert np.isfinite(c).all() and np.abs(c[4:12, 4:12] - 2.0).max() < 1e-5
    huge = np.zeros((8, 8, 1), np.float32)
    huge[:, 4:] = np.finfo(np.float32).max
    assert np.isfinite(bspline_coefficients(huge)).all()
    assert not bspline_coefficients(np.zeros((5, 7, 3))).any()


def test_the_four_tap_bspline_listing_is_the_bspline():
    """docs/format.md's SampleBSpline (4 bilinear taps) ported line by line: it equals the
    16-texel B-spline sum; and the documented poles and gain are AREA_KERNEL's."""
    rng = np.random.default_rng(11)
    image = rng.uniform(-1.0, 1.0, (20, 24, 3))  # coefficients can be negative
    size = np.array([24.0, 20.0])
    t = rng.uniform(0.0, 1.0, (1000, 2))
    p = t * size - 0.5
    i = np.floor(p)
    f = p - i
    s = 1.0 - f
    w0, w1 = s * s * s / 6, (4 + f * f * (3 * f - 6)) / 6
    w2, w3 = (1 + 3 * f * (1 + f * s)) / 6, f * f * f / 6
    g0, g1 = w0 + w1, w2 + w3
    c0, c1 = (i - 0.5 + w1 / g0) / size, (i + 1.5 + w3 / g1) / size

    def tap(cx, cy):
        return sample_bilinear(image, np.column_stack([cx[:, 0], cy[:, 1]]), clamp=True)

    out = (tap(c0, c0) * g0[:, :1] + tap(c1, c0) * g1[:, :1]) * g0[:, 1:] + (
        tap(c0, c1) * g0[:, :1] + tap(c1, c1) * g1[:, :1]
    ) * g1[:, 1:]
    assert np.allclose(out, sample_bicubic(image, t, clamp=True, kernel="bspline"), atol=1e-12)
    poles = np.sort(np.roots(AREA_KERNEL * 384.0).real)
    inside = poles[np.abs(poles) < 1]
    assert np.allclose(inside, [-0.3613412, -0.0137254], atol=1e-7)
    assert np.prod((1 - inside) * (1 - 1 / inside)) == pytest.approx(384.0)
