"""The EEVEE preview's Encoded mode: an atlas encoded (or re-encoded) as HL2, H-basis, SG or the
SH encodings shows through that model's own node group, which reconstructs the irradiance at the
shading normal exactly as the core basis' `irradiance(c, n_v, n)` does from the EXR channels.

The atlas is written without tracing (a smooth radiance SH field over a tilted 2 m plane whose
lightmap UVs are its own 0–1 UVs: `encoding.encode_atlas` + `write_atlas`, as a bake writes it),
then re-encoded into each model by `bake.reencode`, the Re-encode operator's core. Two checks:
  * the maths, every model, on a plane facing up and one facing down (the tangent frame's sign
    flips at n_z = 0): a Cycles Emission bake of the previewed material through the lightmap UVs
    (one sample at each pixel's centre: exact float bilinear filtering) at a constant shading
    normal 35° off n_v, against albedo × basis.irradiance(bilinear(channels), n_v, n);
  * EEVEE, HL2 / L2 H-basis / SG9 through a tangent-space normal map, the preview's inputs read
    back per pixel (tests/test_preview_eevee.py `render_inputs`) and the same tolerance model as
    that file's (half-float film, the GPU's 8-bit bilinear weights).
Measured (Blender 5.3): bench/results/preview_encodings.md.
"""

import numpy as np
import pytest

from hhd_lightmapper.core import sh
from hhd_lightmapper.core.encoding import registry
from hhd_lightmapper.core.encoding.settings import EncoderSettings
from hhd_lightmapper.core.files import exr
from hhd_lightmapper.core.textures import sample_bilinear
from scenekit import blender as kit
from test_preview_eevee import normal_mapped_material, render, render_inputs, texel_corners, tree_state, unit

pytestmark = [pytest.mark.bpy]
RES = 16  # texels per side
MODELS = ("hl2", "hbasis_l1", "hbasis_l2", "sg5", "sg6", "sg9", "sg12", "sh_l1", "sh_l2")
ALBEDO = (0.7, 0.6, 0.5)
GROUP_NAMES = {
    "hl2": "HL2 Lightmap",
    "hbasis_l1": "L1 H-basis Lightmap",
    "hbasis_l2": "L2 H-basis Lightmap",
    **{f"sg{k}": f"SG{k} Lightmap" for k in (5, 6, 9, 12)},
    "sh_l1": "L1 SH Lightmap",
    "sh_l2": "L2 SH Lightmap",
}


def sh_field(normal) -> np.ndarray:
    """Radiance SH `(RES, RES, 9, 3)` over a surface of normal `normal`: a dim uniform hemisphere
    plus a bright lobe whose direction turns along u and rises along v (20–60° off the normal)."""
    u, v = np.meshgrid((np.arange(RES) + 0.5) / RES, (np.arange(RES) + 0.5) / RES)
    frame = sh.tangent_frames(np.asarray([normal], np.float64))[0]
    theta, phi = np.radians(20 + 40 * v), np.radians(30 + 200 * u)
    local = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    d = local @ frame.T
    lobe = sh.evaluate(d)[:, :, None] * np.array([2.0, 1.6, 1.1]) + sh.evaluate(-d)[:, :, None] * 0.05
    ambient = sh.evaluate(np.asarray([normal], np.float64))[0][None, :, None] * np.array([0.3, 0.35, 0.5])
    return (np.pi * lobe + ambient + np.eye(9)[0][None, :, None] * 0.4).reshape(RES, RES, 9, 3)


def write_plane_atlas(folder, normal):
    """The atlas "Lightmap" of `sh_field(normal)` written as a bake writes it (HHD, raw files)."""
    from hhd_lightmapper.core import encoding
    from hhd_lightmapper.core.files.lightmap_files import AtlasFiles, write_atlas

    files = AtlasFiles(folder, "Lightmap")
    data = encoding.TexelData(
        sh=sh_field(normal).astype(np.float32),
        normal=np.broadcast_to(np.float32(normal), (RES, RES, 3)).copy(),
        coverage=np.ones((RES, RES), np.float32),
    )
    encoded = encoding.encode_atlas(data, encoding.for_settings(EncoderSettings()))
    with exr.Staging() as staging:
        write_atlas(staging, files, encoded, {})
        staging.commit()
    return files


def plane_scene(folder, rotation, mat=None):
    """A cleared scene with a 2 m plane rotated by `rotation` whose lightmap UVs are its 0–1 UVs,
    its output folder `folder`; its material: `mat()` or a plain one of ALBEDO."""
    scene = kit.clear_scene()
    mat = mat() if mat is not None else kit.material("Surface", ALBEDO)
    plane = kit.plane("Plane", (0, 0, 0), 2, mat, rotation=rotation)
    plane.data.uv_layers.new(name=kit.LAYER)
    plane.data.uv_layers.active = plane.data.uv_layers[kit.LAYER]
    scene.hhd.output_dir = str(folder)
    kit.select([plane])
    return scene, plane, mat


def world_normal(plane) -> np.ndarray:
    n = np.array(plane.matrix_world.to_3x3() @ plane.data.polygons[0].normal)
    return n / np.linalg.norm(n)


def coefficients(files, model) -> np.ndarray:
    """The encoding's EXR channels as `(H, W, K, 3)`, rows bottom-up (the lightmap's UV)."""
    spec = registry.ENCODINGS[model].FILE
    channels, _ = exr.read(files.folder / f"{files.name}{spec.suffix}")
    return np.stack(
        [np.stack([exr.from_exr_rows(channels[n]) for n in ch.exr_names], -1) for ch in spec.channels], -2
    ).astype(np.float64)


def expected_radiance(files, model, luv, n, nv, albedo):
    """albedo × basis.irradiance of the channels sampled bilinearly at `luv` `(P, 2)`, and the
    spread of it over the 2×2 texels each lookup blends (for the GPU's 8-bit weights)."""
    basis = registry.basis_of(EncoderSettings(model=model))
    c = coefficients(files, model)
    h, w, k, _ = c.shape
    flat = c.reshape(h, w, -1)
    sampled = sample_bilinear(flat, luv, clamp=True).reshape(-1, k, 3)
    expected = albedo * basis.irradiance(sampled, nv, n)
    corners = texel_corners({"c": flat}, luv)["c"].reshape(4, -1, k, 3)
    at = np.stack([albedo * basis.irradiance(corners[q], nv, n) for q in range(4)])
    return expected, at.max(axis=0) - at.min(axis=0)


def reencode(files, model):
    from hhd_lightmapper.core import bake

    bake.reencode(files, EncoderSettings(model=model), threads=1, stitch_seams=False)


@pytest.mark.cycles
@pytest.mark.parametrize("rotation", [(0.7, 0.3, 0.0), (np.pi - 0.6, 0.4, 0.0)], ids=["up", "down"])
def test_each_encoding_group_equals_its_basis(extension, restore_hhd_settings, tmp_path, rotation):
    """Every model's group, at a constant shading normal 35° off n_v, against its core basis.
    Measured: bench/results/preview_encodings.md (half-float channels: ~1e-4 relative)."""
    import bpy

    scene, plane, mat = plane_scene(tmp_path / "lightmaps", rotation)
    nv = world_normal(plane)
    files = write_plane_atlas(tmp_path / "lightmaps", nv)
    frame = sh.tangent_frames(nv[None])[0]
    n = frame @ np.array([np.sin(np.radians(35)) * 0.6, np.sin(np.radians(35)) * 0.8, np.cos(np.radians(35))])
    constant = mat.node_tree.nodes.new("ShaderNodeCombineXYZ")
    for socket, value in zip(constant.inputs, n):
        socket.default_value = value
    mat.node_tree.links.new(constant.outputs[0], mat.node_tree.nodes["Principled BSDF"].inputs["Normal"])
    size = 4 * RES
    target = bpy.data.images.new("HHD encoded bake", size, size, float_buffer=True)
    target.colorspace_settings.is_data = True
    scene.render.engine = 'CYCLES'
    scene.cycles.device, scene.cycles.samples = 'CPU', 1
    scene.render.bake.margin = 0
    u, v = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size)
    luv = np.stack([u.ravel(), v.ravel()], -1)
    albedo = np.broadcast_to(ALBEDO, luv.shape[:1] + (3,))
    ns, nvs = np.broadcast_to(n, albedo.shape), np.broadcast_to(nv, albedo.shape)
    scene.hhd.preview_mode = 'ENCODED'
    errors = {}
    for model in MODELS:
        reencode(files, model)
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        tree = mat.node_tree
        group = next(node for node in tree.nodes if node.type == 'GROUP')
        assert group.node_tree.name == GROUP_NAMES[model]
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image = target
        tree.nodes.active = node
        assert bpy.ops.object.bake(type='EMIT') == {'FINISHED'}
        tree.nodes.remove(node)
        got = np.empty(size * size * 4, np.float32)
        target.pixels.foreach_get(got)
        got = got.reshape(-1, 4)[:, :3].astype(np.float64)
        expected, _ = expected_radiance(files, model, luv, ns, nvs, albedo)
        scale = np.abs(expected).max()
        errors[model] = float(np.abs(got - expected).max() / scale)
        # a mistake in the frame (the tangent turned 90° about n_v) or a dropped normal: far off
        turned = nv * (nv @ n) + np.cross(nv, n)
        for wrong_n in (turned, nv):
            wrong, _ = expected_radiance(files, model, luv, np.broadcast_to(wrong_n, albedo.shape), nvs, albedo)
            assert np.abs(wrong - expected).max() / scale > 0.03, (model, wrong_n)
        assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    print(f"n_v {np.round(nv, 3)}, max error / max value:", {m: f"{e:.2e}" for m, e in errors.items()})
    assert max(errors.values()) < 1e-3, errors


@pytest.mark.eevee
@pytest.mark.slow
def test_eevee_renders_each_encoding_through_a_normal_map(extension, restore_hhd_settings, tmp_path):
    """HL2, L2 H-basis and SG9 rendered by EEVEE on a tilted, normal-mapped plane: the radiance
    per pixel against albedo × basis.irradiance at the pixel's read-back UV, n and n_v (the
    inputs render once: they do not depend on the model). Tolerance as tests/test_preview_eevee.py's:
    99% of pixels within 1% of the value plus 2% of the 2×2 texels' spread, median relative error
    < 0.3%, none beyond 5%. Show/Hide leave the material exactly as it was."""
    import bpy

    from hhd_lightmapper import blender_compat

    scene, plane, mat = plane_scene(tmp_path / "lightmaps", (0.5, -0.35, 0.0), lambda: normal_mapped_material("Bumpy"))
    nv_plane = world_normal(plane)
    files = write_plane_atlas(tmp_path / "lightmaps", nv_plane)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.data.type, cam.data.ortho_scale = 'ORTHO', 1.2  # inside the plane at any roll
    cam.location, cam.rotation_euler = tuple(3.0 * nv_plane), kit.rotation_pointing(tuple(-nv_plane))
    scene.camera = cam
    scene.render.engine = blender_compat.eevee_engine()
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.resolution_percentage = 100
    scene.render.filter_size = 0.0
    scene.eevee.taa_render_samples = 1
    scene.view_settings.view_transform = 'Standard'
    scene.render.image_settings.file_format, scene.render.image_settings.color_depth = 'OPEN_EXR', '32'
    before = tree_state(mat)
    scene.hhd.preview_mode = 'ENCODED'
    images, stats = None, {}
    for model in ("hl2", "hbasis_l2", "sg9"):
        reencode(files, model)
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        if images is None:
            images = render_inputs(scene, mat, tmp_path)
            own = {name for name, *_ in before[0]}  # the read-back's helper nodes go: Hide is what is checked
            for node in [x for x in mat.node_tree.nodes if x.name not in own and not x.name.startswith("HHD Preview")]:
                mat.node_tree.nodes.remove(node)
            n, nv = unit(images["n"]), unit(images["nv"])
            tilt = np.degrees(np.arccos(np.clip(np.einsum("pi,pi->p", n, nv), -1.0, 1.0)))
            assert tilt.max() > 20.0 and np.abs(nv - nv_plane).max() < 2e-3  # the normal map is in play
            radiance = images["radiance"]
        else:
            radiance = render(scene, tmp_path / f"{model}.exr")
        expected, contrast = expected_radiance(files, model, images["luv"][:, :2], n, nv, images["albedo"])
        error = np.abs(radiance - expected)
        relative = error / np.maximum(np.abs(expected), 1e-6)
        stats[model] = [float(np.median(relative)), float(np.quantile(relative, 0.99)), float(relative.max())]
        assert (error <= 0.01 * np.abs(expected) + 0.02 * contrast + 1e-5).mean() > 0.99, (model, stats[model])
        assert stats[model][0] < 3e-3 and stats[model][2] < 0.05, (model, stats[model])
        assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
        assert tree_state(mat) == before
    print("relative error (median, p99, max):", stats)


def test_modes_refuse_what_they_cannot_show_and_encoded_follows_the_model(extension, restore_hhd_settings, tmp_path):
    """An atlas re-encoded from HHD to SG9 keeps its (now stale) HHD preview images: HHD, AHD and
    Scalar refuse it by its sidecar's model, naming the Encoded mode; L1/L2 (the raw SH file) and
    Encoded show it. Encoded on an HHD atlas is the HHD group. An atlas encoded before its model
    had preview images is refused with the re-encode it needs. Hide restores the material."""
    import bpy

    scene, plane, mat = plane_scene(tmp_path / "lightmaps", (0.2, 0.0, 0.0))
    files = write_plane_atlas(tmp_path / "lightmaps", world_normal(plane))
    before = tree_state(mat)

    def group_after_show(mode):
        scene.hhd.preview_mode = mode
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        return next(n for n in mat.node_tree.nodes if n.type == 'GROUP').node_tree.name

    assert group_after_show('ENCODED') == "HHD Lightmap"
    reencode(files, "sg9")
    assert files.preview_image("iz").is_file()  # stale: the refusal goes by the sidecar's model
    for mode in ('HHD', 'AHD', 'SCALAR'):
        scene.hhd.preview_mode = mode
        with pytest.raises(RuntimeError, match="encoded as sg9: choose Preview Encoded"):
            bpy.ops.hhd.preview_show()
    assert group_after_show('L2') == "L2 SH Lightmap"
    assert group_after_show('ENCODED') == "SG9 Lightmap"
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert tree_state(mat) == before
    files.preview_image("sg9_4").unlink()  # as an SG9 bake made before the Encoded mode left it
    with pytest.raises(RuntimeError, match="lacks the preview images of its SG9 layers"):
        bpy.ops.hhd.preview_show()
