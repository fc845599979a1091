"""The denoise post stage: Open Image Denoise's lightmap filter on an atlas's SH, chart by chart. No bpy.

Input and output are `encoding.TexelData` images (rows bottom-up): only the SH of baked texels
(covered, not buried) changes. Per atlas:

1. **Charts**: the 8-connected components of the covered texels (`label_charts`). A chart is
   denoised only with its own texels: the other charts' texels and buried texels inside its
   rectangle are masked out and refilled smoothly from its own (`_smooth_fill`: a local mean
   of its texels; copying the nearest texel repeats its noise in streaks the filter keeps).
2. **Pages**: each chart's rectangle plus MARGIN texels goes into a page image (shelf packing,
   `layout`). Every OIDN call has a fixed cost whatever the size, and real atlases hold thousands of
   charts a few texels wide, so charts share pages; a chart then sees its neighbours in the page
   2·MARGIN texels away at the closest. To keep that from bleeding light, a page only holds charts
   whose mean luminance lies within one BRIGHTNESS_BAND factor of each other, and each page has
   its own `inputScale` (OIDN's auto-exposure rule over its charts' texels; a chart is never
   split between pages, so no chart sees two exposures).
3. **Filter** (`Denoiser`, RTLightmap), per page: L0 and I_z (the irradiance along n_v, RGB: what
   the HHD file stores first, and the part of band 1 along n_v) as HDR colour; the rest of band 1
   (across n_v) and band 2 in luminance, in directional mode, divided by the *denoised*
   luminance L0 and by the band's bound (|c_k / c_0| ≤ √3 in band 1, ≤ √5 in band 2 for any
   radiance ≥ 0) times DIRECTIONAL_RANGE, then scaled back by each colour's denoised L0 (one
   direction for all colours, as HHD's highlight direction is). Dividing by the denoised L0 (a
   smooth image) keeps the ratio linear in the noisy coefficient. Five OIDN calls per page.
4. **Energy**: at a few samples per texel the noise is heavy-tailed and the filter takes rare
   bright samples for outliers, darkening (by several percent in rooms lit by small emitters).
   L0 and I_z are scaled per page so their sums over its chart texels are the traced sums (an
   unbiased estimate with little noise of its own): each page keeps the traced mean, though
   light can still move between the charts of one page.

5. **Noise clamp**: where the tracer measured each texel's noise (`TexelData.noise`, the
   standard error of its luminance L0 from the spread between passes; unknown before
   `stages.NOISE_PASSES` passes),
   no coefficient moves further from the traced value than NOISE_CLAMP standard errors (scaled
   to its colour). A filter also changes what is not noise: it bleeds light into contact
   shadows and blurs edges, and at high sample counts that is all it changes. The clamp lets it
   remove noise where there is noise and keeps converged texels (a black corner every pass
   agreed on) as traced, so a denoised bake converges to the same image as a raw one.

Charts darker than BLACK (mean L0 luminance) are left as they are: nothing to denoise.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import dilate
from .colour import LUMINANCE
from .encoding import TexelData
from .oidn import Denoiser, DenoiserError
from .sh import IRRADZ_FROM_R10, hemisphere_irradz

#: Texels of each chart's own (dilated) values around it in its page.
MARGIN = 2
#: Reach in texels of the smooth fill around a chart (`_smooth_fill`).
FILL_BLUR = 2
#: Farther than FILL_BLUR, a masked texel copies the nearest filled one within this many rings.
FILL_RINGS = 16
#: Page width in texels (at most the atlas's; a wider chart gets a page as wide as it) and the
#: height a page is closed at (its last shelf may pass it).
PAGE_SIZE = 512
#: Charts sharing a page differ in mean luminance by at most this factor.
BRIGHTNESS_BAND = 4.0
#: Mean L0 luminance below which a chart counts as black and is left alone.
BLACK = 1e-12
#: The directional coefficients are scaled into ±DIRECTIONAL_RANGE (of OIDN's [-1, 1]) for
#: radiance ≥ 0; the rest of the range is headroom for the noise (Unreal uses 0.5).
DIRECTIONAL_RANGE = 0.5
#: |c / c_0| bound of an SH coefficient for any radiance ≥ 0 (max |Y| / Y_00), per band.
BAND1_BOUND, BAND2_BOUND = math.sqrt(3.0), math.sqrt(5.0)
#: Bound of the per-page energy correction of the HDR channels (`_hdr`).
ENERGY_CLAMP = 1.5
#: Most standard errors (of the traced value, `TexelData.noise`) the denoiser may move a coefficient.
NOISE_CLAMP = 2.5
#: OIDN's auto-exposure key value (its `autoexposure` op): inputScale = KEY / geometric-mean luminance.
KEY = 0.18


def label_charts(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """8-connected components of an `(H, W)` bool mask: `(H, W)` int64 labels (-1 outside the
    mask, 0..n-1 inside, in row-major order of each component's first run) and n.

    Works on horizontal runs of the mask: runs on adjacent rows that touch (diagonally
    included) are joined by a vectorised union-find (hooking to the smaller root, then
    pointer jumping), so the cost is in runs, not texels."""
    h, w = mask.shape
    edges = np.diff(np.pad(mask.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    row, start = np.nonzero(edges == 1)
    _, end = np.nonzero(edges == -1)  # exclusive; same order as the starts
    n = len(row)
    labels = np.full(h * w, -1, np.int64)
    if n == 0:
        return labels.reshape(h, w), 0
    stride = w + 2
    first_of_row = np.searchsorted(row, np.arange(h + 2))
    # runs j on row r + 1 touching run i on row r: end_j > start_i - 1 and start_j < end_i + 1
    lo = np.searchsorted(row * stride + end, (row + 1) * stride + start, side="left")
    hi = np.searchsorted(row * stride + start, (row + 1) * stride + end + 1, side="left")
    lo = np.maximum(lo, first_of_row[row + 1])
    hi = np.minimum(hi, first_of_row[row + 2])
    count = np.maximum(hi - lo, 0)
    a = np.repeat(np.arange(n), count)
    b = _ranges(lo, count)
    parent = np.arange(n)
    while True:
        pa, pb = parent[a], parent[b]
        if np.array_equal(pa, pb):
            break
        low = np.minimum(pa, pb)
        np.minimum.at(parent, pa, low)
        np.minimum.at(parent, pb, low)
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    roots, run_label = np.unique(parent, return_inverse=True)
    length = end - start
    labels[_ranges(row * w + start, length)] = np.repeat(run_label, length)
    return labels.reshape(h, w), len(roots)


def _ranges(first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenation of arange(first[i], first[i] + count[i]) over i."""
    offsets = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    return np.repeat(first, count) + offsets


@dataclass
class Page:
    """One image handed to OIDN: `shape` (h, w) and, per chart placed in it, the chart label,
    its rectangle in the atlas (y0, x0, h, w; MARGIN included, may reach outside the atlas) and
    its corner (y, x) in the page."""

    shape: tuple[int, int]
    charts: list[int] = field(default_factory=list)
    rects: list[tuple[int, int, int, int]] = field(default_factory=list)
    corners: list[tuple[int, int]] = field(default_factory=list)


def layout(labels: np.ndarray, n: int, brightness: np.ndarray) -> list[Page]:
    """Pages holding every chart whose `brightness` (n,) exceeds BLACK: charts grouped into
    brightness bands of factor BRIGHTNESS_BAND, then shelf-packed by decreasing height."""
    h, w = labels.shape
    ys, xs = np.nonzero(labels >= 0)
    lab = labels[ys, xs]
    y0 = np.full(n, h, np.int64)
    x0 = np.full(n, w, np.int64)
    y1 = np.zeros(n, np.int64)
    x1 = np.zeros(n, np.int64)
    np.minimum.at(y0, lab, ys)
    np.minimum.at(x0, lab, xs)
    np.maximum.at(y1, lab, ys + 1)
    np.maximum.at(x1, lab, xs + 1)
    rh, rw = y1 - y0 + 2 * MARGIN, x1 - x0 + 2 * MARGIN
    lit = np.flatnonzero(brightness > BLACK)
    band = np.floor(np.log(brightness[lit]) / math.log(BRIGHTNESS_BAND)).astype(np.int64)
    pages = []
    for b in np.unique(band):
        members = lit[band == b]
        members = members[np.lexsort((-rw[members], -rh[members]))]
        pages += _shelves(members, rh, rw, y0 - MARGIN, x0 - MARGIN, min(PAGE_SIZE, w))
    return pages


def _shelves(charts: np.ndarray, rh, rw, ry, rx, width: int) -> list[Page]:
    """Shelf packing of `charts` (sorted by decreasing height) into pages at most `width` wide
    (or as wide as the widest chart) and no wider than their charts, closed at PAGE_SIZE high."""
    width = max(width, int(rw[charts].max()))
    pages: list[Page] = []
    page, x, y, shelf = None, 0, 0, 0
    for c in charts.tolist():
        if page is None or x + rw[c] > width:
            y, x = y + shelf, 0
            shelf = int(rh[c])
            if page is None or y >= PAGE_SIZE:
                page, y = Page((0, 0)), 0
                pages.append(page)
        page.charts.append(c)
        page.rects.append((int(ry[c]), int(rx[c]), int(rh[c]), int(rw[c])))
        page.corners.append((y, x))
        x += int(rw[c])
        page.shape = (max(page.shape[0], y + shelf), max(page.shape[1], x))
    return pages


def input_scale(colour: np.ndarray) -> float:
    """OIDN's auto-exposure over HDR colours `(T, 3)` (a page's texels): KEY over the geometric
    mean luminance of the non-black ones (1 if all are black)."""
    lum = colour @ LUMINANCE
    lum = lum[lum > 1e-8]
    if not len(lum):
        return 1.0
    return float(KEY / np.exp2(np.mean(np.log2(lum.astype(np.float64)))))


@dataclass
class DenoiseReport:
    """What one atlas's denoise did: charts denoised, pages (OIDN images) and their texels,
    seconds of wall time."""

    charts: int = 0
    pages: int = 0
    page_texels: int = 0
    seconds: float = 0.0

    def sidecar(self) -> dict:
        return {
            "charts": self.charts,
            "pages": self.pages,
            "page_texels": self.page_texels,
            "seconds": round(self.seconds, 3),
        }


def denoise_texels(
    data: TexelData, denoiser: Denoiser, check: Callable[[], None] | None = None
) -> tuple[TexelData, DenoiseReport]:
    """`data` with the SH of its baked texels denoised (the module's steps, the noise clamp
    where `data.noise` is known); everything else as it was. A baked texel with a non-finite coefficient is not
    used and gets the denoised value of its surroundings. `check()`, if given, runs between pages
    (it raises to cancel). Raises DenoiserError if OIDN fails."""
    t0 = time.perf_counter()
    h, w = data.coverage.shape
    labels, n = label_charts(data.coverage != 0.0)
    labels = np.where(data.baked, labels, -1)  # buried texels: masked like other charts' texels
    finite = _finite_texels(data.sh).reshape(-1)
    # the SH is read per page, a non-finite texel's as 0 (no atlas-wide copy: memory)
    sh = data.sh.reshape(h * w, 9, 3)
    flat = labels.reshape(-1)
    texels = np.flatnonzero((flat >= 0) & finite)
    lum = sh[texels, 0, :].astype(np.float64) @ LUMINANCE
    brightness = np.bincount(flat[texels], lum, minlength=n) / np.maximum(np.bincount(flat[texels], minlength=n), 1)
    del texels, lum
    normal = data.normal.reshape(h * w, 3)
    report = DenoiseReport()
    out = data.sh.copy().reshape(h * w, 9, 3)
    for page in layout(labels, n, brightness):
        if check is not None:
            check()
        rows, cols, atlas_index = _page_texels(page, labels)
        chart_sh = sh[atlas_index]
        chart_sh[~finite[atlas_index]] = 0.0
        values = np.zeros(page.shape + (9, 3), np.float32)
        values[rows, cols] = chart_sh
        normals = np.zeros(page.shape + (3,), np.float32)
        normals[rows, cols] = normal[atlas_index]
        source = np.zeros(page.shape, bool)
        source[rows, cols] = finite[atlas_index]
        scales = (input_scale(chart_sh[:, 0, :]), input_scale(hemisphere_irradz(chart_sh, normal[atlas_index])))
        del chart_sh
        features, unit_normals = _page_features(values, normals)
        del values, normals
        clean = _denoise_features(features, unit_normals, source, denoiser, scales)
        del features, unit_normals, source
        out[atlas_index] = clean[rows, cols]
        del clean
        report.charts += len(page.charts)
        report.pages += 1
        report.page_texels += page.shape[0] * page.shape[1]
    clean = out.reshape(data.sh.shape)
    if data.noise is not None:
        clean = clamp_to_noise(clean, data.sh, data.noise, out=clean)
    report.seconds = time.perf_counter() - t0
    return replace(data, sh=clean), report


#: Rows of the atlas per step of the atlas-wide passes (`clamp_to_noise`, `_finite_texels`): bounds their temporaries.
ROWS_PER_STEP = 64


def _finite_texels(sh: np.ndarray) -> np.ndarray:
    """`(H, W)` bool: the texels of SH `(H, W, 9, 3)` whose every coefficient is finite."""
    out = np.empty(sh.shape[:2], bool)
    for y in range(0, sh.shape[0], ROWS_PER_STEP):
        out[y : y + ROWS_PER_STEP] = np.isfinite(sh[y : y + ROWS_PER_STEP]).all(axis=(2, 3))
    return out


def clamp_to_noise(
    denoised: np.ndarray, traced: np.ndarray, noise: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """`denoised` SH `(H, W, 9, 3)` moved back to within NOISE_CLAMP standard errors of the
    `traced` SH, per coefficient and colour: the bound is NOISE_CLAMP × `noise` `(H, W)` (the
    standard error of the traced luminance L0) × each colour's share of that luminance (|L0_c| /
    L0 luminance; 1 where it is not positive). Texels whose noise is unknown (NaN) are not
    clamped; non-finite traced values are not either (the filter replaced them). float32, into
    `out` if given (it may be `denoised` itself), ROWS_PER_STEP rows at a time (memory)."""
    if out is None:
        out = np.empty(denoised.shape, np.float32)
    for y in range(0, denoised.shape[0], ROWS_PER_STEP):
        rows = slice(y, y + ROWS_PER_STEP)
        out[rows] = _clamp_rows(denoised[rows], traced[rows], noise[rows])
    return out


def _clamp_rows(denoised: np.ndarray, traced: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """`clamp_to_noise` of some rows."""
    l0 = traced[..., 0, :].astype(np.float64)
    l0_lum = l0 @ LUMINANCE
    lit = l0_lum > 0.0
    colour = np.where(lit[..., None], np.abs(l0) / np.where(lit, l0_lum, 1.0)[..., None], 1.0)
    known = np.isfinite(noise) & np.isfinite(traced).all(axis=(2, 3))
    if not known.any():  # nothing to clamp (e.g. fewer than NOISE_PASSES passes)
        return denoised.astype(np.float32, copy=False)
    bound = NOISE_CLAMP * np.where(known, noise, 0.0)[..., None] * colour  # (H, W, 3)
    step = np.clip(denoised - traced, -bound[:, :, None, :], bound[:, :, None, :])
    return np.where(known[..., None, None], traced + step, denoised).astype(np.float32)


def _page_texels(page: Page, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Page rows, page columns and flat atlas indices of the texels of the page's charts."""
    h, w = labels.shape
    rows, cols, index = [], [], []
    for c, (ry, rx, rh, rw), (py, px) in zip(page.charts, page.rects, page.corners):
        ay0, ax0 = max(ry, 0), max(rx, 0)
        window = labels[ay0 : min(ry + rh, h), ax0 : min(rx + rw, w)]
        yy, xx = np.nonzero(window == c)
        rows.append(yy + (ay0 - ry) + py)
        cols.append(xx + (ax0 - rx) + px)
        index.append((yy + ay0) * w + xx + ax0)
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(index)


def _page_features(values: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One page's inputs to the filter (`_denoise_features`), from its SH `(h, w, 9, 3)` and unit
    n_v `(h, w, 3)`: `(h, w, 14)` float64: L0 (RGB), I_z (RGB), band 1 across n_v and band 2
    (luminance); and the unit n_v `(h, w, 3)` float64."""
    n = normal.astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    v = _band1_vector(values[:, :, :4]).astype(np.float64)  # (h, w, 3 axes, 3 colours); exact: a sign and a cast
    along = np.einsum("hwa,hwac->hwc", n, v)
    v -= n[..., None] * along[:, :, None, :]  # in place: v is not needed any more
    across = np.einsum("hwac,c->hwa", v, LUMINANCE)
    del v
    features = np.concatenate(
        [values[:, :, 0, :], IRRADZ_FROM_R10 * np.maximum(along, 0.0), across, values[:, :, 4:, :] @ LUMINANCE],
        axis=-1,
    )
    return features, n


def _denoise_features(
    features: np.ndarray, n: np.ndarray, source: np.ndarray, denoiser: Denoiser, scales: tuple[float, float]
) -> np.ndarray:
    """One page denoised from its `_page_features` (consumed: filled in place), meaningful at its
    chart texels `source`: they are filled smoothly elsewhere (`_smooth_fill`), then L0 and I_z
    are denoised as HDR colour (`scales`: their inputScale) and the rest in directional mode over
    the denoised L0 (module docstring). Returns `(h, w, 9, 3)` float32."""
    features = _smooth_fill(features, source)
    l0 = _hdr(features[..., 0:3], source, scales[0], denoiser)
    iz = _hdr(features[..., 3:6], source, scales[1], denoiser)
    # the rest in luminance over luminance L0 (one direction for all colours, as HHD keeps), scaled by each colour's L0
    l0_lum = l0 @ LUMINANCE
    across = _directional(features[..., 6:9], l0_lum, BAND1_BOUND, denoiser)
    across -= n * np.einsum("hwa,hwa->hw", n, across)[..., None]
    band2 = _directional(features[..., 9:14], l0_lum, BAND2_BOUND, denoiser)
    del features
    colour = l0 / np.where(l0_lum > 0.0, l0_lum, 1.0)[..., None]  # (h, w, 3): L0 of each colour / luminance L0
    scaled_iz = iz / IRRADZ_FROM_R10
    out = np.empty(l0.shape[:2] + (9, 3), np.float32)
    out[:, :, 0, :] = l0
    # v = across ⊗ colour + n ⊗ I_z / IRRADZ_FROM_R10 (3 axes × 3 colours), one axis at a time (memory)
    for k, (axis, sign) in zip((1, 2, 3), ((1, -1.0), (2, 1.0), (0, -1.0))):
        v = across[..., axis, None] * colour + n[..., axis, None] * scaled_iz
        out[:, :, k, :] = -v if sign < 0 else v
    out[:, :, 4:, :] = band2[..., None] * colour[:, :, None, :]
    return out


def _hdr(colour: np.ndarray, source: np.ndarray, scale: float, denoiser: Denoiser) -> np.ndarray:
    """An HDR colour image `(h, w, 3)` denoised (inputScale `scale`), ≥ 0, then scaled per channel
    so its sum over the chart texels `source` is the input's (clamped to ×[1/ENERGY_CLAMP,
    ENERGY_CLAMP]): at a few samples per texel the noise is heavy-tailed and the filter takes the
    rare bright samples for outliers, darkening the page; the sum over a page of texels is an
    unbiased estimate with little noise of its own."""
    out = np.maximum(denoiser.denoise(colour.astype(np.float32), input_scale=scale), 0.0)
    before = colour[source].sum(axis=0, dtype=np.float64)
    after = out[source].sum(axis=0, dtype=np.float64)
    ratio = np.where(after > 0.0, before / np.where(after > 0.0, after, 1.0), 1.0)
    return out * np.clip(ratio, 1.0 / ENERGY_CLAMP, ENERGY_CLAMP).astype(np.float32)


def _smooth_fill(image: np.ndarray, source: np.ndarray) -> np.ndarray:
    """`image` `(h, w, c)` (changed in place) with its non-chart texels filled smoothly (float64): within FILL_BLUR
    texels of a chart texel, the mean of the chart texels in the (2·FILL_BLUR + 1)² box around it
    (copying the nearest texel would repeat its noise in streaks, which the filter keeps as
    detail); farther, the nearest such texel (FILL_RINGS rings), beyond that the page mean."""
    weight = _box_sum(source.astype(np.float64)[..., None], FILL_BLUR)[..., 0]
    near = weight > 0.0
    inv = np.where(near, 1.0 / np.where(near, weight, 1.0), 0.0)
    del weight
    image = image.astype(np.float64, copy=False)
    outside = ~source
    image[outside] = 0.0  # in place: where(source, image, 0)
    for k in range(image.shape[2]):  # where(source, image, box mean), one channel at a time, in place
        mean = _box_sum(image[..., k : k + 1], FILL_BLUR)[..., 0]
        mean *= inv
        channel = image[..., k]
        channel[outside] = mean[outside]
    return dilate.Fill(near, FILL_RINGS).apply(image, in_place=True)


def _box_sum(image: np.ndarray, r: int) -> np.ndarray:
    """Sum of `image` `(h, w, c)` over the (2r + 1)² box around each texel (zero outside),
    float64, one channel at a time (memory: a few channel images)."""
    h, w = image.shape[:2]
    out = np.empty(image.shape, np.float64)
    c = np.zeros((h + 1, w + 1))
    y0, y1 = np.clip(np.arange(h) - r, 0, h), np.clip(np.arange(h) + r + 1, 0, h)
    x0, x1 = np.clip(np.arange(w) - r, 0, w), np.clip(np.arange(w) + r + 1, 0, w)
    for k in range(image.shape[2]):
        np.cumsum(np.cumsum(image[..., k], axis=0, dtype=np.float64), axis=1, out=c[1:, 1:])
        out[..., k] = c[y1][:, x1] - c[y0][:, x1] - c[y1][:, x0] + c[y0][:, x0]
    return out


def _band1_vector(sh: np.ndarray) -> np.ndarray:
    """v = (-r_1^1, -r_1^-1, r_1^0) of SH `(..., 9, C)` -> `(..., 3, C)`: I_z is IRRADZ_FROM_R10 · v·n_v."""
    return np.stack([-sh[..., 3, :], -sh[..., 1, :], sh[..., 2, :]], axis=-2)


def _directional(coefficients: np.ndarray, l0: np.ndarray, bound: float, denoiser: Denoiser) -> np.ndarray:
    """Luminance coefficients `(h, w, m)` denoised in OIDN's directional mode, three at a time:
    divided by the denoised luminance L0 `(h, w)` and by `bound` (their largest |c / c_0| for
    radiance ≥ 0) times DIRECTIONAL_RANGE, clipped to [-1, 1], denoised, scaled back; 0 where L0 is."""
    to_unit = DIRECTIONAL_RANGE / bound
    lit = (l0 > 0.0)[..., None]
    ratio = np.where(lit, coefficients / np.where(lit, l0[..., None], 1.0) * to_unit, 0.0)
    ratio = np.clip(ratio, -1.0, 1.0).astype(np.float32)
    clean = np.concatenate(
        [
            denoiser.denoise(ratio[..., k : k + 3], directional=True, input_scale=1.0)
            for k in range(0, ratio.shape[-1], 3)
        ],
        axis=-1,
    )
    return clean / to_unit * l0[..., None]


#: One Denoiser per (library, threads) for the process: the device and weights load once.
_DENOISERS: dict[tuple[str, int], Denoiser] = {}


def denoiser_for(library: str | Path | None, threads: int) -> Denoiser:
    """The process's Denoiser for `library` (OIDN's shared library; None or "" = not found) on
    `threads` threads. Raises DenoiserUnavailable with the reason."""
    from .oidn import DenoiserUnavailable

    if not library:
        raise DenoiserUnavailable("Open Image Denoise library not found in this Blender")
    key = (str(library), int(threads))
    if key not in _DENOISERS:
        _DENOISERS[key] = Denoiser(library, threads=threads)
    return _DENOISERS[key]


__all__ = [
    "DenoiseReport",
    "clamp_to_noise",
    "DenoiserError",
    "denoise_texels",
    "denoiser_for",
    "input_scale",
    "label_charts",
    "layout",
]
