"""The comparison in steps (`bridge.compare`: `prepare`, `begin` / `advance`, `run_steps`), as the
command line and the operator's modal path (one `advance` per timer event) run it: a progress
line per step with fractions rising to 1, and a cancel or a failure half-way leaves an earlier
report's files and the scene (every render, Cycles, image and view setting, every material's
node tree) as they were. A tiny scene: a floor and a cube under a sky, baked at 64², compared
at 48×36 pixels with two Cycles samples, HHD and L2 SH, one roughness."""

import re
from pathlib import Path

import numpy as np
import pytest

from scenekit import blender as kit

pytestmark = pytest.mark.bpy

MODELS, ROUGHNESS = ("hhd", "sh_l2"), (0.5,)
OPTIONS = dict(models=MODELS, roughness=ROUGHNESS, samples=2, percentage=50)
#: The same comparison with other samples: its report's table differs from OPTIONS' one.
OTHER = dict(OPTIONS, samples=4)


@pytest.fixture(scope="module")
def baked(extension, tmp_path_factory):
    """A saved .blend of the baked scene (its lightmaps beside it)."""
    import bpy

    from conftest import hhd_settings_restored

    folder = tmp_path_factory.mktemp("compare_steps")
    with hhd_settings_restored():
        scene = kit.clear_scene()
        floor = kit.plane("Floor", (0, 0, 0), 4, kit.material("grey", (0.5, 0.5, 0.5)))
        bpy.ops.mesh.primitive_cube_add(size=0.8, location=(0.3, 0.2, 0.4))
        cube = bpy.context.active_object
        cube.data.materials.append(kit.material("red", (0.7, 0.2, 0.2)))
        kit.world((0.4, 0.5, 0.6))
        cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
        scene.collection.objects.link(cam)
        cam.location, cam.rotation_euler = (0.3, -1.5, 1.9), (np.radians(45.0), 0.0, 0.0)
        scene.camera = cam
        scene.render.resolution_x, scene.render.resolution_y = 96, 72
        s = scene.hhd
        s.preset = 'CUSTOM'
        s.resolution, s.samples, s.bounces, s.denoise = 64, 4, 1, False
        s.output_dir = str(folder / "lightmaps")
        kit.unwrap([floor, cube])
        kit.select([floor, cube])
        assert bpy.ops.hhd.bake() == {'FINISHED'}
        blend = folder / "scene.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    return blend


def _open(blend):
    """The baked scene, with render settings unlike any the comparison sets (so that putting
    them back is seen)."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    r = scene.render
    r.engine, r.filepath, r.resolution_percentage, r.film_transparent = 'BLENDER_WORKBENCH', "//frames/", 37, True
    scene.cycles.samples, scene.cycles.seed, scene.cycles.max_bounces = 7, 11, 5
    r.image_settings.file_format = 'PNG'
    scene.view_settings.exposure = 0.5
    return scene


def _scene_state(scene) -> dict:
    """Every value of the render, Cycles, output image, view and display settings, and every
    material's node tree (nodes with their inputs' values, links), comparable with ==."""
    import bpy

    def values(struct):
        out = {}
        for p in struct.bl_rna.properties:
            if p.type in {'POINTER', 'COLLECTION'} or p.identifier == "rna_type":
                continue
            v = getattr(struct, p.identifier)
            out[p.identifier] = tuple(v) if hasattr(v, "__len__") and not isinstance(v, str) else v
        return out

    state = {
        name: values(struct)
        for name, struct in [
            ("render", scene.render),
            ("cycles", scene.cycles),
            ("image", scene.render.image_settings),
            ("view", scene.view_settings),
            ("display", scene.display_settings),
        ]
    }
    state["camera"] = scene.camera.name if scene.camera else None
    for mat in bpy.data.materials:
        tree = mat.node_tree
        if tree is None:
            continue
        nodes = sorted(
            (n.name, n.bl_idname, n.label, tuple(n.location), [values(s) for s in n.inputs]) for n in tree.nodes
        )
        links = sorted(
            (k.from_node.name, k.from_socket.identifier, k.to_node.name, k.to_socket.identifier) for k in tree.links
        )
        state[f"material {mat.name}"] = (nodes, links)
    return state


def _files(folder) -> dict:
    """{name: (bytes, mtime in ns)} of every file in `folder` (temporaries included)."""
    return {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.iterdir())}


def _atlases(blend) -> int:
    return len(list((blend.parent / "lightmaps").glob("*.json")))


def test_the_command_line_prints_a_line_per_step_rising_to_one(baked, cli_run, restore_hhd_settings, tmp_path):
    args = ("--models", *MODELS, "--roughness", *map(str, ROUGHNESS), "--cycles-samples", "2", "--percentage", "50")
    run = cli_run(baked, "compare", "--report", str(tmp_path / "report"), *args)
    assert run.returncode == 0, run.stderr + run.stdout
    (steps,) = (int(m[1]) for m in re.finditer(r"^compare: (\d+) steps", run.stdout, re.M))
    # a render per pass and seed, per atlas its post stages and each encoding, the report
    assert _atlases(baked) >= 1
    assert steps == 2 * (1 + len(ROUGHNESS)) + _atlases(baked) * (1 + len(MODELS)) + 1
    lines = re.findall(r"^\[\s*([\d.]+)%\] (.*)$", run.stdout, re.M)
    assert len(lines) == steps + 1, run.stdout  # each step as it starts, then the end
    fractions = [float(f) for f, _ in lines]
    assert fractions[0] == 0.0 and fractions[-1] == 100.0 and all(np.diff(fractions) > 0), fractions
    messages = [m for _, m in lines]
    assert sum("Cycles reference" in m for m in messages) == 2 * (1 + len(ROUGHNESS)), messages
    assert sum("encoding atlas" in m for m in messages) == _atlases(baked) * len(MODELS), messages
    assert "writing the report" in messages[-2] and "report written" in messages[-1], messages
    assert sorted(p.name for p in (tmp_path / "report").iterdir()) == [
        "compare.json",
        "compare.md",
        "contact_sheet.png",
    ]


def _run_cancelled_after(job, k: int):
    """`run_steps` with a cancel turning true after `k` steps: (what it raised, the messages it
    reported)."""
    from hhd_lightmapper.bridge import compare

    heard: list[str] = []
    try:
        compare.run_steps(job, lambda f, m: heard.append(m), lambda: job.done >= k)
    except Exception as exc:
        return exc, heard
    return None, heard


def test_a_cancel_after_any_step_changes_nothing(baked, restore_hhd_settings, tmp_path):
    """The step runner with a cancel that turns true after k steps (the modal operator's Esc):
    after the first render, and after everything but the report: the earlier report and the
    scene are as they were, the temporary renders gone. Not cancelled, the same comparison does
    replace the report (so the checks could fail)."""
    import bpy

    from hhd_lightmapper.bridge import compare
    from hhd_lightmapper.core.errors import BakeCancelled

    scene = _open(baked)
    report = tmp_path / "report"
    compare.run(bpy.context, folder=str(report), **OPTIONS, progress=lambda f, m: None)
    before, state = _files(report), _scene_state(scene)
    for k in (1, None):
        job = compare.prepare(bpy.context, folder=str(report), **OTHER)
        k = k or len(job.steps) - 1
        temporary = job._tmp.name
        error, heard = _run_cancelled_after(job, k)
        assert isinstance(error, BakeCancelled), error
        assert job.done == k and len(heard) == k + 1, heard
        assert _files(report) == before, k
        assert _scene_state(scene) == state, k
        assert not Path(temporary).exists(), k
    compare.run(bpy.context, folder=str(report), **OTHER, progress=lambda f, m: None)
    after = _files(report)
    assert after["compare.md"][0] != before["compare.md"][0]
    assert _scene_state(scene) == state


def test_a_render_failing_half_way_restores_the_scene_and_names_it(baked, restore_hhd_settings, tmp_path):
    """The camera deleted between two steps (the UI is live between the modal operator's steps):
    the next render fails; the error names it, the scene's settings and materials are as they
    were, and the earlier report too."""
    import bpy

    from hhd_lightmapper.bridge import compare
    from hhd_lightmapper.core.errors import BakeError

    scene = _open(baked)
    report = tmp_path / "report"
    compare.run(bpy.context, folder=str(report), **OPTIONS, progress=lambda f, m: None)
    before, state = _files(report), _scene_state(scene)
    job = compare.prepare(bpy.context, folder=str(report), **OTHER)
    temporary = job._tmp.name
    heard = []
    compare.begin(job, lambda f, m: heard.append(m))
    assert compare.advance(job, lambda f, m: heard.append(m), lambda: False)
    assert compare.advance(job, lambda f, m: heard.append(m), lambda: False)
    assert heard[-1].startswith("Cycles reference 3/4: glossy r=0.5, seed 1"), heard
    camera, scene.camera = scene.camera, None
    with pytest.raises(BakeError, match=r"the Cycles reference render \(glossy r=0\.5, seed 1\) failed: .*camera"):
        compare.advance(job, lambda f, m: heard.append(m), lambda: False)
    scene.camera = camera
    assert _scene_state(scene) == state
    assert _files(report) == before
    assert not Path(temporary).exists()


def test_the_operator_reports_what_stopped_it(baked, restore_hhd_settings, tmp_path):
    """`bpy.ops.hhd.compare()` in background mode, invoked or not, runs `execute` (the steps in a
    row; the modal path needs a window): an output folder without the bake is refused before any
    render, named in the error, and nothing is written."""
    import bpy

    _open(baked)
    bpy.context.scene.hhd.output_dir = str(tmp_path / "empty")
    with pytest.raises(RuntimeError, match=r"Compare failed: atlas 'Lightmap' has no bake in .*empty: bake it first"):
        bpy.ops.hhd.compare('INVOKE_DEFAULT', samples=2, percentage=25)
    assert not (tmp_path / "empty").exists()
