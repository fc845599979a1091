"""Progress and cancel of the unwrap: the core reports monotonic progress and stops its xatlas
children on cancel (nothing cached), the operator prints a progress line headless and a
cancelled unwrap leaves the UV layers as they were, and the command line's Ctrl-C exits with
EXIT_CANCELLED leaving the .blend unchanged."""

import importlib
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import EXTENSION_MODULE
from hhd_lightmapper import cli
from hhd_lightmapper.core import unwrap
from hhd_lightmapper.core.errors import BakeCancelled
from hhd_lightmapper.core.unwrap import worker_runs
from scenekit import meshes


@pytest.fixture(autouse=True)
def fresh_cache():
    unwrap.clear_chart_cache()
    yield
    unwrap.clear_chart_cache()


@pytest.fixture
def child_pids(monkeypatch):
    """Pids of the xatlas children started during the test."""
    pids, real = [], subprocess.Popen

    def popen(*args, **kw):
        proc = real(*args, **kw)
        pids.append(proc.pid)
        return proc

    monkeypatch.setattr(worker_runs.subprocess, "Popen", popen)
    return pids


def sphere_mesh(name="Sphere", rings=128, segments=256):
    v, f = meshes.uv_sphere(rings, segments)
    return unwrap.UnwrapMesh(name, v, f)


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def running(pid: int) -> bool:
    """Whether our child `pid` has not exited yet (its exit status is left to be reaped)."""
    try:
        return os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is None
    except ChildProcessError:  # exited and already reaped
        return False


def test_progress_is_monotonic_and_ends_at_one():
    calls = []
    unwrap.unwrap(
        [sphere_mesh(rings=24, segments=48), unwrap.UnwrapMesh("Cube", *meshes.cube())],
        unwrap.UnwrapSettings(resolution=256),
        lambda f, msg: calls.append((f, msg)),
    )
    fractions = [f for f, _ in calls]
    assert len(calls) >= 3 and fractions == sorted(fractions) and fractions[-1] == 1.0
    assert all(0.0 <= f <= 1.0 for f in fractions) and all(isinstance(m, str) and m for _, m in calls)


@pytest.mark.parametrize("one_child", [True, False], ids=["fit-in-one-child", "rounds-driven-here"])
def test_progress_goes_on_while_xatlas_charts_a_part_and_packs_a_round(monkeypatch, one_child):
    """xatlas says nothing while it charts a part or packs a round (seconds each on a level):
    while a child works, the calling thread reports every HEARTBEAT seconds, with the seconds
    waited, never going back, from no other thread."""
    import threading

    monkeypatch.setattr(worker_runs, "HEARTBEAT", 0.05)
    if not one_child:  # the rounds of two densities packed side by side, driven from here
        monkeypatch.setattr(unwrap.packing, "ONE_CHILD_TRIANGLES", 0)
        monkeypatch.setattr(unwrap.packing, "_cores", lambda: 2)
    calls, caller = [], threading.get_ident()
    unwrap.unwrap(
        [sphere_mesh(rings=48, segments=96)],  # 9k triangles: about a second of charting
        unwrap.UnwrapSettings(resolution=1024),
        lambda f, msg: calls.append((f, msg, threading.get_ident())),
    )
    fractions = [f for f, _, _ in calls]
    assert fractions == sorted(fractions) and {t for *_, t in calls} == {caller}
    waited = [re.fullmatch(r"xatlas: (charting|packing).*, (\d+) s", m) for _, m, _ in calls]
    charting = [int(w[2]) for w in waited if w and w[1] == "charting"]
    packing = [int(w[2]) for w in waited if w and w[1] == "packing"]
    assert len(charting) >= 3 and len(packing) >= 2, [m for _, m, _ in calls]
    assert charting == sorted(charting)  # one wait; the packing's restart each round
    if not one_child:  # each round's wait says which density it packs
        assert all("texels/m" in m for _, m, _ in calls if re.match(r"xatlas: packing.*, \d+ s$", m))


def test_cancel_while_charting_kills_the_child_and_caches_nothing(child_pids):
    mesh = sphere_mesh(rings=48, segments=96)  # 9k triangles: about a second of charting
    at_cancel = []  # the children started when the cancel came, each still running or not

    def cancel():  # the first poll after the charting child started (CANCEL_POLL in)
        if not child_pids:
            return False
        at_cancel.append([running(pid) for pid in child_pids])
        return True

    start = time.perf_counter()
    with pytest.raises(BakeCancelled):
        unwrap.unwrap([mesh], unwrap.UnwrapSettings(resolution=1024), cancel=cancel)
    assert at_cancel == [[True]]  # one child, the charting one, and it was running: cancelled while charting
    assert time.perf_counter() - start < 5.0
    assert child_pids and all(gone(pid) for pid in child_pids)
    assert unwrap.chart_key(mesh) not in unwrap._CACHE and not unwrap._PACKED
    # the same mesh unwraps completely afterwards
    result = unwrap.unwrap([mesh], unwrap.UnwrapSettings(resolution=1024))
    assert result.objects[0].uv.shape == (len(mesh.triangles), 3, 2)


def test_cancel_while_packing_keeps_the_charts_but_no_atlas(child_pids):
    mesh = sphere_mesh(rings=48, segments=96)
    packing = []
    with pytest.raises(BakeCancelled):
        unwrap.unwrap(
            [mesh],
            unwrap.UnwrapSettings(resolution=1024),
            lambda f, m: packing.append(1) if f >= 0.8 else None,
            cancel=lambda: bool(packing),
        )
    assert all(gone(pid) for pid in child_pids)
    assert unwrap.chart_key(mesh) in unwrap._CACHE and not unwrap._PACKED


def test_a_cancel_before_the_start_runs_no_child(child_pids):
    with pytest.raises(BakeCancelled):
        unwrap.unwrap([unwrap.UnwrapMesh("Cube", *meshes.cube())], unwrap.UnwrapSettings(), cancel=lambda: True)
    assert child_pids == [] and not unwrap._CACHE


# --- in Blender ---


def uv_bytes() -> dict:
    import bpy

    out = {}
    for mesh in bpy.data.meshes:
        for layer in mesh.uv_layers:
            uv = np.zeros(len(mesh.loops) * 2, np.float32)
            layer.data.foreach_get("uv", uv)
            out[(mesh.name, layer.name)] = uv.tobytes()
    return out


@pytest.fixture
def sphere_scene(extension):
    """One UV sphere (object "Sphere", 9k triangles) selected, with a lightmap layer already unwrapped."""
    import bpy

    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    for m in list(bpy.data.meshes):
        bpy.data.meshes.remove(m)
    s = bpy.context.scene
    s.hhd.uv_layer, s.hhd.resolution, s.hhd.atlas_mode, s.hhd.texel_density = "HHD_Lightmap", 512, 'SHARED', 0.0
    importlib.import_module(extension + ".core.unwrap").clear_chart_cache()
    bpy.ops.mesh.primitive_uv_sphere_add(segments=96, ring_count=48)
    obj = bpy.context.active_object
    obj.name = "Sphere"
    obj.select_set(True)
    return s, obj


@pytest.mark.bpy
def test_operator_prints_progress_headless_and_a_cancel_changes_no_uv(sphere_scene, capfd):
    import bpy

    scene, obj = sphere_scene
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    out = capfd.readouterr().out
    assert "%] xatlas: charting" in out and "[100.0%] xatlas: done" in out
    assert re.search(r"%\] xatlas: (charted|packing)[^\n]*, ETA \d", out)  # as a bake's lines
    obj.rotation_euler.z = 0.3  # the same mesh rotated: charted again, not cached
    bpy.context.view_layer.update()
    before = uv_bytes()
    ops = importlib.import_module(EXTENSION_MODULE + ".operators.unwrap")
    cancelled = importlib.import_module(EXTENSION_MODULE + ".core.errors").BakeCancelled
    job = ops.read_objects([obj], scene.hhd)  # what the modal operator reads, then runs on a thread
    seen = []
    with pytest.raises(cancelled):
        ops.compute(job, lambda f, m: seen.append(f), cancel=lambda: bool(seen))
    assert uv_bytes() == before
    with pytest.raises(cancelled):  # the synchronous path too
        ops.unwrap_objects([obj], scene.hhd, cancel=lambda: True)
    assert uv_bytes() == before


@pytest.mark.bpy
@pytest.mark.slow
def test_command_line_unwrap_shows_progress_and_ctrl_c_leaves_the_blend_unchanged(sphere_scene, cli_run, tmp_path):
    """In a process of its own (the signal is what is tested): Ctrl-C while xatlas charts three
    dense spheres stops within seconds and leaves the .blend as it was. The same command then
    runs to its end, shown in this process on the one sphere."""
    import bpy

    small = tmp_path / "small.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(small))
    blend = tmp_path / "scene.blend"
    for k in range(3):  # enough triangles that charting takes a while (65k each, each its own charts)
        v, f = meshes.uv_sphere(rings=128, segments=256, radius=1.0 + 0.1 * k)
        mesh = bpy.data.meshes.new(f"Dense{k}")
        mesh.from_pydata(v.tolist(), [], f.tolist())  # a tenth of the sphere operator's time
        dense = bpy.data.objects.new(f"Dense{k}", mesh)
        dense.location = (3 * (k + 1), 0, 0)
        bpy.context.collection.objects.link(dense)
    bpy.ops.object.select_all(action='SELECT')
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    saved = blend.read_bytes()
    command = [sys.executable, "-m", "hhd_lightmapper.cli", str(blend), "unwrap", "--save", "--resolution", "2048"]
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    for line in proc.stdout:
        if "xatlas: charting" in line:  # the children are running
            time.sleep(0.5)
            proc.send_signal(signal.SIGINT)
            break
    start = time.perf_counter()
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == cli.EXIT_CANCELLED, err
    assert time.perf_counter() - start < 10.0
    assert blend.read_bytes() == saved
    done = cli_run(small, "unwrap", "--save")
    assert done.returncode == cli.EXIT_OK, done.stderr
    assert "[100.0%] xatlas: done" in done.stdout
