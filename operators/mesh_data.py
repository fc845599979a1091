"""Reading Blender meshes into numpy and writing lightmap UV layers back (the bpy boundary).

Reads use foreach_get into preallocated arrays. Unwrapping reads each object's own mesh
(obj.data, before modifiers): the UV layer written there flows through the modifier stack, so
the bake, which reads the evaluated mesh, sees UVs for subdivided/modified geometry too.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import BakeError
from ..core.unwrap import UnwrapMesh

MAX_UV_LAYERS = 8   # Blender's limit per mesh


def target_meshes(objects) -> list:
    """The mesh objects among `objects`, in name order (deterministic atlas layout)."""
    return sorted((o for o in objects if o.type == 'MESH'), key=lambda o: o.name)


def shared_meshes(objects) -> dict:
    """{mesh name: [object names]} for meshes used by more than one of `objects`."""
    users = {}
    for o in objects:
        users.setdefault(o.data.name, []).append(o.name)
    return {mesh: names for mesh, names in users.items() if len(names) > 1}


def make_single_user(objects) -> int:
    """Give every object but the first user of a shared mesh its own copy; returns the count."""
    seen, copies = set(), 0
    for o in objects:
        if o.data.name in seen:
            o.data = o.data.copy()
            copies += 1
        seen.add(o.data.name)
    return copies


def read_unwrap_mesh(obj) -> tuple[UnwrapMesh, np.ndarray]:
    """(UnwrapMesh in world space, loop indices (T, 3) of each triangle corner) for obj.data."""
    mesh = obj.data
    mesh.calc_loop_triangles()
    n_tri, n_vert = len(mesh.loop_triangles), len(mesh.vertices)
    if n_tri == 0:
        raise BakeError(f"'{obj.name}' has no faces to unwrap")
    co = np.zeros(n_vert * 3, dtype=np.float64)
    mesh.vertices.foreach_get("co", co)
    tri = np.zeros(n_tri * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", tri)
    loops = np.zeros(n_tri * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("loops", loops)
    m = np.array(obj.matrix_world, dtype=np.float64)
    world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    overrides = obj.hhd
    return UnwrapMesh(obj.name, world, tri.reshape(-1, 3),
                      resolution=overrides.resolution or None,
                      texel_density=overrides.texel_density or None), loops.reshape(-1, 3)


def write_uv_layer(obj, name: str, loops: np.ndarray, uv: np.ndarray) -> int:
    """Write per-corner UVs `(T, 3, 2)` into the layer `name` (created if missing), leaving every
    other layer and the active/render-active choice untouched. Returns the number of polygons
    whose triangles landed in different charts (their loops can hold only one UV)."""
    mesh = obj.data
    layers = mesh.uv_layers
    layer = layers.get(name)
    if layer is None:
        if len(layers) >= MAX_UV_LAYERS:
            raise BakeError(f"'{obj.name}' already has {MAX_UV_LAYERS} UV maps (Blender's limit): "
                            f"remove one or set the lightmap UV layer to an existing name")
        active = layers.active.name if layers.active else None
        render = next((l.name for l in layers if l.active_render), None)
        layer = layers.new(name=name, do_init=False)
        if active is not None:
            layers.active = layers[active]
        if render is not None:
            layers[render].active_render = True
    data = np.zeros((len(mesh.loops), 2), dtype=np.float32)
    flat_loops = loops.ravel()
    flat_uv = uv.reshape(-1, 2)
    data[flat_loops] = flat_uv
    mismatch = np.abs(data[flat_loops] - flat_uv).max(axis=1) > 1e-6
    layer.data.foreach_set("uv", data.ravel())
    mesh.update()
    if not mismatch.any():
        return 0
    poly = np.zeros(len(mesh.loop_triangles), dtype=np.int64)
    mesh.loop_triangles.foreach_get("polygon_index", poly)
    return len(np.unique(poly[mismatch.reshape(-1, 3).any(axis=1)]))


def _material_albedo(mat) -> tuple:
    """Constant linear RGB albedo of a material: the Principled BSDF's unlinked Base Color, else
    the viewport colour. (Texture albedo comes with the scene extraction of the bake.)"""
    if mat is None:
        return (0.8, 0.8, 0.8)
    if mat.use_nodes and mat.node_tree:
        for node in mat.node_tree.nodes:
            if node.type == 'BSDF_PRINCIPLED' and not node.inputs["Base Color"].is_linked:
                return tuple(node.inputs["Base Color"].default_value[:3])
    return tuple(mat.diffuse_color[:3])


def read_triangles(mesh, matrix_world):
    """World-space triangles of a mesh: (positions (T, 3, 3), loop indices (T, 3), material
    index (T,)), or None when it has no faces."""
    mesh.calc_loop_triangles()
    n_tri = len(mesh.loop_triangles)
    if n_tri == 0:
        return None
    loops = np.zeros(n_tri * 3, np.int64)
    mesh.loop_triangles.foreach_get("loops", loops)
    verts = np.zeros(n_tri * 3, np.int64)
    mesh.loop_triangles.foreach_get("vertices", verts)
    mat_index = np.zeros(n_tri, np.int64)
    mesh.loop_triangles.foreach_get("material_index", mat_index)
    co = np.zeros(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    m = np.array(matrix_world, dtype=np.float64)
    world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    return world[verts].reshape(-1, 3, 3), loops.reshape(-1, 3), mat_index


def slot_albedo(obj, mat_index):
    """Constant albedo (T, 3) per triangle from the object's material slots."""
    albedo = np.array([_material_albedo(s.material) for s in obj.material_slots] or [(0.8, 0.8, 0.8)])
    return albedo[np.minimum(mat_index, len(albedo) - 1)]


def read_surface(objects, uv_layer: str, depsgraph):
    """SurfaceTriangles of the evaluated meshes of `objects` (modifiers applied, world space):
    positions, corner normals (smooth/flat/custom as Blender shades them), lightmap UVs, object
    index and constant albedo per triangle."""
    from ..core.bakepoints import SurfaceTriangles
    parts = []
    for index, obj in enumerate(objects):
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            if uv_layer not in mesh.uv_layers:
                raise BakeError(f"'{obj.name}' has no '{uv_layer}' UV layer: run Unwrap first")
            tris = read_triangles(mesh, evaluated.matrix_world)
            if tris is None:
                continue
            positions, loops, mat_index = tris
            normals = np.zeros(len(mesh.loops) * 3)
            mesh.corner_normals.foreach_get("vector", normals)
            uv = np.zeros(len(mesh.loops) * 2)
            mesh.uv_layers[uv_layer].data.foreach_get("uv", uv)
            normal_matrix = np.linalg.inv(np.array(evaluated.matrix_world, dtype=np.float64)[:3, :3]).T
            n_world = normals.reshape(-1, 3) @ normal_matrix.T
            n_world /= np.maximum(np.linalg.norm(n_world, axis=1, keepdims=True), 1e-30)
            parts.append((positions, n_world[loops], uv.reshape(-1, 2)[loops], np.full(len(loops), index),
                          slot_albedo(evaluated, mat_index)))
        finally:
            evaluated.to_mesh_clear()
    return SurfaceTriangles(*(np.concatenate(x) for x in zip(*parts)))
