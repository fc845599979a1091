"""The denoise post stage's driver (`denoise_texels`): an atlas's pages denoised one by one, a
page larger than a band in horizontal bands with the whole page's bits (`_denoise_banded`), the
result written through the noise clamp. No bpy. The steps: the package's docstring."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...colour import LUMINANCE
from ...encoding import TexelData
from ...progress import ticker
from ...sh import hemisphere_irradz
from .fill import FILL_BLUR, FILL_RINGS, _smooth_fill
from .filtering import (
    ALL,
    DIRECTIONAL,
    FEATURE_ROWS,
    HDR,
    _assemble,
    _compressed,
    _compressed_scale,
    _denoise_features,
    _energy_ratio,
    _hdr_filtered,
    _page_features,
    _ratios,
    _scale_of_luminance,
)
from .layout import BAND_ALIGN, Page, _page_texels, label_charts, layout
from .noise_clamp import ROWS_PER_STEP, _ChartNoise, _clamp_unwritten, _write
from .oidn import Denoiser, DenoiserError

#: A page larger than this many texels per band goes through the filter in horizontal bands
#: (`_denoise_banded`): each band's core rows (a multiple of BAND_ALIGN, about BAND_TEXELS
#: texels) with BAND_OVERLAP rows of context above and below, so that the page's own buffers
#: (SH, features, smooth fill, output) exist for one band at a time, not for the page.
BAND_TEXELS = 1 << 20
#: Rows of context on each side of a band: OIDN's receptive field is ±87 texels (its own tiles
#: overlap by 96); a band aligned to BAND_ALIGN rows with this context gives OIDN's bits.
BAND_OVERLAP = 96
#: Texels of SH gathered at once for a banded page's inputScale (`_page_scales`).
SCALE_CHUNK = 1 << 16


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
    raw_sh: Callable[[], np.ndarray] | None = None,
) -> tuple[TexelData, DenoiseReport]:
    """`data` with the SH of its baked texels denoised (the module's steps, the noise clamp
    where `data.noise` is known); everything else as it was. A baked texel with a non-finite coefficient is not
    used and gets the denoised value of its surroundings. `check()`, if given, runs between pages
    (it raises to cancel). Raises DenoiserError if OIDN fails.

    `data` is this stage's (`core.memory`): the denoised SH is written into `data.sh` itself, and
    nothing of the SH it replaces is kept (no copy of the atlas's SH, nor of a page's:
    `_denoise_banded`). On an error or cancellation after some texel was written, the SH of
    the baked texels is put back from `raw_sh()`, the atlas's SH as handed over read back
    `(H, W, 9, 3)` (the raw SH file a bake writes first), before the exception leaves (an
    exception of `raw_sh` itself leaves instead, chained to the first). Without `raw_sh`,
    `data.sh` is then left partly denoised, and a DenoiserError leaves as a RuntimeError (the
    post stage lets the SH pass undenoised after a DenoiserError: not this SH). Before any
    texel is written, nothing is read back."""
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
    out = sh  # written where it is read: a page reads its texels before writing them (`_denoise_banded`)
    written = np.zeros(h * w, bool)  # texels written (set before they are: `raw_sh`)
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
                _denoise_banded(
                    page,
                    labels,
                    sh,
                    normal,
                    noise=noise,
                    finite=finite,
                    out=out,
                    denoiser=denoiser,
                    band=band,
                    check=part,
                    written=written,
                )
            else:
                _denoise_page(
                    page, labels, sh, normal, noise=noise, finite=finite, out=out, denoiser=denoiser, written=written
                )
            report.charts += len(page.charts)
            report.pages += 1
            report.page_texels += page.shape[0] * page.shape[1]
        del labels, flat, finite, noise
        parts[-1].at(0.0, f"{len(pages)} pages denoised, clamping to the noise")
        if data.noise is not None:  # the clamp of the texels no page changed (traced + 0: as `clamp_to_noise`)
            clamping = True
            _clamp_unwritten(out.reshape(data.sh.shape), data.noise, written)
    except BaseException as e:
        if clamping or written.any():
            if raw_sh is not None:
                _put_back(data, raw_sh())
            elif isinstance(e, DenoiserError):
                raise RuntimeError(f"the denoiser failed with the SH partly denoised ({e})") from e
        raise
    del written
    report.seconds = time.perf_counter() - t0
    return data, report


def _put_back(data: TexelData, sh: np.ndarray) -> None:
    """The SH of `data`'s baked texels put back into `data.sh` from `sh` `(H, W, 9, 3)`, the
    whole atlas's (its window's part where `data` has a window, `TexelData.window`): a denoise
    failing half-way (the denoiser writes baked texels only)."""
    window = data.window
    if window is not None:
        sh = sh[window.y0 : window.y0 + window.h, window.x0 : window.x0 + window.w]
    h, w = data.sh.shape[:2]
    baked = np.flatnonzero(data.baked)
    data.sh.reshape(h * w, -1)[baked] = np.ascontiguousarray(sh).reshape(h * w, -1)[baked]


def _denoise_page(
    page: Page,
    labels: np.ndarray,
    sh: np.ndarray,
    normal: np.ndarray,
    *,
    noise: _ChartNoise | None,
    finite: np.ndarray,
    out: np.ndarray,
    denoiser: Denoiser,
    written: np.ndarray,
) -> None:
    """One page denoised whole, its chart texels written into `out` `(H·W, 9, 3)` (clamped to
    the noise if `noise` (`_ChartNoise`) is given) and marked in `written` (H·W,) first. It reads a copy
    of the page's texels' SH (`out` may be `sh`: the noise clamp reads each chunk's traced SH
    there before writing it), no larger than one band of a banded page, whose window is taller
    than this page."""
    rows, cols, atlas_index = _page_texels(page, labels)
    ok = finite[atlas_index]
    chart_sh = np.where(ok[:, None, None], sh[atlas_index], np.float32(0.0))
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
    # the traced SH the noise clamp needs read from `sh` as each chunk is written (memory: no copy
    # of the page's SH kept through the filter; nothing wrote these texels since they were read)
    _write(out, atlas_index, clean, sh, noise, gather=True)


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
    *,
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


def _finite_texels(sh: np.ndarray) -> np.ndarray:
    """`(H, W)` bool: the texels of SH `(H, W, 9, 3)` whose every coefficient is finite."""
    out = np.empty(sh.shape[:2], bool)
    for y in range(0, sh.shape[0], ROWS_PER_STEP):
        out[y : y + ROWS_PER_STEP] = np.isfinite(sh[y : y + ROWS_PER_STEP]).all(axis=(2, 3))
    return out
