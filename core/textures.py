"""Texture lookups and colour decoding shared by bake points and the tracer. No bpy."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Texture:
    """An albedo image as Blender's Image Texture node samples it: pixels (H, W, 3) linear RGB,
    row 0 at v = 0; interpolation 'Linear' | 'Closest' (Cubic/Smart are sampled as Linear);
    extension 'REPEAT' | 'EXTEND' | 'CLIP' (CLIP: black outside [0, 1]²; MIRROR as REPEAT)."""

    pixels: np.ndarray
    interpolation: str = "Linear"
    extension: str = "REPEAT"

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Colours (P, 3) at uv (P, 2)."""
        uv = np.asarray(uv, dtype=np.float64)
        if self.extension == "EXTEND":
            uv = np.clip(uv, 0.0, 1.0 - 1e-9)
        if self.interpolation == "Closest":
            h, w = self.pixels.shape[:2]
            x = np.floor(uv[:, 0] * w).astype(np.int64)
            y = np.floor(uv[:, 1] * h).astype(np.int64)
            out = self.pixels[y % h, x % w][:, :3]
        else:
            out = sample_bilinear(self.pixels, uv, clamp=self.extension == "EXTEND")[:, :3]
        if self.extension == "CLIP":
            outside = ((uv < 0.0) | (uv > 1.0)).any(axis=1)
            out = np.where(outside[:, None], 0.0, out)
        return out


def sample_bilinear(image: np.ndarray, uv: np.ndarray, clamp: bool = False) -> np.ndarray:
    """Bilinear lookup, Blender's convention: image `(H, W, C)` with row 0 at v = 0 (bottom),
    texel centres at (i + 0.5)/W; neighbours wrap around (repeat) or, with clamp, stop at the
    edge. uv `(P, 2)` -> `(P, C)`."""
    h, w = image.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    if clamp:
        xs = (np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1))
        ys = (np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1))
    else:
        xs, ys = (x0 % w, (x0 + 1) % w), (y0 % h, (y0 + 1) % h)
    return (
        (1 - fx) * (1 - fy) * image[ys[0], xs[0]]
        + fx * (1 - fy) * image[ys[0], xs[1]]
        + (1 - fx) * fy * image[ys[1], xs[0]]
        + fx * fy * image[ys[1], xs[1]]
    )


#: The bicubic kernels `sample_bicubic` knows: Catmull-Rom (interpolating, the runtime option's;
#: weights can be negative) and the uniform cubic B-spline (approximating, weights ≥ 0: the
#: "fast bicubic" of 4 bilinear taps).
KERNELS = ("catmull_rom", "bspline")


def catmull_rom_weights(t: np.ndarray) -> np.ndarray:
    """Catmull-Rom weights `(..., 4)` of the texels at offsets −1, 0, 1, 2 from a fraction t ∈ [0, 1)
    past texel 0: they sum to 1, reproduce quadratics exactly and interpolate (t = 0 → (0, 1, 0, 0))."""
    t = np.asarray(t, dtype=np.float64)
    t2, t3 = t * t, t * t * t
    return np.stack([(-t3 + 2 * t2 - t) / 2, (3 * t3 - 5 * t2 + 2) / 2, (-3 * t3 + 4 * t2 + t) / 2, (t3 - t2) / 2], -1)


def bspline_weights(t: np.ndarray) -> np.ndarray:
    """Uniform cubic B-spline weights `(..., 4)` of the texels at offsets −1, 0, 1, 2 (t as in
    `catmull_rom_weights`): non-negative, summing to 1, t = 0 → (1, 4, 1, 0)/6 (it blurs)."""
    t = np.asarray(t, dtype=np.float64)
    t2, t3 = t * t, t * t * t
    s = 1.0 - t
    return np.stack([s * s * s / 6, (3 * t3 - 6 * t2 + 4) / 6, (-3 * t3 + 3 * t2 + 3 * t + 1) / 6, t3 / 6], -1)


def sample_bicubic(
    image: np.ndarray, uv: np.ndarray, clamp: bool = False, kernel: str = "catmull_rom", nonnegative: bool = False
) -> np.ndarray:
    """Bicubic lookup in `sample_bilinear`'s convention (image `(H, W, C)`, row 0 at v = 0, texel
    centres at (i + 0.5)/W, repeat or with clamp the edge texel): the 4 × 4 texels around uv
    `(P, 2)` weighted by `kernel` (KERNELS) per axis -> `(P, C)` float64. Its footprint reaches one
    texel further each way than bilinear's 2 × 2, so a chart needs ≥ 2 texels of filled gutter
    (the unwrap's padding ≥ 4). Catmull-Rom's negative lobes overshoot next to a step;
    `nonnegative` clamps the result at 0 (irradiance). Summed in float64: finite for any finite
    float32 image."""
    if kernel not in KERNELS:
        raise ValueError(f"unknown bicubic kernel {kernel!r}: one of {KERNELS}")
    weights = catmull_rom_weights if kernel == "catmull_rom" else bspline_weights
    h, w = image.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    wx, wy = weights(x - x0), weights(y - y0)
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    out = np.zeros((len(uv),) + image.shape[2:], np.float64)
    for j in range(4):
        row = np.clip(y0 + j - 1, 0, h - 1) if clamp else (y0 + j - 1) % h
        for i in range(4):
            col = np.clip(x0 + i - 1, 0, w - 1) if clamp else (x0 + i - 1) % w
            weight = wx[:, i] * wy[:, j]
            out += weight.reshape((-1,) + (1,) * (out.ndim - 1)) * image[row, col]
    return np.maximum(out, 0.0) if nonnegative else out


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function, inverse (what Blender applies to sRGB byte images)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
