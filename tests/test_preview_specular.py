"""The EEVEE preview's Specular term (`scene.hhd.preview_term`, shaders/specular_nodes.py) equals
core's specular (`core.encoding.hhd_specular.specular` for HHD, `ggx.sh_specular` for L2 SH) at each
pixel's read-back lightmap UV, shading normal and n_v, the orthographic camera's view direction,
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
from hhd_lightmapper.core.encoding.preview import sampled
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


def test_eevee_specular_term_equals_core(extension, restore_hhd_settings, tmp_path):
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
    before = tree_state(mat)
    scene.hhd.preview_term = 'SPECULAR'
    inputs, stats = None, {}
    for mode in ('HHD', 'L2'):
        scene.hhd.preview_mode = mode
        assert bpy.ops.hhd.preview_show() == {'FINISHED'}
        if inputs is None:
            inputs = render_inputs(scene, mat, tmp_path)
            own = {name for name, *_ in before[0]}
            for node in [x for x in mat.node_tree.nodes if x.name not in own and not x.name.startswith("HHD Preview")]:
                mat.node_tree.nodes.remove(node)
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
        error = np.abs(radiance - expected)
        relative = error / np.maximum(np.abs(expected), 1e-6)
        stats[mode] = [float(np.median(relative)), float(np.quantile(relative, 0.99)), float(relative.max())]
        # a wrong term (diffuse instead, F0 = 1, α = R) is far off
        assert np.abs(radiance).max() > 0 and np.median(np.abs(expected)) > 1e-4
        wrong, _ = _expected(mode, images, luv, n, nv, np.broadcast_to(nv_plane, n.shape))
        assert np.median(np.abs(wrong - expected) / np.abs(expected)) > 0.02
        print(mode, "relative error (median, p99, max):", stats[mode])
        assert (error <= 0.05 * np.abs(expected) + 0.02 * contrast + 1e-5).mean() > 0.99, (mode, stats[mode])
        assert stats[mode][0] < 1e-2 and stats[mode][2] < 0.15, (mode, stats[mode])
        assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
        assert tree_state(mat) == before
