"""Instances: linked duplicates (objects sharing one mesh) unwrap and bake without being made
single user (core/unwrap/instances.py). Three meshes × four instances each, some under a roof (shade),
some in the sun: the mesh count stays, each instance has its own rectangle, the sidecar records
it, and each instance's mean I_z equals that of the same scene made single user with the same
atlas UVs, baked with the same seed and samples (an independent path: ordinary objects, whose
layers hold atlas UVs). The EEVEE preview shows each instance its own texels (`preview_matches_bake`).
Hide restores the materials. A collection instance bakes from the command line."""

from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.textures import sample_bilinear
from scenekit import blender as kit

pytestmark = pytest.mark.bpy
LAYER = "HHD_Lightmap"


def iz_image(path: Path) -> np.ndarray:
    channels, _ = exr.read(path)
    return np.stack([exr.from_exr_rows(channels[f"Iz.{c}"]) for c in "RGB"], -1).astype(np.float64)


def object_means(folder: Path, atlas: str) -> dict[str, float]:
    """Per object of the atlas: mean luminance-free I_z (RGB mean) over the covered texels of its
    rectangle (instances' rectangles hold only their own texels)."""
    files = lightmap_files.AtlasFiles(folder, atlas)
    doc = lightmap_files.read_sidecar(files.sidecar)
    iz = iz_image(files.hhd)
    channels, _ = exr.read(files.texels)
    cover = exr.from_exr_rows(channels[next(n for n in channels if "overage" in n)])
    out = {}
    for o in doc["objects"]:
        x0, y0, x1, y1 = o["rect"]
        mask = cover[y0:y1, x0:x1] > 0
        out[o["name"]] = float(iz[y0:y1, x0:x1][mask].mean())
    return out


@pytest.fixture
def scene(extension, restore_hhd_settings, tmp_path):
    import bpy

    scene = kit.clear_scene()
    grey = kit.material("grey", (0.6, 0.6, 0.6))
    kit.plane("Floor", (0, 0, 0), 12, grey)  # floor and roof occlude and reflect, not baked
    kit.plane("Roof", (-3.5, 0, 2.0), 7, grey)  # shades the instances at x < 0
    bpy.ops.mesh.primitive_cube_add(size=0.6)
    cube = bpy.context.active_object
    bpy.ops.mesh.primitive_cylinder_add(vertices=8, radius=0.3, depth=0.6)
    cylinder = bpy.context.active_object
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=0.35)
    ico = bpy.context.active_object
    instances = []
    for row, (src, colour) in enumerate(((cube, (0.8, 0.3, 0.2)), (cylinder, (0.3, 0.8, 0.3)), (ico, (0.7, 0.7, 0.8)))):
        src.data.materials.append(kit.material(f"m{row}", colour))
        for k, x in enumerate((-4.0, -2.5, 2.5, 4.0)):
            obj = src if k == 0 else bpy.data.objects.new(f"{src.name}.{k}", src.data)
            if k:
                scene.collection.objects.link(obj)
            obj.name = f"{src.data.name}_{k}"
            obj.location = (x, -2.0 + 2.0 * row, 0.4)
            obj.rotation_euler = (0.0, 0.0, 0.4 * k)
            obj.scale = (-1.0, 1.0, 1.0) if k == 3 else (1.0 + 0.15 * k,) * 3  # one mirrored
            instances.append(obj)
    kit.sun(70.0, 30.0, 3.0, 2.0)
    kit.world((0.1, 0.12, 0.15))
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.resolution, s.samples, s.bounces, s.seed, s.denoise, s.pack_images = 128, 8, 1, 0, False, False
    s.output_dir = str(tmp_path / "instanced")
    return scene, instances, instances, tmp_path


def test_instances_bake_like_single_user_objects_and_preview_their_own_texels(scene):
    import bpy

    scene, receivers, instances, tmp = scene
    meshes = len(bpy.data.meshes)
    kit.unwrap(receivers)
    kit.select(receivers)
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    assert len(bpy.data.meshes) == meshes  # nothing made single user
    assert {o.hhd.atlas for o in instances} == {"Lightmap_instances"}
    rects = {o.name: tuple(o.hhd.lightmap_rect) for o in instances}
    assert len(set(rects.values())) == len(instances)
    files = lightmap_files.AtlasFiles(tmp / "instanced", "Lightmap_instances")
    doc = lightmap_files.read_sidecar(files.sidecar)
    for o in doc["objects"]:
        rec = o["instance"]
        assert rec["mesh"] == bpy.data.objects[o["name"]].data.name
        assert tuple(rec["scale"] + rec["offset"]) == rects[o["name"]]
    instanced = object_means(tmp / "instanced", "Lightmap_instances")

    # different light: each instance in the sun is brighter than every one under the roof
    for mesh in {o.data.name for o in instances}:
        mine = [o for o in instances if o.data.name == mesh]
        shade = [instanced[o.name] for o in mine if o.location.x < 0]
        sun = [instanced[o.name] for o in mine if o.location.x > 0]
        assert min(sun) > 1.5 * max(shade), (mesh, shade, sun)

    # the EEVEE preview: each instance samples its own rectangle of the shared layer
    preview_matches_bake(scene, instances, files)

    # the same scene made single user, each layer holding its instance's atlas UVs: ordinary objects
    for obj in instances:
        rect = np.array(obj.hhd.lightmap_rect)
        obj.data = obj.data.copy()
        layer = obj.data.uv_layers[LAYER]
        uv = np.zeros(len(layer.data) * 2, np.float32)
        layer.data.foreach_get("uv", uv)
        layer.data.foreach_set("uv", (uv.reshape(-1, 2) * rect[:2] + rect[2:]).astype(np.float32).ravel())
        obj.hhd.lightmap_rect = (1.0, 1.0, 0.0, 0.0)
    scene.hhd.output_dir = str(tmp / "single")
    kit.select(receivers)
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    single = object_means(tmp / "single", "Lightmap_instances")
    assert (
        "instance"
        not in lightmap_files.read_sidecar(lightmap_files.AtlasFiles(tmp / "single", "Lightmap_instances").sidecar)[
            "objects"
        ][0]
    )
    for name, value in instanced.items():
        assert abs(value - single[name]) <= 1e-3 * single[name], (name, value, single[name])


def top_face_pixels(obj, cam, size: int):
    """Pixels (P, 2) (x, y from the bottom) of a size² orthographic top view from `cam` whose
    centres fall on the cube instance's top face at least 1.5 pixels from its edges and 2.5
    pixels from its diagonal (the edge between its two triangles), and the layer UVs (P, 2)
    there (the face's UVs are an affine map of its local x, y). Why the diagonal: this EEVEE
    (software GL, headless) samples a coarse mip level in the 2 × 2 pixel quads that straddle a
    triangle edge, on any object (a plain floor shows it too), so those pixels show the blur of
    the whole atlas, not the texels there."""
    mesh = obj.data
    top = max(mesh.polygons, key=lambda p: p.normal.z)
    local = np.array([mesh.vertices[mesh.loops[i].vertex_index].co for i in top.loop_indices])
    uv = np.array([mesh.uv_layers[LAYER].data[i].uv for i in top.loop_indices])
    affine = np.linalg.lstsq(np.column_stack([local[:, :2], np.ones(len(local))]), uv, rcond=None)[0]
    mesh.calc_loop_triangles()
    a, b = (set(t.vertices) for t in mesh.loop_triangles if t.polygon_index == top.index)
    ends = np.array([mesh.vertices[v].co[:2] for v in sorted(a & b)])  # the diagonal's two corners
    step = cam.data.ortho_scale / size
    j, i = np.mgrid[0:size, 0:size]
    world = np.stack(
        [
            cam.location.x + (i + 0.5) * step - cam.data.ortho_scale / 2,
            cam.location.y + (j + 0.5) * step - cam.data.ortho_scale / 2,
        ],
        -1,
    ).reshape(-1, 2)
    inverse = np.array(obj.matrix_world.inverted())
    points = np.column_stack([world, np.full(len(world), (obj.matrix_world @ top.center).z), np.ones(len(world))])
    p = (points @ inverse.T)[:, :2]
    local_step = step / min(abs(v) for v in obj.matrix_world.to_scale())
    half = np.abs(local[:, :2]).max() - 1.5 * local_step
    along = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    off_diagonal = np.abs((p - ends[0]) @ np.array([-along[1], along[0]])) > 2.5 * local_step
    inside = (np.abs(p[:, 0]) < half) & (np.abs(p[:, 1]) < half) & off_diagonal
    assert inside.sum() >= 50
    pixels = np.column_stack([i.ravel(), j.ravel()])[inside]
    return pixels, np.column_stack([p[inside], np.ones(inside.sum())]) @ affine


def preview_matches_bake(scene, instances, files):
    """Show Preview, render two cube instances from above (one in shade, one in sun) in EEVEE,
    pixels smaller than texels (no minification: mip level 0): each pixel of each one's top face
    shows albedo × its own baked I_z, sampled bilinearly through its rectangle at the pixel's
    point (at n = n_v the HHD reconstruction is I_z exactly, docs/format.md). A wrong rectangle
    (another instance's texels, a flipped v) is off by the shade/sun contrast, ≥ 5×. Hide
    restores the material."""
    import bpy

    from hhd_lightmapper import blender_compat

    a, b = (
        o for o in instances if o.data.name == instances[0].data.name and o.scale.x > 0 and abs(o.location.x) == 2.5
    )
    mat = a.material_slots[0].material
    before = sorted((n.name, n.bl_idname) for n in mat.node_tree.nodes), len(mat.node_tree.links)
    scene.hhd.preview_mode = 'HHD'
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    size = 160  # 160 / 6 m ≈ 27 pixels per metre, more than the cube's ≈ 20 texels per metre
    cam.data.type, cam.data.ortho_scale = 'ORTHO', 6.0
    cam.location = (0.0, a.location.y, 6.0)
    scene.camera = cam
    bpy.data.objects["Roof"].hide_render = True  # it hides the shaded instances from above; they show baked light
    scene.render.engine = blender_compat.eevee_engine()
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = size, size, 100
    scene.render.filter_size = 0.0
    scene.eevee.taa_render_samples = 1
    scene.view_settings.view_transform = 'Standard'
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth = 'OPEN_EXR', '32'
    scene.render.filepath = str(Path(files.folder) / "render.exr")
    bpy.ops.render.render(write_still=True)
    channels, _ = exr.read(Path(scene.render.filepath))
    image = np.stack([exr.from_exr_rows(channels[c]) for c in "RGB"], -1).astype(np.float64)
    baked = iz_image(files.hhd)
    albedo = np.array(
        next(n for n in mat.node_tree.nodes if n.type == 'BSDF_PRINCIPLED').inputs["Base Color"].default_value[:3]
    )
    means, cubes = [], [o for o in instances if o.data.name == a.data.name]
    for obj in (a, b):
        pixels, uv = top_face_pixels(obj, cam, size)
        rendered = image[pixels[:, 1], pixels[:, 0], 0]

        def error(
            rect, uv=uv, rendered=rendered
        ):  # median relative error of the red channel against I_z read through rect
            expected = albedo[0] * sample_bilinear(baked, uv * rect[:2] + rect[2:], clamp=True)[:, 0]
            return float(np.median(np.abs(rendered - expected) / np.maximum(expected, 1e-6))), expected

        own, expected = error(np.array(obj.hhd.lightmap_rect))
        others = [error(np.array(o.hhd.lightmap_rect))[0] for o in cubes if o is not obj]
        flipped = error(np.array(obj.hhd.lightmap_rect) * [1, -1, 1, 1] + [0, 0, 0, obj.hhd.lightmap_rect[1]])[0]
        # 8 samples: neighbouring shaded texels differ up to 3×, and EEVEE's texture filtering is not
        # exactly bilinear there, so compare medians. Measured (shade): own 4%, the other shaded
        # cube's rectangle 25%, the sunlit ones' 97%, own with v flipped 77%.
        assert own < 0.1 and own < 0.5 * min([*others, flipped]), (obj.name, own, others, flipped)
        means.append(expected.mean())
    assert means[1] > 5.0 * means[0]  # one in the sun, one in the shade
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert (sorted((n.name, n.bl_idname) for n in mat.node_tree.nodes), len(mat.node_tree.links)) == before
    scene.render.engine = 'CYCLES'
    bpy.data.objects["Roof"].hide_render = False  # it shades the next bake again


def test_collection_instances_bake_from_the_command_line(extension, restore_hhd_settings, cli_run, tmp_path):
    """An Empty instancing a collection, named on the command line, stands for the collection's
    objects: `bake --unwrap --save --objects Floor Chairs` exits 0 and the sidecar lists "Chairs/Cube"
    with its rectangle; `bake --only Chairs` re-traces it into the same files (exit 0), and after
    the Empty moved, `bake --changed` re-traces it alone."""
    import bpy

    scene = kit.clear_scene()
    props = bpy.data.collections.new("Props")
    bpy.ops.mesh.primitive_cube_add(size=0.5)
    cube = bpy.context.active_object
    for c in list(cube.users_collection):
        c.objects.unlink(cube)
    props.objects.link(cube)
    kit.plane("Floor", (0, 0, 0), 4, kit.material("grey", (0.5, 0.5, 0.5)))
    empty = bpy.data.objects.new("Chairs", None)
    empty.instance_type, empty.instance_collection = 'COLLECTION', props
    empty.location = (0.5, 0.0, 0.25)
    scene.collection.objects.link(empty)
    kit.sun(50.0, 30.0, 3.0, 1.0)
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.resolution, s.samples, s.bounces, s.denoise = 64, 4, 1, False
    mesh = cube.data.name
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "cli"
    run = cli_run(blend, "bake", "--unwrap", "--save", "--objects", "Floor", "Chairs", "--out", str(out))
    assert run.returncode == 0, run.stderr + run.stdout
    doc = lightmap_files.read_sidecar(lightmap_files.AtlasFiles(out, "Lightmap_instances").sidecar)
    (record,) = doc["objects"]
    assert record["name"] == "Chairs/Cube" and record["instance"]["mesh"] == mesh
    run = cli_run(blend, "bake", "--only", "Chairs", "--out", str(out))
    assert run.returncode == 0, run.stderr + run.stdout
    bpy.data.objects["Chairs"].location.x += 0.3  # moving the Empty changes its instance, not the floor
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    run = cli_run(blend, "bake", "--changed", "--out", str(out))
    assert run.returncode == 0, run.stderr + run.stdout
    (line,) = [line for line in run.stdout.splitlines() if "Re-traced" in line]
    assert "Re-traced Chairs/Cube:" in line and "Floor" not in line, line
