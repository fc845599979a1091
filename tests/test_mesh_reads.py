"""The mesh reads of `bridge.mesh_data` that take Blender's arrays in one copy (`corner_vertices`
from the `.corner_vert` attribute, `polygon_materials` from `material_index`) against the RNA
properties read item by item, on evaluated meshes of every kind of polygon."""

import numpy as np
import pytest

pytestmark = pytest.mark.bpy


def _cube(size):
    h = size / 2
    verts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return verts, faces


def _ngon(sides):
    angles = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    return [(np.cos(a), np.sin(a), 0.0) for a in angles], [tuple(range(sides))]


def _grid(nx, ny):
    verts = [(x, y, 0.0) for y in range(ny + 1) for x in range(nx + 1)]
    faces = [(y * (nx + 1) + x, y * (nx + 1) + x + 1, (y + 1) * (nx + 1) + x + 1, (y + 1) * (nx + 1) + x) for y in range(ny) for x in range(nx)]  # fmt: skip
    return verts, faces


@pytest.fixture
def meshes():
    """Objects whose evaluated meshes the test reads as the bake does (to_mesh): quads with three
    materials, an n-gon, a mirrored and subdivided cube (modifiers), triangles only (the
    triangulation's shortcut), a mirrored grid (negative scale) with no material_index attribute."""
    import bpy

    made = []

    def add(name, shape, modifiers=()):
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata(shape[0], [], shape[1])
        obj = bpy.data.objects.new(name, mesh)
        bpy.context.scene.collection.objects.link(obj)
        for kind in modifiers:
            obj.modifiers.new(kind.lower(), kind)
        made.append(obj)
        return obj

    cube = add("reads_cube", _cube(1.0))
    for k in range(3):
        cube.data.materials.append(bpy.data.materials.new(f"reads_{k}"))
    cube.data.polygons.foreach_set("material_index", np.array([0, 1, 2, 2, 1, 0], np.int32))
    add("reads_ngon", _ngon(11))
    add("reads_modified", _cube(2.0), ("MIRROR", "SUBSURF"))
    add("reads_triangulated", _ngon(7), ("SUBSURF", "TRIANGULATE"))
    plain = add("reads_plain", _grid(3, 4))
    plain.scale.x = -1.0
    bpy.context.view_layer.update()
    yield made
    for obj in made:
        mesh = obj.data
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)


def test_mesh_arrays_read_in_one_copy_equal_the_rna_properties(meshes):
    import bpy

    from hhd_lightmapper.bridge import mesh_data

    depsgraph = bpy.context.evaluated_depsgraph_get()
    assert "material_index" not in meshes[-1].data.attributes  # the fallback to slot 0 is exercised
    shortcuts = 0
    for obj in meshes:
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            corners = mesh_data.corner_vertices(mesh)
            assert corners.dtype == np.int32
            assert corners.tolist() == [loop.vertex_index for loop in mesh.loops]
            materials = mesh_data.polygon_materials(mesh)
            assert materials.tolist() == [p.material_index for p in mesh.polygons]
            mesh.calc_loop_triangles()
            tri_corners = mesh_data.triangle_corners(mesh, len(mesh.loop_triangles))
            assert tri_corners.tolist() == [c for tri in mesh.loop_triangles for c in tri.loops]
            shortcuts += len(mesh.loops) == 3 * len(mesh.polygons)
            positions, loops, mat_index = mesh_data.read_triangles(mesh, evaluated.matrix_world)
            m = np.array(evaluated.matrix_world)
            for t, tri in enumerate(mesh.loop_triangles):
                order = list(tri.vertices)[:: -1 if np.linalg.det(m[:3, :3]) < 0 else 1]
                world = [m[:3, :3] @ np.array(mesh.vertices[v].co) + m[:3, 3] for v in order]
                np.testing.assert_allclose(positions[t], world, rtol=0, atol=1e-6)
                assert mat_index[t] == mesh.polygons[tri.polygon_index].material_index
        finally:
            evaluated.to_mesh_clear()
    assert sorted(set(mesh_data.polygon_materials(meshes[0].data).tolist())) == [0, 1, 2]
    assert shortcuts == 1  # the triangulated mesh: its own triangulation
