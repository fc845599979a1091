"""Light sets against Cycles: a scene with two lamps in two Light Groups, baked once by the
operator, blended at weights (w_A, w_B) (`core.light_sets.blend_atlas` on the bake's files); the
blend's I_z must agree with Cycles' Diffuse bake (Direct + Indirect, Color off) of the same scene
with the lamps scaled by w_A and w_B, within the noise bound of the other Cycles tests
(cycles_compare.assert_agree: both sides run twice with different seeds)."""

import sys

import numpy as np
import pytest

import cycles_compare as cc
from conftest import EXTENSION_MODULE
from hhd_lightmapper.core import light_sets
from hhd_lightmapper.core.bakepoints import data as bakepoint_data
from hhd_lightmapper.core.files import exr, lightmap_files
from scenekit import blender as kit

pytestmark = [pytest.mark.bpy, pytest.mark.cycles, pytest.mark.slow]

SAMPLES, BOUNCES = 32, 1
#: (w_A, w_B): an RGB weight on the warm lamp, a scalar one on the cool lamp
WEIGHTS = {"A": (1.0, 0.5, 0.25), "B": 2.0}
COLOUR = {"A": (1.0, 0.8, 0.6), "B": (0.5, 0.7, 1.0)}
#: Texels per metre of the 2 m floor: a quarter of the 256² atlas's (cost ∝ texels); the bias
#: tolerance stays ≥ 10× four standard errors of the mean (the allowance dominates it), and the
#: per-texel agreement does not depend on the texel count (as tests/test_bake_cycles.py's).
DENSITY = 64.0


@pytest.fixture(autouse=True)
def cycles_footprint(monkeypatch, extension):
    """Our bake averages each texel over the same footprint as the running Blender's Cycles, in
    both copies of core: the tests' and the installed extension's (which the operator runs)."""
    monkeypatch.setattr(bakepoint_data, "FOOTPRINT", cc.cycles_footprint())
    installed = sys.modules.get(f"{EXTENSION_MODULE}.core.bakepoints.data")
    if installed is not None:
        monkeypatch.setattr(installed, "FOOTPRINT", cc.cycles_footprint())


@pytest.fixture
def two_lamps(extension, restore_hhd_settings, tmp_path):
    """A floor and a box; a warm point lamp in light group "A", a cool one in "B" (both in the view
    layer's light groups, as Blender's UI makes them); our bake's settings; the output folder."""
    import bpy

    scene = kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 2.0, kit.material("Floor", (0.8, 0.8, 0.8)))
    kit.box("Blocker", (0.2, 0.1, 0.35), (0.4, 0.4, 0.3), kit.material("Blocker", (0.6, 0.5, 0.4)))
    lamps = {
        "A": kit.light('POINT', (-0.5, -0.3, 1.0), energy=150.0, name="LampA", shadow_soft_size=0.1),
        "B": kit.light('POINT', (0.6, 0.5, 0.8), energy=80.0, name="LampB", shadow_soft_size=0.1),
    }
    layer = bpy.context.view_layer
    for group, lamp in lamps.items():
        lamp.data.color = COLOUR[group]
        if group not in layer.lightgroups:
            layer.lightgroups.add(name=group)
        lamp.lightgroup = group
    kit.unwrap([floor], DENSITY)
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.denoise, s.stitch_seams = SAMPLES, BOUNCES, False, False
    s.output_dir = str(tmp_path / "lightmaps")
    return floor, lamps, lightmap_files.AtlasFiles(tmp_path / "lightmaps", "Lightmap")


def blended_iz(files, seed):
    """Bake with the operator at `seed`, blend the sets at WEIGHTS into the atlas's HHD file;
    its I_z `(H·W, 3)`, rows bottom-up (Blender's pixel order)."""
    import bpy

    bpy.context.scene.hhd.seed = seed
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    doc = lightmap_files.read_sidecar(files.sidecar)
    assert [entry["name"] for entry in doc["light_sets"]] == ["A", "B"]
    light_sets.blend_atlas(files, WEIGHTS)
    return rows(files.hhd, [f"Iz.{c}" for c in "RGB"])


def rows(path, names):
    channels, _ = exr.read(path)
    return np.stack([exr.from_exr_rows(channels[n]).reshape(-1) for n in names], axis=-1).astype(np.float64)


def scale_lamps(lamps):
    """The lamps as the weights make them: A's colour times its RGB weight, B's power times 2."""
    lamps["A"].data.color = tuple(c * w for c, w in zip(COLOUR["A"], WEIGHTS["A"]))
    lamps["B"].data.energy *= WEIGHTS["B"]


def agreement(o1, o2, c1, c2):
    """cycles_compare.compare's statistics from two runs of each side (texels × channels)."""
    o, c = 0.5 * (o1 + o2), 0.5 * (c1 + c2)
    noise = np.mean(((o1 - o2) ** 2 + (c1 - c2) ** 2) / 4)
    return dict(
        mean=float(np.mean(c)),
        bias=float(np.mean(o - c)),
        rms=float(np.sqrt(np.mean((o - c) ** 2))),
        noise_rms=float(np.sqrt(noise)),
        se_mean=float(np.sqrt(noise / o.size)),
    )


def test_blended_light_sets_match_cycles_with_the_lamps_scaled(two_lamps):
    floor, lamps, files = two_lamps
    o1, o2 = blended_iz(files, 1), blended_iz(files, 2)
    coverage = rows(files.texels, ["Coverage.V"])[:, 0]
    keep = np.nonzero(coverage >= 1.0 - 1e-6)[0]  # fully covered, not buried (−1)
    scale_lamps(lamps)
    points = type("Texels", (), {"texel": keep})  # cycles_compare.cycles reads .texel
    c1 = cc.cycles([floor], points, 64, BOUNCES, seed=1)
    c2 = cc.cycles([floor], points, 64, BOUNCES, seed=2)
    r = agreement(o1[keep], o2[keep], c1, c2)
    ratio = (4 * r["se_mean"] + 0.01 * r["mean"]) / (4 * r["se_mean"])  # assert_agree's bias tolerance
    print("light sets vs Cycles:", r, f"bias tolerance {ratio:.1f}× four standard errors")
    assert r["mean"] > 0.1, r
    cc.assert_agree(r)
    # the blended file is the weighted sum of the sets' files in I_z (exact up to half floats)
    set_a, set_b = files.light_sets(lightmap_files.read_sidecar(files.sidecar))
    iz_a, iz_b = rows(set_a.hhd, ["Iz.R", "Iz.G", "Iz.B"]), rows(set_b.hhd, ["Iz.R", "Iz.G", "Iz.B"])
    want = np.asarray(WEIGHTS["A"]) * iz_a + WEIGHTS["B"] * iz_b
    assert np.abs(o2 - want)[keep].max() <= 2e-3 * want[keep].max()
