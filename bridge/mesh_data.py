"""Reading Blender meshes into numpy and writing lightmap UV layers back (the bpy boundary).

Reads use foreach_get into preallocated arrays. Unwrapping reads each object's own mesh
(obj.data, before modifiers): the UV layer written there flows through the modifier stack, so
the bake, which reads the evaluated mesh, sees UVs for subdivided/modified geometry too.
"""

from __future__ import annotations

import numpy as np

from .. import blender_compat
from ..core.errors import BakeError
from ..core.unwrap import UnwrapMesh

MAX_UV_LAYERS = 8  # Blender's limit per mesh


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
    """(UnwrapMesh in world space with each triangle's polygon, loop indices (T, 3) of each
    triangle corner) for obj.data."""
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
    polygons = np.zeros(n_tri, dtype=np.int64)
    mesh.loop_triangles.foreach_get("polygon_index", polygons)
    m = np.array(obj.matrix_world, dtype=np.float64)
    world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    overrides = obj.hhd
    return UnwrapMesh(
        obj.name,
        world,
        tri.reshape(-1, 3),
        resolution=overrides.resolution or None,
        texel_density=overrides.texel_density or None,
        polygons=polygons,
    ), loops.reshape(-1, 3)


def write_uv_layer(obj, name: str, loops: np.ndarray, uv: np.ndarray) -> None:
    """Write per-corner UVs `(T, 3, 2)` into the layer `name` (created if missing), leaving every
    other layer and the active/render-active choice untouched. The unwrap gives every corner of
    a loop one UV (a polygon's triangles share a chart), so the layer holds exactly `uv`; a
    loop given two different UVs is a bug, refused before anything is written."""
    mesh = obj.data
    data = np.zeros((len(mesh.loops), 2), dtype=np.float32)
    flat_loops = loops.ravel()
    flat_uv = np.asarray(uv, dtype=np.float32).reshape(-1, 2)
    data[flat_loops] = flat_uv
    if (data[flat_loops] != flat_uv).any():
        raise BakeError(
            f"'{obj.name}': the unwrap gave one loop two lightmap UVs (a bug: please report "
            "it with the .blend); the UV layer was left unchanged"
        )
    layers = mesh.uv_layers
    layer = layers.get(name)
    if layer is None:
        if len(layers) >= MAX_UV_LAYERS:
            raise BakeError(
                f"'{obj.name}' already has {MAX_UV_LAYERS} UV maps (Blender's limit): "
                f"remove one or set the lightmap UV layer to an existing name"
            )
        active = layers.active.name if layers.active else None
        render = next((l.name for l in layers if l.active_render), None)
        layer = layers.new(name=name, do_init=False)
        if active is not None:
            layers.active = layers[active]
        if render is not None:
            layers[render].active_render = True
    layer.data.foreach_set("uv", data.ravel())
    mesh.update()


def surface_node(mat):
    """The node feeding the active Material Output's Surface, or None."""
    if mat is None or blender_compat.node_tree_of(mat) is None:
        return None
    output = next((n for n in mat.node_tree.nodes if n.type == 'OUTPUT_MATERIAL' and n.is_active_output), None)
    if output is None or not output.inputs["Surface"].is_linked:
        return None
    return output.inputs["Surface"].links[0].from_node


def material_albedo_source(mat):
    """Where a material's albedo comes from: ('constant', rgb, note or None) or ('texture',
    (Image Texture node, UV map name or '' for the render UV map), None). A Principled BSDF's
    unlinked Base Color is a constant; linked straight from an Image Texture it is that image
    through the texture's own UV map; an Emission shader alone reflects nothing (black); any
    other setup falls back to the viewport colour with a note saying so."""
    if mat is None:
        return 'constant', (0.8, 0.8, 0.8), None
    surface = surface_node(mat)
    if surface is not None and surface.type == 'EMISSION':
        return 'constant', (0.0, 0.0, 0.0), None  # an Emission shader reflects nothing
    bsdf = None
    if mat.node_tree is not None:
        bsdf = next((n for n in mat.node_tree.nodes if n.type == 'BSDF_PRINCIPLED'), None)
    if bsdf is None:
        return (
            'constant',
            tuple(mat.diffuse_color[:3]),
            (f"material '{mat.name}': no Principled BSDF; baking with its viewport colour"),
        )
    base = bsdf.inputs["Base Color"]
    if not base.is_linked:
        return 'constant', tuple(base.default_value[:3]), None
    node = base.links[0].from_node
    if node.type == 'TEX_IMAGE' and node.image is not None:
        vector = node.inputs["Vector"]
        uv_map = ''
        if vector.is_linked and vector.links[0].from_node.type == 'UVMAP':
            uv_map = vector.links[0].from_node.uv_map
        return 'texture', (node, uv_map), None
    return (
        'constant',
        tuple(mat.diffuse_color[:3]),
        (
            f"material '{mat.name}': Base Color comes from a {node.type.replace('_', ' ').lower()} node; "
            "baking with its viewport colour"
        ),
    )


class TextureCache:
    """Image Texture nodes read once as core Textures (linear pixels, interpolation, extension),
    shared by every triangle using them."""

    def __init__(self):
        self.images: list = []
        self._index: dict = {}

    def add(self, node) -> int:
        from ..core.textures import Texture, srgb_to_linear

        image = node.image
        key = (image.name, node.interpolation, node.extension)
        if key not in self._index:
            w, h = image.size
            if w == 0 or h == 0:
                raise BakeError(f"image '{image.name}' has no pixels (missing file?)")
            px = np.zeros(w * h * 4, dtype=np.float32)
            image.pixels.foreach_get(px)
            rgb = px.reshape(h, w, 4)[..., :3].astype(np.float64)
            if image.colorspace_settings.name == 'sRGB' and not image.is_float:
                rgb = srgb_to_linear(rgb)
            self._index[key] = len(self.images)
            self.images.append(Texture(rgb, node.interpolation, node.extension))
        return self._index[key]


def triangle_albedo(obj, mesh, loops, mat_index, cache: TextureCache, notes: list):
    """(albedo (T, 3), texture_index (T,), texture_uv (T, 3, 2)) of a mesh's triangles."""
    slots = [s.material for s in obj.material_slots] or [None]
    constant, texture, uv_name = [], [], []
    for mat in slots:
        kind, value, note = material_albedo_source(mat)
        if note and note not in notes:
            notes.append(note)
        constant.append(value if kind == 'constant' else (0.8, 0.8, 0.8))
        texture.append(cache.add(value[0]) if kind == 'texture' else -1)
        uv_name.append(value[1] if kind == 'texture' else None)
    pick = np.minimum(mat_index, len(slots) - 1)
    texture_uv = np.zeros(loops.shape + (2,))
    for name in {n for n in uv_name if n is not None}:
        layer = mesh.uv_layers.get(name) if name else next((l for l in mesh.uv_layers if l.active_render), None)
        if layer is None:
            raise BakeError(f"'{obj.name}' has no UV map '{name or '(render)'}' for its albedo texture")
        uv = np.zeros(len(mesh.loops) * 2)
        layer.data.foreach_get("uv", uv)
        rows = np.isin(pick, [i for i, n in enumerate(uv_name) if n == name])
        texture_uv[rows] = uv.reshape(-1, 2)[loops[rows]]
    return np.array(constant)[pick], np.array(texture)[pick], texture_uv


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


def read_shape(obj, depsgraph):
    """SurfaceTriangles of the evaluated mesh of `obj` for the shape alone (positions, corner
    normals, polygon per triangle, world space; no UVs or albedo: zeros), or None without faces.
    What `core.inward` needs, before any unwrap."""
    from ..core.bakepoints import SurfaceTriangles

    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        tris = read_triangles(mesh, evaluated.matrix_world)
        if tris is None:
            return None
        positions, loops, _mat = tris
        n_world = world_corner_normals(mesh, evaluated.matrix_world)
        polygon = triangle_polygons(mesh, len(loops))
    finally:
        evaluated.to_mesh_clear()
    t = len(loops)
    return SurfaceTriangles(
        positions, n_world[loops], np.zeros((t, 3, 2)), np.zeros(t, np.int64), np.zeros((t, 3)), polygon=polygon
    )


def world_corner_normals(mesh, matrix_world) -> np.ndarray:
    """(loops, 3) the mesh's corner normals (smooth/flat/custom as Blender shades them) in world
    space, through the normal matrix (a mirrored object's normals stay outward), unit length."""
    normals = np.zeros(len(mesh.loops) * 3)
    mesh.corner_normals.foreach_get("vector", normals)
    normal_matrix = np.linalg.inv(np.array(matrix_world, dtype=np.float64)[:3, :3]).T
    n_world = normals.reshape(-1, 3) @ normal_matrix.T
    n_world /= np.maximum(np.linalg.norm(n_world, axis=1, keepdims=True), 1e-30)
    return n_world


def triangle_polygons(mesh, count: int) -> np.ndarray:
    """(count,) int64: the polygon of each of the mesh's `count` loop triangles."""
    polygon = np.zeros(count, np.int64)
    mesh.loop_triangles.foreach_get("polygon_index", polygon)
    return polygon


def read_surface(objects, uv_layer: str, depsgraph, cache: TextureCache | None = None, notes: list | None = None):
    """SurfaceTriangles of the evaluated meshes of `objects` (modifiers applied, world space):
    positions, corner normals (smooth/flat/custom as Blender shades them), lightmap UVs, object
    index and albedo (constant or image texture) per triangle. `notes` collects fallbacks."""
    from ..core.bakepoints import SurfaceTriangles

    cache = cache or TextureCache()
    notes = notes if notes is not None else []
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
            n_world = world_corner_normals(mesh, evaluated.matrix_world)
            uv = np.zeros(len(mesh.loops) * 2)
            mesh.uv_layers[uv_layer].data.foreach_get("uv", uv)
            albedo, tex_index, tex_uv = triangle_albedo(evaluated, mesh, loops, mat_index, cache, notes)
            polygon = triangle_polygons(mesh, len(loops))
            parts.append(
                (
                    positions,
                    n_world[loops],
                    uv.reshape(-1, 2)[loops],
                    np.full(len(loops), index),
                    albedo,
                    tex_index,
                    tex_uv,
                    polygon,
                )
            )
        finally:
            evaluated.to_mesh_clear()
    if not parts:
        raise BakeError("none of the objects has faces to bake")
    *arrays, polygon = (np.concatenate(x) for x in zip(*parts))
    return SurfaceTriangles(*arrays, textures=cache.images, polygon=polygon)
