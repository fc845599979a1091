"""Octahedral packing of unit directions into 2 channels in [-1, 1]. No bpy.

Cigolle et al. 2014, "A Survey of Efficient Representations for Independent Unit Vectors".
The highlight direction is stored this way in world space (docs/conventions.md#direction-storage).
Decoding renormalises, so any 2-channel value decodes to a unit vector.
"""

from __future__ import annotations

import numpy as np


def _sign_not_zero(v: np.ndarray) -> np.ndarray:
    return np.where(v >= 0.0, 1.0, -1.0)


def encode(dirs: np.ndarray) -> np.ndarray:
    """Unit directions `(N, 3)` -> `(N, 2)` in [-1, 1]²; a zero vector (a texel with no light:
    no direction) -> (0, 0), which decodes to +z, never NaN."""
    d = np.asarray(dirs, dtype=np.float64)
    norm1 = np.abs(d).sum(axis=1, keepdims=True)
    p = d[:, :2] / np.where(norm1 > 0.0, norm1, 1.0)
    lower = d[:, 2] < 0.0
    folded = (1.0 - np.abs(p[:, ::-1])) * _sign_not_zero(p)
    return np.where(lower[:, None], folded, p)


def decode(uv: np.ndarray) -> np.ndarray:
    """`(N, 2)` in [-1, 1]² -> unit directions `(N, 3)`."""
    uv = np.asarray(uv, dtype=np.float64)
    z = 1.0 - np.abs(uv).sum(axis=1)
    t = np.clip(-z, 0.0, None)
    xy = uv - t[:, None] * _sign_not_zero(uv)
    d = np.column_stack([xy, z])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def quantize(uv: np.ndarray, bits: int) -> np.ndarray:
    """Round `(N, 2)` values in [-1, 1] to the nearest of 2^bits levels per channel (snorm/unorm
    both map [-1, 1] onto an evenly spaced grid with the end points exact), returning floats."""
    levels = (1 << bits) - 1
    return np.round((np.clip(uv, -1.0, 1.0) * 0.5 + 0.5) * levels) / levels * 2.0 - 1.0
