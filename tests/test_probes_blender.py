"""Probe volumes from Blender: an Irradiance Volume is baked with the lightmaps (its transform,
resolution and Validity Threshold read in both Blender versions), per light set too."""

import json

import numpy as np
import pytest

from hhd_lightmapper.core import probes
from scenekit import blender as kit

pytestmark = pytest.mark.bpy


@pytest.fixture
def scene(extension, restore_hhd_settings, tmp_path):
    """A floor with a closed box, a sun in light group "Sun", the world in none; an Irradiance
    Volume 4×1×2 over the floor whose probes at x ≈ 0.25 sit inside the box; 8 samples."""
    import bpy

    scene = kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4, kit.material("grey"))
    kit.box("Box", (0.25, 0.0, 0.5), (0.6, 0.6, 1.2), kit.material("white"))
    sun = kit.light('SUN', rotation=(0.6, 0.2, 0.4), energy=3.0, name="Sun")
    sun.lightgroup = "Sun"
    kit.world((0.2, 0.3, 0.5))
    bpy.ops.object.lightprobe_add(type='VOLUME', location=(0.0, 0.0, 0.75))
    volume = bpy.context.active_object
    volume.name = "Volume"
    volume.scale = (1.0, 0.5, 0.5)  # probes at x = ±0.25, ±0.75; z = 0.5, 1.0
    probe = volume.data
    probe.resolution_x, probe.resolution_y, probe.resolution_z = 4, 1, 2
    kit.unwrap([floor])
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.seed, s.denoise, s.pack_images = 8, 1, 0, False, False
    s.output_dir = str(tmp_path / "lightmaps")
    kit.select([floor])
    return scene, tmp_path / "lightmaps"


def test_an_irradiance_volume_bakes_with_the_lightmaps(scene):
    import bpy

    scene, folder = scene
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    doc = json.loads((folder / "probes.json").read_text())
    entry = doc["volumes"][0]
    assert entry["name"] == "Volume" and entry["resolution"] == [4, 1, 2]
    assert entry["validity_threshold"] == pytest.approx(0.4)
    grid, sh, valid = probes.read(folder, "Volume")
    np.testing.assert_allclose(grid.positions()[:4, 0], [-0.75, -0.25, 0.25, 0.75], atol=1e-6)
    np.testing.assert_allclose(grid.positions()[[0, 4], 2], [0.5, 1.0], atol=1e-6)
    # the probes inside the box (x = 0.25, both heights) are invalid and filled from neighbours
    np.testing.assert_array_equal(valid, [True, True, False, True] * 2)
    assert entry["invalid"] == 2
    # sets: the sun's and the world's (Default) sum to the probes
    assert [s["name"] for s in entry["light_sets"]] == ["Default", "Sun"]
    _, sky, _ = probes.read(folder, "Volume", "Default")
    _, sun, _ = probes.read(folder, "Volume", "Sun")
    np.testing.assert_allclose(sky + sun, sh, rtol=1e-5, atol=1e-6)
    # a probe sees the sky above: L0 at least the sky's upper half
    assert (sh[valid, 0, 2] > 0.5 * np.sqrt(np.pi) * 0.5).all()
