"""The EEVEE preview's Specular term (`scene.hhd.preview_term`, shaders/specular_nodes.py) equals
core's specular (`core.encoding.hhd_specular.specular` for HHD, `ggx.sh_specular` for L2 SH,
`SGBasis.specular` for the Encoded mode's SG5 / SG12) at each pixel's lightmap UV, shading normal
and n_v (read back; for SG the UV and n_v from the geometry), the orthographic camera's view direction,
the Principled BSDF's α = Roughness² and F0 = 0.08 × Specular IOR Level (IOR 1.5, Metallic 0).

A tilted, normal-mapped plane over a written atlas (tests/test_preview_encodings.py), rendered by
EEVEE once per mode; the inputs are read back as tests/test_preview_eevee.py does. Tolerance
(measured, Blender 5.3: see the print): the half-float film and inputs, the GPU's 8-bit bilinear
weights on the lightmap (2% of the 2×2 texels' spread) and on the GGX table's lookup (its
float32 table, on the GPU in half floats with 8-bit weights): measured relative error median /
p99 / max 0.44% / 4.4% / 8.0% (HHD), 0.30% / 3.6% / 7.1% (L2); bounds: 99% of pixels within 5%
plus 2% of the spread, median < 1%, max < 15% (a dropped 1/Y₀₀ on the ambient, found this way,
gave a median of 17%; the view along n_v instead of the camera's moves the median > 2%)."""

import numpy as np
import pytest

from hhd_lightmapper.core import hhd
from hhd_lightmapper.core.encoding import ggx
from hhd_lightmapper.core.encoding.hhd_specular import specular
from hhd_lightmapper.core.files.preview import sampled
from hhd_lightmapper.core.textures import sample_bilinear
from scenekit import blender as kit
from test_preview_eevee import normal_mapped_material, read_rgb, render, render_inputs, texel_corners, tree_state, unit
from test_preview_encodings import plane_scene, world_normal, write_plane_atlas

pytestmark = [pytest.mark.bpy, pytest.mark.eevee]
ROUGHNESS = 0.5
F0 = 0.04  # Principled's default IOR 1.5, Specular IOR Level 0.5


def _core(mode, s: dict, n, nv, v):
    """Core's specular from the mode's preview-image values `s` {layer name: (P, 3)}."""
    alpha = ROUGHNESS**2
    if mode == 'HHD':
        p = hhd.HHDParams(s["Iz"], s["Wa"][:, 0], unit(s["Direction"]))
        return specular(p, nv, n, v, alpha, F0)
    return ggx.sh_specular(np.stack([s[f"SH{k}"] for k in range(9)], 1), n, v, alpha, F0)


def _expected(mode, images: dict, luv, n, nv, v):
    """At the bilinear samples of the images at `luv`, and the spread over the 2×2 texels."""
    value = _core(mode, {k: sample_bilinear(x, luv, clamp=True) for k, x in images.items()}, n, nv, v)
    corners = texel_corners(images, luv)
    at = np.stack([_core(mode, {k: x[q] for k, x in corners.items()}, n, nv, v) for q in range(4)])
    return value, at.max(axis=0) - at.min(axis=0)


def _specular_scene(tmp_path):
    """The tilted, normal-mapped plane over a written atlas, an orthographic camera ~30° off its
    normal, EEVEE at 48², Specular term: (scene, material, camera, files, n_v of the plane)."""
    import bpy

    from hhd_lightmapper import blender_compat

    scene, plane, mat = plane_scene(tmp_path / "lightmaps", (0.5, -0.35, 0.0), lambda: normal_mapped_material("Bumpy"))
    mat.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = ROUGHNESS
    nv_plane = world_normal(plane)
    files = write_plane_atlas(tmp_path / "lightmaps", nv_plane)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.data.type, cam.data.ortho_scale = 'ORTHO', 1.2
    view = unit(nv_plane + np.array([0.36, -0.48, 0.0]))  # ~30° off the plane's normal
    cam.location, cam.rotation_euler = tuple(3.0 * view), kit.rotation_pointing(tuple(-view))
    scene.camera = cam
    scene.render.engine = blender_compat.eevee_engine()
    scene.render.resolution_x = scene.render.resolution_y = 48
    scene.render.resolution_percentage = 100
    scene.render.filter_size = 0.0
    scene.eevee.taa_render_samples = 1
    scene.view_settings.view_transform = 'Standard'
    scene.render.image_settings.file_format, scene.render.image_settings.color_depth = 'OPEN_EXR', '32'
    scene.hhd.preview_term = 'SPECULAR'
    return scene, mat, cam, files, nv_plane


def _read_inputs(scene, mat, tmp_path, before) -> dict:
    """The preview's inputs per pixel (render_inputs), the nodes that read them removed again."""
    inputs = render_inputs(scene, mat, tmp_path)
    own = {name for name, *_ in before[0]}
    for node in [x for x in mat.node_tree.nodes if x.name not in own and not x.name.startswith("HHD Preview")]:
        mat.node_tree.nodes.remove(node)
    return inputs


def _check(mode, radiance, expected, contrast, wrong) -> list[float]:
    """The tolerance of the module docstring; returns the relative error's median, p99, max."""
    error = np.abs(radiance - expected)
    relative = error / np.maximum(np.abs(expected), 1e-6)
    stats = [float(np.median(relative)), float(np.quantile(relative, 0.99)), float(relative.max())]
    # a wrong term (diffuse instead, F0 = 1, α = R, the view along n_v) is far off
    assert np.abs(radiance).max() > 0 and np.median(np.abs(expected)) > 1e-4
    assert np.median(np.abs(wrong - expected) / np.abs(expected)) > 0.02
    print(mode, "relative error (median, p99, max):", stats)
    assert (error <= 0.05 * np.abs(expected) + 0.02 * contrast + 1e-5).mean() > 0.99, (mode, stats)
    assert stats[0] < 1e-2 and stats[2] < 0.15, (mode, stats)
    return stats


def test_eevee_specular_term_equals_core(extension, restore_hhd_settings, tmp_path):
    import bpy

    scene, mat, cam, files, nv_plane = _specular_scene(tmp_path)
    before = tree_state(mat)
    inputs = None
    for mode in ('HHD', 'L2'):
        scene.hhd.preview_mode = mode
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        if inputs is None:
            inputs = _read_inputs(scene, mat, tmp_path, before)
            n, nv = unit(inputs["n"]), unit(inputs["nv"])
            assert np.degrees(np.arccos(np.clip(np.einsum("pi,pi->p", n, nv), -1, 1))).max() > 20.0
            radiance = inputs["radiance"]
        else:
            radiance = render(scene, tmp_path / f"{mode}.exr")
        camera_z = np.array(cam.matrix_world.to_3x3().col[2])
        v = np.broadcast_to(camera_z / np.linalg.norm(camera_z), n.shape)
        images = {layer.name: read_rgb(files.preview_image(layer.preview)) for layer in sampled(mode)}
        luv = inputs["luv"][:, :2]
        expected, contrast = _expected(mode, images, luv, n, nv, v)
        wrong, _ = _expected(mode, images, luv, n, nv, np.broadcast_to(nv_plane, n.shape))
        _check(mode, radiance, expected, contrast, wrong)
        assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
        assert tree_state(mat) == before


#: The SG encodings the EEVEE test renders, with their fits ("ls": amplitudes of either sign,
#: so the per-lobe max(·, 0) matters).
SG_CASES = (("sg5", "nnls"), ("sg12", "ls"))


def _pixel_uv(scene, cam, plane) -> np.ndarray:
    """The plane's UV (= its lightmap UV: 0–1 over the primitive's 2 × 2 local square) at each
    pixel centre `(P, 2)`, rows bottom-up as `render` returns them: the orthographic camera's
    rays through the pixel centres intersected with the plane, in the plane's local space."""
    import bpy

    bpy.context.view_layer.update()
    m = np.array(cam.matrix_world)
    size = scene.render.resolution_x
    s = ((np.arange(size) + 0.5) / size - 0.5) * cam.data.ortho_scale
    y, x = np.meshgrid(s, s, indexing="ij")
    start = m[:3, 3] + x[..., None] * m[:3, 0] + y[..., None] * m[:3, 1]
    inv = np.array(plane.matrix_world.inverted())
    local, ray = start @ inv[:3, :3].T + inv[:3, 3], -m[:3, 2] @ inv[:3, :3].T
    hit = local + (-local[..., 2] / ray[2])[..., None] * ray
    return ((hit[..., :2] + 1.0) / 2.0).reshape(-1, 2)


def _render_normal(scene, mat, path) -> np.ndarray:
    """The shading normal that feeds the specular group, per pixel `(P, 3)` (unit), rendered
    through the preview's Emission packed as 0.5·n + 0.5 (the film is half float)."""
    tree = mat.node_tree
    emission = tree.nodes["HHD Preview Emission"]
    radiance = emission.inputs["Color"].links[0].from_socket
    pack = tree.nodes.new("ShaderNodeVectorMath")
    pack.operation = 'MULTIPLY_ADD'
    tree.links.new(tree.nodes["HHD Preview Specular"].inputs["Normal"].links[0].from_socket, pack.inputs[0])
    pack.inputs[1].default_value = pack.inputs[2].default_value = (0.5, 0.5, 0.5)
    tree.links.new(pack.outputs["Vector"], emission.inputs["Color"])
    n = unit(2.0 * render(scene, path) - 1.0)
    tree.links.new(radiance, emission.inputs["Color"])
    tree.nodes.remove(pack)
    return n


def test_eevee_sg_specular_term_equals_core(extension, restore_hhd_settings, tmp_path):
    """The Encoded mode's Specular term of SG-encoded atlases (shaders/specular_nodes.build_sg)
    against `SGBasis.specular` of the bilinearly sampled lobe amplitudes, with the tolerance of
    the HHD/SH test; n_v is the flat plane's normal and the lightmap UV the camera rays' hit on
    it (fewer renders). An HL2 atlas shows diffuse and a note naming HL2."""
    import bpy

    from hhd_lightmapper.core import bake
    from hhd_lightmapper.core.encoding import registry
    from hhd_lightmapper.core.encoding.settings import EncoderSettings
    from hhd_lightmapper.shaders import preview

    scene, mat, cam, files, nv_plane = _specular_scene(tmp_path)
    (plane,) = [o for o in scene.objects if o.type == 'MESH']
    scene.hhd.preview_mode = 'ENCODED'
    before = tree_state(mat)
    luv = _pixel_uv(scene, cam, plane)
    v = np.broadcast_to(unit(np.array(cam.matrix_world)[:3, 2]), luv.shape[:1] + (3,))
    nv = np.broadcast_to(nv_plane, v.shape)
    n = None
    for model, solve in SG_CASES:
        settings = EncoderSettings(model=model, solve=solve)
        bake.reencode(files, settings, threads=1, stitch_seams=False)
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        assert mat.node_tree.nodes["HHD Preview Specular"].node_tree.name == f"{model.upper()} Specular"
        if n is None:
            n = _render_normal(scene, mat, tmp_path / "n.exr")
            assert np.degrees(np.arccos(np.clip(np.einsum("pi,pi->p", n, nv), -1, 1))).max() > 20.0
        radiance = render(scene, tmp_path / f"{model}.exr")
        basis = registry.basis_of(settings)
        layers = sampled(model.upper())
        images = np.stack([read_rgb(files.preview_image(layer.preview)) for layer in layers], -2)  # (H, W, K, 3)
        if solve == "ls":
            assert (images < 0).any(), "the ls fit was meant to give negative amplitudes somewhere"
        flat = images.reshape(*images.shape[:2], -1)

        def core(c, view, basis=basis, n=n):
            return basis.specular(c.reshape(len(n), -1, 3), nv, n, view, ROUGHNESS**2, F0)

        at = np.stack([core(corners, v) for corners in texel_corners({"c": flat}, luv)["c"]])
        sampled_c = sample_bilinear(flat, luv, clamp=True)
        wrong = core(sampled_c, np.broadcast_to(nv_plane, n.shape))
        _check(model, radiance, core(sampled_c, v), at.max(axis=0) - at.min(axis=0), wrong)
        assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
        assert tree_state(mat) == before
    # no specular model: the diffuse reconstruction, and a note that names the model
    bake.reencode(files, EncoderSettings(model="hl2"), threads=1, stitch_seams=False)
    notes = preview.show([plane], {plane.name: files}, 'ENCODED', scene.hhd.uv_layer, scene=scene)
    assert any("HL2 encodes no specular" in note for note in notes), notes
    emission = mat.node_tree.nodes["HHD Preview Emission"]
    assert emission.inputs["Color"].links[0].from_socket.name == "Radiance"
    assert "HHD Preview Specular" not in mat.node_tree.nodes
    preview.hide()
    assert tree_state(mat) == before
