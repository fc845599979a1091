"""The denoise post stage: Open Image Denoise's lightmap filter on an atlas's SH, chart by chart. No bpy.

Input and output are `encoding.TexelData` images (rows bottom-up): only the SH of baked texels
(covered, not buried) changes. Per atlas:

1. **Charts**: the 8-connected components of the covered texels (`label_charts`). A chart is
   denoised only with its own texels: the other charts' texels and buried texels inside its
   rectangle are masked out and refilled from its own: next to the chart its texels mirrored
   through its border (`_mirror`, a CNN's reflect padding), farther a local mean of its texels
   (`_smooth_fill`; copying the nearest texel repeats its noise in streaks the filter keeps).
2. **Pages**: each chart's rectangle plus MARGIN texels goes into a page image (skyline packing,
   `layout`). Every OIDN call has a fixed cost whatever the size, and real atlases hold thousands of
   charts a few texels wide, so charts share pages; a chart then sees its neighbours in the page
   2·MARGIN texels away at the closest. To keep that from bleeding light, a page only holds charts
   whose mean luminance lies within one BRIGHTNESS_BAND factor of each other, and each page has
   its own `inputScale` (OIDN's auto-exposure rule over its charts' texels; a chart is never
   split between pages, so no chart sees two exposures).
3. **Filter** (`Denoiser`, RTLightmap), per page: L0 and I_z (the irradiance along n_v, RGB: what
   the HHD file stores first, and the part of band 1 along n_v) as HDR colour, raised to
   HDR_POWER (a compressed range) and back; the rest of band 1
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
   agreed on) as traced, so a denoised bake converges to the same image as a raw one. On a chart
   of fewer than SMALL_CHART texels the bound shrinks with the square root of its texel count:
   the filter has few texels there to tell the signal from the noise, and smooths over the
   chart's shading instead; within EDGE_RINGS texels of a chart's edge it is EDGE_CLAMP times
   as wide: there the filter sees the chart on one side only, and a chart's edge is where
   geometry meets (a wall's corner, an object's contact shadow), the shading steepest
   (`_ChartNoise`).

Charts darker than BLACK (mean L0 luminance) are left as they are: nothing to denoise.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import dilate
from .colour import LUMINANCE
from .encoding import TexelData
from .oidn import Denoiser, DenoiserError
from .progress import ticker
from .sh import IRRADZ_FROM_R10, hemisphere_irradz

#: Texels of each chart's own (dilated) values around it in its page.
MARGIN = 2
#: Reach in texels of the smooth fill around a chart (`_smooth_fill`).
FILL_BLUR = 2
#: Farther than FILL_BLUR, a masked texel copies the nearest filled one within this many rings.
FILL_RINGS = 16
#: Masked texels within this many rings of a chart texel take the chart texel mirrored through
#: their nearest one (`_mirror`), where there is one, instead of the smooth fill.
MIRROR_RINGS = 2
#: Page width in texels (at most the atlas's; a wider chart gets a page as wide as it) and the
#: height at or above which no chart starts in a page (its top may pass it).
PAGE_SIZE = 512
#: A brightness band's pages are square for this many times its charts' rectangles' area (`_page_width`).
PACKING_SLACK = 1.1
#: Charts sharing a page differ in mean luminance by at most this factor.
BRIGHTNESS_BAND = 4.0
#: Mean L0 luminance below which a chart counts as black and is left alone.
BLACK = 1e-12
#: The directional coefficients are scaled into ±DIRECTIONAL_RANGE (of OIDN's [-1, 1]) for
#: radiance ≥ 0; the rest of the range is headroom for the noise (Unreal uses 0.5).
DIRECTIONAL_RANGE = 0.5
#: |c / c_0| bound of an SH coefficient for any radiance ≥ 0 (max |Y| / Y_00), per band.
BAND1_BOUND, BAND2_BOUND = math.sqrt(3.0), math.sqrt(5.0)
#: L0 and I_z go through the filter raised to this power (`_hdr_filtered`), and are raised back
#: after: a compressed range, in which a chart's darkest texels next to its brightest ones (a
#: sunlit strip beside a shadowed face, both a texel wide) take less of their light. The per-page
#: energy correction restores the mean the power's curvature takes (bench/results).
HDR_POWER = 0.7
#: Bound of the per-page energy correction of the HDR channels (`_hdr`).
ENERGY_CLAMP = 1.5
#: Most standard errors (of the traced value, `TexelData.noise`) the denoiser may move a coefficient.
NOISE_CLAMP = 2.5
#: Baked texels of a chart below which its NOISE_CLAMP bound shrinks (`_ChartNoise`).
SMALL_CHART = 256
#: The NOISE_CLAMP bound of a texel within EDGE_RINGS (chessboard distance) of a texel that is
#: not of its chart is EDGE_CLAMP times as wide (`_ChartNoise`).
EDGE_RINGS, EDGE_CLAMP = 2, 0.6
#: OIDN's auto-exposure key value (its `autoexposure` op): inputScale = KEY / geometric-mean luminance.
KEY = 0.18
#: A page larger than this many texels per band goes through the filter in horizontal bands
#: (`_denoise_banded`): each band's core rows (a multiple of BAND_ALIGN, about BAND_TEXELS
#: texels) with BAND_OVERLAP rows of context above and below, so that the page's own buffers
#: (SH, features, smooth fill, output) exist for one band at a time, not for the page.
BAND_TEXELS = 1 << 20
#: Rows of context on each side of a band: OIDN's receptive field is ±87 texels (its own tiles
#: overlap by 96); a band aligned to BAND_ALIGN rows with this context gives OIDN's bits.
BAND_OVERLAP = 96
#: Band rows are multiples of this (OIDN's tile alignment: its U-Net pools 4 times).
BAND_ALIGN = 16
#: Texels of SH gathered at once for a banded page's inputScale (`_page_scales`).
SCALE_CHUNK = 1 << 16
#: The features (`_page_features`) each pass over a banded page builds: all (the fill's page
#: mean), L0 and I_z (filtered as HDR colour), the rest (filtered in directional mode).
ALL, HDR, DIRECTIONAL = slice(0, 14), slice(0, 6), slice(6, 14)
#: Texels clamped to the noise and written (`_write`), or assembled (`_assemble`), at once.
WRITE_CHUNK = 1 << 16
#: Rows of a band's features built at once (`_denoise_banded`): bounds the SH image and the
#: temporaries `_page_features` makes (several times the features' own 112 bytes a texel).
FEATURE_ROWS = 32


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


def layout(labels: np.ndarray, n: int, brightness: np.ndarray, atlas_width: int | None = None) -> list[Page]:
    """Pages holding every chart whose `brightness` (n,) exceeds BLACK: charts grouped into
    brightness bands of factor BRIGHTNESS_BAND, then packed by decreasing height (`_skyline`).
    `atlas_width`: the atlas's width when `labels` is a window of it (`TexelData.window`; pages
    are as wide as the whole atlas's would be), default the labels' own."""
    h, w = labels.shape
    page_width = min(PAGE_SIZE, w if atlas_width is None else atlas_width)
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
        pages += _skyline(members, rh, rw, y0 - MARGIN, x0 - MARGIN, page_width)
    return pages


def _skyline(charts: np.ndarray, rh, rw, ry, rx, width: int) -> list[Page]:
    """Skyline packing of `charts` (sorted by decreasing height) into pages `_page_width` wide:
    each chart goes where it lands lowest on the skyline of the charts placed before it
    (leftmost of equals), so small charts stack beside a tall one, in the space a shelf of its
    height would leave empty. A chart that would land at or above PAGE_SIZE begins a new page
    (a page's top may pass it)."""
    width = _page_width(rh[charts], rw[charts], width)
    pages: list[Page] = []
    page, sky = None, np.zeros(width, np.int64)
    for c in charts.tolist():
        h, w = int(rh[c]), int(rw[c])
        tops = np.lib.stride_tricks.sliding_window_view(sky, w).max(axis=1)
        x = int(np.argmin(tops))
        y = int(tops[x])
        if page is None or y >= PAGE_SIZE:
            page, y, x = Page((0, 0)), 0, 0
            sky[:] = 0
            pages.append(page)
        sky[x : x + w] = y + h
        page.charts.append(c)
        page.rects.append((int(ry[c]), int(rx[c]), h, w))
        page.corners.append((y, x))
        page.shape = (max(page.shape[0], y + h), max(page.shape[1], x + w))
    return pages


def _page_width(rh: np.ndarray, rw: np.ndarray, width: int) -> int:
    """Width of the pages of rectangles `rh` × `rw`: about square for their area (OIDN's cost is
    its image's area, padded to BAND_ALIGN, and a fixed cost per image), rounded up to
    BAND_ALIGN, at most `width` but at least the widest rectangle."""
    area = float(np.sum(rh * rw))
    square = -(-math.ceil(math.sqrt(PACKING_SLACK * area)) // BAND_ALIGN) * BAND_ALIGN
    return max(min(width, square), int(rw.max()))


def input_scale(colour: np.ndarray) -> float:
    """OIDN's auto-exposure over HDR colours `(T, 3)` (a page's texels): KEY over the geometric
    mean luminance of the non-black ones (1 if all are black)."""
    return _scale_of_luminance(colour @ LUMINANCE)


def _scale_of_luminance(lum: np.ndarray) -> float:
    """`input_scale` of the luminances `lum` (T,)."""
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
    data: TexelData,
    denoiser: Denoiser,
    check: Callable[[], None] | None = None,
    in_place: bool = False,
    restore: Callable[[], None] | None = None,
) -> tuple[TexelData, DenoiseReport]:
    """`data` with the SH of its baked texels denoised (the module's steps, the noise clamp
    where `data.noise` is known); everything else as it was. A baked texel with a non-finite coefficient is not
    used and gets the denoised value of its surroundings. `check()`, if given, runs between pages
    (it raises to cancel). Raises DenoiserError if OIDN fails.

    `in_place` (memory, for a caller that has written the raw SH file already, as a bake has):
    the denoised SH is written into `data.sh` itself, and nothing of the SH it replaces is kept
    (no copy of the atlas's SH, nor of a page's: `_denoise_banded`). On an error or cancellation
    after some texel was written, `restore()` is called (the caller's way to put the traced SH
    back, e.g. from the raw file) before the exception leaves (an exception of `restore` itself
    leaves instead, chained to the first); without `restore`, `data.sh` is then left partly
    denoised. Before any texel is written, `restore` is not called."""
    t0 = time.perf_counter()
    h, w = data.coverage.shape
    labels, n = label_charts(data.coverage != 0.0)
    labels = np.where(data.baked, labels, -1)  # buried texels: masked like other charts' texels
    if n < 2**31:  # int32 while the pages are denoised (memory: 4 bytes an atlas texel)
        labels = labels.astype(np.int32)
    finite = _finite_texels(data.sh).reshape(-1)
    # the SH is read per page, a non-finite texel's as 0 (no atlas-wide copy: memory)
    sh = data.sh.reshape(h * w, 9, 3)
    flat = labels.reshape(-1)
    texels = np.flatnonzero((flat >= 0) & finite)
    lum = sh[texels, 0, :].astype(np.float64) @ LUMINANCE
    brightness = np.bincount(flat[texels], lum, minlength=n) / np.maximum(np.bincount(flat[texels], minlength=n), 1)
    del texels, lum
    normal = data.normal.reshape(h * w, 3)
    noise = None if data.noise is None else _ChartNoise(data.noise.reshape(h * w), labels, n)
    report = DenoiseReport()
    out = sh if in_place else data.sh.copy().reshape(h * w, 9, 3)
    written = np.zeros(h * w, bool)  # texels written (set before they are: `restore`)
    clamping = False
    tick = ticker(check)
    try:
        pages = layout(labels, n, brightness, data.atlas_shape[1])
        parts = tick.split([page.shape[0] * page.shape[1] for page in pages] + [0.02 * h * w])
        for k, (page, part) in enumerate(zip(pages, parts)):
            part.at(0.0, f"page {k + 1} of {len(pages)}")
            band = _band_rows(page.shape)
            if band:
                part.name = ": ".join(x for x in (part.name, f"page {k + 1} of {len(pages)}") if x)
                _denoise_banded(page, labels, sh, normal, noise, finite, out, denoiser, band, part, written)
            else:
                _denoise_page(page, labels, sh, normal, noise, finite, out, denoiser, written)
            report.charts += len(page.charts)
            report.pages += 1
            report.page_texels += page.shape[0] * page.shape[1]
        del labels, flat, finite, noise
        parts[-1].at(0.0, f"{len(pages)} pages denoised, clamping to the noise")
        if data.noise is not None:  # the clamp of the texels no page changed (traced + 0: as `clamp_to_noise`)
            clamping = True
            _clamp_unwritten(out.reshape(data.sh.shape), data.noise, written)
    except BaseException:
        if in_place and restore is not None and (clamping or written.any()):
            restore()
        raise
    del written
    report.seconds = time.perf_counter() - t0
    return replace(data, sh=out.reshape(data.sh.shape)), report


class _ChartNoise:
    """The standard errors the noise clamp scales, read per texel: the traced `noise` (H·W,)
    float32 times min(1, √(baked texels of the texel's chart / SMALL_CHART)), and times
    EDGE_CLAMP within EDGE_RINGS of the chart's edge (`labels` (H, W) chart labels 0..n-1, -1
    elsewhere, where both factors are 1). Indexing gathers only the texels asked for: no
    atlas-wide copy of the noise (memory: one byte an atlas texel for the edge)."""

    def __init__(self, noise: np.ndarray, labels: np.ndarray, n: int):
        self.noise, self.flat = noise, labels.reshape(-1)
        size = np.bincount(self.flat[self.flat >= 0], minlength=n)
        self.factor = np.minimum(1.0, np.sqrt(size / SMALL_CHART)).astype(np.float32)
        self.edge = chart_edge(labels, EDGE_RINGS).reshape(-1)

    def __getitem__(self, index) -> np.ndarray:
        label = self.flat[index]
        chart = np.where(label >= 0, self.factor[np.maximum(label, 0)], np.float32(1.0))
        edge = np.where(self.edge[index] & (label >= 0), np.float32(EDGE_CLAMP), np.float32(1.0))
        return self.noise[index] * chart * edge


def chart_edge(labels: np.ndarray, rings: int) -> np.ndarray:
    """`(H, W)` bool: the texels with a texel of another label (or outside the atlas) within
    `rings` texels (chessboard distance) of them, from `labels` `(H, W)`. A texel's whole
    (2·rings + 1)² window has its label iff every row of the window does: each row's run of
    2·rings + 1 texels is checked once (`same_row`), then `rings` rows up and down;
    ROWS_PER_STEP rows at a time (memory)."""
    h, w = labels.shape
    edge = np.empty((h, w), bool)
    for y0 in range(0, h, ROWS_PER_STEP):
        y1 = min(y0 + ROWS_PER_STEP, h)
        lo, hi = max(y0 - rings, 0), min(y1 + rings, h)
        block = labels[lo:hi]
        padded = np.pad(block, ((0, 0), (rings, rings)), constant_values=-2)
        same_row = np.ones(block.shape, bool)  # the row's run around each texel has its label
        for dx in range(-rings, rings + 1):
            if dx:
                same_row &= padded[:, rings + dx : rings + dx + w] == block
        inner = np.ones((y1 - y0, w), bool)
        centre = labels[y0:y1]
        for dy in range(-rings, rings + 1):
            ys = np.arange(y0, y1) + dy
            inside = (ys >= 0) & (ys < h)
            rows = np.clip(ys, 0, h - 1) - lo
            inner &= inside[:, None] & same_row[rows] & (block[rows] == centre)
        edge[y0:y1] = ~inner
    return edge


def _denoise_page(
    page: Page,
    labels: np.ndarray,
    sh: np.ndarray,
    normal: np.ndarray,
    noise: _ChartNoise | None,
    finite: np.ndarray,
    out: np.ndarray,
    denoiser: Denoiser,
    written: np.ndarray,
) -> None:
    """One page denoised whole, its chart texels written into `out` `(H·W, 9, 3)` (clamped to
    the noise if `noise` (`_ChartNoise`) is given) and marked in `written` (H·W,) first. It reads a copy
    of the page's texels' SH (`out` may be `sh`), no larger than one band of a banded page,
    whose window is taller than this page."""
    rows, cols, atlas_index = _page_texels(page, labels)
    traced = sh[atlas_index]
    ok = finite[atlas_index]
    chart_sh = np.where(ok[:, None, None], traced, np.float32(0.0))
    values = np.zeros(page.shape + (9, 3), np.float32)
    values[rows, cols] = chart_sh
    normals = np.zeros(page.shape + (3,), np.float32)
    normals[rows, cols] = normal[atlas_index]
    source = np.zeros(page.shape, bool)
    source[rows, cols] = ok
    scales = (
        _compressed_scale(chart_sh[:, 0, :]),
        _compressed_scale(hemisphere_irradz(chart_sh, normal[atlas_index])),
    )
    del chart_sh, ok
    features, unit_normals = _page_features(values, normals)
    del values, normals
    clean = _denoise_features(features, unit_normals, source, denoiser, scales, (rows, cols))
    del features, unit_normals, source
    written[atlas_index] = True
    _write(out, atlas_index, clean, traced, noise)


def _write(
    out: np.ndarray,
    index: np.ndarray,
    clean: np.ndarray,
    traced: np.ndarray | None,
    noise: _ChartNoise | None,
    gather: bool = False,
) -> None:
    """Denoised SH `clean` `(T, 9, 3)` of the texels `index` into `out`, clamped to the noise
    around their `traced` SH where `noise` (`_ChartNoise`) is given (`clamp_to_noise`'s bits, per texel;
    `traced` is then required), WRITE_CHUNK texels at a time (the clamp's temporaries: memory).
    `gather`: `traced` is the `(H·W, 9, 3)` SH to read them at `index` from (it may be `out`:
    each chunk is read before it is written)."""
    if noise is None:
        out[index] = clean
        return
    assert traced is not None
    for s in range(0, len(index), WRITE_CHUNK):
        part = index[s : s + WRITE_CHUNK]
        before = traced[part] if gather else traced[s : s + WRITE_CHUNK]
        out[part] = _clamp_rows(clean[None, s : s + WRITE_CHUNK], before[None], noise[part][None])[0]


def _clamp_unwritten(sh: np.ndarray, noise: np.ndarray, written: np.ndarray) -> None:
    """`clamp_to_noise` of the texels of `sh` `(H, W, 9, 3)` no page wrote (`written` (H·W,)
    False; denoised = traced: traced + 0, which only turns -0 into +0), in place, ROWS_PER_STEP
    rows at a time. Only texels of known noise are touched: the clamp leaves the others as
    they are (most unwritten texels lie outside the charts, where the noise is unknown)."""
    written = written.reshape(sh.shape[:2])
    for y in range(0, sh.shape[0], ROWS_PER_STEP):
        rows = slice(y, y + ROWS_PER_STEP)
        keep = ~written[rows] & np.isfinite(noise[rows])
        if not keep.any():
            continue
        block = sh[rows][keep]
        sh[rows][keep] = _clamp_rows(block[None], block[None], noise[rows][keep][None])[0]


def _band_rows(shape: tuple[int, int]) -> int:
    """Core rows of each band of a page of `shape` (h, w) denoised in bands, 0 if it is
    denoised whole (not larger than one band and its context)."""
    h, w = shape
    band = max(BAND_ALIGN, BAND_TEXELS // max(w, 1) // BAND_ALIGN * BAND_ALIGN)
    return band if h > band + 2 * BAND_OVERLAP else 0


def _denoise_banded(
    page: Page,
    labels: np.ndarray,
    sh: np.ndarray,
    normal: np.ndarray,
    noise: _ChartNoise | None,
    finite: np.ndarray,
    out: np.ndarray,
    denoiser: Denoiser,
    band: int,
    check: Callable[[], None] | None,
    written: np.ndarray,
) -> None:
    """One page denoised in horizontal bands of `band` rows, its chart texels written into `out`
    `(H·W, 9, 3)` as `_denoise_page` writes them: the same values as the whole page gives, with
    the page's buffers one band at a time. Each band is filtered with BAND_OVERLAP rows of context
    on each side (OIDN tiles a large image the same way: its bits), and its features are built and smoothly filled with
    FILL_BLUR + FILL_RINGS rows more (the fill's reach), the box sums continuing the rows
    above's (`_box_sum`'s `seed`). What the page shares is found first: the inputScales
    (`_page_scales`), the page mean of the fill where some texel is beyond its reach; then L0 and
    I_z are filtered band by band (kept for the page, 24 bytes a texel) and their energy sums
    added up, in the page's order; then, band by band again, the rest (`_assemble`).

    No copy of the page's SH is made (`out` may be `sh`): the bands read `sh` itself. The first
    two passes write nothing, and the last holds each texel's output back until no later band's
    rows (built from BAND_OVERLAP + FILL_BLUR + FILL_RINGS rows above its core) reach its row
    (at the defaults, bands being taller than that, the top rows of one band until the next is
    built), reading the traced SH its noise clamp needs from `sh` just before writing. Texels
    are marked in `written` (H·W,) before they are written.

    The features each pass builds are the channels it uses (ALL, HDR, DIRECTIONAL), and the
    last pass drops them before its filter runs (`_ratios`); the directional SH is assembled at
    the chart texels of the core only (`_assemble`'s `at`)."""
    ph, pw = page.shape
    rows, cols, index = _page_texels(page, labels)
    ok = finite[index]
    scales = _page_scales(sh, normal, index, ok)
    order = np.argsort(rows, kind="stable")  # bands select their texels by row
    rows, cols, index, ok = rows[order].astype(np.int32), cols[order].astype(np.int32), index[order], ok[order]
    del order
    halo = FILL_BLUR + FILL_RINGS
    cores = [(y, min(y + band, ph)) for y in range(0, ph, band)]
    windows = []  # per band: its core, the rows filtered and the rows built (page rows)
    for y0, y1 in cores:
        fa, fb = max(y0 - BAND_OVERLAP, 0), min(y1 + BAND_OVERLAP, ph)
        windows.append(((y0, y1), (fa, fb), (max(fa - halo, 0), min(fb + halo, ph))))

    def built(i: int, seed, mean, channels: slice = ALL, fill: bool = True, with_normals: bool = False):
        """Band i's rows built: filled features (only `channels`: the smooth fill is per
        channel, so they have the bits of all of them), unit n_v (`with_normals`, else None),
        chart texels, the next band's seed (of those channels), the texels near a chart one."""
        _, _, (wa, wb) = windows[i]
        keep = windows[i + 1][2][0] - 1 - wa if i + 1 < len(windows) else None
        lo, hi = np.searchsorted(rows, (wa, wb))
        source = np.zeros((wb - wa, pw), bool)
        source[rows[lo:hi] - wa, cols[lo:hi]] = ok[lo:hi]
        features = np.empty((wb - wa, pw, len(range(14)[channels])), np.float64)
        unit_normals = np.empty((wb - wa, pw, 3), np.float64) if with_normals else None
        # FEATURE_ROWS rows at a time: `_page_features` is per texel, so they get the band's bits
        for y in range(wa, wb, FEATURE_ROWS):
            y1 = min(y + FEATURE_ROWS, wb)
            a, b = np.searchsorted(rows, (y, y1), side="left")
            r, c, idx, good = rows[a:b] - y, cols[a:b], index[a:b], ok[a:b]
            values = np.zeros((y1 - y, pw, 9, 3), np.float32)
            # the rows still hold the traced SH (the last pass writes behind them); the others stay +0
            values[r[good], c[good]] = sh[idx[good]]
            normals = np.zeros((y1 - y, pw, 3), np.float32)
            normals[r, c] = normal[idx]
            part, unit = _page_features(values, normals)
            del values, normals
            features[y - wa : y1 - wa] = part[..., channels]
            if unit_normals is not None:
                unit_normals[y - wa : y1 - wa] = unit
            del part, unit
        features, kept, near = _smooth_fill(
            features,
            source,
            seed,
            keep if keep is not None and keep >= 0 else None,
            None if mean is None else mean[channels],
            fill,
        )
        return features, unit_normals, source, kept, near

    tick = ticker(check)
    rounds = 2 if _within(ok, rows, cols, page.shape, halo) else 3  # the passes over the bands below
    done_passes = [0]

    def passes():
        """Band indices in order, with cancellation (and progress) between them."""
        for i in range(len(windows)):
            if i:
                tick.at(done_passes[0] / (rounds * len(windows)), f"band {i + 1} of {len(windows)}")
            yield i
            done_passes[0] += 1

    # the page mean of the fill (`dilate.Fill.apply`'s: added up in the same order) if it is used
    mean: np.ndarray | None = None
    if rounds == 3:
        total: np.ndarray | None = None
        count, seed = 0, None
        for i in passes():
            (y0, y1), _, (wa, _) = windows[i]
            features, _, _, seed, near = built(i, seed, None, ALL, fill=False)
            core = features[y0 - wa : y1 - wa][near[y0 - wa : y1 - wa]]
            total = _carried_sum(total, core)
            count += len(core)
            del features, near, core
        mean = total / count if count and total is not None else np.zeros(14)
    # L0 and I_z, filtered band by band, then their energy corrections over the page
    l0 = np.empty((ph, pw, 3), np.float32)
    iz = np.empty((ph, pw, 3), np.float32)
    sums: list = [None] * 4
    seed = None
    for i in passes():
        (y0, y1), (fa, fb), (wa, _) = windows[i]
        features, _, source, seed, _ = built(i, seed, mean, HDR)
        core = slice(y0 - wa, y1 - wa)
        for k, image, scale in ((0, l0, scales[0]), (2, iz, scales[1])):
            colour = features[fa - wa : fb - wa, :, 3 * k // 2 : 3 * k // 2 + 3]
            filtered = _hdr_filtered(colour, scale, denoiser)[y0 - fa : y1 - fa]
            image[y0:y1] = filtered
            chart = source[core]
            sums[k] = _carried_sum(sums[k], features[core][chart][:, 3 * k // 2 : 3 * k // 2 + 3])
            sums[k + 1] = _carried_sum(sums[k + 1], filtered[chart].astype(np.float64))
            del filtered
        del features, source
    for k, image in ((0, l0), (2, iz)):
        image *= _energy_ratio(sums[k], sums[k + 1])
    # the rest, band by band, into `out`
    seed = None
    pending: deque[tuple[int, int, np.ndarray]] = deque()  # texels not written yet: [lo, hi) in page order, SH
    done = 0  # the page rows below this one are written
    for i in passes():
        (y0, y1), (fa, fb), (wa, _) = windows[i]
        assert wa >= done, "a band would read rows of `sh` already denoised"
        features, unit_normals, _, seed, _ = built(i, seed, mean, DIRECTIONAL, with_normals=True)
        assert unit_normals is not None
        l0_lum = l0[fa:fb] @ LUMINANCE
        ratios = _ratios(features[fa - wa : fb - wa], l0_lum)
        n = unit_normals[y0 - wa : y1 - wa].copy()
        del features, unit_normals  # before the filter runs (memory)
        lo, hi = np.searchsorted(rows, (y0, y1))
        core = slice(y0 - fa, y1 - fa)
        clean = _assemble(ratios, n, l0[fa:fb], iz[fa:fb], l0_lum, denoiser, core, (rows[lo:hi] - y0, cols[lo:hi]))
        del ratios, n, l0_lum
        pending.append((lo, hi, clean))
        del clean
        # write the texels on rows no later band reads (all of them after the last band)
        done = windows[i + 1][2][0] if i + 1 < len(windows) else ph
        upto = int(np.searchsorted(rows, done))
        while pending and pending[0][0] < upto:
            lo, hi, values = pending.popleft()
            m = min(hi, upto)
            written[index[lo:m]] = True
            _write(out, index[lo:m], values[: m - lo], sh, noise, gather=True)
            if m < hi:  # the rows the next band reads: kept (a copy, the rest of the band's SH goes)
                pending.appendleft((m, hi, values[m - lo :].copy()))
            del values


def _carried_sum(total: np.ndarray | None, values: np.ndarray) -> np.ndarray:
    """`values` `(T, c)` summed over T (float64) after `total` `(c,)` (None: nothing before): the
    same additions, in the same order, as one sum of the rows that gave `total` and then these."""
    if total is None:
        return values.sum(axis=0, dtype=np.float64)
    return np.concatenate([total[None], values.astype(np.float64, copy=False)]).sum(axis=0)


def _page_scales(sh: np.ndarray, normal: np.ndarray, index: np.ndarray, ok: np.ndarray) -> tuple[float, float]:
    """The inputScales of L0 and I_z of a page's texels (flat atlas `index`, in the page's order;
    `ok`: finite, the others taken as 0), as the whole page's `_compressed_scale`, SCALE_CHUNK
    texels' SH at a time."""
    lum = np.empty((2, len(index)), np.float64)
    for s in range(0, len(index), SCALE_CHUNK):
        chart_sh = sh[index[s : s + SCALE_CHUNK]]
        chart_sh[~ok[s : s + SCALE_CHUNK]] = 0.0
        lum[0, s : s + SCALE_CHUNK] = _compressed(chart_sh[:, 0, :]) @ LUMINANCE
        irradz = hemisphere_irradz(chart_sh, normal[index[s : s + SCALE_CHUNK]])
        lum[1, s : s + SCALE_CHUNK] = _compressed(irradz) @ LUMINANCE
    return _scale_of_luminance(lum[0]), _scale_of_luminance(lum[1])


def _within(ok: np.ndarray, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int], reach: int) -> bool:
    """Whether every texel of a page of `shape` lies within `reach` texels (chessboard) of one of
    its chart texels (`ok` at `rows`, `cols`): then the smooth fill never takes the page mean."""
    h, w = shape
    if not ok.any():
        return False
    mask = np.zeros(shape, bool)
    mask[rows[ok], cols[ok]] = True
    for axis, n in ((0, h), (1, w)):  # a max filter of width 2·reach + 1, one axis at a time
        count = np.cumsum(mask, axis=axis, dtype=np.int32)
        count = np.concatenate([np.zeros((1, w) if axis == 0 else (h, 1), np.int32), count], axis=axis)
        hi = np.minimum(np.arange(n) + reach + 1, n)
        lo = np.maximum(np.arange(n) - reach, 0)
        window = count.take(hi, axis=axis) - count.take(lo, axis=axis)
        mask = window > 0
        del count, window
    return bool(mask.all())


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
    features: np.ndarray,
    n: np.ndarray,
    source: np.ndarray,
    denoiser: Denoiser,
    scales: tuple[float, float],
    at: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """One page denoised from its `_page_features` (consumed: filled in place), meaningful at its
    chart texels `source`: they are filled smoothly elsewhere (`_smooth_fill`), then L0 and I_z
    are denoised as HDR colour (`scales`: their inputScale) and the rest in directional mode over
    the denoised L0 (module docstring). Returns `(h, w, 9, 3)` float32, or `(T, 9, 3)` at the
    texels `at` (rows, columns) only."""
    features = _smooth_fill(features, source)[0]
    l0 = _hdr(features[..., 0:3], source, scales[0], denoiser)
    iz = _hdr(features[..., 3:6], source, scales[1], denoiser)
    l0_lum = l0 @ LUMINANCE
    ratios = _ratios(features[..., DIRECTIONAL], l0_lum)
    del features
    return _assemble(ratios, n, l0, iz, l0_lum, denoiser, at=at)


def _ratios(directional: np.ndarray, l0_lum: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The directional filter's inputs (`_ratio`) from a page's (or band's) filled features
    DIRECTIONAL `(h, w, 8)` (band 1 across n_v, band 2) and its denoised luminance L0 `(h, w)`."""
    return _ratio(directional[..., 0:3], l0_lum, BAND1_BOUND), _ratio(directional[..., 3:8], l0_lum, BAND2_BOUND)


def _assemble(
    ratios: tuple[np.ndarray, np.ndarray],
    n: np.ndarray,
    l0: np.ndarray,
    iz: np.ndarray,
    l0_lum: np.ndarray,
    denoiser: Denoiser,
    core: slice | None = None,
    at: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The SH `(h, w, 9, 3)` float32 of a page (or band) from its `_ratios`, its denoised,
    energy-corrected L0 and I_z `(h, w, 3)` (`_hdr`) and luminance L0 `(h, w)`: band 1 across
    n_v and band 2 denoised in directional mode over the denoised luminance L0, scaled by each
    colour's L0. `core`: only these rows (a band's; the filter still sees every row); `n`: the
    unit n_v of the rows returned; `at` (rows, columns) (in `core`'s rows): only these texels,
    `(T, 9, 3)` (memory: no SH image), WRITE_CHUNK at a time. What follows the filter is per
    texel, so they have the bits the whole image gives them."""
    # the rest in luminance over luminance L0 (one direction for all colours, as HHD keeps), scaled by each colour's L0
    across = _directional(ratios[0], l0_lum, BAND1_BOUND, denoiser, core)
    band2 = _directional(ratios[1], l0_lum, BAND2_BOUND, denoiser, core)
    if core is not None:
        l0, iz, l0_lum = l0[core], iz[core], l0_lum[core]
    across -= n * np.einsum("hwa,hwa->hw", n, across)[..., None]
    images = (across, band2, n, l0, iz, l0_lum)
    if at is None:
        return _sh_of(*images)
    # per texel from here: the texels asked for only, WRITE_CHUNK at a time (memory)
    out = np.empty((len(at[0]), 9, 3), np.float32)
    for s in range(0, len(out), WRITE_CHUNK):
        part = (at[0][s : s + WRITE_CHUNK], at[1][s : s + WRITE_CHUNK])
        out[s : s + WRITE_CHUNK] = _sh_of(*(image[part] for image in images))
    return out


def _sh_of(
    across: np.ndarray, band2: np.ndarray, n: np.ndarray, l0: np.ndarray, iz: np.ndarray, l0_lum: np.ndarray
) -> np.ndarray:
    """`_assemble`'s SH `(..., 9, 3)` float32 from its parts `(..., c)` (per texel): the denoised
    band 1 across n_v (3 axes, luminance) and band 2 (5, luminance), unit n_v, L0 and I_z (RGB),
    luminance L0."""
    colour = l0 / np.where(l0_lum > 0.0, l0_lum, 1.0)[..., None]  # (..., 3): L0 of each colour / luminance L0
    scaled_iz = iz / IRRADZ_FROM_R10
    out = np.empty(l0.shape[:-1] + (9, 3), np.float32)
    out[..., 0, :] = l0
    # v = across ⊗ colour + n ⊗ I_z / IRRADZ_FROM_R10 (3 axes × 3 colours), one axis at a time (memory)
    for k, (axis, sign) in zip((1, 2, 3), ((1, -1.0), (2, 1.0), (0, -1.0))):
        v = across[..., axis, None] * colour + n[..., axis, None] * scaled_iz
        out[..., k, :] = -v if sign < 0 else v
    out[..., 4:, :] = band2[..., None] * colour[..., None, :]
    return out


def _hdr(colour: np.ndarray, source: np.ndarray, scale: float, denoiser: Denoiser) -> np.ndarray:
    """An HDR colour image `(h, w, 3)` denoised (inputScale `scale`), ≥ 0, then scaled per channel
    so its sum over the chart texels `source` is the input's (clamped to ×[1/ENERGY_CLAMP,
    ENERGY_CLAMP]): at a few samples per texel the noise is heavy-tailed and the filter takes the
    rare bright samples for outliers, darkening the page; the sum over a page of texels is an
    unbiased estimate with little noise of its own."""
    out = _hdr_filtered(colour, scale, denoiser)
    before = colour[source].sum(axis=0, dtype=np.float64)
    after = out[source].sum(axis=0, dtype=np.float64)
    return out * _energy_ratio(before, after)


def _hdr_filtered(colour: np.ndarray, scale: float, denoiser: Denoiser) -> np.ndarray:
    """`_hdr`'s filter, before its energy correction: the colour `(h, w, 3)` (≥ 0) raised to
    HDR_POWER, denoised (inputScale `scale`: `_compressed_scale`'s), ≥ 0, raised back. float32,
    finite (at most float32's largest value)."""
    out = np.maximum(denoiser.denoise(_compressed(colour).astype(np.float32), input_scale=scale), 0.0)
    back = np.power(out, 1.0 / HDR_POWER, dtype=np.float64)
    return np.minimum(back, np.finfo(np.float32).max).astype(np.float32)


def _compressed_scale(colour: np.ndarray) -> float:
    """The inputScale of `_hdr_filtered` for HDR colours `(T, 3)` ≥ 0 (a page's chart texels):
    OIDN's auto-exposure (`input_scale`) of the image it filters, the colours raised to HDR_POWER."""
    return input_scale(_compressed(colour))


def _compressed(colour: np.ndarray) -> np.ndarray:
    """HDR colours (any shape) ≥ 0 raised to HDR_POWER (negative values taken as 0), float64."""
    return np.power(np.maximum(colour, 0.0), HDR_POWER, dtype=np.float64)


def _energy_ratio(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """`_hdr`'s energy correction (3,) float32 from the traced and the filtered sums."""
    ratio = np.where(after > 0.0, before / np.where(after > 0.0, after, 1.0), 1.0)
    return np.clip(ratio, 1.0 / ENERGY_CLAMP, ENERGY_CLAMP).astype(np.float32)


def _smooth_fill(
    image: np.ndarray,
    source: np.ndarray,
    seed: np.ndarray | None = None,
    keep: int | None = None,
    mean: np.ndarray | None = None,
    fill: bool = True,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """`image` `(h, w, c)` (changed in place) with its non-chart texels filled (float64): within
    MIRROR_RINGS of a chart texel, the chart mirrored through its border where it can be
    (`_mirror`); else within FILL_BLUR texels of one, the mean of the chart texels in the
    (2·FILL_BLUR + 1)² box around it (copying the nearest texel would repeat its noise in
    streaks, which the filter keeps as detail); farther, the nearest such mean (FILL_RINGS
    rings), beyond that the page mean.

    For a band of a page (`_denoise_banded`), rows of it: `seed` `(c, w)`, the column sums of
    the page's masked channels over the rows above the band (`_box_sum`), `keep` a row whose
    column sums to return for the next band, `mean` `(c,)` the page mean (None: the band's), and
    `fill=False` stops before the nearest-texel fill. Returns the image, the kept column sums
    (None without `keep`) and the mask of texels within FILL_BLUR of a chart texel."""
    weight = _box_sum(source.astype(np.float64)[..., None], FILL_BLUR)[0][..., 0]
    near = weight > 0.0
    inv = np.where(near, 1.0 / np.where(near, weight, 1.0), 0.0)
    del weight
    image = image.astype(np.float64, copy=False)
    outside = ~source
    image[outside] = 0.0  # in place: where(source, image, 0)
    kept = None if keep is None else np.empty((image.shape[2], image.shape[1]), np.float64)
    for k in range(image.shape[2]):  # where(source, image, box mean), one channel at a time, in place
        box, column = _box_sum(image[..., k : k + 1], FILL_BLUR, None if seed is None else seed[k : k + 1], keep)
        box = box[..., 0]
        box *= inv
        channel = image[..., k]
        channel[outside] = box[outside]
        if kept is not None and column is not None:
            kept[k] = column[0]
    if not fill:
        return image, kept, near
    filler = dilate.Fill(near, FILL_RINGS)
    if mean is None:
        return _mirror(filler.apply(image, in_place=True), source), kept, near
    # `Fill.apply` with the page's mean for the texels out of reach
    flat = image.reshape((-1, image.shape[2]))
    reached = filler.source >= 0
    flat[filler.empty[reached]] = flat[filler.source[reached]]
    flat[filler.empty[~reached]] = mean
    return _mirror(image, source), kept, near


def _mirror(image: np.ndarray, source: np.ndarray) -> np.ndarray:
    """`image` `(h, w, c)` (changed in place and returned) where each masked texel within
    MIRROR_RINGS of a chart texel `source` `(h, w)` takes the value of the texel mirrored through
    its nearest chart texel (point reflection: 2·nearest − itself), if that one is a chart texel.
    Next to a chart the filter then sees the chart's own noise continued, not a smooth band it
    keeps as an edge (bench/denoise_fill.py). It reads only texels within MIRROR_RINGS rows, so a
    band's rows get the whole page's bits."""
    h, w = source.shape
    nearest = dilate.nearest_source(source, MIRROR_RINGS).reshape(-1)
    empty = np.flatnonzero((nearest >= 0) & ~source.reshape(-1))
    ey, ex = np.divmod(empty, w)
    ny, nx = np.divmod(nearest[empty], w)
    my, mx = 2 * ny - ey, 2 * nx - ex
    inside = (my >= 0) & (my < h) & (mx >= 0) & (mx < w)
    mirrored = np.where(inside, my * w + mx, 0)
    inside &= source.reshape(-1)[mirrored]
    flat = image.reshape((h * w, image.shape[2]))
    flat[empty[inside]] = flat[mirrored[inside]]
    return image


def _box_sum(
    image: np.ndarray, r: int, seed: np.ndarray | None = None, keep: int | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Sum of `image` `(h, w, c)` over the (2r + 1)² box around each texel (zero outside),
    float64, one channel at a time (memory: a few channel images); and, with `keep`, the column
    sums `(c, w)` of rows 0..keep (the summed-area table's, so None without it).

    `seed` `(c, w)`: the image is rows of a larger one, and these are the column sums of its rows
    above: the summed-area table then continues the larger one's, the same additions in the same
    order, so a row r texels or more inside the rows has the bits the larger image gives it."""
    h, w = image.shape[:2]
    out = np.empty(image.shape, np.float64)
    kept = None if keep is None else np.empty((image.shape[2], w), np.float64)
    c = np.zeros((h + 1, w + 1))
    y0, y1 = np.clip(np.arange(h) - r, 0, h), np.clip(np.arange(h) + r + 1, 0, h)
    x0, x1 = np.clip(np.arange(w) - r, 0, w), np.clip(np.arange(w) + r + 1, 0, w)
    for k in range(image.shape[2]):
        if seed is None:
            column = np.cumsum(image[..., k], axis=0, dtype=np.float64)
            np.cumsum(column, axis=1, out=c[1:, 1:])
            if kept is not None and keep is not None:
                kept[k] = column[keep]
        else:
            column = np.cumsum(np.concatenate([seed[k][None], image[..., k]]), axis=0, dtype=np.float64)
            np.cumsum(column, axis=1, out=c[:, 1:])
            if kept is not None and keep is not None:
                kept[k] = column[keep + 1]
        del column
        out[..., k] = c[y1][:, x1] - c[y0][:, x1] - c[y1][:, x0] + c[y0][:, x0]
    return out, kept


def _band1_vector(sh: np.ndarray) -> np.ndarray:
    """v = (-r_1^1, -r_1^-1, r_1^0) of SH `(..., 9, C)` -> `(..., 3, C)`: I_z is IRRADZ_FROM_R10 · v·n_v."""
    return np.stack([-sh[..., 3, :], -sh[..., 1, :], sh[..., 2, :]], axis=-2)


def _ratio(coefficients: np.ndarray, l0: np.ndarray, bound: float) -> np.ndarray:
    """`_directional`'s input: luminance coefficients `(h, w, m)` divided by the denoised
    luminance L0 `(h, w)` and by `bound` (their largest |c / c_0| for radiance ≥ 0) times
    DIRECTIONAL_RANGE, clipped to [-1, 1]; 0 where L0 is. float32, FEATURE_ROWS rows at a time
    (per texel; memory)."""
    to_unit = DIRECTIONAL_RANGE / bound
    ratio = np.empty(coefficients.shape, np.float32)
    for y in range(0, len(ratio), FEATURE_ROWS):
        rows = slice(y, y + FEATURE_ROWS)
        lit = (l0[rows] > 0.0)[..., None]
        part = np.where(lit, coefficients[rows] / np.where(lit, l0[rows, :, None], 1.0) * to_unit, 0.0)
        ratio[rows] = np.clip(part, -1.0, 1.0)
        del part
    return ratio


def _directional(
    ratio: np.ndarray, l0: np.ndarray, bound: float, denoiser: Denoiser, core: slice | None = None
) -> np.ndarray:
    """Luminance coefficients, as their `_ratio` `(h, w, m)`, denoised in OIDN's directional
    mode, three at a time, and scaled back by L0 `(h, w)` and `bound`; `core`: only these rows
    are scaled back and returned."""
    to_unit = DIRECTIONAL_RANGE / bound
    clean = np.concatenate(
        [
            denoiser.denoise(ratio[..., k : k + 3], directional=True, input_scale=1.0)
            for k in range(0, ratio.shape[-1], 3)
        ],
        axis=-1,
    )
    if core is not None:
        clean, l0 = clean[core], l0[core]
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
