"""Light sets from Blender: Light Groups on lamps, emissive meshes and the world become sets; one
bake writes each set's files and lists them in the panel; `blend` (command line) writes the
blended state. Denoising off: these bakes need no OIDN weights."""

import json

import numpy as np
import pytest

from hhd_lightmapper import cli
from hhd_lightmapper.core.files import exr, lightmap_files
from scenekit import blender as kit

pytestmark = pytest.mark.bpy


def iz(path):
    channels, _ = exr.read(path)
    return np.stack([channels[f"Iz.{c}"] for c in "RGB"], axis=-1).astype(np.float64)


@pytest.fixture
def scene(extension, restore_hhd_settings, tmp_path):
    """A floor with a box, lit by a red point lamp (group "Red"), a blue one (group "Blue"), an
    emissive panel (no group: "Default") and the world (group "Blue"); 8 samples, 1 bounce."""

    scene = kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4, kit.material("grey"))
    box = kit.box("Box", (0.5, 0.3, 0.4), (0.8, 0.8, 0.8), kit.material("white"))
    panel = kit.plane("Panel", (-1.2, 1.2, 1.5), 0.5, kit.material("glow", emission=(1.0, 1.0, 1.0, 5.0)))
    red = kit.light('POINT', (-1.0, -1.0, 1.5), energy=150.0, name="RedLamp", color=(1.0, 0.1, 0.05))
    blue = kit.light('POINT', (1.2, 1.0, 1.2), energy=100.0, name="BlueLamp", color=(0.1, 0.2, 1.0))
    kit.world((0.05, 0.05, 0.08))
    red.lightgroup, blue.lightgroup, scene.world.lightgroup = "Red", "Blue", "Blue"
    kit.unwrap([floor, box])
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.seed, s.denoise, s.pack_images = 8, 1, 0, False, False
    s.output_dir = str(tmp_path / "lightmaps")
    kit.select([floor, box])
    assert panel.lightgroup == ""
    return scene, tmp_path / "lightmaps"


def test_light_groups_bake_as_sets_listed_in_the_panel_and_blend_from_the_command_line(scene, capsys):
    import bpy

    scene, folder = scene
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    files = lightmap_files.AtlasFiles(folder, "Lightmap")
    doc = lightmap_files.read_sidecar(files.sidecar)
    assert [s["name"] for s in doc["light_sets"]] == ["Blue", "Default", "Red"]
    assert [item.name for item in scene.hhd.light_sets] == ["Blue", "Default", "Red"]
    blue, default, red = files.light_sets(doc)
    total = iz(files.hhd)
    # each set holds its own light: red lamp red, blue lamp + world blue, the panel white
    for f, channel in ((red, 0), (blue, 2)):
        mean = iz(f.hhd).reshape(-1, 3).mean(axis=0)
        assert mean.argmax() == channel, (f.name, mean)
    assert np.abs(iz(red.hhd) + iz(blue.hhd) + iz(default.hhd) - total).mean() <= 2e-3 * total.mean()

    # the panel's weights are the default; the command line overrides them
    scene.hhd.light_sets["Red"].weight = (0.0, 0.0, 0.0)
    capsys.readouterr()
    code = cli.main(["blend", "--objects", "Floor", "Box", "--weights", "Blue=2", "Default=0,0,0"])
    out = capsys.readouterr().out
    assert code == cli.EXIT_OK, out
    assert "Red=0" in out and "Blue=2" in out
    record = json.loads(files.sidecar.read_text())["blend"]
    assert record["weights"] == {"Blue": [2.0] * 3, "Default": [0.0] * 3, "Red": [0.0] * 3}
    want = 2.0 * iz(blue.hhd)
    assert np.abs(iz(files.hhd) - want).mean() <= 3e-3 * want.mean()

    assert cli.main(["blend", "--objects", "Floor", "--weights", "Green=1"]) == cli.EXIT_INPUT
    assert cli.main(["blend", "--weights", "Red"]) == cli.EXIT_USAGE
