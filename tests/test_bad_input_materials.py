"""The bake reads material node trees and lights honestly (issue 53, "never silently wrong"):
the node-tree evaluation of bridge/materials.py (Mix/Add Shader, textures on emission, the
shaders it approximates, each with a note naming the material), negative lights and emission
refused by name, non-finite or absurd values refused, and a receiver whose modifiers leave no
faces named in a warning. Tiny scenes: the evaluator checks bake nothing; the bakes are 32²
texels at a few samples."""

import hashlib
import math
import re

import numpy as np
import pytest

from hhd_lightmapper import blender_compat, cli
from hhd_lightmapper.bridge import materials, scene_data
from hhd_lightmapper.core.bakepoints import data as bakepoint_data
from hhd_lightmapper.core.errors import BakeError
from scenekit import blender as kit

pytestmark = pytest.mark.bpy

#: texels per metre of the receivers: the 2 m floor is about 32 texels across
DENSITY = 16.0
FLT_MAX = 3.4028234663852886e38


def new_material(name):
    import bpy

    mat = bpy.data.materials.new(name)
    blender_compat.ensure_node_tree(mat)
    return mat


def shader(mat, kind, **inputs):
    """A new node of `kind` in `mat` with its inputs set (colours as RGB)."""
    node = mat.node_tree.nodes.new(kind)
    for name, value in inputs.items():
        socket = node.inputs[name]
        socket.default_value = (*value, 1.0) if isinstance(value, tuple) else value
    return node


def to_output(mat, node):
    """Link `node`'s first output to the Surface of the material's output."""
    tree = mat.node_tree
    tree.links.new(node.outputs[0], materials.output_node(mat).inputs["Surface"])


def mix(mat, fac, a, b):
    node = mat.node_tree.nodes.new("ShaderNodeMixShader")
    node.inputs[0].default_value = fac
    mat.node_tree.links.new(a.outputs[0], node.inputs[1])
    mat.node_tree.links.new(b.outputs[0], node.inputs[2])
    return node


def image(name, rgb, size=4):
    """A float image of one linear colour."""
    import bpy

    img = bpy.data.images.new(name, size, size, float_buffer=True)
    img.pixels.foreach_set(np.tile([*rgb, 1.0], size * size).astype(np.float32))
    return img


# the evaluator, on node setups (no bake) -----------------------------------------------------------


@pytest.fixture
def empty(extension):
    kit.clear_scene()


def test_mix_shader_is_the_weighted_sum_of_its_single_shader_twins(empty):
    red, light = (0.9, 0.1, 0.05), (1.0, 0.8, 0.5)
    diffuse_only, emission_only, mixed = (new_material(n) for n in ("Diffuse", "Emission", "Mixed"))
    to_output(diffuse_only, shader(diffuse_only, "ShaderNodeBsdfDiffuse", Color=red))
    to_output(emission_only, shader(emission_only, "ShaderNodeEmission", Color=light, Strength=6.0))
    d = shader(mixed, "ShaderNodeBsdfDiffuse", Color=red)
    e = shader(mixed, "ShaderNodeEmission", Color=light, Strength=6.0)
    to_output(mixed, mix(mixed, 0.5, d, e))
    a, b, m = (materials.evaluate(x) for x in (diffuse_only, emission_only, mixed))
    assert np.allclose(a.albedo.constant, red, atol=1e-6) and not a.emission.constant.any()
    assert np.allclose(b.emission.constant, 6.0 * np.array(light), atol=1e-5) and not b.albedo.constant.any()
    assert np.allclose(m.albedo.constant, 0.5 * a.albedo.constant)
    assert np.allclose(m.emission.constant, 0.5 * b.emission.constant)
    assert m.notes == []  # nothing approximated


def test_add_shader_sums_and_clamps_the_albedo_with_a_note(empty):
    mat = new_material("Added")
    a = shader(mat, "ShaderNodeBsdfDiffuse", Color=(0.8, 0.5, 0.1))
    b = shader(mat, "ShaderNodeBsdfDiffuse", Color=(0.6, 0.2, 0.1))
    add = mat.node_tree.nodes.new("ShaderNodeAddShader")
    mat.node_tree.links.new(a.outputs[0], add.inputs[0])
    mat.node_tree.links.new(b.outputs[0], add.inputs[1])
    to_output(mat, add)
    s = materials.evaluate(mat)
    assert np.allclose(s.albedo.constant, (1.0, 0.7, 0.2), atol=1e-6)
    assert any("material 'Added'" in n and "clamped" in n and "Add Shader" in n for n in s.notes), s.notes


def test_reroutes_rgb_and_value_nodes_are_read_and_a_linked_fac_takes_its_value_with_a_note(empty):
    mat = new_material("Routed")
    tree = mat.node_tree
    rgb = tree.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (0.2, 0.4, 0.6, 1.0)
    reroute = tree.nodes.new("NodeReroute")
    d = shader(mat, "ShaderNodeBsdfDiffuse")
    tree.links.new(rgb.outputs[0], reroute.inputs[0])
    tree.links.new(reroute.outputs[0], d.inputs["Color"])
    e = shader(mat, "ShaderNodeEmission", Color=(1.0, 1.0, 1.0))
    value = tree.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = 3.0
    tree.links.new(value.outputs[0], e.inputs["Strength"])
    m = mix(mat, 0.25, d, e)
    noise = tree.nodes.new("ShaderNodeTexNoise")
    tree.links.new(noise.outputs[0], m.inputs[0])
    to_output(mat, m)
    s = materials.evaluate(mat)
    assert np.allclose(s.albedo.constant, 0.75 * np.array([0.2, 0.4, 0.6]), atol=1e-6)
    assert np.allclose(s.emission.constant, 0.25 * 3.0, atol=1e-6)
    (note,) = s.notes
    assert note.startswith("material 'Routed': ") and "Noise Texture" in note and "0.25" in note


def test_a_textured_albedo_mixed_with_a_constant_is_the_weighted_texture(empty):
    """Mix Shader (Fac 0.25) of a Principled BSDF with an image Base Color and a blue Diffuse:
    the albedo texture the bake samples is 0.75 × image + 0.25 × blue."""
    mat = new_material("Mixed texture")
    tree = mat.node_tree
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image("grey", (0.4, 0.5, 0.6))
    bsdf = tree.nodes["Principled BSDF"]
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    blue = shader(mat, "ShaderNodeBsdfDiffuse", Color=(0.0, 0.0, 1.0))
    to_output(mat, mix(mat, 0.25, bsdf, blue))
    cache, notes = materials.TextureCache(), []
    _constant, index, uv_map = materials.albedo_of(mat, cache, notes)
    assert index >= 0 and uv_map == "" and notes == []
    expected = 0.75 * np.array([0.4, 0.5, 0.6]) + 0.25 * np.array([0.0, 0.0, 1.0])
    assert np.allclose(cache.images[index].pixels, expected, atol=1e-6)


def test_unlinked_output_is_black_with_a_note_as_cycles_renders_it(empty):
    mat = new_material("Unlinked")
    tree = mat.node_tree
    tree.nodes["Principled BSDF"].inputs["Emission Strength"].default_value = 5.0
    for link in list(materials.output_node(mat).inputs["Surface"].links):
        tree.links.remove(link)
    s = materials.evaluate(mat)
    assert not s.albedo.constant.any() and s.emission.is_zero
    (note,) = s.notes
    assert note.startswith("material 'Unlinked': nothing is linked to the Surface") and "black" in note


def test_no_material_is_cycles_default_grey():
    s = materials.evaluate(None)
    assert np.allclose(s.albedo.constant, 0.8) and s.emission.is_zero and s.notes == []


@pytest.mark.parametrize(
    "kind, albedo",
    [("ShaderNodeBsdfGlossy", 0.0), ("ShaderNodeBsdfTranslucent", 0.0), ("ShaderNodeSubsurfaceScattering", 0.5)],
)
def test_a_shader_the_bake_approximates_is_named_in_a_note(empty, kind, albedo):
    mat = new_material("Odd")
    node = shader(mat, kind, Color=(0.5, 0.5, 0.5))
    to_output(mat, node)
    s = materials.evaluate(mat)
    assert np.allclose(s.albedo.constant, albedo, atol=1e-6)
    (note,) = s.notes
    assert note.startswith("material 'Odd': ") and node.bl_label in note


def test_a_colour_from_a_node_the_bake_does_not_evaluate_falls_back_to_the_viewport_colour(empty):
    mat = new_material("Mixed colour")
    mat.diffuse_color = (0.3, 0.2, 0.1, 1.0)
    tree = mat.node_tree
    checker = tree.nodes.new("ShaderNodeTexChecker")
    tree.links.new(checker.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    s = materials.evaluate(mat)
    assert np.allclose(s.albedo.constant, (0.3, 0.2, 0.1), atol=1e-6)
    (note,) = s.notes
    assert "'Mixed colour'" in note and "Checker Texture" in note and "Viewport Display" in note


def test_negative_and_absurd_emission_are_refused_by_name(empty):
    mat = new_material("Dark lamp")
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Emission Strength"].default_value = -10.0
    with pytest.raises(BakeError, match=r"material 'Dark lamp'.*negative emission.*cannot subtract light"):
        materials.evaluate(mat)
    bsdf.inputs["Emission Strength"].default_value = math.inf  # Blender stores FLT_MAX
    assert bsdf.inputs["Emission Strength"].default_value == pytest.approx(FLT_MAX)
    with pytest.raises(BakeError, match=r"material 'Dark lamp': Emission Strength .* 3\.4\d*e\+38"):
        materials.evaluate(mat)
    with pytest.raises(BakeError, match="light 'x': its power is nan"):
        materials.checked([1.0, math.nan], "light 'x': its power")


# read from the scene and baked -------------------------------------------------------------------


def emitter(name, mat, z=1.0):
    return kit.plane(name, (0, 0, z), 0.8, mat, rotation=(math.pi, 0, 0))


@pytest.mark.cycles
def test_an_emission_texture_lights_the_receiver_in_its_colour(empty, monkeypatch):
    """A Principled BSDF whose Emission Color is a red image emits the image's colour (each
    triangle the mean over its UV footprint; a note says so), not the socket's white: the lit
    floor's colour matches its constant-red twin's, and Cycles'."""
    import bpy

    import cycles_compare as cc

    monkeypatch.setattr(bakepoint_data, "FOOTPRINT", cc.cycles_footprint())  # Cycles' texel footprint
    floor = kit.plane("Floor", (0, 0, 0), 2.0, kit.material("Floor"))
    red = (0.9, 0.15, 0.05)
    textured = kit.material("Textured lamp", (0.0, 0.0, 0.0), emission=(1.0, 1.0, 1.0, 8.0))
    tex = textured.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image("red", red)
    textured.node_tree.links.new(
        tex.outputs["Color"], textured.node_tree.nodes["Principled BSDF"].inputs["Emission Color"]
    )
    lamp = emitter("Lamp", textured)
    kit.unwrap([floor], DENSITY)

    depsgraph = bpy.context.evaluated_depsgraph_get()
    read = scene_data.read_bake_scene(depsgraph)
    assert np.allclose(read.emission.max(axis=0), 8.0 * np.array(red), rtol=1e-5)
    assert any("'Textured lamp'" in n and "averaged per triangle" in n for n in read.notes), read.notes

    points, textured_iz, _ = cc.ours([floor], samples=16, bounces=0, seed=1)
    lamp.data.materials[0] = kit.material("Red lamp", (0.0, 0.0, 0.0), emission=(*red, 8.0))
    _, constant_iz, _ = cc.ours([floor], samples=16, bounces=0, seed=1)
    lit = constant_iz[:, 0] > 0.1 * constant_iz[:, 0].max()
    assert lit.sum() > 100
    ratio = textured_iz[lit].sum(0) / constant_iz[lit].sum(0)
    assert np.allclose(ratio, 1.0, rtol=1e-6), ratio  # same emission, same seed: the same bake
    colour = textured_iz[lit].sum(0) / textured_iz[lit, 0].sum()
    assert np.allclose(colour, np.array(red) / red[0], rtol=1e-6), colour  # red, not white

    lamp.data.materials[0] = textured
    r = cc.compare([floor], samples=16, bounces=0, cycles_samples=16)
    assert r["mean"] > 0.1
    cycles_colour = r["cycles"].mean(0) / r["cycles"][:, 0].mean()
    assert np.allclose(cycles_colour, np.array(red) / red[0], atol=0.01), cycles_colour
    cc.assert_agree(r, allowance=0.02)


@pytest.fixture
def saved_scene(extension, restore_hhd_settings, tmp_path):
    """Floor + Cube receivers under a sun, unwrapped at DENSITY, saved as tmp_path/scene.blend,
    the bake settings tiny (4 samples, 1 bounce, no denoise)."""
    import bpy

    scene = kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 2.0, kit.material("Floor"))
    cube = kit.box("Cube", (0, 0, 0.3), (0.4, 0.4, 0.4), kit.material("Box", (0.6, 0.5, 0.4)))
    kit.light('SUN', rotation=(0.5, 0.2, 0), energy=3.0, name="Sun")
    scene.hhd.samples, scene.hhd.bounces, scene.hhd.denoise = 4, 1, False
    kit.unwrap([floor, cube], DENSITY)
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    return blend


def bake_args(out):
    return ("bake", "--out", str(out), "--objects", "Floor", "Cube", "--threads", "2")


def digest(folder) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def resave(blend, change):
    """Open `blend`, apply `change()` and save it back."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    change(bpy.data)
    bpy.ops.wm.save_mainfile()


def test_absurd_light_power_is_refused_and_the_previous_files_stay(saved_scene, cli_run, tmp_path):
    out = tmp_path / "lightmaps"
    first = cli_run(saved_scene, *bake_args(out))
    assert first.returncode == cli.EXIT_OK, first.stderr
    before = digest(out)
    assert before

    def lamp(power):
        def change(data):
            data.lights["Sun"].energy = power

        return change

    # a light's energy keeps inf (a material's sockets store FLT_MAX): both are refused
    for power, shown in ((math.inf, r"is (inf|3\.4\d*e\+38)"), (FLT_MAX, r"is 3\.4\d*e\+38"), (1e31, r"is 1e\+31")):
        resave(saved_scene, lamp(power))
        refused = cli_run(saved_scene, *bake_args(out))
        assert refused.returncode == cli.EXIT_INPUT == 1, refused.stdout
        assert "light 'Sun': its strength is" in refused.stderr and re.search(shown, refused.stderr)
        assert digest(out) == before


@pytest.mark.parametrize("what", ["lamp", "emission"])
def test_negative_light_is_refused_naming_it(saved_scene, cli_run, tmp_path, what):
    import bpy

    def change(data):
        if what == "lamp":
            lamp = data.lights.new("Lamp", 'POINT')
            lamp.energy = -200.0
            obj = data.objects.new("Lamp", lamp)
            obj.location = (0, 0, 1.5)
            bpy.context.scene.collection.objects.link(obj)
        else:
            mat = kit.material("Dark", (0.0, 0.0, 0.0), emission=(1.0, 1.0, 1.0, -10.0))
            emitter("Dark panel", mat, z=1.5)

    resave(saved_scene, change)
    refused = cli_run(saved_scene, *bake_args(tmp_path / "out"))
    assert refused.returncode == cli.EXIT_INPUT, refused.stdout
    expected = (
        "light 'Lamp' has a negative power (-200 W): the bake cannot subtract light"
        if what == "lamp"
        else "material 'Dark': 'Principled BSDF' has a negative emission (Emission Strength -10)"
    )
    assert expected in refused.stderr, refused.stderr
    assert not (tmp_path / "out").exists()


def test_a_receiver_whose_modifiers_leave_no_faces_is_named_in_a_warning(saved_scene, cli_run, tmp_path):
    def change(data):
        weld = data.objects["Cube"].modifiers.new("Weld everything", 'WELD')
        weld.merge_threshold = 10.0  # every vertex into one: no face left

    resave(saved_scene, change)
    out = tmp_path / "out"
    run = cli_run(saved_scene, *bake_args(out))
    assert run.returncode == cli.EXIT_OK, run.stderr
    assert "warning: 'Cube': its modifiers leave no faces; nothing baked for it, its texels stay empty" in run.stdout
    assert (out / "Lightmap_hhd.exr").is_file()
