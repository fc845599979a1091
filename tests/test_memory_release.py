"""What lets a 4096² bake fit in 3 GB without changing a bit (issue 23, bench/memory.py): arrays
whose pages go back to the system once spent (`memory.releasable_zeros`, `release_rows`), the SH imaged a part at a time as its compact copy goes
(`TexelData.from_traced`) and the bake points a compact trace keeps
(`BakePoints.for_files`). No Blender."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core import bakepoints, encoding, memory, stages, tracer
from hhd_lightmapper.core.scene import BakeScene, SunLight
from scenekit import meshes

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="resident memory read from /proc")


def resident_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


@linux
def test_spent_rows_go_back_and_the_rest_keep_their_values():
    rows = 1 << 21  # 216 MB of (rows, 9, 3) float32
    a = memory.releasable_zeros((rows, 9, 3), np.float32)
    a[:] = np.arange(27, dtype=np.float32).reshape(9, 3) + 1.0
    kept = a[rows // 2 :].copy()
    before = resident_mb()
    memory.release_rows(a, rows // 2)
    assert before - resident_mb() > 0.9 * a.nbytes / 2 / 2**20
    np.testing.assert_array_equal(a[rows // 2 + 1 :], kept[1:])  # rows past the first partial page
    plain = np.ones((1000, 9, 3), np.float32)
    memory.release_rows(plain, 1000)  # not a releasable array: left alone
    assert (plain == 1.0).all()


def test_a_kept_copy_is_the_stages_to_spend_and_the_callers_stays():
    """`memory.keep`: an array's copy (releasable: spending it gives its pages back), a hand-off
    object with its arrays copied and its other fields shared; anything else is refused."""
    a = np.arange(4096 * 27, dtype=np.float32).reshape(4096, 9, 3)
    copy = memory.keep(a)
    assert not np.shares_memory(copy, a) and copy.flags.c_contiguous
    np.testing.assert_array_equal(copy, a)
    memory.release_rows(copy, len(copy))
    if sys.platform.startswith("linux"):
        assert not copy.any()  # given back
    assert a[1:].all()
    window = stages.Window(0, 0, 8, 8, (16, 16))
    data = encoding.TexelData(
        np.ones((8, 8, 9, 3), np.float32), np.ones((8, 8, 3), np.float32), np.ones((8, 8)), window=window
    )
    kept = memory.keep(data)
    assert kept.window is window and kept.sh_error is None
    for name in ("sh", "normal", "coverage"):
        assert not np.shares_memory(getattr(kept, name), getattr(data, name))
        np.testing.assert_array_equal(getattr(kept, name), getattr(data, name))
    with pytest.raises(TypeError):
        memory.keep([a])


def sheet():
    v, f = meshes.plane(2.0)
    uv = (v[f][..., :2] + 1.0) / 2.2 + 0.02
    normals = np.tile([0, 0, 1.0], (len(f), 3, 1))
    surface = bakepoints.SurfaceTriangles(v[f], normals, uv, np.zeros(len(f), int), np.full((len(f), 3), 0.5))
    scene = BakeScene(v[f], np.full((len(f), 3), 0.5), lights=[SunLight(np.array([0.3, 0.2, 0.93]), np.ones(3))])
    return surface, scene


def sheet_points(albedo=True):
    surface, scene = sheet()
    return bakepoints.build(surface, 64, 64, albedo=albedo), scene


def test_the_traced_atlas_imaged_a_part_at_a_time_is_the_traced_atlas_imaged_whole(monkeypatch):
    """`TexelData.from_traced` (parts of 97 rows, each given back, for real where the platform
    can, once imaged) gives the images `from_points` gives of the same SH, which it only reads;
    the traced atlas is spent: its bake points and SH dropped, the SH's rows released as imaged."""
    points, scene = sheet_points()
    traced = tracer.bake(points, scene, tracer.BakeSettings(samples=4, pass_samples=4, bounces=0), compact=True)
    sh = traced.sh
    whole = encoding.TexelData.from_points(traced.points, sh.copy(), noise=traced.noise())
    monkeypatch.setattr(encoding.stage, "IMAGE_ROWS", 97)
    released = []
    monkeypatch.setattr(
        encoding.stage, "release_rows", lambda a, stop: (released.append(stop), memory.release_rows(a, stop))
    )
    parts = encoding.TexelData.from_traced(traced)
    assert len(released) > 20 and released[-1] == len(points.texel)
    assert released == sorted(released) and released[::2] == released[1::2]  # the SH's rows, then its error's
    for name in ("sh", "normal", "coverage", "noise"):
        assert getattr(parts, name).tobytes() == getattr(whole, name).tobytes(), name
    assert traced.points is None and len(traced.sh) == 0 and len(traced.sh_error) == 0
    if sys.platform.startswith("linux"):  # given back: the spent rows read 0 now
        assert not sh[: released[-2] - 1024].any()


def test_a_compact_trace_keeps_what_the_files_take_and_the_same_sh():
    points, scene = sheet_points()
    lean, _ = sheet_points(albedo=False)
    assert lean.albedo is None and points.albedo is not None
    assert points.texel.dtype == np.int32 and points.triangle.dtype == np.int32
    settings = tracer.BakeSettings(samples=4, pass_samples=4, bounces=1, seed=2)
    full = tracer.bake(points, scene, settings)
    compact = tracer.bake(lean, scene, settings, compact=True)
    np.testing.assert_array_equal(compact.sh, full.sh.astype(np.float32))
    kept = compact.points
    for name in ("texel", "normal", "coverage", "buried", "object_index"):
        np.testing.assert_array_equal(getattr(kept, name), getattr(points, name))
    assert len(kept.position) == 0 and len(kept.face_normal) == 0 and len(kept.triangle) == 0


@linux
def test_finish_atlas_spends_the_traced_atlas_and_a_kept_copy_leaves_it_whole():
    """`finish_atlas` owns the traced atlas: its SH (rows given back) and bake points are gone
    afterwards. A farm worker that may hand the atlas back to the client (OIDN failing there)
    hands over a copy of the SH and standard error (`memory.keep`): the atlas it keeps is
    whole, and the files are the same."""
    from hhd_lightmapper.core import bake
    from hhd_lightmapper.core.bake import finishing
    from hhd_lightmapper.core.farm.finishing import _Kept

    surface, scene = sheet()
    atlas = bake.AtlasInput("Lightmap", 64, 64, surface, ["sheet"])
    settings = bake.PipelineSettings(trace=tracer.BakeSettings(samples=4, pass_samples=4, bounces=0, threads=1))
    points = bake.points_of(atlas, None, 1)
    traced = tracer.bake(points, scene, settings.trace, compact=True)
    del points
    sh, sh_error, points = traced.sh, traced.sh_error, traced.points
    before = sh.copy(), sh_error.copy()
    kept, spent = _Kept(), _Kept()
    copy = replace(traced, sh=memory.keep(sh), sh_error=memory.keep(sh_error))
    finishing.finish_atlas(atlas, copy, settings, 0.0, {}, kept)
    assert copy.points is None and len(copy.sh) == 0  # the copy is spent
    assert traced.points is points and traced.sh is sh
    assert sh.tobytes() == before[0].tobytes() and sh_error.tobytes() == before[1].tobytes()
    finishing.finish_atlas(atlas, traced, settings, 0.0, {}, spent)
    assert traced.points is None and len(traced.sh) == 0 and len(traced.sh_error) == 0
    assert before[0][:-100].any() and not sh[:-100].any()  # its rows given back
    assert kept.traced_sh("Lightmap", "").tobytes() == spent.traced_sh("Lightmap", "").tobytes()


def test_a_spending_trace_gives_the_bake_points_rows_back_behind_its_chunks_and_the_same_sh(monkeypatch):
    """`tracer.bake(..., compact=True, spend_points=True)` (as a bake runs): the same SH as a
    trace that keeps its bake points, the tracing-only arrays given back a chunk at a time, in
    order, up to every texel (for real where the platform can: their rows read 0 then)."""
    from hhd_lightmapper.core.tracer import scheduler

    settings = tracer.BakeSettings(samples=8, pass_samples=4, bounces=1, seed=2, chunk_texels=128)
    kept, scene = sheet_points()
    spent, _ = sheet_points()
    reference = tracer.bake(kept, scene, settings, compact=True)
    released = []
    monkeypatch.setattr(
        scheduler, "release_rows", lambda a, stop: (released.append(stop), memory.release_rows(a, stop))
    )
    traced = tracer.bake(spent, scene, settings, compact=True, spend_points=True)
    np.testing.assert_array_equal(traced.sh, reference.sh)
    n, arrays = len(spent.texel), len([a for a in bakepoints.BakePoints.TRACING_ONLY if getattr(spent, a) is not None])
    assert n > 4 * 128 and released == sorted(released) and released[-1] == n
    assert len(released) == arrays * -(-n // 128)  # each array, behind each chunk
    assert len(kept.position) == n  # a trace that does not spend them leaves them alone
    for name in bakepoints.BakePoints.TRACING_ONLY:  # what the files' bake points leave out
        assert getattr(traced.points, name) is None or len(getattr(traced.points, name)) == 0, name
    if sys.platform.startswith("linux"):
        assert not spent.position[: n - 256].any() and not spent.face_normal[: n - 256].any()


def test_the_encoder_holds_the_baked_texels_values_only_while_the_sh_is_whole():
    """`encode_images` keeps the encoding's values of the baked texels only (placed in the layer
    images once the SH is taken): on an atlas with one texel in 16 baked, what it has allocated
    when a chunk is encoded, beyond the chunk's own SH and normals, is less than one layer's image."""
    import tracemalloc

    h, w = 128, 128
    coverage = np.zeros((h, w), np.float32)
    coverage[::4, ::4] = 1.0
    baked = coverage > 0
    sh = np.zeros((h, w, 9, 3), np.float32)
    sh[baked, 0] = np.random.default_rng(1).uniform(0.5, 1.0, (int(baked.sum()), 3))
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = 1.0
    data = encoding.TexelData(sh=sh, normal=normal, coverage=coverage)
    real = encoding.for_settings(encoding.EncoderSettings())
    fill = data.fill()
    extra = []

    class Watched:
        file = real.file

        def encode(self, sh_rows, normals):
            extra.append(tracemalloc.get_traced_memory()[0] - start - sh_rows.nbytes - normals.nbytes)
            return real.encode(sh_rows, normals)

        def summary(self, stats, texels):
            return real.summary(stats, texels)

    tracemalloc.start()
    start = tracemalloc.get_traced_memory()[0]
    try:
        images, _ = encoding.stage.encode_images(data, Watched(), fill, threads=1)
    finally:
        tracemalloc.stop()
    assert extra and max(extra) < h * w * 3 * 4  # one (H, W, 3) float32 layer
    assert data.sh.size == 0 and set(images) >= {"Iz.R", "Iz.G", "Iz.B"}


def test_an_encoder_releasing_the_sh_gives_it_back_behind_its_chunks_and_the_same_images(monkeypatch):
    """`encode_atlas(..., release_sh=True)` (as a bake encodes): the SH's rows are given back in
    order behind the chunks encoded, up to every texel (for real where the platform can: a kept
    reference to the SH reads 0 there), and the images are those of an encoder that keeps it."""
    h, w = 64, 64
    coverage = np.zeros((h, w), np.float32)
    coverage[4:60:2, 3:61] = 1.0
    baked = coverage > 0
    sh = np.zeros((h, w, 9, 3), np.float32)
    sh[baked] = np.random.default_rng(2).uniform(0.1, 1.0, (int(baked.sum()), 9, 3))
    sh[baked, 0] += 2.0
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = 1.0
    data = memory.keep(encoding.TexelData(sh=sh, normal=normal, coverage=coverage))
    encoder = encoding.for_settings(encoding.EncoderSettings())
    monkeypatch.setattr(encoding.stage, "ENCODE_CHUNK", 128)
    kept = encoding.encode_atlas(replace(data), encoder, raw=False, threads=1)
    assert data.sh.shape == sh.shape  # a TexelData of the same arrays keeps them
    released = []
    monkeypatch.setattr(
        encoding.stage, "release_rows", lambda a, stop: (released.append(stop), memory.release_rows(a, stop))
    )
    the_sh = data.sh
    spent = encoding.encode_atlas(replace(data), encoder, raw=False, threads=1, release_sh=True)
    assert len(released) > 8 and released == sorted(released) and released[-1] == h * w
    images, reference = spent.files[encoder.file.key][1], kept.files[encoder.file.key][1]
    for name in reference:
        np.testing.assert_array_equal(images[name], reference[name])
    if sys.platform.startswith("linux"):
        assert not the_sh[: h // 2].any()  # pages wholly behind the chunks: given back
