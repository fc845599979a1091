"""Light sets in the tracer and the bake (no Blender): one trace, one SH per set, summing to the
bake without sets of the same seed; every kind of emitter credited to its own set."""

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, encoding, light_sets, rays, tracer
from hhd_lightmapper.core.errors import BakeError
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.scene import AreaLight, BakeScene, PointLight, SunLight, light_set_names
from scenekit import meshes


def room_points():
    """A floor in an open box with a pillar: shadows, bounces and every kind of emitter."""
    v, f = meshes.plane(2.0)
    v = v - [1.0, 1.0, 0.0]
    surface = _floor_surface()
    pillar_v, pillar_f = meshes.cube(1.0, centre=(0.0, 0.0, 0.5))
    lamp_v, lamp_f = meshes.plane(0.4)
    tris = np.concatenate([v[f], (pillar_v * [0.3, 0.3, 1.0])[pillar_f], (lamp_v + [0.6, -0.6, 1.2])[lamp_f]])
    return bakepoints.build(surface, 64, 64, occluders=rays.RayScene(tris)), tris


def scene_with_groups(tris, groups=("Lamp", "Sun", "", "Glow")):
    """A point lamp, a sun, an area light and an emissive quad, each in the given light group,
    and a constant world in the area light's group."""
    emission = np.zeros((len(tris), 3))
    emission[-2:] = [4.0, 3.0, 2.0]
    return BakeScene(
        tris,
        np.full((len(tris), 3), 0.6),
        emission=emission,
        emission_group=np.array([""] * (len(tris) - 2) + [groups[3]] * 2),
        lights=[
            PointLight(np.array([-0.7, 0.5, 1.0]), np.array([30.0, 20.0, 10.0]), radius=0.1, group=groups[0]),
            SunLight(np.array([0.5, 0.1, 0.86]), np.array([1.0, 2.0, 3.0]), group=groups[1]),
            AreaLight(
                np.array([0.0, 0.8, 1.5]),
                np.array([0.2, 0, 0]),
                np.array([0, 0.2, 0]),
                np.array([0, 0, -1.0]),
                np.array([20.0, 20.0, 20.0]),
                group=groups[2],
            ),
        ],
        world=np.array([0.1, 0.2, 0.3]),
        world_group=groups[2],
    )


@pytest.fixture(scope="module")
def baked():
    points, tris = room_points()
    scene = scene_with_groups(tris)
    settings = tracer.BakeSettings(samples=32, pass_samples=4, bounces=2, seed=3)
    with_sets = tracer.bake(points, scene, settings)
    without = tracer.bake(
        points, scene, tracer.BakeSettings(samples=32, pass_samples=4, bounces=2, seed=3, light_sets=False)
    )
    return points, tris, with_sets, without


def test_sets_are_the_light_groups_in_use_and_ungrouped_emitters_form_the_default_set(baked):
    _, _, with_sets, without = baked
    assert with_sets.sets == ("Default", "Glow", "Lamp", "Sun")
    assert with_sets.set_sh.shape == (4, *with_sets.sh.shape)
    assert without.sets == () and without.set_sh is None
    assert light_set_names(["", ""]) == ()
    assert light_set_names(["A", ""]) == ("A", "Default")


def test_the_sets_sum_to_the_bake_without_sets_of_the_same_seed(baked):
    _, _, with_sets, without = baked
    np.testing.assert_allclose(with_sets.set_sh.sum(axis=0), without.sh, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(with_sets.sh, without.sh, rtol=1e-9, atol=1e-12)
    assert with_sets.rays == without.rays  # K sets cost one bake's rays
    assert np.all(with_sets.texel_samples == without.texel_samples)


def test_each_set_holds_only_its_own_emitters_light(baked):
    """Bake each light alone (the others removed): each set's SH is that bake's, statistically;
    the delta sun, unshadowed where it lands, exactly at the texels only it can light."""
    points, tris, with_sets, _ = baked
    full = scene_with_groups(tris)
    settings = tracer.BakeSettings(samples=32, pass_samples=4, bounces=2, seed=3)
    for k, name in enumerate(with_sets.sets):
        alone = scene_with_groups(tris)
        keep = {"Lamp": [0], "Sun": [1], "Default": [2], "Glow": []}[name]
        alone.lights = [full.lights[i] for i in keep]
        if name != "Glow":
            alone.emission = None
        if name != "Default":
            alone.world = None
        single = tracer.bake(points, alone, settings)
        got, want = with_sets.set_sh[k][:, 0], single.sh[:, 0]
        error = np.sqrt(with_sets.set_sh_error[k][:, 0] ** 2 + single.sh_error[:, 0] ** 2)
        # the per-texel difference of two independent estimates, in units of its standard error
        z = (got - want) / np.maximum(error, 1e-12)
        assert np.abs(np.mean(got - want)) <= 4 * np.sqrt(np.mean(error**2) / got.size) + 1e-9, name
        assert np.mean(np.abs(z) < 4) > 0.97, name
        assert got.mean() > 0.0, name


def test_a_scene_without_light_groups_is_an_ordinary_bake():
    points, tris = room_points()
    scene = scene_with_groups(tris, groups=("", "", "", ""))
    result = tracer.bake(points, scene, tracer.BakeSettings(samples=16, bounces=1))
    assert result.sets == () and result.set_sh is None and result.sh.shape[2] == 3


def test_weights_are_checked():
    names = ("A", "Default")
    np.testing.assert_array_equal(light_sets.weight_array(names, {"A": 0.5}), [[0.5] * 3, [1.0] * 3])
    np.testing.assert_array_equal(light_sets.weight_array(names, {"A": (1, 0, 2)})[0], [1, 0, 2])
    for bad in ({"B": 1.0}, {"A": -1.0}, {"A": float("nan")}):
        with pytest.raises(BakeError):
            light_sets.weight_array(names, bad)


def read_iz(path):
    channels, _ = exr.read(path)
    return np.stack([channels[f"Iz.{c}"] for c in "RGB"], axis=-1).astype(np.float64)


@pytest.fixture(scope="module")
def baked_files(tmp_path_factory):
    """A bake of the room with its four light sets, written by the pipeline (denoiser off)."""
    points, tris = room_points()
    folder = tmp_path_factory.mktemp("sets")
    atlas = bake.AtlasInput("Lightmap", 64, 64, _floor_surface(), ["floor"])
    settings = bake.PipelineSettings(trace=tracer.BakeSettings(samples=16, bounces=1, seed=1))
    bake.run([atlas], scene_with_groups(tris), settings, folder)
    return lightmap_files.AtlasFiles(folder, "Lightmap")


def _floor_surface():
    v, f = meshes.plane(2.0)
    v = v - [1.0, 1.0, 0.0]
    uv = (v[f][:, :, :2] + 1.0) * 0.45 + 0.05
    return bakepoints.SurfaceTriangles(
        v[f], np.tile([0, 0, 1.0], (2, 3, 1)), uv, np.zeros(2, int), np.full((2, 3), 0.5)
    )


def test_a_bake_writes_each_set_as_an_ordinary_atlas_listed_in_the_sidecar(baked_files):
    files = baked_files
    sidecar = lightmap_files.read_sidecar(files.sidecar)
    assert [s["name"] for s in sidecar["light_sets"]] == ["Default", "Glow", "Lamp", "Sun"]
    sets = files.light_sets(sidecar)
    assert [f.name for f in sets] == ["Lightmap.Default", "Lightmap.Glow", "Lightmap.Lamp", "Lightmap.Sun"]
    for f in sets:
        doc = lightmap_files.read_sidecar(f.sidecar)
        assert doc["light_set"] == {"name": f.name.split(".")[1], "of": "Lightmap"}
        assert f.hhd.is_file() and f.sh.is_file() and f.texels.is_file() and f.preview_image("iz").is_file()
    # I_z is linear in the SH: the sets' I_z sum to the atlas's (half floats; negative I_z of
    # noisy texels is clamped per set)
    total = sum(read_iz(f.hhd) for f in sets)
    main = read_iz(files.hhd)
    assert np.abs(total - main).mean() <= 2e-3 * main.mean()


def test_blend_writes_the_blended_state_and_reencode_restores_the_sum(baked_files):
    files = baked_files
    sets = files.light_sets(lightmap_files.read_sidecar(files.sidecar))
    main_before = read_iz(files.hhd)
    record = light_sets.blend_atlas(files, {"Lamp": 1.0, "Sun": 0.0, "Default": (0.0, 0.0, 0.0), "Glow": 0.0})
    assert record["weights"]["Lamp"] == [1.0, 1.0, 1.0]
    lamp = read_iz(sets[2].hhd)
    np.testing.assert_allclose(read_iz(files.hhd), lamp, rtol=2e-3, atol=1e-3 * lamp.mean())
    assert lightmap_files.read_sidecar(files.sidecar)["blend"] == record
    light_sets.blend_atlas(files, {"Lamp": 2.0})  # the others weigh 1
    want = main_before + read_iz(sets[2].hhd)
    assert np.abs(read_iz(files.hhd) - want).mean() <= 3e-3 * want.mean()
    bake.reencode(files, encoding.EncoderSettings())
    assert "blend" not in lightmap_files.read_sidecar(files.sidecar)
    np.testing.assert_array_equal(read_iz(files.hhd), main_before)
    with pytest.raises(BakeError, match="unknown light set"):
        light_sets.blend_atlas(files, {"Nope": 1.0})
