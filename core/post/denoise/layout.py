"""The denoiser's charts and pages: the atlas's charts (`label_charts`), packed into the page
images OIDN filters (`layout`, skyline packing, charts grouped by brightness). No bpy."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: Texels of each chart's own (dilated) values around it in its page.
MARGIN = 2
#: Page width in texels (at most the atlas's; a wider chart gets a page as wide as it) and the
#: height at or above which no chart starts in a page (its top may pass it).
PAGE_SIZE = 512
#: A brightness band's pages are square for this many times its charts' rectangles' area (`_page_width`).
PACKING_SLACK = 1.1
#: Charts sharing a page differ in mean luminance by at most this factor.
BRIGHTNESS_BAND = 4.0
#: Mean L0 luminance below which a chart counts as black and is left alone.
BLACK = 1e-12
#: Band rows are multiples of this (OIDN's tile alignment: its U-Net pools 4 times).
BAND_ALIGN = 16


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
