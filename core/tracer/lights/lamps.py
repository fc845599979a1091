"""The lights rays never hit: sun, point, spot and area lights (next-event estimation only;
an area light by a direction uniform in its solid angle). No bpy."""

from __future__ import annotations

import numpy as np

from ... import sh as _sh
from ...colour import LUMINANCE
from ...scene import AreaLight, PointLight, SpotLight, SunLight
from .. import light_kernels as _kernels
from .emitters import SOLID_ANGLE_RANGE
from .light import Light, Sample, Strata, _rows, uniforms


class Sun(Light):
    """A distant light: a direction (delta, angle 0) or a uniform cone of angular diameter
    `angle`; value: its irradiance at normal incidence (an unshadowed delta sun adds exactly
    s·Y(l) to the SH: no noise)."""

    at_infinity = True

    def __init__(self, light: SunLight):
        self.direction, self.irradiance, self.angle = light.direction, light.irradiance, light.angle
        self.is_delta, self.group = light.is_delta, light.group

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        r = len(x)
        axis = np.broadcast_to(self.direction, (r, 3))
        dirs = axis if self.is_delta else _cone_directions(rng, axis, np.cos(0.5 * self.angle), strata)
        return dirs, np.broadcast_to(self.irradiance, (r, 3)), np.full(r, np.inf)

    @property
    def power(self) -> float:
        return float(np.asarray(self.irradiance) @ LUMINANCE)


class Point(Light):
    """A point light of power P (W, RGB): a true point (radius 0, exact direction) or, with a
    radius r, radiance P/(4π² r²) over the cone it subtends, sampled uniformly: a disk facing the
    shaded point with soft falloff (Blender's default), else a sphere (Cycles' point_light_sample)."""

    chosen = True

    def __init__(self, light: PointLight):
        self.position, self.rgb_power, self.radius = light.position, light.power, light.radius
        self.soft_falloff, self.is_delta, self.group = light.soft_falloff, light.is_delta, light.group

    def choice_row(self) -> list[float]:
        """Its row of `Choice.table`: its sphere, P/4π as the intensity, lit all round."""
        r = float(self.radius)
        return [*map(float, self.position), r * r, r, self.power / (4.0 * np.pi), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.pi]

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        to = self.position - x
        dist = np.maximum(np.linalg.norm(to, axis=1), 1e-30)
        axis = to / dist[:, None]
        if self.is_delta:
            return axis, self.rgb_power[None, :] / (4.0 * np.pi * dist**2)[:, None], dist
        if self.soft_falloff:  # a disk of radius r facing the point
            cos_a = dist / np.sqrt(dist**2 + self.radius**2)
        else:  # a sphere of radius r
            cos_a = np.sqrt(1.0 - np.minimum(self.radius / dist, 1.0) ** 2)
        # radiance P/(4π² r²) over the cone the light subtends, solid angle 2π(1 - cos α)
        value = self.rgb_power[None, :] / (4.0 * np.pi**2 * self.radius**2) * (2.0 * np.pi * (1.0 - cos_a))[:, None]
        return _cone_directions(rng, axis, cos_a, strata), value, np.maximum(dist - self.radius, 0.0)

    @property
    def power(self) -> float:
        return float(np.asarray(self.rgb_power) @ LUMINANCE)


class Spot(Point):
    """A point light limited to a cone (core.scene.SpotLight): Cycles' smoothstep attenuation of
    the angle between the spot's axis and the direction from the light to the shaded point."""

    def __init__(self, light: SpotLight):
        super().__init__(light)
        self.axis, self.size, self.blend = light.direction, light.size, light.blend

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        dirs, value, dist = super().sample(rng, x, ray_pdf, strata)
        return dirs, value * self.attenuation(-dirs)[:, None], dist

    def choice_row(self) -> list[float]:
        """The point light's row, with its cone: its axis and half-angle (dark outside)."""
        return super().choice_row()[:9] + [*map(float, self.axis), 0.5 * float(self.size)]

    def attenuation(self, light_to_point: np.ndarray) -> np.ndarray:
        """(R,) in [0, 1] for unit directions (R, 3) from the light towards the shaded points."""
        cos_half = np.cos(0.5 * self.size)
        x = light_to_point @ self.axis - cos_half
        if self.blend <= 0.0:
            return (x > 0.0).astype(np.float64)
        f = np.clip(x / ((1.0 - cos_half) * self.blend), 0.0, 1.0)
        return f * f * (3.0 - 2.0 * f)


class Area(Light):
    """A one-sided Lambertian rectangle, square, disk or ellipse (core.scene.AreaLight) of
    radiance P / (π A). Sampled by a uniform direction in the solid angle of its rectangle
    (`sample_spherical_rectangles`; compiled: `light_kernels.sample_area_light`, whose numpy spec is
    `sample_numpy`): no 1/d² spikes beside the lamp. A disk or ellipse is counted
    where that direction meets it (its bounding rectangle's solid angle × inside: unbiased, and
    bounded by 2π × the radiance); where the rectangle subtends less than SOLID_ANGLE_RANGE's
    least, by a uniform point on its surface (the two agree there)."""

    chosen = True

    def __init__(self, light: AreaLight):
        self.position, self.axis_u, self.axis_v = light.position, light.axis_u, light.axis_v
        self.normal, self.rgb_power, self.shape = light.normal, light.power, light.shape
        self.area, self.group = light.area, light.group

    def choice_row(self) -> list[float]:
        """Its row of `Choice.table`: the sphere through its corners, the intensity of a
        Lambertian emitter of its power along its normal (P/π), one-sided along the normal."""
        r2 = float(self.axis_u @ self.axis_u + self.axis_v @ self.axis_v)
        return [
            *map(float, self.position),
            r2,
            r2**0.5,
            self.power / np.pi,
            *map(float, self.normal),
            0.0,
            0.0,
            0.0,
            np.pi,
        ]

    def sample(self, rng, x, ray_pdf=None, strata=1, normals=None) -> Sample:
        u1, u2 = uniforms(rng, len(x), strata, 2), uniforms(rng, len(x), strata, 3)
        dirs, solid_angle, dist = _kernels.get().sample_area_light(
            _rows(x),
            np.ascontiguousarray(u1, np.float64),
            np.ascontiguousarray(u2, np.float64),
            self._rect,
            self._light,
            self.shape in ("DISK", "ELLIPSE"),
            SOLID_ANGLE_RANGE[0],
        )
        radiance = self.rgb_power / (np.pi * self.area)
        return dirs, radiance[None, :] * solid_angle[:, None], dist

    def sample_numpy(self, rng, x, strata=1) -> Sample:
        """`sample` in numpy: the spec of the compiled `light_kernels.sample_area_light`, the tests
        compare them."""
        u1, u2 = uniforms(rng, len(x), strata, 2), uniforms(rng, len(x), strata, 3)
        corner = self.position - self.axis_u - self.axis_v
        p, solid_angle = sample_spherical_rectangles(x, corner, 2.0 * self.axis_u, 2.0 * self.axis_v, u1, u2)
        by_direction = (solid_angle >= SOLID_ANGLE_RANGE[0]) & np.isfinite(p).all(axis=1)
        p = np.where(by_direction[:, None], p, self._surface_points(u1, u2))
        to = p - x
        dist = np.maximum(np.linalg.norm(to, axis=1), 1e-30)
        dirs = to / dist[:, None]
        cos_l = np.maximum(-(dirs @ self.normal), 0.0)
        if self.shape in ("DISK", "ELLIPSE"):
            solid_angle = solid_angle * self._inside(p)
        # radiance × the solid angle the sample stands for (of the area element: A cos_l / d²)
        weight = np.where(by_direction, np.where(cos_l > 0.0, solid_angle, 0.0), self.area * cos_l / dist**2)
        radiance = self.rgb_power / (np.pi * self.area)
        return dirs, radiance[None, :] * weight[:, None], dist

    @property
    def _rect(self) -> np.ndarray:
        """(4, 3) for the kernel: the rectangle's corner, unit edges, (edge lengths, 0)."""
        eu, ev = 2.0 * self.axis_u, 2.0 * self.axis_v
        lu, lv = float(np.linalg.norm(eu)), float(np.linalg.norm(ev))
        return np.array([self.position - self.axis_u - self.axis_v, eu / lu, ev / lv, [lu, lv, 0.0]], np.float64)

    @property
    def _light(self) -> np.ndarray:
        """(4, 3) for the kernel: centre, axis_u, axis_v, unit normal."""
        return np.array([self.position, self.axis_u, self.axis_v, self.normal], np.float64)

    def sample_points(self, rng: np.random.Generator, n: int, strata: Strata = 1) -> np.ndarray:
        """n points (n, 3) uniform over the light's surface (`strata`: `uniforms`)."""
        return self._surface_points(uniforms(rng, n, strata, 2), uniforms(rng, n, strata, 3))

    def _surface_points(self, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
        """Points (n, 3) on the light's surface, uniform for uniform numbers u1, u2 (n,)."""
        if self.shape in ("DISK", "ELLIPSE"):
            r, phi = np.sqrt(u1), 2.0 * np.pi * u2
            a, b = r * np.cos(phi), r * np.sin(phi)
        else:
            a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
        return self.position + a[:, None] * self.axis_u + b[:, None] * self.axis_v

    def _inside(self, p: np.ndarray) -> np.ndarray:
        """(n,) 1.0 where points p (n, 3) of the light's plane lie in its disk or ellipse, else 0."""
        rel = p - self.position
        a = rel @ self.axis_u / (self.axis_u @ self.axis_u)
        b = rel @ self.axis_v / (self.axis_v @ self.axis_v)
        return (a * a + b * b <= 1.0).astype(np.float64)

    @property
    def power(self) -> float:
        return float(np.asarray(self.rgb_power) @ LUMINANCE)


def sample_spherical_rectangles(
    x: np.ndarray, corner: np.ndarray, ex: np.ndarray, ey: np.ndarray, u1: np.ndarray, u2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Points (R, 3) on the rectangle corner + s·ex + t·ey (corner, ex, ey (3,); ex ⟂ ey; s, t in
    [0, 1]) whose directions from x (R, 3) are uniform in the solid angle it subtends there, for
    uniform numbers u1, u2 (R,), and that solid angle (R,) in steradians (0 from its plane; NaN
    where it cannot be found). Ureña, Fajardo & King 2013, in PBRT-v4's SampleSphericalRectangle
    form: in a frame with z away from the rectangle, the solid angle is the sum of the angles
    between the planes through x and its edges, less 2π; u1 picks the x of the point by the
    solid angle left of it, u2 its y, uniformly in the sine of the elevation."""
    exl, eyl = float(np.linalg.norm(ex)), float(np.linalg.norm(ey))
    ax, ay = ex / exl, ey / eyl
    az = np.cross(ax, ay)
    d = corner - x
    x0, y0, z = d @ ax, d @ ay, d @ az
    h = np.abs(z)  # the local z axis points away from the rectangle: z0 = −h
    x1, y1 = x0 + exl, y0 + eyl
    zz = z * z
    # corner angles g_i = arg(c_i + i·s_i) (between the planes through x and two edges), summed
    # by multiplying: the solid angle Σg − 2π takes one arctan, and au needs only cos and sin of
    # g2 + g3 (au = u1·solid angle − g2 − g3 ≡ Ureña's u1·S + 2π − g2 − g3)
    c0, s0 = x1 * y0, h * np.sqrt(x1 * x1 + y0 * y0 + zz)
    c1, s1 = -x1 * y1, h * np.sqrt(x1 * x1 + y1 * y1 + zz)
    c2, s2 = x0 * y1, h * np.sqrt(x0 * x0 + y1 * y1 + zz)
    c3, s3 = -x0 * y0, h * np.sqrt(x0 * x0 + y0 * y0 + zz)
    ca, sa = c0 * c1 - s0 * s1, c0 * s1 + s0 * c1
    cb, sb = c2 * c3 - s2 * s3, c2 * s3 + s2 * c3
    solid_angle = np.mod(np.arctan2(ca * sb + sa * cb, ca * cb - sa * sb), 2.0 * np.pi)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.sqrt(cb * cb + sb * sb)
        v = u1 * solid_angle
        cos_au = (np.cos(v) * cb + np.sin(v) * sb) * inv
        sin_au = (np.sin(v) * cb - np.cos(v) * sb) * inv
        b0, b1 = -y0 / np.sqrt(zz + y0 * y0), y1 / np.sqrt(zz + y1 * y1)
        fu = (cos_au * b0 - b1) / sin_au
        cu = np.clip(np.copysign(1.0 / np.sqrt(fu * fu + b0 * b0), fu), -1.0 + 1e-12, 1.0 - 1e-12)
        xu = np.clip(h * cu / np.sqrt(1.0 - cu * cu), x0, x1)
        dd = np.sqrt(xu * xu + zz)
        h0, h1 = y0 / np.sqrt(dd * dd + y0 * y0), y1 / np.sqrt(dd * dd + y1 * y1)
        hv = h0 + u2 * (h1 - h0)
        yv = np.where(hv * hv < 1.0 - 1e-12, hv * dd / np.sqrt(np.maximum(1.0 - hv * hv, 1e-300)), y1)
    points = x + xu[:, None] * ax + yv[:, None] * ay + z[:, None] * az
    return points, np.where(z == 0.0, 0.0, solid_angle)


def _cone_directions(rng, axis: np.ndarray, cos_max, strata: Strata = 1) -> np.ndarray:
    """Uniform directions in cones around `axis` (R, 3) with half-angle arccos(cos_max)
    (`strata`: `uniforms`)."""
    u1, u2 = uniforms(rng, len(axis), strata, 2), uniforms(rng, len(axis), strata, 3)
    z = 1.0 - u1 * (1.0 - cos_max)
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    local = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    return np.einsum("rij,rj->ri", _sh.tangent_frames(axis), local)
