"""The bake on a Dask cluster (core/farm.py), on this machine only (127.0.0.1): the same bytes as
the local bake with 1 and 2 worker processes, with light sets and with a noise target; the post
stages and encoding of each atlas run on a worker (a finishing task), denoised there when the
worker has the client's OIDN, on the client otherwise; a worker killed mid-bake (tracing or
finishing) costs a retry; a cancelled client cancels the farm's tasks and the same command
resumes from its checkpoints; what a farm refuses, and the messages it gives."""

import json
import os
import platform
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, farm, tracer
from hhd_lightmapper.core.errors import BakeCancelled, BakeError, DependencyMissing
from hhd_lightmapper.core.post.denoise import oidn
from hhd_lightmapper.core.scene import BakeScene, PointLight, SunLight
from scenekit import meshes
from test_oidn import bpy_library_dirs

pytestmark = pytest.mark.farm  # Dask clusters of local processes

distributed = pytest.importorskip("distributed")

SIZE = 128
TRACE = tracer.BakeSettings(samples=8, pass_samples=4, bounces=1, seed=5, chunk_texels=2048, threads=2)


def floor_and_box():
    """A 2 m floor (the receiver) under a box: shadows, bounces, buried texels; a sun and a lamp
    in two light groups and a sky in none, so the bake has three light sets."""
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
            SunLight(np.array([0.6, 0.2, 0.77]), np.array([3.0, 2.5, 2.0]), group="Sun"),
            PointLight(np.array([0.3, 1.6, 0.8]), np.array([40.0, 30.0, 20.0]), radius=0.1, group="Lamp"),
        ],
        world=np.array([0.1, 0.2, 0.3]),
    )
    return bake.AtlasInput("Lightmap", SIZE, SIZE, surface, ["floor"]), scene


def two_atlases():
    """The floor in a 128² atlas and again in a 64² one ("Small"): 8 + 2 chunks of 2048 texels."""
    atlas, scene = floor_and_box()
    small = bake.AtlasInput("Small", SIZE // 2, SIZE // 2, atlas.surface, ["floor"])
    return [atlas, small], scene


def cluster(workers: int):
    """A LocalCluster of `workers` worker processes of one thread each, on 127.0.0.1."""
    return distributed.LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=":0"
    )


def exr_bytes(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*.exr"))}


def sidecars(folder: Path) -> dict:
    """Every JSON sidecar of `folder` without what differs between two runs: timings."""
    docs = {}
    for path in sorted(folder.glob("*.json")):
        doc = json.loads(path.read_text())
        doc.pop("timings_seconds", None)
        records = list(doc["post"].values())
        while records:  # a post stage's own timings (and its parts')
            record = records.pop()
            record.pop("seconds", None)
            records += [v for v in record.values() if isinstance(v, dict)]
        docs[path.name] = doc
    return docs


def seams_arrays(folder: Path) -> dict:
    """Every seams file of `folder` as {file: {array name: bytes}} (the zip's own dates differ)."""
    out = {}
    for path in sorted(folder.glob("*_seams.npz")):
        with np.load(path) as f:
            out[path.name] = {k: f[k].tobytes() for k in f.files}
    return out


def same_files(folder: Path, local: Path) -> None:
    """`folder` holds the files of the local bake in `local`: EXRs byte for byte, seams, and
    sidecars but for their timings."""
    assert exr_bytes(folder) == exr_bytes(local)
    assert sidecars(folder) == sidecars(local)
    assert seams_arrays(folder) == seams_arrays(local) != {}


def finished_on_workers(f: farm.Farm, atlases: int, pids: dict) -> None:
    """Every atlas's finishing task ran in one of the worker processes `pids` ({worker: pid},
    `client.run(os.getpid)`), not in this one."""
    workers = {f"{platform.node()}:{pid}" for pid in pids.values()}
    assert len(f.finishing) == atlases
    for record in f.finishing:
        assert record["finished_on"] == "worker" and record["seconds"] > 0
        assert record["worker"] in workers and record["worker"] != f"{platform.node()}:{os.getpid()}"


@pytest.fixture(scope="module")
def local_files(local_folder):
    files = exr_bytes(local_folder)
    assert any(name.startswith("Lightmap.Lamp_") for name in files)  # the light sets' files too
    assert any(name.startswith("Small_") for name in files)
    return files


@pytest.fixture(scope="module")
def local_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("local")
    atlases, scene = two_atlases()
    bake.run(atlases, scene, bake.PipelineSettings(trace=TRACE), folder)
    return folder


@pytest.fixture(scope="module")
def library() -> str:
    """Blender's OIDN library (of the bpy module), as the client finds it."""
    path = oidn.find_library(bpy_library_dirs())
    if path is None:
        pytest.skip("no Open Image Denoise library in the bpy module")
    return str(path)


#: Denoised, with a noise target (two task stages per group) and three light sets.
NOISY = tracer.BakeSettings(
    samples=24, pass_samples=4, bounces=1, seed=3, chunk_texels=4096, noise_target=0.1, threads=2
)


@pytest.fixture(scope="module")
def local_denoised(tmp_path_factory, library):
    folder = tmp_path_factory.mktemp("denoised")
    atlases, scene = two_atlases()
    [result, _] = bake.run(
        atlases, scene, bake.PipelineSettings(trace=NOISY, denoise=True, denoiser_library=library), folder
    )
    assert result.warnings == []  # denoised
    doc = json.loads((folder / "Lightmap.json").read_text())
    assert doc["post"]["denoise"]["applied"] and doc["bake"]["stopped_by"] in ("noise_target", "samples")
    assert doc["bake"]["mean_samples_per_texel"] < NOISY.samples  # texels did stop early
    return folder


@pytest.fixture(scope="module")
def two_workers():
    with cluster(2) as c:
        yield c


@pytest.mark.parametrize("workers", [1, 2])
def test_a_farm_bake_writes_the_bytes_of_the_local_bake(workers, local_files, local_folder, two_workers, tmp_path):
    atlases, scene = two_atlases()
    context = cluster(1) if workers == 1 else None
    address = context.scheduler_address if context else two_workers.scheduler_address
    try:
        with farm.connect(address, chunks_per_task=2) as f:
            assert f.workers() == workers and f.warnings == []
            bake.run(atlases, scene, bake.PipelineSettings(trace=TRACE), tmp_path, farm=f)
            assert len(f.tasks) == 4 + 1  # 8 + 2 fixed chunks of 2048 texels, 2 per task
            assert f._submitted == {}  # the tasks bake.run submitted up front were the ones collected
            assert len(f._points) == 2  # the bake points came from the workers too
            assert len({t["worker"] for t in f.tasks}) <= workers
            finished_on_workers(f, 2, f.client.run(os.getpid))  # post stages and encoding too
            assert f._finishing == []
    finally:
        if context:
            context.close()
    assert exr_bytes(tmp_path) == local_files
    same_files(tmp_path, local_folder)
    assert not (tmp_path / farm.client.CHECKPOINTS).exists()  # gone once the files are committed


def test_denoised_with_a_noise_target_on_workers_with_the_clients_oidn(local_denoised, library, two_workers, tmp_path):
    atlases, scene = two_atlases()
    settings = bake.PipelineSettings(trace=NOISY, denoise=True, denoiser_library=library)
    with farm.connect(two_workers.scheduler_address, chunks_per_task=2) as f:
        results = bake.run(atlases, scene, settings, tmp_path, farm=f)
        assert len(f.tasks) == 2 * (2 + 1)  # 4 + 1 chunks of 4096 texels, 2 per task, in two stages
        finished_on_workers(f, 2, f.client.run(os.getpid))  # the workers found the same OIDN (the bpy module's)
        assert f._oidn == {farm.finishing.denoiser_identity(library): sorted(f.client.scheduler_info()["workers"])}
    assert [r.warnings for r in results] == [[], []]
    same_files(tmp_path, local_denoised)


def test_workers_without_the_clients_oidn_leave_the_denoising_to_the_client(
    local_denoised, library, tmp_path, monkeypatch
):
    atlases, scene = two_atlases()
    settings = bake.PipelineSettings(trace=NOISY, denoise=True, denoiser_library=library)
    monkeypatch.setenv(farm.finishing.OIDN_ENV, str(tmp_path / "no-oidn-here"))  # the workers' environment
    messages = []
    with cluster(1) as c, farm.connect(c.scheduler_address, chunks_per_task=2) as f:
        assert f.client.run(farm.finishing.local_denoiser) == {
            w: ("", None) for w in f.client.scheduler_info()["workers"]
        }
        bake.run(atlases, scene, settings, tmp_path / "out", progress=lambda _, m: messages.append(m), farm=f)
        assert [r["finished_on"] for r in f.finishing] == ["client", "client"]
    assert any("here (no farm worker has this OIDN)" in m for m in messages)
    same_files(tmp_path / "out", local_denoised)


def test_with_a_noise_target_the_farm_traces_what_the_local_bake_traces(two_workers, tmp_path):
    atlas, scene = floor_and_box()
    settings = tracer.BakeSettings(
        samples=32, pass_samples=4, bounces=1, seed=2, chunk_texels=4096, noise_target=0.05, threads=2
    )
    ray_scene = bake.ray_scene_of(scene)
    points = bake.points_of(atlas, ray_scene)
    local = tracer.bake(points, scene, settings, ray_scene=ray_scene)
    assert local.texel_samples.min() < local.texel_samples.max()  # texels did stop early
    with farm.connect(two_workers.scheduler_address, chunks_per_task=1) as f:
        remote = tracer.bake(points, scene, settings, ray_scene=ray_scene, runner=f.runner("a", tmp_path))
        assert len(f.tasks) == 2 * 4  # first MIN_ADAPTIVE_PASSES passes, then the rest
    np.testing.assert_array_equal(remote.texel_samples, local.texel_samples)
    np.testing.assert_array_equal(remote.sh, local.sh)
    np.testing.assert_array_equal(remote.sh_error, local.sh_error)
    np.testing.assert_array_equal(remote.set_sh, local.set_sh)
    assert (remote.rays, remote.stopped_by, remote.sets) == (local.rays, local.stopped_by, local.sets)


def test_the_denoiser_identity_is_of_the_library_files_beside_it_too(library, tmp_path):
    identity = farm.finishing.denoiser_identity(library)
    assert identity is not None and farm.finishing.local_denoiser() == (library, identity)  # a worker of this Python
    alone = tmp_path / Path(library).name  # the same loader without its core and CPU-device libraries
    alone.write_bytes(Path(library).read_bytes())
    assert farm.finishing.denoiser_identity(str(alone)) not in (None, identity)
    assert farm.finishing.denoiser_identity(str(tmp_path / "missing.so")) is None
    assert farm.finishing.denoiser_identity("") is None


def test_a_worker_killed_mid_bake_costs_only_a_retry(local_files, tmp_path):
    atlases, scene = two_atlases()
    killed = []
    with cluster(2) as c, farm.connect(c.scheduler_address, chunks_per_task=1) as f:
        pids = f.client.run(os.getpid)

        def progress(fraction, message):
            if killed or "farm:" not in message:  # once, while tracing
                return
            busy = [w for w, tasks in f.client.processing().items() if tasks]
            if busy:  # SIGKILL: no goodbye to the scheduler, its running task is lost
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])

        bake.run(atlases, scene, bake.PipelineSettings(trace=TRACE), tmp_path, progress=progress, farm=f)
    assert killed
    assert exr_bytes(tmp_path) == local_files


def test_a_worker_killed_while_finishing_an_atlas_costs_only_a_retry(local_denoised, library, tmp_path):
    atlases, scene = two_atlases()
    settings = bake.PipelineSettings(trace=NOISY, denoise=True, denoiser_library=library)
    killed = []
    with cluster(2) as c, farm.connect(c.scheduler_address, chunks_per_task=2) as f:
        pids = f.client.run(os.getpid)

        def progress(fraction, message):
            if killed or "on the farm" not in message:  # once, while the client waits for a finishing task
                return
            while any(not h.done() for h in f._finishing):
                finishing = [w for w, keys in f.client.processing().items() if any("hhd-finish" in k for k in keys)]
                if finishing:  # SIGKILL mid-task: Dask runs it again, on the other worker
                    os.kill(pids[finishing[0]], signal.SIGKILL)
                    killed.append(finishing[0])
                    return
                time.sleep(0.01)

        bake.run(atlases, scene, settings, tmp_path, progress=progress, farm=f)
        assert killed
        [survivor] = [pid for w, pid in pids.items() if w not in killed]
        assert f"{platform.node()}:{survivor}" in [r["worker"] for r in f.finishing]
    same_files(tmp_path, local_denoised)


def test_cancel_stops_the_farm_and_the_same_bake_resumes_from_its_checkpoints(local_files, two_workers, tmp_path):
    atlases, scene = two_atlases()
    settings = bake.PipelineSettings(trace=TRACE)
    with farm.connect(two_workers.scheduler_address, chunks_per_task=1) as f:
        tasks_done = []

        def progress(fraction, message):
            if "farm:" in message:
                tasks_done.append(fraction)

        with pytest.raises(BakeCancelled):
            bake.run(atlases, scene, settings, tmp_path, progress=progress, cancel=lambda: len(tasks_done) >= 2, farm=f)
        saved = sorted((tmp_path / farm.client.CHECKPOINTS).rglob("task-*.npz"))
        assert 2 <= len(saved) < 10
        assert not exr_bytes(tmp_path)  # nothing written
        # no task of the cancelled bake is left on the farm
        deadline = time.monotonic() + 10
        while f.client.run_on_scheduler(_task_count) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert f.client.run_on_scheduler(_task_count) == 0
    with farm.connect(two_workers.scheduler_address, chunks_per_task=1) as f:  # a restarted client
        bake.run(atlases, scene, settings, tmp_path, farm=f)
        assert len(f.tasks) == 10 - len(saved)  # only what was not checkpointed ran
    assert exr_bytes(tmp_path) == local_files
    assert not (tmp_path / farm.client.CHECKPOINTS).exists()


def test_cancel_while_an_atlas_finishes_on_the_farm(two_workers, tmp_path):
    atlases, scene = two_atlases()
    with farm.connect(two_workers.scheduler_address, chunks_per_task=2) as f:
        waiting = []

        def progress(fraction, message):
            if "on the farm" in message:  # the client waits for a finishing task
                waiting.append(message)

        with pytest.raises(BakeCancelled):
            bake.run(
                atlases,
                scene,
                bake.PipelineSettings(trace=TRACE),
                tmp_path,
                progress=progress,
                cancel=lambda: bool(waiting),
                farm=f,
            )
        assert waiting and f.finishing == [] and f._finishing == []  # no atlas was finished nor written
        assert not exr_bytes(tmp_path)
        deadline = time.monotonic() + 10
        while f.client.run_on_scheduler(_task_count) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert f.client.run_on_scheduler(_task_count) == 0  # no finishing (nor tracing) task left
    assert len(list((tmp_path / farm.client.CHECKPOINTS).rglob("task-*.npz"))) == 5  # kept for the next run


def _task_count(dask_scheduler):
    return len(dask_scheduler.tasks)


def test_other_settings_or_inputs_do_not_reuse_checkpoints(two_workers, tmp_path):
    atlas, scene = floor_and_box()
    with farm.connect(two_workers.scheduler_address, chunks_per_task=4) as f:
        ray_scene = bake.ray_scene_of(scene)
        points = bake.points_of(atlas, ray_scene)
        for seed in (1, 2):
            run = f.runner("a", tmp_path)
            settings = tracer.BakeSettings(samples=4, pass_samples=4, bounces=0, seed=seed, chunk_texels=8192)
            tracer.bake(points, scene, settings, ray_scene=ray_scene, runner=run)
        assert len(list((tmp_path / farm.client.CHECKPOINTS).iterdir())) == 2  # one folder per key
        assert len(f.tasks) == 2  # 16384 texels: 2 chunks, one task
        f.finished()
    assert not (tmp_path / farm.client.CHECKPOINTS).exists()


def test_a_time_budget_is_refused_on_a_farm():
    with pytest.raises(BakeError, match="time budget cannot be used with --scheduler"):
        farm.Farm.check(tracer.BakeSettings(time_budget=60.0))
    farm.Farm.check(tracer.BakeSettings(noise_target=0.05))  # a noise target is fine


def test_workers_of_other_code_or_packages_are_refused_with_what_differs():
    mine = farm.worker.environment()
    assert set(mine) >= {"code", "python", "numpy", "numba", "embreex", "cpu"}
    assert farm.client.check_workers({"tcp://a": mine, "tcp://b": dict(mine)}) == []
    with pytest.raises(BakeError, match=r"tcp://b: code 0+ \(here "):
        farm.client.check_workers({"tcp://a": mine, "tcp://b": {**mine, "code": "000"}})
    with pytest.raises(BakeError, match=r"numba 0\.1 \(here"):
        farm.client.check_workers({"tcp://a": {**mine, "numba": "0.1"}})
    with pytest.raises(BakeError, match=r"pip install \"hhd_lightmapper\[farm\]\""):
        farm.client.check_workers({"tcp://a": ModuleNotFoundError("No module named 'hhd_lightmapper'")})
    [warning] = farm.client.check_workers({"tcp://a": mine, "tcp://b": {**mine, "cpu": "other"}})
    assert "2 CPU kinds" in warning and "NUMBA_CPU_NAME" in warning and "HHD_EMBREE_CONFIG" in warning


def test_a_worker_refuses_a_task_of_other_code():
    with pytest.raises(BakeError, match="other tracer code"):
        farm.worker.trace_group(b"", "", {}, "not this code", [(0, 0, 1)])


def test_without_dask_the_message_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(DependencyMissing, match=r"pip install \"dask\[distributed\]\""):
        farm.connect("tcp://127.0.0.1:1")


def test_an_unreachable_scheduler_is_named():
    with pytest.raises(BakeError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        farm.connect("tcp://127.0.0.1:9", timeout=2)


def test_a_local_bake_never_imports_dask():
    import subprocess

    script = (
        "import sys\n"
        "from hhd_lightmapper.core import bake, tracer\n"
        "assert 'distributed' not in sys.modules and 'dask' not in sys.modules\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_what_a_worker_returns_names_no_module_of_the_package():
    """A client inside Blender names the package `bl_ext.<repo>.hhd_lightmapper`, a worker
    `hhd_lightmapper`: the plain data a finishing task returns (its encoded file specs hold the
    package's functions, e.g. the direction's octahedral `pack`) must pickle without the
    package's module names, and come back as this process's objects."""
    import pickle

    from hhd_lightmapper.core import octahedral
    from hhd_lightmapper.core.encoding import hhd as hhd_encoding

    spec = hhd_encoding.FILE
    sent = pickle.dumps(farm.names.plain({"file": spec, "channels": [spec.channels]}))
    assert b"hhd_lightmapper" not in sent
    back = farm.names.unplain(pickle.loads(sent))
    assert back["file"] == spec
    assert back["file"].channels[-1].pack is octahedral.encode


def test_a_finishing_task_keeps_copies_of_the_raw_files_and_gives_the_traced_sh_back():
    """A worker's `_Kept` stands in for `bake.Staged`: the raw files it is handed before the post
    stages are views of the SH the denoiser then writes into, so it keeps copies, and a denoiser
    failing half-way reads the traced SH back from them (`traced_sh`, as `Staged` reads the file)."""
    from hhd_lightmapper.core import encoding

    rng = np.random.default_rng(5)
    coverage = np.zeros((12, 10), np.float32)
    coverage[2:9, 1:7] = 1.0
    sh = np.zeros((12, 10, 9, 3), np.float32)
    sh[2:9, 1:7] = rng.normal(size=(7, 6, 9, 3))
    data = encoding.TexelData(sh=sh, normal=np.zeros((12, 10, 3), np.float32), coverage=coverage)
    traced = data.sh.copy()
    kept = farm.finishing._Kept()
    with encoding.raw_files(data, data.fill()) as images_of:
        kept.raw("Lightmap", "", images_of)
    data.sh[...] = 7.0  # a post stage writing in place
    ((method, (name, parent, plain_files)),) = kept.calls
    assert (method, name, parent) == ("raw", "Lightmap", "")
    back = kept.traced_sh("Lightmap", "")
    assert back.shape == traced.shape
    baked = coverage > 0
    np.testing.assert_array_equal(back[baked], traced[baked])
    assert (back[~baked] != 7.0).all()  # the kept images are the files' (dilated), not views
    with pytest.raises(KeyError):
        kept.traced_sh("Other", "")
