"""Texture lookups and colour decoding shared by bake points and the tracer. No bpy."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
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


#: A texel holds the mean of its 1 × 1 footprint (the bake averages the texel's box), so the cubic
#: B-spline f(x) = Σ_j c_j β3(x − j) that the texels describe is the one whose means over the
#: texels are the texels: per axis, (β3 ∗ box)(k) = β4(k) at the integers, the quartic B-spline's
#: values (1, 76, 230, 76, 1)/384. Interpolating the texel values as if they were point samples
#: (kernel (1, 4, 1)/6) blurs a shadow's edge more.
AREA_KERNEL = np.array([1.0, 76.0, 230.0, 76.0, 1.0]) / 384.0
#: AREA_KERNEL's z-transform's roots inside the unit circle (the others are their inverses).
_AREA_POLES = tuple(float(z) for z in np.sort(np.roots(AREA_KERNEL * 384.0).real) if abs(z) < 1.0)
#: Unfilled texels (outside the charts and their gutter) are given their nearest filled
#: neighbours' mean this many rings out before the prefilter: its response decays by |pole| ≈ 0.36
#: per texel, so a step left at the gutter's edge would ring into the chart.
FILL_RINGS = 8


def bspline_coefficients(image: np.ndarray, filled: np.ndarray | None = None) -> np.ndarray:
    """The cubic B-spline coefficients `(H, W, C)` float32 of `image` `(H, W, C)` (texel means):
    `sample_bicubic(coefficients, uv, kernel="bspline")` is the smooth surface whose mean over
    every texel is that texel (AREA_KERNEL per axis, solved exactly by the recursive filter of
    its poles, mirrored at the image's borders). `filled` `(H, W)` bool marks the texels that
    hold data; the others first take a nearest filled texel's value (FILL_RINGS). Non-finite
    texels count as unfilled. The coefficients overshoot next to a step (negative next to
    black): clamp after sampling. Values beyond float32's range are clipped to it."""
    image = np.asarray(image)
    planes = image[..., None] if image.ndim == 2 else image
    finite = np.isfinite(planes).all(axis=-1)
    known = finite if filled is None else (np.asarray(filled, bool) & finite)
    source = _nearest_filled(known).ravel()
    unknown = np.flatnonzero(~known)
    far = unknown[source[unknown] >= 0]
    big = float(np.finfo(np.float32).max)
    out = np.empty(planes.shape, np.float32)
    for c in range(planes.shape[-1]):
        work = np.array(planes[..., c], dtype=np.float64, order="C")
        flat = work.reshape(-1)
        near = flat[source[far]]
        flat[unknown] = 0.0
        flat[far] = near
        _deconvolve(work)
        out[..., c] = np.clip(work, -big, big)  # a step of float32's largest overshoots past it
    return out if image.ndim == 3 else out[..., 0]


def _nearest_filled(known: np.ndarray) -> np.ndarray:
    """`(H, W)` int64: the flat index of a nearest `known` texel (4-neighbour rings, FILL_RINGS
    out), −1 where none is that close."""
    h, w = known.shape
    source = np.where(known, np.arange(h * w).reshape(h, w), -1)
    for _ in range(FILL_RINGS):
        if (source >= 0).all():
            break
        s = source
        for dst, src in ((s[1:], s[:-1]), (s[:-1], s[1:]), (s[:, 1:], s[:, :-1]), (s[:, :-1], s[:, 1:])):
            take = (dst < 0) & (src >= 0)
            dst[take] = src[take]
    return source


def _deconvolve(x: np.ndarray) -> np.ndarray:
    """`x` `(H, W)` float64 (C-contiguous), in place: convolved along its rows, then its
    columns, with AREA_KERNEL's inverse (`texture_kernels`), split over every core."""
    from . import parallel, texture_kernels

    kernels = texture_kernels.get()
    poles = np.array(_AREA_POLES)
    gain = float(np.prod([(1.0 - z) * (1.0 - 1.0 / z) for z in poles]))
    threads = parallel.machine_threads()
    with ThreadPoolExecutor(threads) as pool:
        for kernel, n, m in ((kernels.deconvolve_rows, *x.shape), (kernels.deconvolve_columns, *x.shape[::-1])):
            horizons = np.array([min(m, int(np.ceil(np.log(1e-17) / np.log(abs(z)))) + 1) for z in poles])
            bounds = np.linspace(0, n, min(n, 4 * threads) + 1).astype(int)
            runs = [(bounds[k], bounds[k + 1], poles, horizons, gain) for k in range(len(bounds) - 1)]
            list(pool.map(lambda run, kernel=kernel: kernel(x, *run), runs))
    return x


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function, inverse (what Blender applies to sRGB byte images)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
