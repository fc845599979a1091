"""Light sets in Blender: the scene's list of sets keeps its weights when synced, and the EEVEE
live blend (Show Preview of an atlas baked with light sets) renders what numpy computes,
`core.light_sets.blend` of the sets' sampled texels followed by `core.hhd.reconstruct` at the
shading normal, at weights that come from keyframes (frame 1, then frame 2).

No tracing: two sets' radiance SH over a plane are written by hand (a hemisphere sky plus a sun
whose direction drifts across the atlas, the two suns on opposite sides), encoded and written as
the bake writes them (`encode_atlas`, `write_atlas`) to `Lightmap.<set>`, and the atlas's own
files (their sum) get a sidecar listing the sets.

Tolerance: that of tests/test_preview_eevee.py, for the same reasons (half-float film and
read-back inputs, the GPU's 8-bit bilinear weights moving a pixel by up to 1/256 of the spread of
the result over the 2×2 texels the lookup blends, here the spread of the whole blend evaluated
at each texel); the blend adds float32 arithmetic in the shader (relative ~1e-6, also in the
closed-form solve's p − √disc, whose cancellation costs at most ~1e-6 × I_z) and nothing the
tolerance has to absorb. So 99% of pixels within 1% + 2% of the spread, none beyond 5%, the
median within 0.3%. Measured (bpy 5.3): median 0.07%, p99 1.0%, max 1.8% at frame 1; median
0.04%, max 0.4% at frame 2. The wrong blends differ from the right one on these texels by a
median of 2–4% (p99 23–97%): the parameter blend the talk warns against, and the sum of the
sets' reconstructed irradiances (what a blend that skipped the solve back to HHD would show).
"""

import importlib
import json

import numpy as np
import pytest

from hhd_lightmapper.core import encoding, hhd, light_sets, sh
from hhd_lightmapper.core.files import exr
from hhd_lightmapper.core.files.lightmap_files import AtlasFiles, write_atlas
from scenekit import blender as kit
from test_preview_eevee import normal_mapped_material, read_rgb, render, render_inputs, texel_corners, unit

pytestmark = [pytest.mark.bpy, pytest.mark.eevee]
ATLAS = "Lightmap"  # bridge.bake_session.DEFAULT_ATLAS: the atlas of objects never unwrapped
SETS = ("Lamp", "Sky")
RES = 32
#: {frame: {set: RGB weight}}: both sets keyed at both frames
WEIGHTS = {
    1: {"Lamp": (1.0, 0.8, 0.6), "Sky": (0.25, 0.25, 0.25)},
    2: {"Lamp": (0.2, 0.4, 1.0), "Sky": (1.5, 1.0, 0.5)},
}


def bridge_sets(extension):
    """The installed extension's bpy side of light sets (`bridge.light_sets`)."""
    return importlib.import_module(f"{extension}.bridge.light_sets")


def set_sh(name: str) -> np.ndarray:
    """Hemisphere-sampled radiance SH `(RES, RES, 9, 3)` of set `name` over a floor (n_v = +z):
    a hemisphere sky of constant radiance plus a sun whose direction drifts across the atlas."""
    u, v = np.meshgrid((np.arange(RES) + 0.5) / RES, (np.arange(RES) + 0.5) / RES)
    if name == "Lamp":  # warm sun, elevation 70° → 25° along u, azimuth 30°
        theta, phi = np.radians(20 + 45 * u), np.full_like(u, np.radians(30))
        sun, sky = np.array([3.0, 2.2, 1.4]), np.array([0.05, 0.06, 0.08])
    else:  # blue light from the other side, azimuth 150° → 210° along v
        theta, phi = np.full_like(u, np.radians(60)), np.radians(150 + 60 * v)
        sun, sky = np.array([0.4, 0.7, 1.5]), np.array([0.3, 0.35, 0.5])
    d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    hemisphere = np.zeros(9)
    hemisphere[0], hemisphere[2] = np.sqrt(np.pi), np.sqrt(3 * np.pi) / 2  # radiance 1 over z > 0
    out = np.pi * sh.evaluate(d)[:, :, None] * sun + hemisphere[None, :, None] * sky
    return out.reshape(RES, RES, 9, 3)


def write_files(folder, name, sh_image, sidecar, ambient="luminance"):
    """Encode (HHD, searched direction, w_a per `ambient`) and write one atlas's files as a bake does."""
    data = encoding.TexelData(
        sh=sh_image.astype(np.float32),
        normal=np.broadcast_to(np.float32([0, 0, 1]), (RES, RES, 3)).copy(),
        coverage=np.ones((RES, RES), np.float32),
    )
    encoded = encoding.encode_atlas(data, encoding.for_settings(encoding.EncoderSettings(ambient=ambient)))
    with exr.Staging() as staging:
        write_atlas(staging, AtlasFiles(folder, name), encoded, sidecar)
        staging.commit()


@pytest.fixture(params=["luminance"])
def light_set_files(request, extension, restore_hhd_settings, tmp_path):
    """A normal-mapped 2 m floor whose lightmap UVs are its own 0–1 UVs, the files of its atlas
    baked with light sets SETS in tmp_path/lightmaps (w_a encoded as the param says:
    'luminance' or 'rgb'), the output folder pointing there."""
    import bpy

    scene = kit.clear_scene()
    scene.hhd.light_sets.clear()
    floor = kit.plane("Floor", (0, 0, 0), 2, normal_mapped_material("Floor"))
    floor.data.uv_layers.new(name=kit.LAYER)  # a copy of the plane's 0–1 UVs
    folder = tmp_path / "lightmaps"
    per_set = {name: set_sh(name) for name in SETS}
    entries = []
    for name in SETS:
        set_atlas = light_sets.set_atlas_name(ATLAS, name)
        write_files(folder, set_atlas, per_set[name], {"light_set": {"name": name, "of": ATLAS}}, request.param)
        entries.append({"name": name, "atlas": set_atlas})
    write_files(folder, ATLAS, sum(per_set.values()), {"light_sets": entries}, request.param)
    scene.hhd.output_dir = str(folder)
    kit.select([floor])
    yield scene, floor, folder
    scene.hhd.light_sets.clear()
    bpy.context.scene.frame_set(1)


def test_sync_keeps_weights_and_order(extension):
    import bpy

    sync = bridge_sets(extension).sync_light_sets
    scene = bpy.context.scene
    scene.hhd.light_sets.clear()
    assert sync(scene, ["Lamp", "Default"]) == ["Lamp", "Default"]
    scene.hhd.light_sets["Lamp"].weight = (0.5, 0.25, 0.0)
    assert sync(scene, ["Default", "Lamp", "Sun"]) == ["Sun"]
    items = scene.hhd.light_sets
    assert [i.name for i in items] == ["Lamp", "Default", "Sun"]  # appended only: keyframes address items by index
    assert tuple(items["Lamp"].weight) == (0.5, 0.25, 0.0)
    assert tuple(items["Sun"].weight) == tuple(items["Default"].weight) == (1.0, 1.0, 1.0)
    path = bridge_sets(extension).weight_path("Lamp")
    assert scene.path_resolve(path)[:] == items["Lamp"].weight[:]  # what the blend group's attributes read
    scene.hhd.light_sets.clear()


def test_refresh_reads_the_sets_of_the_sidecars(light_set_files):
    import bpy

    scene, _, folder = light_set_files
    assert json.loads((folder / f"{ATLAS}.json").read_text())["light_sets"][0]["name"] == "Lamp"
    scene.hhd.light_sets.add().name = "Sky"
    scene.hhd.light_sets["Sky"].weight = (0.1, 0.2, 0.3)
    assert bpy.ops.hhd.refresh_light_sets() == {'FINISHED'}
    assert [i.name for i in scene.hhd.light_sets] == ["Sky", "Lamp"]
    assert tuple(scene.hhd.light_sets["Sky"].weight) == pytest.approx((0.1, 0.2, 0.3))


def test_show_inserts_the_live_blend_and_hide_restores(light_set_files):
    import bpy

    from test_preview_eevee import tree_state

    scene, floor, _ = light_set_files
    mat = floor.material_slots[0].material
    before = tree_state(mat)
    scene.hhd.preview_mode = 'HHD'
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    assert [i.name for i in scene.hhd.light_sets] == list(SETS)  # Show lists the sets it blends
    group = next(n for n in mat.node_tree.nodes if n.type == 'GROUP')
    assert group.node_tree.name == "HHD Light Set Blend ×2"
    weights = [n for n in mat.node_tree.nodes if n.type == 'ATTRIBUTE' and n.attribute_type == 'VIEW_LAYER']
    assert sorted(n.attribute_name for n in weights) == [f'hhd.light_sets["{s}"].weight' for s in SETS]
    assert group.inputs["Iz 2"].links[0].from_node.image.filepath.endswith("Lightmap.Sky_preview/iz.exr")
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert tree_state(mat) == before


def camera_and_film(scene):
    """An orthographic camera over the middle 1.6 m of the floor (lightmap UV 0.1–0.9), EEVEE
    with one sample and no pixel filter (inputs and output at one point), a float EXR film."""
    import bpy

    from hhd_lightmapper import blender_compat

    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.data.type, cam.data.ortho_scale = 'ORTHO', 1.6
    cam.location = (0.0, 0.0, 3.0)
    scene.camera = cam
    scene.render.engine = blender_compat.eevee_engine()
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.resolution_percentage = 100
    scene.render.filter_size = 0.0
    scene.eevee.taa_render_samples = 1
    scene.view_settings.view_transform = 'Standard'
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth = 'OPEN_EXR', '32'


def key_weights(scene):
    """Keyframe every set's weight at each frame of WEIGHTS; then zero them, so only the
    animation can give the renders their weights."""
    for frame, weights in WEIGHTS.items():
        for name, weight in weights.items():
            item = scene.hhd.light_sets[name]
            item.weight = weight
            item.keyframe_insert("weight", frame=frame)
    for item in scene.hhd.light_sets:
        item.weight = (0.0, 0.0, 0.0)


def blend_at(images: dict, weights: dict, n, nv, rgb: bool = False):
    """numpy's irradiance: the sets' sampled HHD (iz, wa: its one channel, or RGB with `rgb`,
    dir: the blend of unit vectors, renormalised, per set) blended by `core.light_sets.blend`, reconstructed at the shading
    normals n."""
    params = [
        hhd.HHDParams(
            images[s]["iz"],
            images[s]["wa"] if rgb else images[s]["wa"][:, 0],
            unit(images[s]["dir"]),
        )
        for s in SETS
    ]
    blended = light_sets.blend(params, nv, light_sets.weight_array(SETS, weights))
    return hhd.reconstruct(blended, nv, n)


@pytest.mark.slow
@pytest.mark.parametrize("light_set_files", ["luminance", "rgb"], indirect=True)
def test_eevee_live_blend_equals_numpy_at_keyframed_weights(light_set_files, tmp_path):
    """Per ambient mode: in 'rgb' the group blends each channel's w_a as core.hhd.to_linear_sh does."""
    import bpy

    scene, floor, folder = light_set_files
    scene.hhd.preview_mode = 'HHD'
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    key_weights(scene)
    camera_and_film(scene)
    scene.frame_set(1)
    inputs = render_inputs(scene, floor.material_slots[0].material, tmp_path)
    scene.frame_set(2)
    rendered = {1: inputs["radiance"], 2: render(scene, tmp_path / "frame2.exr")}
    luv, albedo = inputs["luv"][:, :2], inputs["albedo"]
    n, nv = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in (inputs["n"], inputs["nv"]))
    files = {
        s: {
            k: read_rgb(folder / f"{light_sets.set_atlas_name(ATLAS, s)}_preview" / f"{k}.exr")
            for k in ("iz", "wa", "dir")
        }
        for s in SETS
    }
    from hhd_lightmapper.core.textures import sample_bilinear

    rgb = json.loads((folder / f"{ATLAS}.json").read_text())["encoder"]["ambient"] == "rgb"
    sampled = {s: {k: sample_bilinear(v, luv, clamp=True) for k, v in f.items()} for s, f in files.items()}
    corners = {s: texel_corners(f, luv) for s, f in files.items()}
    stats = {}
    for frame, weights in WEIGHTS.items():
        expected = albedo * blend_at(sampled, weights, n, nv, rgb)
        # what the GPU's 8-bit bilinear weights can move: the spread of the blend over the 2×2 texels
        at_corners = np.stack(
            [
                albedo * blend_at({s: {k: v[c] for k, v in corners[s].items()} for s in SETS}, weights, n, nv, rgb)
                for c in range(4)
            ]
        )
        contrast = at_corners.max(axis=0) - at_corners.min(axis=0)
        error = np.abs(rendered[frame] - expected)
        relative = error / np.maximum(expected, 1e-6)
        stats[frame] = (float(np.median(relative)), float(np.quantile(relative, 0.99)), float(relative.max()))
        assert (error <= 0.01 * expected + 0.02 * contrast + 1e-5).mean() > 0.99, (frame, stats[frame])
        assert stats[frame][0] < 3e-3 and stats[frame][2] < 0.05, (frame, stats[frame])
    # the animation really changed the lighting, and the normal map is really in play
    change = np.abs(rendered[2] - rendered[1]) / np.maximum(rendered[1], 1e-6)
    assert np.median(change) > 0.2, np.median(change)
    assert np.degrees(np.arccos(np.clip(np.einsum("pi,pi->p", n, nv), -1, 1))).max() > 20.0
    print("relative error (median, p99, max) per frame:", stats)


def test_blend_operator_writes_the_blend_into_the_atlas(light_set_files):
    """Blend: the atlas's own files become core.light_sets.blend_atlas of the sets at the
    scene's weights (recorded in its sidecar)."""
    import bpy

    scene, _, folder = light_set_files
    assert bpy.ops.hhd.refresh_light_sets() == {'FINISHED'}
    scene.hhd.light_sets["Sky"].weight = (0.0, 0.5, 1.0)
    before = read_rgb(folder / f"{ATLAS}_preview" / "iz.exr")
    assert bpy.ops.hhd.blend_light_sets() == {'FINISHED'}
    sidecar = json.loads((folder / f"{ATLAS}.json").read_text())
    assert sidecar["blend"]["weights"] == {"Lamp": [1.0, 1.0, 1.0], "Sky": [0.0, 0.5, 1.0]}
    after = read_rgb(folder / f"{ATLAS}_preview" / "iz.exr")
    sky = read_rgb(folder / f"{light_sets.set_atlas_name(ATLAS, 'Sky')}_preview" / "iz.exr")
    # I_z adds exactly through linear SH: the blue sky's R dropped out, its B stayed
    assert np.allclose(after[..., 0], before[..., 0] - sky[..., 0], rtol=2e-3, atol=1e-4)
    assert np.allclose(after[..., 2], before[..., 2], rtol=2e-3, atol=1e-4)
