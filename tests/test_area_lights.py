"""Area lights (core.tracer.lights.Area) sampled by solid angle: the spherical rectangle's solid
angle against its closed form, next-event estimation unbiased against Lambert's formula for every
shape from far away to a millimetre off the lamp, and the noise beside the lamp bounded where a
uniform point on the lamp's surface spikes. No bpy."""

from __future__ import annotations

import numpy as np
import pytest

from hhd_lightmapper.core.scene import AreaLight
from hhd_lightmapper.core.tracer import lights
from test_emitter_clusters import polygon_irradiance

#: A 0.8 × 0.4 m lamp at z = 1, facing down (-z), tilted about x so no axis lines up.
TILT = np.radians(20.0)
AXIS_U = np.array([0.4, 0.0, 0.0])
AXIS_V = 0.2 * np.array([0.0, np.cos(TILT), np.sin(TILT)])
NORMAL = -np.cross(AXIS_U, AXIS_V) / np.linalg.norm(np.cross(AXIS_U, AXIS_V))
CENTRE = np.array([0.1, -0.2, 1.0])
POWER = np.array([60.0, 40.0, 20.0])


def lamp(shape: str) -> lights.lamps.Area:
    return lights.lamps.Area(AreaLight(CENTRE, AXIS_U, AXIS_V, NORMAL, POWER, shape))


def outline(shape: str, sides: int = 2048) -> np.ndarray:
    """The lamp's outline (V, 3): its 4 corners, or a polygon of `sides` inscribed in its ellipse
    (Lambert's formula on it is the ellipse's irradiance within ~(π / sides)² / 3 relative)."""
    if shape in ("SQUARE", "RECTANGLE"):
        a, b = np.array([-1, 1, 1, -1.0]), np.array([-1, -1, 1, 1.0])
    else:
        phi = 2.0 * np.pi * np.arange(sides) / sides
        a, b = np.cos(phi), np.sin(phi)
    return CENTRE + a[:, None] * AXIS_U + b[:, None] * AXIS_V


def receivers() -> list[tuple[np.ndarray, np.ndarray]]:
    """Points below the lamp (far, near, a millimetre off it, off to the side) with normals
    toward it, tilted so that the whole lamp stays above their horizon."""
    out = []
    for gap, tilt in ((5.0, 0.0), (1.0, 0.3), (0.05, 0.0), (1e-3, 0.0), (0.3, -0.4)):
        x = CENTRE + np.array([0.05, 0.03, 0.0]) + gap * NORMAL
        n = -NORMAL + tilt * AXIS_U / np.linalg.norm(AXIS_U)
        out.append((x, n / np.linalg.norm(n)))
    return out


@pytest.mark.parametrize("h", [10.0, 1.0, 0.1, 1e-3, 1e-6])
def test_the_spherical_rectangles_solid_angle_is_the_closed_form_and_its_points_lie_on_it(h):
    """From a point at height h over the rectangle [-1, 1] × [-0.5, 0.5] (its foot at (0.2, 0.1)),
    the solid angle is the sum over the four quadrants around the foot of asin(ab / √((a² + h²)(b²
    + h²))) (the rectangle a × b seen from a height h over its corner)."""
    x = np.tile([0.2, 0.1, -h], (1000, 1))
    rng = np.random.default_rng(1)
    corner, ex, ey = np.array([-1.0, -0.5, 0.0]), np.array([2.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    p, solid_angle = lights.lamps.sample_spherical_rectangles(x, corner, ex, ey, rng.random(1000), rng.random(1000))

    def quadrant(a, b):
        return np.arcsin(a * b / np.sqrt((a * a + h * h) * (b * b + h * h)))

    exact = quadrant(1.2, 0.6) + quadrant(0.8, 0.6) + quadrant(1.2, 0.4) + quadrant(0.8, 0.4)
    np.testing.assert_allclose(solid_angle, exact, rtol=1e-9)
    assert np.abs(p[:, 2]).max() == 0.0
    assert (p[:, 0] >= -1.0 - 1e-12).all() and (p[:, 0] <= 1.0 + 1e-12).all()
    assert (p[:, 1] >= -0.5 - 1e-12).all() and (p[:, 1] <= 0.5 + 1e-12).all()


@pytest.mark.statistical
@pytest.mark.parametrize("shape", ["SQUARE", "RECTANGLE", "DISK", "ELLIPSE"])
def test_next_event_estimate_is_unbiased_against_lamberts_formula_up_to_the_lamp(shape):
    light, k = lamp(shape), 200_000
    radiance = POWER / (np.pi * light.area)
    for x, n in receivers():
        exact = polygon_irradiance(x, n, outline(shape), radiance)
        dirs, value, dist = light.sample(np.random.default_rng(7), np.tile(x, (k, 1)))
        terms = value * np.maximum(dirs @ n, 0.0)[:, None]
        err = terms.std(axis=0) / np.sqrt(k)
        np.testing.assert_array_less(np.abs(terms.mean(axis=0) - exact), 5 * err + 1e-6 * exact)
        hit = value[:, 0] > 0.0
        # the shadow ray ends on the lamp's plane
        np.testing.assert_allclose(((x + dirs[hit] * dist[hit, None]) - CENTRE) @ NORMAL, 0.0, atol=1e-9)


@pytest.mark.parametrize("shape", ["SQUARE", "DISK"])
def test_beside_the_lamp_the_noise_is_bounded_where_surface_points_spike(shape):
    """A millimetre off the lamp: every sample is at most 2π × the radiance (the solid angle of
    a hemisphere), and the per-sample variance of the irradiance a hundred times below that of a
    uniform point on the lamp's surface (radiance × A cosθ_l / d²: unbounded as d → 0)."""
    light, k = lamp(shape), 100_000
    radiance = POWER / (np.pi * light.area)
    x, n = receivers()[3]
    dirs, value, _ = light.sample(np.random.default_rng(3), np.tile(x, (k, 1)))
    assert (value <= 2.0 * np.pi * radiance * (1 + 1e-12)).all()
    ours = (value[:, 1] * np.maximum(dirs @ n, 0.0)).var()
    p = light.sample_points(np.random.default_rng(3), k)
    to = p - x
    d = np.linalg.norm(to, axis=1)
    w = to / d[:, None]
    by_area = radiance[1] * light.area * np.maximum(-(w @ NORMAL), 0.0) * np.maximum(w @ n, 0.0) / d**2
    assert ours < 0.01 * by_area.var()


def test_behind_the_lamp_nothing_arrives():
    x = np.tile(CENTRE - 0.3 * NORMAL, (1000, 1))
    for shape in ("RECTANGLE", "ELLIPSE"):
        _, value, _ = lamp(shape).sample(np.random.default_rng(0), x)
        assert not value.any()


def test_a_far_lamp_falls_back_to_surface_points_and_stays_unbiased():
    """Seen from 200 m the lamp subtends ~8e-6 sr, below SOLID_ANGLE_RANGE: a uniform point on
    its surface (the spherical formulas lose precision there and the two agree anyway)."""
    light, k = lamp("RECTANGLE"), 20_000
    x, n = CENTRE + 200.0 * NORMAL, -NORMAL
    dirs, value, dist = light.sample(np.random.default_rng(5), np.tile(x, (k, 1)))
    exact = polygon_irradiance(x, n, outline("RECTANGLE"), POWER / (np.pi * light.area))
    terms = value * np.maximum(dirs @ n, 0.0)[:, None]
    np.testing.assert_allclose(terms.mean(axis=0), exact, rtol=1e-6)


@pytest.mark.parametrize("shape", ["RECTANGLE", "ELLIPSE"])
def test_the_compiled_samples_are_the_numpy_spec(shape):
    """`light_kernels.sample_area_light` against `Area.sample_numpy` on the same numbers, from points
    far, near, beside, behind and on the lamp's plane. A point on the lamp can draw itself (a
    sample at distance ~1e-17, carrying nothing): its direction is rounding noise, which differs
    between CPUs, so directions are compared where the sample lies apart."""
    light = lamp(shape)
    rng = np.random.default_rng(11)
    x = np.concatenate([CENTRE + rng.normal(0.0, s, (2000, 3)) for s in (0.02, 0.3, 3.0, 100.0)])
    x[:5] = CENTRE + 0.3 * AXIS_U  # in the lamp's plane, on the lamp
    got = light.sample(np.random.default_rng(2), x)
    spec = light.sample_numpy(np.random.default_rng(2), x)
    apart = spec[2] > 1e-9
    assert apart.sum() >= len(x) - 5
    np.testing.assert_allclose(got[0][apart], spec[0][apart], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got[1], spec[1], rtol=1e-9, atol=1e-12)  # every value, the degenerate ones 0
    np.testing.assert_allclose(got[2], spec[2], rtol=1e-9, atol=1e-12)
