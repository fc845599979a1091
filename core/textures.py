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


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function, inverse (what Blender applies to sRGB byte images)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
