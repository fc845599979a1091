"""The bake on a Dask cluster from Blender: `bake --scheduler tcp://127.0.0.1:PORT` with a
`dask scheduler` and two `dask worker` processes (127.0.0.1 only) writes the files of the same bake
without `--scheduler`; the refusals and failures exit with a message; and the extension as
Blender installs it (`bl_ext.user_default.hhd_lightmapper`) drives workers that know the package
only as `hhd_lightmapper`, post stages (denoised) and encoding included. Denoising is off in the
CLI bakes (its tests are tests/test_denoise_blender.py)."""

import importlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper import cli
from scenekit import blender as kit

pytestmark = [pytest.mark.bpy, pytest.mark.farm]
distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """`dask scheduler` and two `dask worker` processes on 127.0.0.1, as a studio starts them;
    yields the scheduler's address."""
    folder = tmp_path_factory.mktemp("dask")
    info = folder / "scheduler.json"
    common = ["--no-dashboard", "--host", "127.0.0.1"]
    log = open(folder / "dask.log", "w")
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--port", "0", "--scheduler-file", str(info), *common],
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    ]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--nworkers", "1", *common],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                )
            )
        with distributed.Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for p in reversed(procs):  # only the processes this fixture started, by their own group
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        log.close()


@pytest.fixture
def blend(extension, restore_hhd_settings, tmp_path):
    """A floor and a cube under a sun (light group "Sun") and a sky, unwrapped at 256², 4 samples,
    1 bounce, Denoise off, saved as tmp_path/scene.blend."""
    import bpy

    scene = kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4, kit.material("grey"))
    cube = kit.box("Cube", (0.5, 0.3, 0.5), (1.0, 1.0, 1.0), kit.material("red", (0.8, 0.2, 0.1)))
    sun = kit.light('SUN', rotation=(0.6, 0.2, 0.4), energy=3.0)
    sun.lightgroup = "Sun"
    kit.world((0.2, 0.3, 0.5))
    s = scene.hhd
    s.resolution = 256
    kit.unwrap([floor, cube])
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.seed, s.denoise, s.pack_images = 4, 1, 0, False, False
    kit.select([floor, cube])
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def exr_bytes(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*.exr"))}


def without_run_details(doc: dict) -> dict:
    """A sidecar without what differs between two runs of one bake: timings (as test_threads) and
    the times the fingerprints and receivers record."""
    doc = json.loads(json.dumps(doc))
    doc.pop("timings_seconds")
    doc.pop("baked", None)  # when each receiver was baked (core.incremental)
    doc.get("fingerprints", {}).pop("time", None)
    records = list(doc["post"].values())
    while records:
        record = records.pop()
        record.pop("seconds", None)
        records += [v for v in record.values() if isinstance(v, dict)]
    return doc


@pytest.mark.slow
def test_bake_with_scheduler_writes_the_files_of_the_local_bake(dask_cluster, blend, cli_run, tmp_path):
    args = ("--objects", "Floor", "Cube", "--threads", "2")
    run_cli = cli_run
    local = run_cli(blend, "bake", "--out", str(tmp_path / "local"), *args)
    assert local.returncode == cli.EXIT_OK, local.stderr
    remote = run_cli(blend, "bake", "--out", str(tmp_path / "farm"), "--scheduler", dask_cluster, *args)
    assert remote.returncode == cli.EXIT_OK, remote.stderr
    assert f"farm: 2 worker(s) at {dask_cluster}" in remote.stdout
    files = exr_bytes(tmp_path / "local")
    assert len(files) > 15 and any(".Sun_" in name for name in files)  # the light set's files too
    assert exr_bytes(tmp_path / "farm") == files
    docs = [json.loads((tmp_path / k / "Lightmap.json").read_text()) for k in ("local", "farm")]
    assert without_run_details(docs[0]) | {"blend_file": ""} == without_run_details(docs[1]) | {"blend_file": ""}
    assert not (tmp_path / "farm" / ".hhd_farm").exists()


def test_scheduler_refuses_a_time_budget_and_names_an_unreachable_scheduler(blend, cli_run, tmp_path):
    """Refused at once: nothing listens on port 9, so the connection is refused (no retrying
    until Dask's timeout)."""
    args = ("bake", "--out", str(tmp_path / "out"), "--objects", "Floor", "Cube")
    run_cli = cli_run
    budget = run_cli(blend, *args, "--scheduler", "tcp://127.0.0.1:9", "--time-budget", "10")
    assert budget.returncode == cli.EXIT_INPUT
    assert "time budget cannot be used with --scheduler" in budget.stderr
    nobody = run_cli(blend, *args, "--scheduler", "tcp://127.0.0.1:9")
    assert nobody.returncode == cli.EXIT_INPUT
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in nobody.stderr
    assert not (tmp_path / "out").exists() or not exr_bytes(tmp_path / "out")


def test_the_installed_extension_drives_workers_that_know_only_hhd_lightmapper(extension, dask_cluster, tmp_path):
    """Inside Blender the package is `bl_ext.user_default.hhd_lightmapper`; the workers import
    `hhd_lightmapper`: the estimator and the task travel under the workers' names."""
    names = importlib.import_module(extension + ".core.farm.names")
    assert names.PACKAGE == extension and names.PACKAGE != names.WORKER_PACKAGE
    ext = importlib.import_module(extension + ".core.farm")
    bake = importlib.import_module(extension + ".core.bake")
    tracer = importlib.import_module(extension + ".core.tracer")
    scene_mod = importlib.import_module(extension + ".core.scene")
    bakepoints = importlib.import_module(extension + ".core.bakepoints")
    from scenekit import meshes

    v, f = meshes.plane(2.0)
    box_v, box_f = meshes.cube(0.6, centre=(1.0, 1.0, 0.3))
    floor = v[f]
    tris = np.concatenate([floor, box_v[box_f]])
    surface = bakepoints.SurfaceTriangles(
        floor, np.tile([0, 0, 1.0], (2, 3, 1)), floor[..., :2] / 2.0, np.zeros(2, int), np.full((2, 3), 0.5)
    )
    scene = scene_mod.BakeScene(
        tris,
        np.full((len(tris), 3), 0.6),
        lights=[scene_mod.SunLight(np.array([0.6, 0.2, 0.77]), np.array([3.0, 2.5, 2.0]), group="Sun")],
        world=np.array([0.1, 0.2, 0.3]),
    )
    library = importlib.import_module(extension + ".bridge.denoiser").oidn_library()  # Blender's, as a bake finds it
    assert library
    settings = bake.PipelineSettings(
        trace=tracer.BakeSettings(samples=8, pass_samples=4, bounces=1, seed=1, chunk_texels=4096, threads=2),
        denoise=True,
        denoiser_library=library,
    )
    atlas = bake.AtlasInput("Lightmap", 96, 96, surface, ["floor"])
    [local] = bake.run([atlas], scene, settings, tmp_path / "local")
    assert local.warnings == []  # denoised
    with ext.connect(dask_cluster, chunks_per_task=1) as farm:
        [remote] = bake.run([atlas], scene, settings, tmp_path / "farm", farm=farm)
        assert len(farm.tasks) == 3 and len(farm._points) == 1  # bake points and tracing on the workers
        # the post stages (denoised: the `dask worker`s find the same bpy module's OIDN) and the encoding too,
        # their images come back as plain data to the client's `bl_ext…` classes
        assert [r["finished_on"] for r in farm.finishing] == ["worker"]
        assert farm.finishing[0]["worker"] != f"{os.uname().nodename}:{os.getpid()}"
    assert remote.warnings == [] and set(remote.seconds) > {"post", "write"}
    assert exr_bytes(tmp_path / "farm") == exr_bytes(tmp_path / "local")
