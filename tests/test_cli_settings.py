"""The command line's options as settings values: a bake with options leaves the scene's HHD
settings as they were (`cli.overrides.overridden`: an overridden view, never written into `scene.hhd`
without --save), and the settings built from the options equal those built from a scene holding
them (`bridge.settings.scene_settings`)."""

import json

import numpy as np
import pytest

from hhd_lightmapper import cli
from hhd_lightmapper.bridge import settings as bridge_settings
from hhd_lightmapper.cli import options, overrides
from scenekit import blender as kit

pytestmark = pytest.mark.bpy

#: Options over every kind of setting: a preset and knobs overriding it, a float a single
#: precision float does not hold exactly (1.3), enums and switches.
OPTIONS = [
    "--preset",
    "preview",
    "--samples",
    "20",
    "--noise-target",
    "1.3",
    "--time-budget",
    "60",
    "--seed",
    "9",
    "--model",
    "sh_l1",
    "--solve",
    "ls",
    "--ambient",
    "rgb",
    "--inward-faces",
    "as-modelled",
    "--no-denoise",
    "--no-stitch",
    "--resolution",
    "512",
]


def scene_settings_now() -> dict:
    """Every plain HHD setting of the scene (`scene.hhd`), by name."""
    import bpy

    settings = bpy.context.scene.hhd
    return {
        p.identifier: getattr(settings, p.identifier)
        for p in settings.bl_rna.properties
        if p.identifier != "rna_type" and p.type in {'BOOLEAN', 'INT', 'FLOAT', 'STRING', 'ENUM', 'POINTER'}
    }


@pytest.fixture
def saved_scene(extension, restore_hhd_settings, tmp_path):
    """Floor + cube under a sun, unwrapped at 256², saved as tmp_path/scene.blend."""
    import bpy

    scene = kit.clear_scene()
    grey = kit.material("grey")
    floor = kit.plane("Floor", (0, 0, 0), 4, grey)
    cube = kit.box("Cube", (0, 0, 0.5), (1, 1, 1), grey)
    kit.light('SUN', rotation=(0.5, 0.2, 0), energy=3.0)
    scene.hhd.samples, scene.hhd.bounces, scene.hhd.output_dir, scene.hhd.pack_images = 8, 1, "//lightmaps", False
    kit.unwrap([floor, cube])
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    return scene, tmp_path


def test_a_command_line_bake_with_options_leaves_the_scene_settings_unchanged(saved_scene):
    scene, folder = saved_scene
    before = scene_settings_now()
    out = folder / "out"
    options = [o for o in OPTIONS if o not in ("--time-budget", "60")] + ["--samples", "8", "--bounces", "1"]
    assert cli.main(["bake", "--objects", "Floor", "Cube", "--out", str(out), "--threads", "2", *options]) == 0
    assert scene_settings_now() == before
    sidecar = json.loads((out / "Lightmap.json").read_text())
    assert (sidecar["bake"]["samples"], sidecar["bake"]["bounces"], sidecar["bake"]["seed"]) == (8, 1, 9)
    assert sidecar["encoder"]["model"] == "sh_l1"
    assert sidecar["bake"]["noise_target"] == float(np.float32(1.3)) / 100.0  # as the scene would hold it


def test_the_settings_from_options_equal_those_of_a_scene_holding_them(saved_scene):
    scene, _ = saved_scene
    args = options.parser().parse_args(["bake", "--threads", "3", *OPTIONS])
    before = scene_settings_now()
    view = overrides.overridden(scene, args)
    from_options = bridge_settings.scene_settings(scene, args.threads, view)
    assert scene_settings_now() == before  # building the value wrote nothing
    overrides.apply_options(scene.hhd, args)  # what --save keeps
    from_scene = bridge_settings.scene_settings(scene, args.threads)
    assert from_options == from_scene
    assert {key: getattr(view, key) for key in before} == scene_settings_now()  # the preset switched to Custom too
    assert scene.hhd.preset == 'CUSTOM' and scene.hhd.noise_target != 1.3  # single precision, as the view holds it
    trace = from_scene.trace
    assert (trace.samples, trace.pass_samples, trace.passes, trace.threads) == (20, 16, 2, 3)
    assert trace.noise_target == scene.hhd.noise_target / 100.0


def test_the_operators_and_the_command_line_take_the_scenes_settings_alike(saved_scene):
    scene, _ = saved_scene
    view = overrides.overridden(scene, options.parser().parse_args(["bake"]))
    assert bridge_settings.scene_settings(scene, None, view) == bridge_settings.scene_settings(scene)
    mode, threads = scene.render.threads_mode, scene.render.threads
    try:
        scene.render.threads_mode, scene.render.threads = 'FIXED', 3  # Render > Performance > Threads
        assert bridge_settings.scene_settings(scene).trace.threads == 3
        assert bridge_settings.scene_settings(scene, 0).trace.threads == bridge_settings.parallel.machine_threads()
    finally:
        scene.render.threads_mode, scene.render.threads = mode, threads
    with pytest.raises(AttributeError, match="read-only"):
        view.samples = 4
