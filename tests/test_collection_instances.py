"""Collection instances: an Empty showing a collection makes each of the collection's mesh
objects a receiver ("<Empty>/<object>", `bridge.collection_instances`) without copying a mesh.
Three Empties show a collection of a cube and a cylinder (one Empty rotated and mirrored, one
under a roof) beside a linked duplicate of the cube: Unwrap places each Empty's copy of the
collection's block in the instance atlas, the bake gives each one its own light, and each
one's mean I_z equals that of the same scene made real (single-user objects in the same places,
their layers holding the same atlas UVs), baked with the same seed. The EEVEE preview reads each
instance's rectangle through its Empty. A nested collection instance is refused by name."""

from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.textures import sample_bilinear
from scenekit import blender as kit
from test_gltf_export import nodes_by_name, read_glb
from test_instances import LAYER, iz_image, object_means, top_face_pixels

pytestmark = pytest.mark.bpy


@pytest.fixture
def scene(extension, restore_hhd_settings, tmp_path):
    import bpy

    scene = kit.clear_scene()
    grey = kit.material("grey", (0.6, 0.6, 0.6))
    kit.plane("Floor", (0, 0, 0), 12, grey)
    kit.plane("Roof", (-3.5, 0, 2.0), 7, grey)  # shades the Empty at x < 0
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.0, 0.0, 0.3))
    cube = bpy.context.active_object
    bpy.ops.mesh.primitive_cylinder_add(vertices=8, radius=0.3, depth=0.6, location=(0.9, 0.2, 0.3))
    cylinder = bpy.context.active_object
    for obj, colour in ((cube, (0.8, 0.3, 0.2)), (cylinder, (0.3, 0.8, 0.3))):
        obj.data.materials.append(kit.material(f"m{obj.name}", colour))
        for c in list(obj.users_collection):
            c.objects.unlink(obj)
        props.objects.link(obj)
    props.instance_offset = (0.45, 0.1, 0.0)
    scene.view_layers[0].layer_collection.children[props.name].exclude = True  # the source is not drawn
    empties = []
    for name, x, angle, mirror in (("SetA", 2.5, 0.0, False), ("SetB", 4.5, 0.7, True), ("SetC", -3.5, 0.3, False)):
        empty = bpy.data.objects.new(name, None)
        empty.instance_type, empty.instance_collection = 'COLLECTION', props
        empty.location, empty.rotation_euler = (x, 0.5, 0.0), (0.0, 0.0, angle)
        empty.scale = (-1.0, 1.0, 1.0) if mirror else (1.2, 1.2, 1.2)
        scene.collection.objects.link(empty)
        empties.append(empty)
    duplicate = bpy.data.objects.new("LooseCube", cube.data)  # a linked duplicate of a member's mesh
    duplicate.location = (2.5, -2.0, 0.3)
    scene.collection.objects.link(duplicate)
    kit.sun(70.0, 30.0, 3.0, 2.0)
    kit.world((0.1, 0.12, 0.15))
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.resolution, s.samples, s.bounces, s.seed, s.denoise, s.pack_images = 128, 8, 1, 0, False, False
    s.output_dir = str(tmp_path / "instanced")
    return scene, empties, duplicate, tmp_path


def test_collection_instances_bake_like_real_objects(scene):
    import bpy

    from hhd_lightmapper.bridge import collection_instances

    scene, empties, duplicate, tmp = scene
    meshes, objects = len(bpy.data.meshes), len(bpy.data.objects)
    kit.select(empties)  # Empties alone are receivers for every operator
    assert all(op.poll() for op in (bpy.ops.hhd.unwrap, bpy.ops.hhd.bake, bpy.ops.hhd.view_show))
    kit.select([*empties, duplicate])
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    kit.select([*empties, duplicate])
    for mode in ('DENSITY', 'CHECKER', 'PROBLEMS'):  # the views before a bake take the Empties too
        assert bpy.ops.hhd.view_show(mode=mode) == {'FINISHED'}
        assert empties[0]["hhd_view_size"][0] == empties[0].hhd.atlas_width
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert not any(k in e for e in empties for k in ("hhd_view_size", "hhd_preview"))
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    assert (len(bpy.data.meshes), len(bpy.data.objects)) == (meshes, objects)  # nothing copied or made real
    members = collection_instances.receivers(empties)
    assert sorted(m.name for m in members) == sorted(f"{e.name}/{o}" for e in empties for o in ("Cube", "Cylinder"))
    assert {e.hhd.atlas for e in empties} == {duplicate.hhd.atlas} == {"Lightmap_instances"}
    rects = {m.name: m.hhd.lightmap_rect for m in members} | {duplicate.name: tuple(duplicate.hhd.lightmap_rect)}
    assert len(set(rects.values())) == len(rects)  # each its own rectangle
    inner = {m.object.name: tuple(m.object.hhd.collection_rect) for m in members}
    for m in members:  # the composition is the rectangle, on whole texels of the atlas
        outer = np.array(m.instancer.hhd.lightmap_rect)
        assert np.allclose(collection_instances.compose(outer, inner[m.object.name]), rects[m.name], atol=1e-6)
        corner = np.array(rects[m.name][2:]) * (m.hhd.atlas_width, m.hhd.atlas_height)
        assert np.allclose(corner, np.round(corner), atol=1e-3), (m.name, corner)
    files = lightmap_files.AtlasFiles(tmp / "instanced", "Lightmap_instances")
    doc = lightmap_files.read_sidecar(files.sidecar)
    records = {o["name"]: o for o in doc["objects"]}
    assert set(records) == set(rects)
    for m in members:
        rec = records[m.name]["instance"]
        assert rec["mesh"] == m.data.name
        assert np.allclose(rec["scale"] + rec["offset"], rects[m.name])
    instanced = object_means(tmp / "instanced", "Lightmap_instances")
    for part in ("Cube", "Cylinder"):  # different light for each instance: the sun against the roof's shade
        assert min(instanced[f"SetA/{part}"], instanced[f"SetB/{part}"]) > 1.5 * instanced[f"SetC/{part}"]

    preview_reads_own_rectangles(scene, [m for m in members if m.object.name == "Cube"], files)
    gltf_nodes_carry_own_rectangles(empties, members, tmp)

    # the same scene made real: single-user objects where the instances are, layers holding atlas UVs
    real = []
    for m in members:
        obj = bpy.data.objects.new(m.name, m.data.copy())
        obj.matrix_world = m.matrix_world
        layer = obj.data.uv_layers[LAYER]
        uv = np.zeros(len(layer.data) * 2, np.float32)
        layer.data.foreach_get("uv", uv)
        rect = np.array(rects[m.name])
        layer.data.foreach_set("uv", (uv.reshape(-1, 2) * rect[:2] + rect[2:]).astype(np.float32).ravel())
        scene.collection.objects.link(obj)
        obj.hhd.atlas, obj.hhd.atlas_width, obj.hhd.atlas_height = m.hhd.atlas, m.hhd.atlas_width, m.hhd.atlas_height
        real.append(obj)
    for e in empties:
        bpy.data.objects.remove(e)
    scene.hhd.output_dir = str(tmp / "real")
    kit.select([*real, duplicate])
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    single = object_means(tmp / "real", "Lightmap_instances")
    # within the 0.5%: the mirrored Empty's twin differs by 0.22% (Blender stores its matrix as
    # location, rotation and a negative scale: float32 round-off moves its bake points); the others by < 0.1%
    for name, value in instanced.items():
        assert abs(value - single[name]) <= 5e-3 * single[name], (name, value, single[name])
    assert np.median([abs(v / single[n] - 1.0) for n, v in instanced.items()]) < 1e-3


def preview_reads_own_rectangles(scene, cubes, files):
    """Show Preview and render the cube Members from above in EEVEE: each pixel of each one's top
    face shows albedo × I_z read through its own rectangle (its Empty's outer ∘ the cube's inner),
    not another instance's (the sun/shade contrast is ≥ 5×)."""
    import bpy

    from hhd_lightmapper import blender_compat

    mat = cubes[0].material_slots[0].material
    scene.hhd.preview_mode = 'HHD'
    assert bpy.ops.hhd.preview_show() == {'FINISHED'}
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    size = 400
    cam.data.type, cam.data.ortho_scale = 'ORTHO', 10.0
    cam.location = (0.5, 0.5, 6.0)
    scene.camera = cam
    bpy.data.objects["Roof"].hide_render = True
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
    for obj in cubes:
        pixels, uv = top_face_pixels(obj, cam, size)
        rendered = image[pixels[:, 1], pixels[:, 0], 0]

        def error(rect, uv=uv, rendered=rendered):
            expected = albedo[0] * sample_bilinear(baked, uv * rect[:2] + rect[2:], clamp=True)[:, 0]
            return float(np.median(np.abs(rendered - expected) / np.maximum(expected, 1e-6)))

        own = error(np.array(obj.hhd.lightmap_rect))
        others = [error(np.array(o.hhd.lightmap_rect)) for o in cubes if o is not obj]
        assert own < 0.1 and own < 0.5 * min(others), (obj.name, own, others)
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert not any("HHD Preview" in n.name for n in mat.node_tree.nodes)
    scene.render.engine = 'CYCLES'
    bpy.data.objects["Roof"].hide_render = False


def gltf_nodes_carry_own_rectangles(empties, members, tmp):
    """Blender's glTF export writes each Empty's collection objects as its child nodes: each one
    carries the scaleOffset of its own Member (v flipped, docs/gltf.md), all the Empties' cube
    nodes one glTF mesh."""
    import bpy

    from hhd_lightmapper.bridge.gltf_export import gltf_scale_offset

    out = tmp / "scene.glb"
    assert bpy.ops.export_scene.gltf(filepath=str(out), export_format='GLB') == {"FINISHED"}
    doc, _ = read_glb(out)
    nodes = nodes_by_name(doc)
    rects = {m.name: m.hhd.lightmap_rect for m in members}
    meshes = set()
    for empty in empties:
        stack, found = list(nodes[empty.name].get("children", [])), {}
        while stack:
            node = doc["nodes"][stack.pop()]
            stack += node.get("children", [])
            if "mesh" in node:
                found[node["name"]] = node["extensions"]["HHD_lightmap"]["scaleOffset"]
                meshes.add((node["name"], node["mesh"]))
        assert set(found) == {"Cube", "Cylinder"}, found
        for part, scale_offset in found.items():
            assert scale_offset == pytest.approx(gltf_scale_offset(rects[f"{empty.name}/{part}"]), abs=1e-7)
    assert len(meshes) == 2  # one glTF mesh per Blender mesh


def test_nested_collection_instances_are_refused_by_name(extension, restore_hhd_settings, tmp_path):
    """An Empty whose collection holds another collection instance: Unwrap reports both by name
    and changes nothing."""
    import bpy

    scene = kit.clear_scene()
    inner = bpy.data.collections.new("Inner")
    bpy.ops.mesh.primitive_cube_add(size=0.5)
    cube = bpy.context.active_object
    for c in list(cube.users_collection):
        c.objects.unlink(cube)
    inner.objects.link(cube)
    outer = bpy.data.collections.new("Outer")
    nested = bpy.data.objects.new("Nested", None)
    nested.instance_type, nested.instance_collection = 'COLLECTION', inner
    outer.objects.link(nested)
    empty = bpy.data.objects.new("Shelf", None)
    empty.instance_type, empty.instance_collection = 'COLLECTION', outer
    scene.collection.objects.link(empty)
    kit.select([empty])
    with pytest.raises(RuntimeError, match=r"collection 'Outer' \(shown by 'Shelf'\) holds 'Nested'.*nested"):
        bpy.ops.hhd.unwrap()
    assert LAYER not in cube.data.uv_layers


def test_a_linked_collection_is_refused_by_name(extension, restore_hhd_settings, tmp_path):
    """A collection linked from another .blend (File > Link, an Empty showing it): its objects
    and meshes are read only here, so Unwrap names them and their library and changes nothing."""
    import bpy

    kit.clear_scene()
    props = bpy.data.collections.new("Props")
    bpy.context.scene.collection.children.link(props)
    bpy.ops.mesh.primitive_cube_add(size=0.5)
    cube = bpy.context.active_object
    for c in list(cube.users_collection):
        c.objects.unlink(cube)
    props.objects.link(cube)
    library, name = tmp_path / "props.blend", props.name  # "Props.001" when an earlier test left a "Props"
    bpy.data.libraries.write(str(library), {props}, fake_user=True)
    scene = kit.clear_scene()
    for c in list(bpy.data.collections):
        bpy.data.collections.remove(c)
    for datablocks in (bpy.data.objects, bpy.data.meshes):
        for block in [b for b in datablocks if b.name.startswith("Cube")]:
            datablocks.remove(block)
    with bpy.data.libraries.load(str(library), link=True) as (_, data_to):
        data_to.collections = [name]
    (linked,) = [c for c in bpy.data.collections if c.library is not None]
    empty = bpy.data.objects.new("Shelf", None)
    empty.instance_type, empty.instance_collection = 'COLLECTION', linked
    scene.collection.objects.link(empty)
    kit.select([empty])
    (member,) = linked.all_objects
    with pytest.raises(RuntimeError, match=rf"'Shelf/{member.name}' \(from .*props.blend\) is linked from a library"):
        bpy.ops.hhd.unwrap()
    assert LAYER not in member.data.uv_layers
