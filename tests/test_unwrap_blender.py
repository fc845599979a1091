"""bpy.ops.hhd.unwrap on real Blender meshes (ngons, loose parts, degenerate faces, negative
scale, modifiers, linked duplicates), through the installed extension."""
import numpy as np
import pytest

from hhd_lightmapper.core import raster
from cycles_compare import select

pytestmark = pytest.mark.bpy
LAYER = "HHD_Lightmap"


@pytest.fixture
def scene(extension):
    import bpy
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    for m in list(bpy.data.meshes):
        bpy.data.meshes.remove(m)
    s = bpy.context.scene
    s.hhd.uv_layer = LAYER
    s.hhd.resolution = 512
    s.hhd.atlas_mode = 'SHARED'
    s.hhd.texel_density = 0.0
    return s


def add(op, **kw):
    import bpy
    op(**kw)
    return bpy.context.active_object


def uv_triangles(obj, name=LAYER, evaluated=False):
    import bpy
    mesh = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh() if evaluated else obj.data
    mesh.calc_loop_triangles()
    loops = np.zeros(len(mesh.loop_triangles) * 3, int)
    mesh.loop_triangles.foreach_get("loops", loops)
    uv = np.zeros(len(mesh.loops) * 2, np.float32)
    mesh.uv_layers[name].data.foreach_get("uv", uv)
    out = uv.reshape(-1, 2)[loops].reshape(-1, 3, 2).astype(np.float64)
    if evaluated:
        obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh_clear()
    return out


def awkward_objects():
    import bpy
    objs = [add(bpy.ops.mesh.primitive_cube_add, location=(0, 0, 0)),
            add(bpy.ops.mesh.primitive_uv_sphere_add, location=(3, 0, 0)),
            add(bpy.ops.mesh.primitive_circle_add, fill_type='NGON', location=(6, 0, 0))]
    mirrored = add(bpy.ops.mesh.primitive_cube_add, location=(0, 3, 0))
    mirrored.scale = (-1.0, 1.0, 2.0)
    objs.append(mirrored)
    # a mesh with a loose vertex, a loose edge and a zero-area face
    mesh = bpy.data.meshes.new("Awkward")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (5, 5, 5), (6, 6, 6), (7, 7, 7), (2, 0, 0), (3, 0, 0)],
                     [(5, 6)], [(0, 1, 2, 3), (1, 7, 8)])
    awkward = bpy.data.objects.new("Awkward", mesh)
    bpy.context.scene.collection.objects.link(awkward)
    objs.append(awkward)
    smooth = add(bpy.ops.mesh.primitive_cube_add, location=(3, 3, 0))
    smooth.modifiers.new("Subdivision", 'SUBSURF').levels = 2
    objs.append(smooth)
    return objs


def test_unwrap_writes_only_its_layer_and_packs_without_overlap(scene):
    import bpy
    objs = awkward_objects()
    before = {o.name: {l.name: np.array([d.uv[:] for d in l.data]) for l in o.data.uv_layers} for o in objs}
    active_before = {o.name: o.data.uv_layers.active.name if o.data.uv_layers.active else None for o in objs}
    select(objs)
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    for _ in range(2):                                   # re-running replaces only that layer
        for o in objs:
            layers = [l.name for l in o.data.uv_layers]
            assert layers.count(LAYER) == 1
            for name, data in before[o.name].items():
                np.testing.assert_array_equal(np.array([d.uv[:] for d in o.data.uv_layers[name].data]), data)
            if active_before[o.name]:
                assert o.data.uv_layers.active.name == active_before[o.name]
        assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    texels = []
    for o in objs:
        uv = uv_triangles(o)
        assert (uv >= 0).all() and (uv <= 1).all()
        texels.append(set(raster.rasterise(uv, 512, 512).texel.tolist()))
    for i in range(len(texels)):
        for j in range(i + 1, len(texels)):
            assert not texels[i] & texels[j], (objs[i].name, objs[j].name)
    summary = scene.hhd.unwrap_summary
    assert "charts" in summary and "512×512" in summary and "% used" in summary
    for o in objs:
        assert f"{o.name}:" in summary


def test_subdivision_modifier_carries_the_lightmap_uvs_into_the_evaluated_mesh(scene):
    import bpy
    obj = add(bpy.ops.mesh.primitive_cube_add)
    obj.modifiers.new("Subdivision", 'SUBSURF').levels = 2
    select([obj])
    bpy.ops.hhd.unwrap()
    base = set(raster.rasterise(uv_triangles(obj), 512, 512).texel.tolist())
    evaluated = uv_triangles(obj, evaluated=True)
    assert len(evaluated) == 16 * 12                     # 6 quads → 96 quads at level 2 → 192 triangles
    inside = set(raster.rasterise(evaluated, 512, 512).texel.tolist())
    assert len(inside - base) <= 0.02 * len(inside)      # subdivided UVs stay inside the base charts


def test_linked_duplicates_are_refused_with_the_fix_then_fixed_on_request(scene):
    import bpy
    a = add(bpy.ops.mesh.primitive_cube_add)
    b = bpy.data.objects.new("Linked Copy", a.data)
    b.location = (3, 0, 0)
    bpy.context.scene.collection.objects.link(b)
    select([a, b])
    with pytest.raises(RuntimeError, match="share the mesh.*single user"):
        bpy.ops.hhd.unwrap()
    assert LAYER not in a.data.uv_layers                 # nothing changed
    assert bpy.ops.hhd.unwrap(make_single_user=True) == {'FINISHED'}
    assert a.data != b.data and LAYER in a.data.uv_layers and LAYER in b.data.uv_layers


def test_per_object_override_gets_its_own_atlas_and_poll_explains(scene):
    import bpy
    a = add(bpy.ops.mesh.primitive_cube_add)
    b = add(bpy.ops.mesh.primitive_cube_add, location=(3, 0, 0))
    b.hhd.resolution = 256
    select([a, b])
    bpy.ops.hhd.unwrap()
    assert "512×512, 256×256" in scene.hhd.unwrap_summary
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    assert not bpy.ops.hhd.unwrap.poll()
