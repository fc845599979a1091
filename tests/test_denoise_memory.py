"""The denoiser owns its TexelData (core/post/denoise/; issue 23: memory): the SH denoised where it is read,
with no copy of what it replaced, and put back from the caller's `raw_sh` on failure. Real OIDN (the fixtures of test_oidn.py:
skipped with the reason when the library or the weights are absent); the filter's numerics are
never replaced, only wrapped to fail."""

import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from hhd_lightmapper.core import encoding, memory
from hhd_lightmapper.core.post.denoise import layout, oidn
from hhd_lightmapper.core.post.denoise import pages as denoise
from test_denoise import atlas_data, banded_atlas
from test_oidn import bpy_library_dirs, denoiser, library  # noqa: F401  (fixtures)


def bits(a: np.ndarray) -> np.ndarray:
    """The float32 bits (-0 and +0 apart, NaNs by payload)."""
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def band_width(data: encoding.TexelData) -> int:
    """Width of the widest page of `data` (BAND_TEXELS = rows × this gives bands of those rows)."""
    labels, n = layout.label_charts(data.coverage != 0)
    return max(p.shape[1] for p in layout.layout(labels, n, np.ones(n)))


def reference_and_lean(data: encoding.TexelData, denoiser, monkeypatch):  # noqa: F811
    """The denoised SH with every page whole (`BAND_TEXELS` unbounded: a page reads its texels
    before it writes any) and with the pages `BAND_TEXELS` bands (the bands read `sh` while the
    last pass writes into it), each on its own copy of `data`."""
    band_texels = denoise.BAND_TEXELS
    with monkeypatch.context() as whole:
        whole.setattr(denoise, "BAND_TEXELS", 1 << 40)
        reference, _ = denoise.denoise_texels(memory.keep(data), denoiser)
    assert denoise.BAND_TEXELS == band_texels
    lean_data = memory.keep(data)
    lean, report = denoise.denoise_texels(lean_data, denoiser)
    assert np.shares_memory(lean.sh, lean_data.sh)
    return reference, lean, report


# A band's rows reach BAND_OVERLAP + FILL_BLUR + FILL_RINGS = 114 rows above its core: a texel is
# written once no later band reads its row. 48 rows: bands shorter than that, texels held back
# over several bands; 128: the top 114 rows of each band held back until the next is built.
@pytest.mark.slow
@pytest.mark.parametrize("band_rows", [48, 128])
def test_a_banded_page_denoised_in_place_has_the_whole_pages_bits(denoiser, monkeypatch, band_rows):  # noqa: F811
    """The tall L chart (the fill's page mean used), a black chart (-0), a buried patch, NaN and
    Inf texels and the noise clamp: in bands, in place, every texel's bits are the whole page's."""
    data = banded_atlas()
    assert data.noise is not None and not np.isfinite(data.sh).all() and (data.coverage < 0).any()
    assert np.signbit(data.sh[100:120, 120:180]).all()  # the black chart's -0
    width = band_width(data)
    monkeypatch.setattr(denoise, "BAND_TEXELS", band_rows * width)
    monkeypatch.setattr(denoise, "SCALE_CHUNK", 1000)
    assert denoise._band_rows((data.coverage.shape[0], width)) == band_rows
    reference, lean, report = reference_and_lean(data, denoiser, monkeypatch)
    np.testing.assert_array_equal(bits(lean.sh), bits(reference.sh))
    assert report.charts == 2 and report.pages == 1  # the L and the patch beside it; the black chart is left
    changed = (bits(lean.sh) != bits(data.sh)).any(axis=(2, 3))
    assert changed[data.coverage > 0].mean() > 0.9  # the filter ran: bits differ from the traced ones


@pytest.mark.slow
def test_a_multi_page_atlas_denoised_in_place_has_the_whole_pages_bits(denoiser, monkeypatch):  # noqa: F811
    """Pages of several brightness bands, small whole pages and a banded one, black and
    non-finite texels, buried texels and the noise clamp: the banded page's bits are its bits
    denoised whole, the other pages' unchanged by it."""
    rng = np.random.default_rng(11)
    charts = [
        (slice(4, 250), slice(4, 30), 1.0),  # tall: its page goes in bands
        (slice(4, 40), slice(40, 80), 1.3),
        (slice(50, 70), slice(40, 60), 30.0),
        (slice(80, 120), slice(40, 90), 0.02),
        (slice(130, 150), slice(40, 70), 0.0),  # black
        (slice(160, 200), slice(40, 100), 1.5),
        (slice(210, 240), slice(40, 60), 300.0),
    ]
    data = atlas_data(charts, size=256, seed=11)
    # directional content (band 1 across n_v, band 2): what the last pass filters reads it
    lit = data.coverage > 0
    y, x = np.mgrid[0:256, 0:256] / 256.0
    for k in (1, 3, 4, 5, 6, 7, 8):
        wave = 0.3 * np.sin(7.0 * x + 3.0 * k) * np.cos(5.0 * y + k) + 0.1 * rng.standard_normal((256, 256))
        data.sh[..., k, :] = np.where(lit[..., None], wave[..., None] * data.sh[..., 0, :], data.sh[..., k, :])
    data.normal[..., 0] = 0.1 * np.sin(np.arange(256) / 7.0)
    data.sh[130:150, 40:70] = -0.0
    data.coverage[20:24, 10:14] = -1.0  # buried inside the tall chart
    data.sh[20:24, 10:14] = 1e4
    data.sh[30, 50] = np.nan
    data.sh[170, 60, 4] = -np.inf
    noise = np.where(data.coverage > 0, 0.05 * rng.random(data.coverage.shape), np.nan).astype(np.float32)
    noise[180:190, 60:90] = np.nan  # texels with too few passes: not clamped
    data = replace(data, noise=noise)
    monkeypatch.setattr(layout, "PAGE_SIZE", 64)
    monkeypatch.setattr(denoise, "BAND_TEXELS", 16 * 32)
    labels, n = layout.label_charts(data.coverage != 0)
    pages = layout.layout(labels, n, np.ones(n))
    assert sum(bool(denoise._band_rows(p.shape)) for p in pages) == 1
    reference, lean, report = reference_and_lean(data, denoiser, monkeypatch)
    assert report.pages >= 5
    np.testing.assert_array_equal(bits(lean.sh), bits(reference.sh))


@pytest.mark.slow
def test_no_page_sized_copy_of_the_traced_sh_is_held(denoiser, monkeypatch):  # noqa: F811
    """Peak of numpy's allocations (tracemalloc) while a banded page (5 bands) is denoised in
    place, against the same page denoised whole (`BAND_TEXELS` large): the banded run's peak is
    lower by more than the page's SH (108 bytes a chart texel), which the bands never copy."""
    data = banded_atlas()
    peaks = {}
    for band_texels in (1 << 40, 128 * band_width(data)):
        monkeypatch.setattr(denoise, "BAND_TEXELS", band_texels)
        work = memory.keep(data)
        tracemalloc.start()
        try:
            out, _ = denoise.denoise_texels(work, denoiser)
            peaks[band_texels] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        del out
    whole, banded = peaks.values()
    texels = int((data.coverage > 0).sum())
    assert whole - banded > 108 * texels, (peaks, texels)


class FailingDenoiser:
    """The real denoiser, raising on its `fail_at`-th call in directional mode (the last pass's
    calls: a banded page's writes happen there), after noting whether `data.sh` had changed."""

    def __init__(self, real, fail_at: int, data: encoding.TexelData, traced: np.ndarray):
        self.real, self.fail_at, self.data, self.traced = real, fail_at, data, traced
        self.calls = 0
        self.written_when_failing: bool | None = None

    def denoise(self, image, directional=False, input_scale=None):
        if directional:
            self.calls += 1
            if self.calls == self.fail_at:
                self.written_when_failing = bool((bits(self.data.sh) != bits(self.traced)).any())
                raise oidn.DenoiserError("injected failure")
        return self.real.denoise(image, directional=directional, input_scale=input_scale)


# the banded page (5 bands of 128 rows) comes first; 3 directional calls a band: call 1 is band
# 0's (nothing written), 4 band 1's (band 0's rows below band 1's reach, 0-13, written), 10 band 3's
@pytest.mark.parametrize(("fail_at", "restored"), [(1, False), (4, True), (10, True)])
def test_a_failure_after_a_write_reads_the_sh_back_and_before_it_does_not(denoiser, monkeypatch, fail_at, restored):  # noqa: F811
    data = banded_atlas()
    monkeypatch.setattr(denoise, "BAND_TEXELS", 128 * band_width(data))
    traced = data.sh.copy()
    failing = FailingDenoiser(denoiser, fail_at, data, traced)
    calls = []

    def raw_sh():
        calls.append(1)
        return traced.copy()  # the caller's copy (e.g. the raw SH file)

    with pytest.raises(oidn.DenoiserError, match="injected failure"):
        denoise.denoise_texels(data, failing, raw_sh=raw_sh)  # type: ignore[arg-type]
    assert failing.written_when_failing is restored
    assert len(calls) == (1 if restored else 0)
    np.testing.assert_array_equal(bits(data.sh), bits(traced))


def cancel(data: encoding.TexelData, denoiser, cancel_at: int, raw_sh) -> None:  # noqa: F811
    """`check` raising KeyboardInterrupt at its `cancel_at`-th call."""
    count = []

    def check():
        count.append(1)
        if len(count) == cancel_at:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        denoise.denoise_texels(data, denoiser, check, raw_sh)


# the banded page first (5 bands of 128 rows): `check` runs once before it, then before bands 1-4
# of each pass (the fill's page mean, L0 and I_z, the rest); 2: in the first pass; 9: the second
# pass's last (nothing written yet); 10: before the last pass's band 1 (band 0's rows 0-13 written)
@pytest.mark.parametrize(("cancel_at", "restored"), [(2, False), (9, False), (10, True)])
def test_a_cancel_reads_the_sh_back_only_once_something_is_written(denoiser, monkeypatch, cancel_at, restored):  # noqa: F811
    data = banded_atlas()
    monkeypatch.setattr(denoise, "BAND_TEXELS", 128 * band_width(data))
    labels, n = layout.label_charts(data.coverage != 0)
    assert [-(-p.shape[0] // 128) for p in layout.layout(labels, n, np.ones(n))] == [5]
    traced = data.sh.copy()
    calls = []

    def raw_sh():
        calls.append(1)
        return traced.copy()  # the caller's copy (e.g. the raw SH file)

    cancel(data, denoiser, cancel_at, raw_sh)
    assert len(calls) == (1 if restored else 0)
    np.testing.assert_array_equal(bits(data.sh), bits(traced))


def test_without_raw_sh_a_cancel_leaves_the_sh_partly_denoised(denoiser, monkeypatch):  # noqa: F811
    data = banded_atlas()
    monkeypatch.setattr(denoise, "BAND_TEXELS", 128 * band_width(data))
    traced = data.sh.copy()
    cancel(data, denoiser, 10, None)
    changed = (bits(data.sh) != bits(traced)).any(axis=(2, 3))
    assert changed.any() and not changed.all()  # as documented


@pytest.mark.parametrize(("fail_at", "written"), [(1, False), (4, True)])
def test_without_raw_sh_a_failure_after_a_write_is_no_denoiser_error(denoiser, monkeypatch, fail_at, written):  # noqa: F811
    """A DenoiserError lets the post stage pass the SH on undenoised: with the SH partly
    denoised and nothing to read it back from, the failure leaves as a RuntimeError instead."""
    data = banded_atlas()
    monkeypatch.setattr(denoise, "BAND_TEXELS", 128 * band_width(data))
    failing = FailingDenoiser(denoiser, fail_at, data, data.sh.copy())
    with pytest.raises(RuntimeError if written else oidn.DenoiserError, match="injected failure") as raised:
        denoise.denoise_texels(data, failing)  # type: ignore[arg-type]
    assert failing.written_when_failing is written
    assert isinstance(raised.value, oidn.DenoiserError) is not written
