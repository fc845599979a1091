"""Thread counts (no Blender): all cores by default, 0 = all, negative refused, Blender's
Threads setting mapped, and the files of a bake byte-identical whatever the thread count (the
sidecar differs only in the count it records and the timings)."""

import json
import os

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, encoding, parallel, tracer
from hhd_lightmapper.core.errors import BakeError
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.scene import BakeScene, PointLight, SunLight
from scenekit import meshes

RESOLUTION = 192
#: More workers than this machine has cores, so chunks finish out of order.
MANY = max(5, parallel.machine_threads() + 3)


def test_machine_threads_is_what_this_process_may_use_and_zero_means_all():
    expected = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert parallel.machine_threads() == expected >= 1
    assert parallel.resolve_threads(0) == parallel.machine_threads()
    assert parallel.resolve_threads(1) == 1 and parallel.resolve_threads(MANY) == MANY
    for bad in (-1, 1.5, True, "2"):
        with pytest.raises(BakeError, match="thread count"):
            parallel.resolve_threads(bad)
    assert tracer.BakeSettings().threads == 0


def test_blender_threads_setting_maps_auto_to_all_and_fixed_to_its_value():
    assert parallel.blender_threads("AUTO", 7) == 0  # Blender reports its own count in AUTO
    assert parallel.blender_threads("FIXED", 3) == 3
    assert parallel.blender_threads("FIXED", 0) == 1
    with pytest.raises(BakeError, match="threads mode"):
        parallel.blender_threads("SOMETIMES", 2)


def floor_and_box():
    """A 2 m floor (the receiver, UVs = its xy) under a box standing on it: shadows, bounces and
    buried texels under the box; a sun, a point light and a sky."""
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
            SunLight(np.array([0.6, 0.2, 0.77]), np.array([3.0, 2.5, 2.0])),
            PointLight(np.array([0.3, 1.6, 0.8]), np.array([40.0, 30.0, 20.0]), radius=0.1),
        ],
        world=np.array([0.1, 0.2, 0.3]),
    )
    return bake.AtlasInput("Lightmap", RESOLUTION, RESOLUTION, surface, ["floor"]), scene


def bake_with(folder, threads):
    atlas, scene = floor_and_box()
    trace = tracer.BakeSettings(samples=8, pass_samples=4, bounces=2, seed=3, chunk_texels=1024, threads=threads)
    bake.run([atlas], scene, bake.PipelineSettings(trace=trace), folder)
    return lightmap_files.AtlasFiles(folder, "Lightmap")


def file_bytes(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def without_run_details(doc):
    doc = json.loads(json.dumps(doc))
    doc["bake"].pop("threads")
    doc.pop("timings_seconds")
    doc.pop("baked", None)  # when each receiver was baked, to the second (core.incremental)
    doc.get("fingerprints", {}).pop("time", None)
    records = list(doc["post"].values())
    while records:  # a post stage's own timings (and its parts')
        record = records.pop()
        record.pop("seconds", None)
        records += [v for v in record.values() if isinstance(v, dict)]
    return doc


@pytest.mark.slow
def test_one_thread_and_many_write_byte_identical_files(tmp_path):
    one = bake_with(tmp_path / "one", 1)
    many = bake_with(tmp_path / "many", MANY)
    default = bake_with(tmp_path / "default", 0)
    exrs = {k: v for k, v in file_bytes(one.folder).items() if k.endswith(".exr")}
    assert len(exrs) == 3 + 3  # hhd, sh, texels + the HHD file's previews (the SH's: on demand)
    for other in (many, default):
        assert {k: v for k, v in file_bytes(other.folder).items() if k.endswith(".exr")} == exrs
    docs = [lightmap_files.read_sidecar(f.sidecar) for f in (one, many, default)]
    assert [d["bake"]["threads"] for d in docs] == [1, MANY, parallel.machine_threads()]
    assert docs[0]["stats"]["texels_buried"] > 0  # the box's footprint
    assert without_run_details(docs[0]) == without_run_details(docs[1]) == without_run_details(docs[2])


def test_reencode_is_byte_identical_whatever_the_thread_count_and_records_it(tmp_path):
    files = bake_with(tmp_path, 2)
    encoder = encoding.EncoderSettings(model="ahd", ambient="rgb")
    bake.reencode(files, encoder, threads=1)
    encoded_one = files.hhd.read_bytes()
    assert lightmap_files.read_sidecar(files.sidecar)["reencode_threads"] == 1
    bake.reencode(files, encoder, threads=MANY)
    assert files.hhd.read_bytes() == encoded_one
    doc = lightmap_files.read_sidecar(files.sidecar)
    assert doc["reencode_threads"] == MANY and doc["bake"]["threads"] == 2  # the bake's own count stays


def test_exr_compression_threads_do_not_change_the_bytes(tmp_path):
    import OpenEXR

    rng = np.random.default_rng(4)
    channels = {"A.V": rng.random((300, 200)).astype(np.float32), "B.V": rng.random((300, 200)).astype(np.float16)}
    written = []
    for k, threads in enumerate((1, MANY)):
        exr.set_threads(threads)
        assert OpenEXR.global_thread_count() == (0 if threads == 1 else threads)
        exr.write(tmp_path / f"{k}.exr", channels)
        written.append((tmp_path / f"{k}.exr").read_bytes())
    assert written[0] == written[1]


def test_the_tracer_reports_the_threads_it_used():
    atlas, scene = floor_and_box()
    points = bakepoints.build(atlas.surface, 32, 32)
    for threads, used in ((0, parallel.machine_threads()), (3, 3)):
        result = tracer.bake(points, scene, tracer.BakeSettings(samples=4, pass_samples=4, bounces=0, threads=threads))
        assert result.threads == used
    with pytest.raises(BakeError, match="thread count"):
        tracer.bake(points, scene, tracer.BakeSettings(samples=4, pass_samples=4, threads=-2))
