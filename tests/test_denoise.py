"""The denoiser (core/post/denoise/) and the denoise post stage, without Blender's UI: chart labelling and pages
(pure numpy), then the filter on synthetic atlases and in the bake pipeline through Blender's own
OIDN library (the fixtures of test_oidn.py: skipped with the reason when it or the weights are absent)."""

from collections import deque
from dataclasses import replace

import numpy as np
import pytest

from hhd_lightmapper.core import bake, encoding, memory, post, sh
from hhd_lightmapper.core.colour import LUMINANCE
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.post.denoise import fill, filtering, layout, noise_clamp, oidn
from hhd_lightmapper.core.post.denoise import pages as denoise
from hhd_lightmapper.core.stages import NOISE_PASSES
from hhd_lightmapper.core.tracer import BakeSettings
from test_oidn import bpy_library_dirs, denoiser, library  # noqa: F401  (fixtures)
from test_pipeline_stages import RES, plane


def bfs_labels(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """8-connected components by breadth-first search: the slow, obvious reference."""
    h, w = mask.shape
    labels = np.full((h, w), -1)
    n = 0
    for y, x in zip(*np.nonzero(mask)):
        if labels[y, x] >= 0:
            continue
        labels[y, x] = n
        queue = deque([(y, x)])
        while queue:
            cy, cx = queue.popleft()
            for ny in range(max(cy - 1, 0), min(cy + 2, h)):
                for nx in range(max(cx - 1, 0), min(cx + 2, w)):
                    if mask[ny, nx] and labels[ny, nx] < 0:
                        labels[ny, nx] = n
                        queue.append((ny, nx))
        n += 1
    return labels, n


@pytest.mark.parametrize("density", [0.0, 0.15, 0.4, 0.55, 0.7, 1.0])
def test_chart_labels_are_the_8_connected_components(density):
    mask = np.random.default_rng(int(density * 100)).random((57, 83)) < density
    labels, n = denoise.label_charts(mask)
    expected, m = bfs_labels(mask)
    assert n == m
    assert ((labels >= 0) == mask).all()
    # the same partition: each of our labels maps to exactly one reference label and back
    pairs = set(zip(labels[mask].tolist(), expected[mask].tolist()))
    assert len(pairs) == n == len({a for a, _ in pairs}) == len({b for _, b in pairs})


def test_diagonal_touch_joins_and_a_one_texel_gap_separates():
    mask = np.zeros((6, 9), bool)
    mask[1, 1] = mask[2, 2] = True  # diagonal neighbours: one chart
    mask[1, 4] = mask[1, 6] = True  # a gap of one texel: two charts
    labels, n = denoise.label_charts(mask)
    assert n == 3 and labels[1, 1] == labels[2, 2] and labels[1, 4] != labels[1, 6]


def test_pages_hold_every_lit_chart_once_without_overlap_and_within_a_brightness_band():
    rng = np.random.default_rng(7)
    mask = np.zeros((300, 300), bool)
    for _ in range(120):
        y, x = rng.integers(0, 290, 2)
        mask[y : y + rng.integers(1, 9), x : x + rng.integers(1, 9)] = True
    mask[10:200, 250:260] = True  # a tall chart
    labels, n = denoise.label_charts(mask)
    brightness = 10.0 ** rng.uniform(-3, 3, n)
    brightness[:5] = 0.0  # black charts are left alone
    pages = denoise.layout(labels, n, brightness)
    placed = [c for p in pages for c in p.charts]
    assert sorted(placed) == list(range(5, n))
    for page in pages:
        b = brightness[page.charts]
        assert b.max() / b.min() <= layout.BRIGHTNESS_BAND
        used = np.zeros(page.shape, int)
        for (_, _, rh, rw), (py, px) in zip(page.rects, page.corners):
            used[py : py + rh, px : px + rw] += 1
        assert used.max() == 1  # rectangles (margins included) never overlap


def test_texels_beside_a_chart_take_it_mirrored_through_its_border():
    """Reflect padding (`_mirror`): beside a straight border, the first masked column takes the
    chart's second-to-last column and the next one the third-to-last (2·nearest − itself); farther
    than MIRROR_RINGS, and where the mirror image falls outside the chart (a one-texel-wide
    chart), the fill already there stays."""
    rng = np.random.default_rng(3)
    source = np.zeros((6, 10), bool)
    source[:, :4] = True  # chart: columns 0-3
    source[2, 8] = True  # a lone texel: its mirror images are not chart texels
    image = rng.random((6, 10, 2))
    before = image.copy()
    out = fill._mirror(image, source)
    assert out is image and fill.MIRROR_RINGS == 2
    np.testing.assert_array_equal(out[:, 4], before[:, 2])
    np.testing.assert_array_equal(out[:, 5], before[:, 1])
    np.testing.assert_array_equal(out[:, :4], before[:, :4])  # chart texels are never written
    np.testing.assert_array_equal(out[:, 6:], before[:, 6:])  # beside the lone texel: nothing to mirror


def atlas_data(charts: list[tuple[slice, slice, float]], size=128, noise=0.3, seed=0) -> encoding.TexelData:
    """A synthetic atlas: per chart (rows, cols, radiance), uniform sky-like radiance with the
    band-1 vector along +z (normals +z), multiplicative noise on every coefficient."""
    rng = np.random.default_rng(seed)
    sh = np.zeros((size, size, 9, 3), np.float32)
    coverage = np.zeros((size, size), np.float32)
    for rows, cols, radiance in charts:
        coverage[rows, cols] = 1.0
        block = sh[rows, cols]
        block[..., 0, :] = radiance * np.sqrt(np.pi)  # L0 of uniform radiance over the upper hemisphere
        block[..., 2, :] = radiance * np.sqrt(3.0 * np.pi) / 2.0  # r_1^0: I_z = radiance
        block *= (1.0 + noise * rng.standard_normal(block.shape[:2] + (1, 1))).clip(0.05, None)
        sh[rows, cols] = block
    normal = np.zeros((size, size, 3), np.float32)
    normal[..., 2] = 1.0
    return encoding.TexelData(sh=sh, normal=normal, coverage=coverage)


def iz(data: encoding.TexelData) -> np.ndarray:
    """I_z `(H, W, 3)` of every texel."""
    h, w = data.coverage.shape
    return sh.hemisphere_irradz(data.sh.reshape(-1, 9, 3), data.normal.reshape(-1, 3)).reshape(h, w, 3)


def test_a_dark_chart_beside_a_bright_one_is_denoised_as_if_alone(denoiser):  # noqa: F811
    dark, bright = (slice(20, 100), slice(10, 60), 1.0), (slice(20, 100), slice(63, 120), 100.0)
    both = atlas_data([dark, bright])
    alone = atlas_data([dark])
    out_both, report = denoise.denoise_texels(memory.keep(both), denoiser)
    out_alone, _ = denoise.denoise_texels(alone, denoiser)
    region = (dark[0], dark[1])
    assert report.charts == 2 and report.pages == 2  # 100x apart: never in one page
    np.testing.assert_array_equal(out_both.sh[region], out_alone.sh[region])
    before, after = iz(both)[region].mean(), iz(out_both)[region].mean()
    assert abs(after / before - 1.0) < 0.01
    # and the denoiser did its job on both charts
    for rows, cols, radiance in (dark, bright):
        raw = np.sqrt(np.mean((iz(both)[rows, cols] - radiance) ** 2))
        clean = np.sqrt(np.mean((iz(out_both)[rows, cols] - radiance) ** 2))
        assert clean < 0.3 * raw, (radiance, clean / raw)


def test_the_compressed_range_keeps_a_bright_strip_from_bleeding_into_the_dark_beside_it(
    denoiser,  # noqa: F811
    monkeypatch,
):
    """A chart whose edge rows are 100x brighter than the rest (a sunlit strip beside a shadowed
    face): the filter bleeds the strip into the dark texels beside it. Filtered raised to
    HDR_POWER, the dark rows beside the strip take less than 60% of the light they take
    filtered linearly (no noise clamp here: the bake has no noise estimate)."""
    data = atlas_data([(slice(20, 100), slice(20, 100), 0.02)], noise=0.1)
    strip = atlas_data([(slice(20, 22), slice(20, 100), 2.0)], noise=0.1, seed=1)
    data.sh[20:22, 20:100] = strip.sh[20:22, 20:100]
    beside = (slice(22, 26), slice(24, 96))

    def bleed() -> float:
        out, _ = denoise.denoise_texels(memory.keep(data), denoiser)
        return float(iz(out)[beside].mean() / iz(data)[beside].mean() - 1.0)

    assert filtering.HDR_POWER < 1.0
    compressed = bleed()
    monkeypatch.setattr(filtering, "HDR_POWER", 1.0)
    linear = bleed()
    assert linear > 0.04, linear  # the fixture does show the bleed
    assert compressed < 0.6 * linear, (compressed, linear)


def test_charts_sharing_a_page_stay_within_one_percent(denoiser):  # noqa: F811
    """Two charts 2x apart in brightness share a page (MARGIN texels of their own values each):
    each one's mean I_z moves by less than 1% against denoising it alone."""
    a, b = (slice(30, 70), slice(20, 50), 1.0), (slice(30, 70), slice(53, 83), 2.0)
    _, report = denoise.denoise_texels(atlas_data([a, b]), denoiser)
    assert report.pages == 1
    together, _ = denoise.denoise_texels(atlas_data([a, b]), denoiser)
    for chart in (a, b):
        alone, _ = denoise.denoise_texels(atlas_data([chart]), denoiser)
        region = (chart[0], chart[1])
        assert abs(iz(together)[region].mean() / iz(alone)[region].mean() - 1.0) < 0.01


def test_black_huge_and_nan_texels_give_finite_output(denoiser):  # noqa: F811
    data = atlas_data([(slice(10, 40), slice(10, 40), 0.0), (slice(50, 90), slice(10, 60), 1e6)])
    data.sh[60, 20] = np.nan
    data.sh[61, 21, 2] = np.inf
    out, _ = denoise.denoise_texels(data, denoiser)
    assert np.isfinite(out.sh).all()
    assert not out.sh[10:40, 10:40].any()  # black stays black
    assert abs(iz(out)[50:90, 10:60].mean() / 1e6 - 1.0) < 0.05
    assert not out.sh[data.coverage == 0].any()  # outside the charts nothing is written


@pytest.mark.parametrize("radiance", [1e-9, 1e20, 1e36])
def test_the_denoised_chart_scales_with_its_radiance_from_dim_to_near_float32s_largest(
    denoiser,  # noqa: F811
    radiance,
):
    """The same noisy chart at radiance 1 and at `radiance`: the same denoised result, scaled
    (the inputScale follows the compressed range), finite up to near float32's largest value.
    The dimmest case stays above BLACK, below which a chart is left as traced."""
    unit, _ = denoise.denoise_texels(atlas_data([(slice(50, 90), slice(10, 60), 1.0)]), denoiser)
    out, _ = denoise.denoise_texels(atlas_data([(slice(50, 90), slice(10, 60), radiance)]), denoiser)
    assert np.isfinite(out.sh).all()
    np.testing.assert_allclose(iz(out)[50:90, 10:60] / radiance, iz(unit)[50:90, 10:60], rtol=1e-3, atol=1e-6)


def test_buried_and_empty_texels_are_neither_used_nor_changed(denoiser):  # noqa: F811
    data = atlas_data([(slice(10, 60), slice(10, 60), 1.0)])
    data.coverage[30:35, 30:35] = -1.0  # buried: black in the files
    data.sh[30:35, 30:35] = 1e4  # would light its neighbours if the filter saw it
    out, _ = denoise.denoise_texels(memory.keep(data), denoiser)
    np.testing.assert_array_equal(out.sh[30:35, 30:35], data.sh[30:35, 30:35])
    assert abs(iz(out)[25:40, 25:40][data.coverage[25:40, 25:40] > 0].mean() - 1.0) < 0.1


def test_no_denoiser_means_an_undenoised_bake_with_a_warning_never_a_failure(tmp_path):
    surface, scene = plane()
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"])
    trace = BakeSettings(samples=8, pass_samples=4, bounces=1, seed=3)
    off = bake.run([atlas], scene, bake.PipelineSettings(trace=trace), tmp_path / "off")
    missing = bake.run(
        [atlas], scene, bake.PipelineSettings(trace=trace, denoise=True, denoiser_library=""), tmp_path / "missing"
    )
    assert off[0].warnings == []
    assert "Open Image Denoise library not found" in missing[0].warnings[0]
    assert read(missing[0].files.hhd) == read(off[0].files.hhd)
    record = lightmap_files.read_sidecar(missing[0].files.sidecar)["post"]["denoise"]
    assert record["enabled"] and not record["applied"] and "not found" in record["warning"]


def read(path) -> dict:
    return {k: v.tobytes() for k, v in exr.read(path)[0].items()}


@pytest.mark.slow
def test_denoised_bake_keeps_the_raw_sh_and_reencode_switches_denoising_off_and_on(tmp_path, library, denoiser):  # noqa: F811
    surface, scene = plane()
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"])
    trace = BakeSettings(samples=8, pass_samples=4, bounces=1, seed=3)
    off = bake.run([atlas], scene, bake.PipelineSettings(trace=trace), tmp_path / "off")[0]
    on = bake.run(
        [atlas], scene, bake.PipelineSettings(trace=trace, denoise=True, denoiser_library=str(library)), tmp_path / "on"
    )[0]
    assert on.warnings == []
    record = lightmap_files.read_sidecar(on.files.sidecar)["post"]["denoise"]
    assert record["applied"] and record["oidn_version"] == denoiser.version and record["charts"] >= 1
    assert read(on.files.sh) == read(off.files.sh)  # the SH as traced
    denoised = read(on.files.hhd)
    assert denoised != read(off.files.hhd)
    _, warnings = bake.reencode(on.files, encoding.EncoderSettings(), threads=2, denoise=False)
    assert warnings == [] and read(on.files.hhd) == read(off.files.hhd)
    assert lightmap_files.read_sidecar(on.files.sidecar)["post"]["denoise"] == {"enabled": False}
    bake.reencode(on.files, encoding.EncoderSettings(), threads=2, denoise=True, denoiser_library=str(library))
    assert read(on.files.hhd) == denoised


def test_missing_weights_are_reported_not_raised(tmp_path, library, monkeypatch):  # noqa: F811
    monkeypatch.setattr(oidn, "WEIGHTS_DIR", tmp_path)
    monkeypatch.setattr(filtering, "_DENOISERS", {})
    monkeypatch.setattr(oidn.Denoiser.__init__, "__defaults__", (0, tmp_path))
    data = atlas_data([(slice(10, 40), slice(10, 40), 1.0)])
    settings = bake.PipelineSettings(denoise=True, denoiser_library=str(library))
    out, records = post.apply(data, settings)
    assert out is data and "weights missing" in records["denoise"]["warning"]


def test_heavy_tailed_noise_keeps_its_mean(denoiser):  # noqa: F811
    """Rare bright samples (2% of texels 40x brighter: a few samples per texel reaching a small
    emitter) look like outliers to the filter, which would darken the chart; the page's energy
    correction keeps the mean I_z of the input (and so the raw bake's, an unbiased estimate)."""
    data = atlas_data([(slice(10, 110), slice(10, 110), 1.0)], noise=0.2)
    spikes = np.random.default_rng(9).random((100, 100)) < 0.02
    data.sh[10:110, 10:110][spikes] *= 40.0
    out, _ = denoise.denoise_texels(memory.keep(data), denoiser)
    region = (slice(10, 110), slice(10, 110))
    assert abs(iz(out)[region].mean() / iz(data)[region].mean() - 1.0) < 1e-3
    assert iz(out)[region].std() < 0.25 * iz(data)[region].std()


def test_texels_every_pass_agreed_on_keep_their_traced_value(denoiser):  # noqa: F811
    """A black strip across a lit chart (a contact shadow every pass saw black: noise 0): the
    filter alone bleeds light into it; with the tracer's noise the strip stays exactly black,
    while the lit texels (noise known, as large as the atlas's) are denoised as before."""
    lit = (slice(10, 90), slice(10, 90), 1.0)
    data = atlas_data([lit], noise=0.3)
    data.sh[40:43, 10:90] = 0.0
    sigma = 0.3 * np.sqrt(np.pi)  # standard error of L0's luminance: 30% of uniform radiance 1
    noise = np.where(data.coverage > 0, sigma, np.nan).astype(np.float32)
    noise[40:43, 10:90] = 0.0
    free, _ = denoise.denoise_texels(memory.keep(data), denoiser)
    clamped, _ = denoise.denoise_texels(memory.keep(replace(data, noise=noise)), denoiser)
    assert iz(free)[40:43, 10:90].max() > 0.02  # the filter alone lights the shadow
    assert not clamped.sh[40:43, 10:90].any()
    rest = np.ones((128, 128), bool)
    rest[40:43] = False
    rest &= data.coverage > 0
    raw_error = np.sqrt(np.mean((iz(data)[rest] - 1.0) ** 2))
    assert np.sqrt(np.mean((iz(clamped)[rest] - 1.0) ** 2)) < 0.3 * raw_error


def test_the_noise_clamp_bounds_every_coefficient_by_its_colours_share():
    rng = np.random.default_rng(4)
    traced = rng.uniform(0.0, 2.0, (6, 7, 9, 3)).astype(np.float32)
    denoised = traced + rng.normal(0.0, 1.0, traced.shape).astype(np.float32)
    noise = rng.uniform(0.0, 0.3, (6, 7)).astype(np.float32)
    noise[0, :3] = np.nan  # unknown: not clamped
    noise[1, :3] = 0.0  # every pass agreed: the traced value
    out = noise_clamp.clamp_to_noise(denoised, traced, noise)
    np.testing.assert_array_equal(out[0, :3], denoised[0, :3])
    np.testing.assert_array_equal(out[1, :3], traced[1, :3])
    colour = traced[..., 0, :] / (traced[..., 0, :] @ LUMINANCE)[..., None]
    bound = noise_clamp.NOISE_CLAMP * np.nan_to_num(noise, nan=np.inf)[..., None] * colour
    assert (np.abs(out - traced) <= bound[:, :, None, :] * (1 + 1e-6) + 1e-7).all()
    inside = np.abs(denoised - traced) < bound[:, :, None, :]
    np.testing.assert_array_equal(out[inside], denoised[inside])


def test_the_texels_file_keeps_the_noise_of_texels_with_enough_passes(tmp_path):
    surface, scene = plane()
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"])
    for passes in (NOISE_PASSES - 1, NOISE_PASSES):
        trace = BakeSettings(samples=4 * passes, pass_samples=4, bounces=1, seed=3)
        result = bake.run([atlas], scene, bake.PipelineSettings(trace=trace), tmp_path / str(passes))[0]
        noise = lightmap_files.read_texel_data(result.files).noise
        charts = lightmap_files.read_texel_data(result.files).coverage > 0
        assert noise is not None and np.isnan(noise[~charts]).all()
        if passes < NOISE_PASSES:
            assert np.isnan(noise[charts]).all()  # too few passes to trust their spread
        else:
            assert np.isfinite(noise[charts]).all() and (noise[charts] >= 0).all() and (noise[charts] > 0).any()


def test_a_bake_without_noise_is_denoised_without_the_clamp(tmp_path, library):  # noqa: F811
    """Texels files written before they kept the noise: read as noise None, denoised unclamped."""
    data = atlas_data([(slice(10, 60), slice(10, 60), 1.0)])
    assert data.noise is None
    settings = bake.PipelineSettings(denoise=True, denoiser_library=str(library))
    out, records = post.apply(data, settings)
    assert records["denoise"]["applied"] and np.isfinite(out.sh).all()


def banded_atlas(h: int = 520) -> encoding.TexelData:
    """A tall L-shaped chart (its page has texels beyond the smooth fill's reach: the page mean is
    used), a small one, a black one (-0 coefficients), a buried patch, non-finite texels and
    the tracer's noise: every path of the banded page. `h` rows: the L's foot (its 60 bottom rows)
    must stay beyond the fill's reach of the charts at the top (the band test checks it)."""
    rng = np.random.default_rng(5)
    w, buried = 200, 300 * h // 520
    data = atlas_data(
        [(slice(10, h - 20), slice(5, 50), 1.0), (slice(h - 80, h - 20), slice(5, 190), 1.0)], size=h, seed=5
    )
    data = replace(
        data, sh=data.sh[:, :w].copy(), normal=data.normal[:, :w].copy(), coverage=data.coverage[:, :w].copy()
    )
    data.coverage[20:60, 120:180] = 1.0
    data.sh[20:60, 120:180] = 1.5 * data.sh[20:60, 20:80]
    data.coverage[100:120, 120:180] = 1.0
    data.sh[100:120, 120:180] = -0.0
    data.coverage[buried : buried + 5, 20:30] = -1.0
    data.sh[buried : buried + 5, 20:30] = 1e4
    data.sh[100, 20] = np.nan
    data.sh[101, 21, 3] = np.inf
    data.normal[..., 0] = 0.1 * np.sin(np.arange(w) / 7.0)
    noise = np.where(data.coverage > 0, 0.05 * rng.random((h, w)), np.nan).astype(np.float32)
    return replace(data, noise=noise)


@pytest.mark.slow
@pytest.mark.parametrize("band_rows", [16, 48, 96])
def test_a_page_denoised_in_bands_has_the_whole_pages_bits(denoiser, monkeypatch, band_rows):  # noqa: F811
    """Bands of 16 to 96 rows (the first bands' context reaching the page's top, box sums and the
    fill's page mean carried from band to band) give bit for bit what the whole page gives, in a
    copy and in place. The atlas is the shortest that keeps all of it (its page 4 bands of 96
    rows; each band costs OIDN its core and 2 × 96 rows of context)."""
    data = banded_atlas(330)
    whole, _ = denoise.denoise_texels(memory.keep(data), denoiser)
    labels, n = denoise.label_charts(data.coverage != 0)
    width = max(p.shape[1] for p in denoise.layout(labels, n, np.ones(n)))
    monkeypatch.setattr(denoise, "BAND_TEXELS", band_rows * width)
    monkeypatch.setattr(denoise, "SCALE_CHUNK", 1000)
    assert denoise._band_rows((data.coverage.shape[0], width)) == band_rows
    within = []  # whether every texel of the page is within the fill's reach of a chart texel
    monkeypatch.setattr(denoise, "_within", lambda *a, real=denoise._within: within.append(real(*a)) or within[-1])
    work = memory.keep(data)
    banded, _ = denoise.denoise_texels(work, denoiser)
    assert within == [False]  # the page mean of the fill is used
    assert np.shares_memory(banded.sh, work.sh)  # denoised where it was read
    np.testing.assert_array_equal(banded.sh.view(np.uint32), whole.sh.view(np.uint32))


def test_a_cancelled_denoise_puts_the_traced_sh_back(denoiser):  # noqa: F811
    """Cancelled between two pages, the first written: the SH is put back from the caller's
    `raw_sh()` (a bake reads it from the raw SH file it wrote first)."""
    data = atlas_data([(slice(10, 40), slice(10, 40), 1.0), (slice(50, 90), slice(10, 60), 30.0)])
    traced = data.sh.copy()
    calls, restored = [], []

    def raw_sh():
        restored.append(bool((data.sh.view(np.uint32) != traced.view(np.uint32)).any()))
        return traced.copy()

    def check():
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        denoise.denoise_texels(data, denoiser, check, raw_sh)
    assert restored == [True]  # called once, after the first page was written
    np.testing.assert_array_equal(data.sh.view(np.uint32), traced.view(np.uint32))


def test_small_charts_fill_the_space_beside_a_tall_one():
    """One tall chart and fifty 5×5 ones: stacked in the space beside the tall chart, the page
    is within half again their rectangles' area (one shelf as tall as the tall chart, holding
    them all in a row, would be 8.8 times it)."""
    mask = np.zeros((400, 400), bool)
    mask[10:110, 10:20] = True  # 100 × 10
    for k in range(50):
        y, x = 150 + 10 * (k // 20), 10 + 10 * (k % 20)
        mask[y : y + 5, x : x + 5] = True
    labels, n = denoise.label_charts(mask)
    (page,) = denoise.layout(labels, n, np.ones(n))
    rects = sum(rh * rw for _, _, rh, rw in page.rects)
    assert len(page.charts) == 51
    assert page.shape[0] * page.shape[1] <= 1.5 * rects


def test_the_clamp_tightens_on_a_chart_smaller_than_small_chart(denoiser):  # noqa: F811
    """An 8×8 chart (64 texels) may move each coefficient only √(64 / SMALL_CHART) of the
    NOISE_CLAMP bound from its traced value; a 20×20 one (400 texels) the whole bound. Unclamped,
    the filter moves texels of both charts further than that."""
    small, large = (slice(10, 18), slice(10, 18)), (slice(40, 60), slice(40, 60))
    data = atlas_data([(*small, 1.0), (*large, 1.0)], noise=0.3)
    sigma = 0.3 * np.sqrt(np.pi)  # standard error of L0's luminance: 30% of uniform radiance 1
    noise = np.where(data.coverage > 0, sigma, np.nan).astype(np.float32)
    free, _ = denoise.denoise_texels(memory.keep(data), denoiser)
    clamped, _ = denoise.denoise_texels(memory.keep(replace(data, noise=noise)), denoiser)
    bound = np.full(data.sh.shape, noise_clamp.NOISE_CLAMP * sigma)  # grey: each colour's share of L0 is 1
    shrink = np.sqrt(64 / noise_clamp.SMALL_CHART)
    assert shrink < 1.0
    inner = (slice(42, 58), slice(42, 58))  # the large chart's texels beyond EDGE_RINGS of its edge
    for region, factor in ((small, shrink), (large, 1.0), (inner, 1.0)):
        moved = np.abs(clamped.sh[region] - data.sh[region])
        assert (moved <= factor * bound[region] * (1 + 1e-5) + 1e-6).all()
        assert (np.abs(free.sh[region] - data.sh[region]) > factor * bound[region]).any()
    assert (np.abs(clamped.sh[inner] - data.sh[inner]) > shrink * bound[inner] * 1.01).any()


def test_the_clamp_tightens_within_edge_rings_of_a_charts_edge(denoiser):  # noqa: F811
    """A 40×40 chart: its texels within EDGE_RINGS of its edge may move only EDGE_CLAMP of the
    NOISE_CLAMP bound, the others the whole bound (and some do move further than the edge's)."""
    chart = (slice(20, 60), slice(20, 60))
    data = atlas_data([(*chart, 1.0)], noise=0.3)
    sigma = 0.3 * np.sqrt(np.pi)
    noise = np.where(data.coverage > 0, sigma, np.nan).astype(np.float32)
    clamped, _ = denoise.denoise_texels(memory.keep(replace(data, noise=noise)), denoiser)
    bound = noise_clamp.NOISE_CLAMP * sigma
    moved = np.abs(clamped.sh - data.sh).max(axis=(2, 3))
    r = noise_clamp.EDGE_RINGS
    edge = data.coverage > 0
    edge[20 + r : 60 - r, 20 + r : 60 - r] = False
    assert edge.sum() == 40 * 40 - (40 - 2 * r) ** 2
    assert (moved[edge] <= noise_clamp.EDGE_CLAMP * bound * (1 + 1e-5) + 1e-6).all()
    inner = moved[20 + r : 60 - r, 20 + r : 60 - r]
    assert (inner <= bound * (1 + 1e-5) + 1e-6).all()
    assert (inner > noise_clamp.EDGE_CLAMP * bound * 1.01).any()


@pytest.mark.parametrize("rings", [1, 2, 3])
def test_chart_edge_is_a_texel_with_another_label_within_rings(rings):
    """`chart_edge` against the window itself, on labels with holes (-1), many charts, and
    charts touching the atlas's border, over more rows than one step."""
    rng = np.random.default_rng(rings)
    labels = rng.integers(0, 3, (15, 10)).repeat(10, axis=0).repeat(10, axis=1)
    labels = np.where(rng.uniform(size=labels.shape) < 0.002, -1, labels)
    edge = noise_clamp.chart_edge(labels, rings)
    padded = np.pad(labels, rings, constant_values=-2)
    h, w = labels.shape
    window = np.lib.stride_tricks.sliding_window_view(padded, (2 * rings + 1, 2 * rings + 1))
    expected = (window != labels[:, :, None, None]).any(axis=(2, 3))
    assert window.shape[:2] == (h, w) and expected.any() and not expected.all()
    np.testing.assert_array_equal(edge, expected)


def test_noise_is_the_spread_widened_for_its_own_degrees_of_freedom():
    """`TracedAtlas.noise`: the luminance L0 standard error × √(ν / (ν − 2)), ν = passes − 1;
    NaN below NOISE_PASSES passes."""
    from hhd_lightmapper.core.stages import TracedAtlas

    error = np.zeros((3, 9, 3), np.float32)
    error[:, 0, :] = 0.5
    traced = TracedAtlas(
        points=None,  # type: ignore[arg-type]  # noise reads the statistics only
        sh=np.zeros((3, 9, 3)),
        sh_error=error,
        texel_samples=np.array([3, 4, 16]) * 8,
        samples=16 * 8,
        passes=16,
    )
    noise = traced.noise()
    assert np.isnan(noise[0])
    np.testing.assert_allclose(noise[1:], 0.5 * np.sqrt([3.0 / 1.0, 15.0 / 13.0]), rtol=1e-6)
