"""The compact trace (`tracer.bake(..., compact=True)`, what `bake.run` traces): the same numbers
as the full statistics reduced to what the files take, streamed chunk by chunk without running
statistics for the whole atlas; and `bake.run` releasing each atlas's SH and bake points once its
files are written. No Blender."""

import gc
import weakref
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, rays, tracer
from hhd_lightmapper.core.bake import finishing
from hhd_lightmapper.core.errors import BakeCancelled
from hhd_lightmapper.core.files import exr
from hhd_lightmapper.core.scene import BakeScene, PointLight, SunLight
from hhd_lightmapper.core.tracer import scheduler, statistics
from scenekit import meshes

RES = 64


def floor_and_box(groups=True):
    """A 2 m floor (the receiver) with a box resting on it (buried texels, shadows, bounces); a
    sun and a lamp in two light groups and a sky in none (three light sets) when `groups`.
    Returns (AtlasInput, BakeScene, RayScene)."""
    v, f = meshes.plane(2.0)
    box_v, box_f = meshes.cube(0.6, centre=(1.0, 1.0, 0.3))
    floor = v[f]
    tris = np.concatenate([floor, box_v[box_f]])
    surface = bakepoints.SurfaceTriangles(
        floor, np.tile([0, 0, 1.0], (2, 3, 1)), floor[..., :2] / 2.0, np.zeros(2, int), np.full((2, 3), 0.5)
    )
    scene = BakeScene(
        tris,
        np.full((len(tris), 3), 0.6),
        lights=[
            SunLight(np.array([0.6, 0.2, 0.77]), np.array([3.0, 2.5, 2.0]), group="Sun" if groups else ""),
            PointLight(
                np.array([0.3, 1.6, 0.8]), np.array([40.0, 30.0, 20.0]), radius=0.1, group="Lamp" if groups else ""
            ),
        ],
        world=np.array([0.1, 0.2, 0.3]),
    )
    return bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"]), scene, rays.RayScene(tris)


@pytest.fixture(scope="module")
def scene():
    atlas, scene, ray_scene = floor_and_box()
    points = bake.points_of(atlas, ray_scene, 1)
    assert points.buried.any()
    return points, scene, ray_scene


#: several passes, chunks of odd size (the last one short), 2 threads
PASSES = tracer.BakeSettings(samples=12, pass_samples=4, bounces=1, seed=4, chunk_texels=700, threads=2)


def assert_compact_of(compact, full):
    """`compact` holds exactly what the files take of `full`: float32 of its SH (the files' bits),
    band 0 of its standard error, per light set too; the same run statistics."""
    assert compact.sh.dtype == np.float32 and compact.sh_error.shape == (len(full.sh), 1, 3)
    np.testing.assert_array_equal(compact.sh, full.sh.astype(np.float32))
    np.testing.assert_array_equal(compact.sh_error, full.sh_error[:, :1])
    np.testing.assert_array_equal(compact.noise(), full.noise())
    assert compact.sets == full.sets
    if full.sets:
        np.testing.assert_array_equal(compact.set_sh, full.set_sh.astype(np.float32))
        np.testing.assert_array_equal(compact.set_sh_error, full.set_sh_error[:, :, :1])
        for k in range(len(full.sets)):
            np.testing.assert_array_equal(compact.light_set(k).noise(), full.light_set(k).noise())
    np.testing.assert_array_equal(compact.texel_samples, full.texel_samples)
    assert (compact.samples, compact.passes, compact.rays, compact.stopped_by) == (
        full.samples,
        full.passes,
        full.rays,
        full.stopped_by,
    )


@pytest.mark.parametrize("samples", [4, 12])
def test_the_streamed_trace_is_the_full_trace_reduced(scene, samples):
    points, scene_, ray_scene = scene
    settings = tracer.BakeSettings(samples=samples, pass_samples=4, bounces=1, seed=4, chunk_texels=700, threads=2)
    full = tracer.bake(points, scene_, settings, ray_scene=ray_scene)
    compact = tracer.bake(points, scene_, settings, ray_scene=ray_scene, compact=True)
    assert len(full.sets) == 3
    assert np.count_nonzero(full.sh_error[:, 0]) > 0 or samples == 4  # errors are compared, not all zero
    assert_compact_of(compact, full)
    one_thread = tracer.bake(
        points, scene_, tracer.BakeSettings(**{**vars(settings), "threads": 1}), ray_scene=ray_scene, compact=True
    )
    np.testing.assert_array_equal(one_thread.sh, compact.sh)
    np.testing.assert_array_equal(one_thread.set_sh_error, compact.set_sh_error)


def test_compact_without_light_sets_and_with_a_noise_target(scene):
    """Without light sets; and with a noise target (every pass over the atlas in turn: full
    statistics during the trace, reduced after it) the same reduction."""
    points, _, _ = scene
    atlas, plain, ray_scene = floor_and_box(groups=False)
    for settings in (PASSES, tracer.BakeSettings(**{**vars(PASSES), "samples": 40, "noise_target": 0.2})):
        full = tracer.bake(points, plain, settings, ray_scene=ray_scene)
        compact = tracer.bake(points, plain, settings, ray_scene=ray_scene, compact=True)
        assert full.sets == () and compact.set_sh is None
        assert_compact_of(compact, full)
    assert full.texel_samples.min() < full.texel_samples.max()  # the noise target stopped some texels


def test_the_streamed_trace_holds_running_statistics_for_one_chunk_only(scene, monkeypatch):
    """No per-texel float64 SH for the whole atlas: every running statistics made while tracing
    is one chunk's, and what the compact TracedAtlas keeps is float32 SH and band 0's error."""
    points, scene_, ray_scene = scene
    sizes = []
    made = statistics.Statistics.__init__

    def record(self, n, normals, channels=3):
        sizes.append(n)
        made(self, n, normals, channels)

    monkeypatch.setattr(statistics.Statistics, "__init__", record)
    traced = tracer.bake(points, scene_, PASSES, ray_scene=ray_scene, compact=True)
    n = len(points.texel)
    assert n > 3 * PASSES.chunk_texels
    assert sizes == [min(PASSES.chunk_texels, n - s) for s in range(0, n, PASSES.chunk_texels)]
    arrays = [traced.sh, traced.sh_error, traced.set_sh, traced.set_sh_error]
    assert all(a.dtype == np.float32 for a in arrays)
    assert sum(a.nbytes for a in arrays) == n * 4 * (9 * 3 + 3) * (1 + len(traced.sets))
    sizes.clear()
    tracer.bake(points, scene_, PASSES, ray_scene=ray_scene)  # the full trace: one for the atlas
    assert sizes == [n]


def test_the_streamed_trace_reports_progress_cancels_and_refuses_what_needs_every_pass(scene):
    points, scene_, ray_scene = scene
    seen = []
    tracer.bake(points, scene_, PASSES, ray_scene=ray_scene, compact=True, progress=lambda f, m: seen.append((f, m)))
    fractions = [f for f, _ in seen]
    chunks = -(-len(points.texel) // PASSES.chunk_texels)
    assert len(seen) == chunks * 3 and fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    assert f"chunk {chunks} of {chunks} (3 passes each)" in seen[-1][1] and "texel-samples/s" in seen[-1][1]
    calls = []
    with pytest.raises(BakeCancelled):
        tracer.bake(
            points, scene_, PASSES, ray_scene=ray_scene, compact=True, cancel=lambda: calls.append(1) or len(calls) > 4
        )
    assert len(calls) == 5
    with pytest.raises(ValueError, match="noise target"):
        scheduler.run_streamed(None, None, tracer.BakeSettings(noise_target=0.1), 0.0)


def files(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.glob("*.exr"))}


def test_bake_run_writes_the_files_of_the_full_trace(tmp_path):
    """`bake.run` (compact, streamed) writes the bytes the full statistics give (`tracer.bake`
    without `compact`, then the same finishing stages)."""
    atlas, scene_, ray_scene = floor_and_box()
    settings = bake.PipelineSettings(trace=PASSES)
    bake.run([atlas], scene_, settings, tmp_path / "run")
    points = bake.points_of(atlas, ray_scene, 2)
    full = tracer.bake(points, scene_, PASSES, ray_scene=ray_scene)
    assert full.sh.dtype == np.float64 and full.sh_error.shape[1] == 9
    with exr.Staging() as staging:
        finishing._write(staging, atlas, full, settings, tmp_path / "full", 0.0, {})
        staging.commit()
    assert files(tmp_path / "run") == files(tmp_path / "full") and len(files(tmp_path / "run")) == 3 * 4


@pytest.mark.slow
def test_bake_run_frees_each_atlas_once_its_files_are_written(tmp_path, monkeypatch):
    """When an atlas is traced, the bake points and traced SH of the atlases before it are gone
    (no reference left: `bake.run` drops them once their files are written), light sets or not."""
    traced_before = tracer.bake
    alive: list = []

    def trace(points, *args, **kwargs):
        gc.collect()
        assert [r() for r in alive] == [None] * len(alive)
        traced = traced_before(points, *args, **kwargs)
        alive.extend([weakref.ref(points), weakref.ref(traced.sh)])
        return traced

    monkeypatch.setattr(tracer, "bake", trace)
    for groups in (False, True):
        atlas, scene_, _ = floor_and_box(groups)
        atlases = [atlas, bake.AtlasInput("Small", RES // 2, RES // 2, atlas.surface, ["floor"])]
        alive.clear()
        bake.run(atlases, scene_, bake.PipelineSettings(trace=PASSES), tmp_path / str(groups))
        gc.collect()
        assert len(alive) == 4 and [r() for r in alive] == [None] * 4
