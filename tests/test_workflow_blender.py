"""The bake workflow in Blender: operators in background mode end to end, re-encode, errors
naming the object, cancel leaving the .blend untouched, and the command line's exit codes."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper import cli
from hhd_lightmapper.core import presets
from hhd_lightmapper.core.tracer import BakeCancelled
from scenekit import blender as kit
from scenekit.blender import scene_hash

pytestmark = pytest.mark.bpy
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def baked_scene(extension, oidn_weights, tmp_path):
    """Floor + cube, sun + sky, unwrapped at 256², saved as tmp_path/scene.blend. Denoise is on
    (the default), so the bakes below run the denoiser: the weights must be there."""
    import bpy

    scene = kit.clear_scene()
    grey = kit.material("grey")
    floor = kit.plane("Floor", (0, 0, 0), 4, grey)
    cube = kit.box("Cube", (0, 0, 0.5), (1, 1, 1), kit.material("red", (0.8, 0.1, 0.1)))
    kit.light('SUN', rotation=(0.5, 0.2, 0), energy=3.0)
    kit.world((0.1, 0.2, 0.3))
    scene.hhd.samples, scene.hhd.bounces, scene.hhd.output_dir = 8, 1, "//lightmaps"
    scene.hhd.model, scene.hhd.ambient, scene.hhd.pack_images = 'HHD', 'LUMINANCE', False
    kit.unwrap([floor, cube])
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    return scene, [floor, cube], tmp_path


def test_bake_and_reencode_operators_end_to_end(baked_scene):
    import bpy

    scene, receivers, folder = baked_scene
    kit.select(receivers)
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    out = folder / "lightmaps"
    assert sorted(p.name for p in out.iterdir()) == [
        "Lightmap.json",
        "Lightmap_hhd.exr",
        "Lightmap_preview",
        "Lightmap_seams.npz",
        "Lightmap_sh.exr",
        "Lightmap_texels.exr",
    ]
    # the raw SH file's previews (sh0 … sh8) are written when an L1/L2 preview first needs them
    assert sorted(p.name for p in (out / "Lightmap_preview").iterdir()) == ["dir.exr", "iz.exr", "wa.exr"]
    doc = json.loads((out / "Lightmap.json").read_text())
    assert [o["name"] for o in doc["objects"]] == ["Cube", "Floor"] and all(o["texels"] > 0 for o in doc["objects"])
    assert doc["bake"]["samples"] == 8 and doc["encoder"]["model"] == "hhd"
    assert doc["post"]["denoise"]["applied"] and doc["post"]["stitch"]["applied"]  # both on by default
    loaded = {Path(bpy.path.abspath(im.filepath)).name: im for im in bpy.data.images}
    assert {"Lightmap_hhd.exr", "Lightmap_sh.exr"} <= set(loaded)
    assert all(im.packed_file is None for im in loaded.values())  # external, not packed
    assert "Baked" in scene.hhd.bake_summary and ", denoised (" in scene.hhd.bake_summary
    sh_bytes, hhd_bytes = (out / "Lightmap_sh.exr").read_bytes(), (out / "Lightmap_hhd.exr").read_bytes()
    scene.hhd.model = 'AHD'
    assert bpy.ops.hhd.encode() == {'FINISHED'}
    assert (out / "Lightmap_sh.exr").read_bytes() == sh_bytes
    assert (out / "Lightmap_hhd.exr").read_bytes() != hhd_bytes
    assert json.loads((out / "Lightmap.json").read_text())["encoder"]["model"] == "ahd"
    scene.hhd.pack_images = True
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    assert all(im.packed_file is not None for im in bpy.data.images if im.name.startswith("Lightmap_"))


def test_errors_name_the_object_and_the_problem(baked_scene):
    import bpy

    scene, (floor, cube), folder = baked_scene
    cube.data.uv_layers.remove(cube.data.uv_layers[kit.LAYER])
    kit.select([floor, cube])
    with pytest.raises(RuntimeError, match="'Cube' has no 'HHD_Lightmap' UV layer: run Unwrap first"):
        bpy.ops.hhd.bake()
    empty = bpy.data.objects.new("Empty Mesh", bpy.data.meshes.new("nothing"))
    scene.collection.objects.link(empty)
    kit.select([empty])
    with pytest.raises(RuntimeError, match="'Empty Mesh' has no faces"):
        bpy.ops.hhd.bake()
    floor.data.uv_layers[kit.LAYER].data.foreach_set("uv", np.zeros(len(floor.data.loops) * 2, np.float32))
    floor.data.update()  # 4.x does not re-evaluate the mesh after a raw foreach_set
    kit.select([floor])
    with pytest.raises(RuntimeError, match="'Floor': the lightmap UVs cover no texel"):
        bpy.ops.hhd.bake()
    assert not (folder / "lightmaps").exists()


def test_cancel_leaves_the_blend_and_the_previous_files_unchanged(baked_scene):
    import bpy

    from hhd_lightmapper.bridge import bake_session

    scene, receivers, folder = baked_scene
    kit.select(receivers)
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    files = {p: p.read_bytes() for p in (folder / "lightmaps").rglob("*") if p.is_file()}
    before = scene_hash()
    scene.hhd.samples = 64
    before = scene_hash()
    session = bake_session.BakeSession(bpy.context)  # what the modal operator runs
    checks = []
    with pytest.raises(BakeCancelled):
        session.run(cancel=lambda: checks.append(1) or len(checks) > 2)  # Esc after two chunks
    assert scene_hash() == before
    assert {p: p.read_bytes() for p in (folder / "lightmaps").rglob("*") if p.is_file()} == files


def test_a_bake_lets_go_of_its_scene_before_the_last_atlas_is_finished(baked_scene, monkeypatch):
    """The session hands its scene and atlases over to `core.bake.run`, which lets go of what the
    bake no longer reads (memory): the atlases' surfaces once the bake points are built, the
    scene and its Embree scene once the last atlas is traced, before its finishing. The session
    runs once."""
    import weakref

    import bpy

    from hhd_lightmapper.bridge import bake_session
    from hhd_lightmapper.core import bake

    scene, receivers, folder = baked_scene
    kit.select(receivers)
    session = bake_session.BakeSession(bpy.context)
    refs = {"scene": weakref.ref(session.scene)}
    refs.update({f"surface of {a.name}": weakref.ref(a.surface) for a in session.atlases})
    make = bake.ray_scene_of

    def ray_scene_of(s):
        out = make(s)
        refs["Embree scene"] = weakref.ref(out)
        return out

    monkeypatch.setattr(bake, "ray_scene_of", ray_scene_of)
    alive = {}  # per progress message, what is still alive

    def progress(fraction, message):
        alive.setdefault(message, {name for name, ref in refs.items() if ref() is not None})

    session.run(progress=progress)
    tracing = [names for message, names in alive.items() if "chunk" in message]
    finishing = [names for message, names in alive.items() if "seams" in message or "imaging" in message]
    assert tracing and finishing
    assert all(names == {"scene", "Embree scene"} for names in tracing), tracing
    assert all(not names for names in finishing), finishing
    assert (folder / "lightmaps" / "Lightmap.json").is_file()
    with pytest.raises(RuntimeError, match="has run already"):
        session.run()


def run_cli_process(blend, *args, env=None, **kw):
    return subprocess.run(
        [sys.executable, "-m", "hhd_lightmapper.cli", str(blend), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        **kw,
    )


@pytest.mark.slow
def test_command_line_exit_codes(baked_scene, cli_run, tmp_path):
    """Exit codes and messages, in this process (`cli_run`); a missing dependency and SIGINT in
    a process of their own (import isolation, signals)."""
    scene, receivers, folder = baked_scene
    blend = folder / "scene.blend"
    run_cli = cli_run
    ok = run_cli(blend, "bake", "--out", str(tmp_path / "cli"), "--objects", "Floor", "Cube", "--preset", "draft")
    assert ok.returncode == cli.EXIT_OK, ok.stderr
    assert "[100.0%]" in ok.stdout and (tmp_path / "cli" / "Lightmap_hhd.exr").is_file()
    # every stage announces itself on the console in bake order, the scene's reading first
    starts = ["reading the scene: objects", "faces that point in", "bake points of 'Lightmap'", "'Lightmap': chunk"]
    starts += ["seams 'Lightmap'", "encode 'Lightmap'", "write 'Lightmap'"]
    where = [next((i for i, line in enumerate(ok.stdout.splitlines()) if s in line), -1) for s in starts]
    assert -1 not in where and where == sorted(where), (where, ok.stdout)
    encode = run_cli(blend, "encode", "--out", str(tmp_path / "cli"), "--objects", "Floor", "Cube", "--model", "ahd")
    assert encode.returncode == cli.EXIT_OK, encode.stderr
    assert json.loads((tmp_path / "cli" / "Lightmap.json").read_text())["encoder"]["model"] == "ahd"
    adaptive = run_cli(
        blend,
        "bake",
        "--out",
        str(tmp_path / "adaptive"),
        "--objects",
        "Floor",
        "Cube",
        "--preset",
        "reference",
        "--samples",
        "96",
        "--noise-target",
        "50",
    )
    assert adaptive.returncode == cli.EXIT_OK, adaptive.stderr
    bake = json.loads((tmp_path / "adaptive" / "Lightmap.json").read_text())["bake"]
    assert bake["samples"] == 96 and bake["noise_target"] == 0.5  # options override the preset
    assert 64 <= bake["mean_samples_per_texel"] <= 96 and bake["bounces"] == presets.get("reference").bounces

    usage = run_cli(blend, "bake", "--samples", "many")
    assert usage.returncode == cli.EXIT_USAGE and "invalid int value" in usage.stderr
    missing = run_cli(blend, "bake", "--objects", "Nope")
    assert missing.returncode == cli.EXIT_INPUT and "no object named 'Nope'" in missing.stderr
    (tmp_path / "a_file").write_text("not a folder")
    unwritable = run_cli(
        blend, "bake", "--out", str(tmp_path / "a_file" / "sub"), "--objects", "Floor", "--samples", "4"
    )
    assert unwritable.returncode == cli.EXIT_OUTPUT and "cannot write the output" in unwritable.stderr

    blocked = tmp_path / "blocked"
    blocked.mkdir()
    (blocked / "OpenEXR.py").write_text("raise ImportError('blocked by the test')\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(blocked), os.environ.get("PYTHONPATH", "")]))
    nodep = run_cli_process(
        blend, "bake", "--out", str(tmp_path / "nodep"), "--objects", "Floor", "--samples", "4", env=env
    )
    assert nodep.returncode == cli.EXIT_DEPENDENCY and "'OpenEXR'" in nodep.stderr

    # Started with SIGINT ignored, as a shell without job control (CI) starts background commands:
    # the bake must still stop on a SIGINT sent to it.
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hhd_lightmapper.cli",
            str(blend),
            "bake",
            "--out",
            str(tmp_path / "interrupted"),
            "--objects",
            "Floor",
            "Cube",
            "--samples",
            "4096",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    for line in proc.stdout:
        if "texel-samples/s" in line:  # tracing has started
            proc.send_signal(signal.SIGINT)
            break
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == cli.EXIT_CANCELLED, err
    assert not (tmp_path / "interrupted").exists() or not any((tmp_path / "interrupted").iterdir())


def test_in_process_entry_point_reports_input_errors(baked_scene):
    assert cli.main(["bake", "--collection", "Nope"]) == cli.EXIT_INPUT
    assert cli.main(["frobnicate"]) == cli.EXIT_USAGE


def exr_bytes(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*.exr"))}


def test_bake_and_reencode_honour_blenders_render_threads_setting(baked_scene):
    import bpy

    from hhd_lightmapper.core import parallel

    scene, receivers, folder = baked_scene
    kit.select(receivers)
    out, sidecar = folder / "lightmaps", folder / "lightmaps" / "Lightmap.json"
    scene.render.threads_mode, scene.render.threads = 'FIXED', 1
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    assert json.loads(sidecar.read_text())["bake"]["threads"] == 1
    one = exr_bytes(out)
    scene.render.threads_mode = 'AUTO'
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    assert json.loads(sidecar.read_text())["bake"]["threads"] == parallel.machine_threads()
    assert exr_bytes(out) == one
    scene.render.threads_mode, scene.render.threads = 'FIXED', 3
    assert bpy.ops.hhd.encode() == {'FINISHED'}
    assert json.loads(sidecar.read_text())["reencode_threads"] == 3


def test_command_line_refuses_a_negative_thread_count(baked_scene, capsys):
    assert cli.main(["bake", "--threads", "-1"]) == cli.EXIT_USAGE
    assert "invalid thread count -1: it must be ≥ 0 (0 = all cores)" in capsys.readouterr().err
    assert cli.main(["encode", "--threads", "two"]) == cli.EXIT_USAGE


@pytest.mark.slow
def test_command_line_threads_follow_the_scene_or_the_flag_and_files_are_identical(baked_scene, cli_run, tmp_path):
    import bpy

    from hhd_lightmapper.core import parallel

    scene, receivers, folder = baked_scene
    scene.render.threads_mode, scene.render.threads = 'FIXED', 1  # saved in the .blend
    blend = folder / "scene.blend"
    bpy.ops.wm.save_mainfile()
    args = ("--objects", "Floor", "Cube", "--preset", "draft")
    run_cli = cli_run
    default = run_cli(blend, "bake", "--out", str(tmp_path / "default"), *args)
    assert default.returncode == cli.EXIT_OK, default.stderr
    every = run_cli(blend, "bake", "--out", str(tmp_path / "every"), "--threads", "0", *args)
    assert every.returncode == cli.EXIT_OK, every.stderr
    assert exr_bytes(tmp_path / "default") == exr_bytes(tmp_path / "every")
    assert len(exr_bytes(tmp_path / "default")) == 6  # hhd, sh, texels and the three preview images of the HHD file
    threads = [
        json.loads((tmp_path / k / "Lightmap.json").read_text())["bake"]["threads"] for k in ("default", "every")
    ]
    assert threads == [1, parallel.machine_threads()]
    encode = run_cli(
        blend, "encode", "--out", str(tmp_path / "default"), "--objects", "Floor", "Cube", "--threads", "2"
    )
    assert encode.returncode == cli.EXIT_OK, encode.stderr
    assert json.loads((tmp_path / "default" / "Lightmap.json").read_text())["reencode_threads"] == 2
    encode = run_cli(blend, "encode", "--out", str(tmp_path / "every"), "--objects", "Floor", "Cube")
    assert encode.returncode == cli.EXIT_OK, encode.stderr
    assert json.loads((tmp_path / "every" / "Lightmap.json").read_text())["reencode_threads"] == 1


@pytest.mark.slow
def test_a_full_atlas_spills_into_numbered_atlases_that_bake_and_preview(extension, restore_hhd_settings, tmp_path):
    """40 spheres at 256² with padding 8: their padding alone exceeds one atlas, so the unwrap
    makes Lightmap, Lightmap_1, … of the same size, each object whole in one; the bake writes
    each atlas's files and sidecar, and the preview finds every object's atlas."""
    import bpy

    scene = kit.clear_scene()
    grey = kit.material("grey")
    spheres = []
    for k in range(40):
        bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8, radius=0.3, location=(k % 8, k // 8, 0.5))
        spheres.append(bpy.context.active_object)
        spheres[-1].data.materials.append(grey)
    floor = kit.plane("Floor", (3.5, 2, 0), 12, grey)
    kit.light('SUN', rotation=(0.5, 0.2, 0), energy=3.0)
    scene.hhd.resolution, scene.hhd.padding, scene.hhd.samples, scene.hhd.bounces = 256, 8, 4, 0
    scene.hhd.output_dir, scene.hhd.pack_images = str(tmp_path), False
    kit.select(spheres + [floor])
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    names = sorted({o.hhd.atlas for o in spheres + [floor]})
    assert len(names) >= 2 and names == ["Lightmap"] + [f"Lightmap_{k}" for k in range(1, len(names))]
    assert all((o.hhd.atlas_width, o.hhd.atlas_height) == (256, 256) for o in spheres + [floor])
    assert f"{len(names)} atlases" in scene.hhd.unwrap_summary
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    for name in names:
        doc = json.loads((tmp_path / f"{name}.json").read_text())
        members = sorted(o.name for o in spheres + [floor] if o.hhd.atlas == name)
        assert doc["atlas"] == name and sorted(o["name"] for o in doc["objects"]) == members
        assert (tmp_path / f"{name}_hhd.exr").exists()
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    # the one material every object shares samples every atlas, each object picks its own
    images = {Path(n.image.filepath).parent.name for n in grey.node_tree.nodes if n.type == 'TEX_IMAGE'}
    assert images == {f"{name}_preview" for name in names}
    assert all(o["hhd_preview_atlas"] == names.index(o.hhd.atlas) for o in spheres + [floor])
    compares = [n for n in grey.node_tree.nodes if n.type == 'MATH' and n.operation == 'COMPARE']
    assert sorted(n.inputs[1].default_value for n in compares) == sorted(
        float(k) for k in range(1, len(names)) for _ in ("iz", "wa", "dir")
    )
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert not any("hhd_preview_atlas" in o for o in spheres + [floor])
