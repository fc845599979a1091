"""An equirectangular HDRI world: radiance lookup and importance sampling. No bpy.

Mapping exactly as Cycles' Environment Texture node (kernel/camera/projection.h): for a lookup
direction b (the world direction through the node's vector mapping, normalised),
    u = 0.5 − atan2(b.y, b.x) / (2π),    v = 1 − acos(b.z) / π,
image row 0 at v = 0 (Blender's bottom-up rows), bilinear filtering with horizontal wrap.

Importance sampling picks a pixel with probability ∝ luminance · sin θ (the pixel's solid angle)
plus a small floor (the luminance is the maximum over the pixel's 3×3 neighbourhood, because
bilinear filtering spreads a bright pixel's radiance half a pixel into its neighbours), then a uniform point inside it; `pdf` returns the matching density per
steradian for any direction, so BSDF-sampled rays that miss can be MIS-weighted against it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .colour import LUMINANCE

#: Share of the sampling distribution spread uniformly over the sphere's pixels, so every
#: direction with radiance has a non-zero light-sampling density.
UNIFORM_FLOOR = 0.02


@dataclass
class EnvironmentMap:
    """pixels (H, W, 3): linear RGB radiance (image × Background strength), row 0 at v = 0;
    mapping (3, 3): world direction → lookup direction (normalised after the product); group:
    the light group the world belongs to ("": the default set)."""

    pixels: np.ndarray
    mapping: np.ndarray = field(default_factory=lambda: np.eye(3))
    group: str = field(default="", kw_only=True)

    def __post_init__(self):
        self.pixels = np.ascontiguousarray(
            np.nan_to_num(np.asarray(self.pixels, np.float64)[..., :3], nan=0.0, posinf=0.0, neginf=0.0).clip(0.0)
        )
        self.mapping = np.asarray(self.mapping, np.float64)
        self.inverse = np.linalg.inv(self.mapping)
        h, w = self.pixels.shape[:2]
        theta = np.pi * (1.0 - (np.arange(h) + 0.5) / h)  # row centre's polar angle
        weight = _neighbourhood_max(self.pixels @ LUMINANCE) * np.sin(theta)[:, None]
        total = weight.sum()
        uniform = np.broadcast_to(np.sin(theta)[:, None], (h, w))
        if total > 0.0:
            weight = (1.0 - UNIFORM_FLOOR) * weight / total + UNIFORM_FLOOR * uniform / uniform.sum()
        else:
            weight = uniform / uniform.sum()
        self.pixel_probability = weight.ravel()
        self.cdf = np.cumsum(self.pixel_probability)
        self.cdf /= self.cdf[-1]

    @property
    def is_black(self) -> bool:
        return not self.pixels.any()

    def _lookup(self, dirs: np.ndarray) -> np.ndarray:
        b = dirs @ self.mapping.T
        return b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-30)

    def uv(self, dirs: np.ndarray) -> np.ndarray:
        """Image coordinates (R, 2) of world directions (R, 3)."""
        b = self._lookup(dirs)
        # contiguous columns: on strided views numpy 1.x's arctan2 switches between two
        # implementations from call to call (they differ in the last bit), so a seed would not
        # reproduce a bake; on contiguous ones it does not (numpy 2 gives the same either way)
        u = 0.5 - np.arctan2(np.ascontiguousarray(b[:, 1]), np.ascontiguousarray(b[:, 0])) / (2.0 * np.pi)
        v = 1.0 - np.arccos(np.clip(b[:, 2], -1.0, 1.0)) / np.pi
        return np.stack([u % 1.0, np.clip(v, 0.0, 1.0)], axis=1)

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        """Radiance (R, 3) arriving from world directions (R, 3)."""
        return _sample_wrap_x(self.pixels, self.uv(dirs))

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n world directions drawn from the importance distribution and their pdf (per sr)."""
        h, w = self.pixels.shape[:2]
        pixel = np.minimum(np.searchsorted(self.cdf, rng.random(n), side="right"), h * w - 1)
        row, col = np.divmod(pixel, w)
        u = (col + rng.random(n)) / w
        v = (row + rng.random(n)) / h
        phi, theta = np.pi - 2.0 * np.pi * u, np.pi - np.pi * v
        s = np.sin(theta)
        b = np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=1)
        dirs = b @ self.inverse.T
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        return dirs, self.pdf(dirs)

    def pdf(self, dirs: np.ndarray) -> np.ndarray:
        """Sampling density per steradian of world directions (R, 3), including the Jacobian of
        a non-rotation mapping (for a rotation it is 1)."""
        h, w = self.pixels.shape[:2]
        uv = self.uv(dirs)
        col = np.minimum((uv[:, 0] * w).astype(np.int64), w - 1)
        row = np.minimum((uv[:, 1] * h).astype(np.int64), h - 1)
        b = self._lookup(dirs)
        sin_theta = np.sqrt(np.maximum(1.0 - b[:, 2] ** 2, 1e-12))
        density_b = self.pixel_probability[row * w + col] * (w * h) / (2.0 * np.pi**2 * sin_theta)
        return density_b * _direction_jacobian(self.mapping, dirs)


def _neighbourhood_max(lum: np.ndarray) -> np.ndarray:
    """Maximum over each pixel's 3×3 neighbourhood (wrapping in u, clamped at the poles)."""
    out = lum.copy()
    padded = np.pad(lum, ((1, 1), (0, 0)), mode="edge")
    for dy in (0, 1, 2):
        row = padded[dy : dy + lum.shape[0]]
        for dx in (-1, 0, 1):
            out = np.maximum(out, np.roll(row, dx, axis=1))
    return out


def _direction_jacobian(m: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """dω_b/dω_world of b = normalise(M d): |det M| / ‖M d‖³ (1 for a rotation)."""
    return abs(np.linalg.det(m)) / np.linalg.norm(dirs @ m.T, axis=1) ** 3


def _sample_wrap_x(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup wrapping in u and clamping in v (the poles)."""
    h, w = image.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = np.clip(uv[:, 1] * h - 0.5, 0.0, h - 1.0)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x1, y1 = (x0 + 1) % w, np.minimum(y0 + 1, h - 1)
    x0 %= w
    return (
        (1 - fx) * (1 - fy) * image[y0, x0]
        + fx * (1 - fy) * image[y0, x1]
        + (1 - fx) * fy * image[y1, x0]
        + fx * fy * image[y1, x1]
    )
