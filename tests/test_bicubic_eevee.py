"""The preview's Bicubic filter in EEVEE: a floor baked at 32 × 32 texels with a plate's hard
shadow on it, shown in HHD mode with Filter Bicubic and rendered from above, shows at each pixel
albedo × core's Catmull-Rom sample of the baked I_z (core.textures.sample_bicubic, clamped at 0)
at the pixel's lightmap UV (flat floor: n = n_v, where the HHD reconstruction is I_z exactly), and
differs from core's bilinear sampling along the shadow's edge by far more than that agreement
(the Bilinear preview is EEVEE's own filter, tested in test_preview_eevee). Then Filter
B-spline (prefiltered): the coefficient image the preview wrote keeps every covered texel's mean
(its B-spline averaged over each texel by Gauss-Legendre is the baked I_z), and the render is
albedo × core's B-spline sample of those coefficients, unlike the Catmull-Rom render along the edge.

The taps are 'Closest' lookups (exact texels) weighted in nodes, so the agreement is float
arithmetic and the half-float film: measured max relative error ~1e-3 (tolerance 1%)."""

import math
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core.files import exr
from hhd_lightmapper.core.textures import sample_bicubic, sample_bilinear
from scenekit import blender as kit

pytestmark = [pytest.mark.bpy, pytest.mark.eevee]
SIZE = 64  # render pixels over the 2 m floor: 2 pixels per texel


def render(scene, path: Path) -> np.ndarray:
    """EEVEE render (SIZE², rows bottom-up) of the red channel, EEVEE's lighting set-up at its
    smallest (`kit.eevee_fast_lighting`: the preview's Emission reads none of it)."""
    import bpy

    kit.eevee_fast_lighting(scene)
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    channels, _ = exr.read(path)
    return exr.from_exr_rows(channels["R"]).astype(np.float64)


def test_bicubic_preview_matches_core(extension, tmp_path):
    import bpy

    from hhd_lightmapper import blender_compat

    scene = kit.clear_scene()
    albedo = 0.8
    floor = kit.plane("Floor", (0, 0, 0), 2.0, kit.material("Floor", (albedo, albedo, albedo)))
    plate = kit.box("Plate", (0.0, 0.0, 0.4), (0.8, 0.8, 0.02), kit.material("Plate", (0.5, 0.5, 0.5)))
    plate.rotation_euler = (0.0, 0.0, math.radians(25.0))
    kit.sun(55.0, 200.0, 3.0, 0.0)
    scene.hhd.samples, scene.hhd.bounces, scene.hhd.denoise = 16, 0, False
    scene.hhd.output_dir = str(tmp_path / "lightmaps")
    kit.unwrap([floor], texel_density=16.0)  # 32 texels across the floor
    kit.select([floor])
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    (sidecar,) = (tmp_path / "lightmaps").glob("*.json")
    channels, _ = exr.read(sidecar.with_name(f"{sidecar.stem}_hhd.exr"))
    iz = np.stack([exr.from_exr_rows(channels[f"Iz.{c}"]) for c in "RGB"], -1).astype(np.float64)

    plate.hide_render = True  # seen from above it would hide the shadow
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.data.type, cam.data.ortho_scale, cam.location = 'ORTHO', 2.0, (0.0, 0.0, 3.0)
    scene.camera = cam
    scene.render.engine = blender_compat.eevee_engine()
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.filter_size = 0.0
    scene.eevee.taa_render_samples = 1
    scene.view_settings.view_transform = 'Standard'
    scene.render.image_settings.file_format, scene.render.image_settings.color_depth = 'OPEN_EXR', '32'
    scene.hhd.preview_filter = 'BICUBIC'
    kit.select([floor])
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    rendered = render(scene, tmp_path / "bicubic.exr")
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    scene.hhd.preview_filter = 'BSPLINE'
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    rendered_bspline = render(scene, tmp_path / "bspline.exr")
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    (coefficient_file,) = (tmp_path / "lightmaps").glob("*_preview/iz_bspline.exr")
    channels, _ = exr.read(coefficient_file)
    coefficients = np.stack([exr.from_exr_rows(channels[c]) for c in "RGB"], -1).astype(np.float64)

    mesh = floor.data
    world = np.array([mesh.vertices[loop.vertex_index].co[:2] for loop in mesh.loops]) * np.array(floor.scale[:2])
    uv = np.array([mesh.uv_layers[scene.hhd.uv_layer].data[k].uv for k in range(len(mesh.loops))])
    affine = np.linalg.lstsq(np.column_stack([world, np.ones(len(world))]), uv, rcond=None)[0]
    j, i = np.mgrid[0:SIZE, 0:SIZE]
    points = np.column_stack([(i.ravel() + 0.5) / SIZE * 2.0 - 1.0, (j.ravel() + 0.5) / SIZE * 2.0 - 1.0])
    inside = (np.abs(points) < 1.0 - 3.0 / 32).all(1)  # 3 texels from the floor's rim
    at = np.column_stack([points, np.ones(len(points))])[inside] @ affine
    expected = albedo * sample_bicubic(iz, at, clamp=True, nonnegative=True)[:, 0]
    linear = albedo * sample_bilinear(iz, at, clamp=True)[:, 0]
    bicubic = rendered.ravel()[inside]
    lit = np.percentile(expected, 95)
    error = np.abs(bicubic - expected) / lit
    assert np.percentile(error, 99) < 0.01 and error.max() < 0.03, (np.percentile(error, 99), error.max())
    edge = np.abs(expected - linear) > 0.05 * lit  # where the kernels disagree: along the shadow's edge
    assert edge.sum() > 100
    assert np.median(np.abs(bicubic - linear)[edge] / lit) > 10 * np.median(error[edge]), np.median(error[edge])

    # the prefiltered B-spline: the coefficients keep the texel means (inside the floor's chart)...
    covered = np.zeros(iz.shape[:2], bool)
    rows, cols = np.nonzero((iz > 0).any(-1))
    covered[rows.min() + 2 : rows.max() - 1, cols.min() + 2 : cols.max() - 1] = True
    means = texel_means(coefficients)
    assert np.abs(means - iz)[covered].max() < 1e-3 * iz.max()
    # ... EEVEE draws their B-spline ...
    expected = albedo * sample_bicubic(coefficients, at, clamp=True, kernel="bspline", nonnegative=True)[:, 0]
    error = np.abs(rendered_bspline.ravel()[inside] - expected) / lit
    assert np.percentile(error, 99) < 0.01 and error.max() < 0.03, (np.percentile(error, 99), error.max())
    assert np.median(np.abs(rendered_bspline.ravel()[inside] - bicubic)[edge] / lit) > 10 * np.median(error[edge])


def texel_means(coefficients: np.ndarray) -> np.ndarray:
    """Each texel's mean of the B-spline of `coefficients` (H, W, C): Gauss-Legendre, 2 points per
    half texel and axis (exact for the piecewise cubic)."""
    h, w = coefficients.shape[:2]
    g = np.array([-1.0, 1.0]) / np.sqrt(3.0)
    offsets = np.concatenate([0.25 + 0.25 * g, 0.75 + 0.25 * g])
    j, i = np.mgrid[0:h, 0:w]
    total = 0.0
    for dy in offsets:
        for dx in offsets:
            uv = np.column_stack([(i.ravel() + dx) / w, (j.ravel() + dy) / h])
            total = total + sample_bicubic(coefficients, uv, clamp=True, kernel="bspline")
    return (total / 16).reshape(coefficients.shape)
