"""Reading Blender meshes into numpy and writing lightmap UV layers back (the bpy boundary).

Reads use foreach_get into preallocated arrays of the property's own type (float32 for
coordinates, normals and UVs: `read_floats`), Blender's fast path; into another type it
converts item by item. Properties Blender computes per item (a corner's vertex, a polygon's
material) are read from the mesh's attribute arrays instead (`corner_vertices`,
`polygon_materials`). Unwrapping reads each object's own mesh
(obj.data, before modifiers): the UV layer written there flows through the modifier stack, so
the bake, which reads the evaluated mesh, sees UVs for subdivided/modified geometry too.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import BakeError
from ..core.unwrap import UnwrapMesh
from . import materials
from .collection_instances import Member
from .materials import TextureCache

MAX_UV_LAYERS = 8  # Blender's limit per mesh


def read_floats(collection, attr: str, count: int) -> np.ndarray:
    """(count,) float64: the float32 RNA property `attr` of every item of `collection`
    (flattened), read through foreach_get's fast path and widened exactly."""
    out = np.empty(count, np.float32)
    collection.foreach_get(attr, out)
    return out.astype(np.float64)


def target_meshes(objects) -> list:
    """The mesh objects among `objects`, in name order (deterministic atlas layout)."""
    return sorted((o for o in objects if o.type == 'MESH'), key=lambda o: o.name)


def refuse_linked(objects) -> None:
    """Raise BakeError naming the receivers whose object, mesh or instancing Empty is linked from
    another .blend (a library: read only here), which cannot hold lightmap UVs or a rectangle."""
    linked = []
    for o in objects:
        parts = (o.instancer, o.object, o.data) if isinstance(o, Member) else (o, o.data)
        library = next((p.library for p in parts if p.library is not None), None)
        if library is not None:
            linked.append(f"'{o.name}' (from {library.filepath})")
    if linked:
        raise BakeError(
            f"{', '.join(linked)} {'is' if len(linked) == 1 else 'are'} linked from a library: linked data is read "
            "only here and cannot hold lightmap UVs; make it local (Object > Relations > Make Local) or unwrap it "
            "in its own .blend"
        )


def shared_meshes(objects) -> dict:
    """{mesh name: [object names]} for meshes used by more than one of `objects`."""
    users = {}
    for o in objects:
        users.setdefault(o.data.name, []).append(o.name)
    return {mesh: names for mesh, names in users.items() if len(names) > 1}


def outside_users(objects) -> dict:
    """{mesh name: [object names]} of the objects outside `objects` that use one of their meshes
    and were unwrapped (they hold an atlas): unwrapping `objects` rewrites those objects'
    lightmap UVs too (one layer per mesh)."""
    mine = {o.data.name for o in objects}
    inside = {o.name for o in objects}
    out: dict = {}
    for o in bpy_objects():
        if o.type == 'MESH' and o.name not in inside and o.data.name in mine and o.hhd.atlas:
            out.setdefault(o.data.name, []).append(o.name)
    return out


def bpy_objects():
    import bpy

    return bpy.data.objects


#: identity rectangle (scale u, scale v, offset u, offset v) of an object with its own mesh
IDENTITY_RECT = (1.0, 1.0, 0.0, 0.0)


def lightmap_rect(obj) -> tuple[float, float, float, float]:
    """The object's lightmap rectangle: atlas UV = layer UV × rect[:2] + rect[2:] (`core.unwrap.instances`);
    identity unless it is an instance of a shared mesh."""
    return tuple(float(v) for v in obj.hhd.lightmap_rect)  # type: ignore[return-value]


def make_single_user(objects) -> int:
    """Give every object but the first user of a shared mesh its own copy; returns the count. A
    collection instance's Members keep their mesh (it is the collection's): every object among
    `objects` that uses it gets a copy."""
    seen, copies = {o.data.name for o in objects if isinstance(o, Member)}, 0
    for o in objects:
        if isinstance(o, Member):
            continue
        if o.data.name in seen:
            o.data = o.data.copy()
            copies += 1
        seen.add(o.data.name)
    return copies


def read_unwrap_mesh(obj, instance_of: str | None = None) -> tuple[UnwrapMesh, np.ndarray]:
    """(UnwrapMesh in world space with each triangle's polygon, loop indices (T, 3) of each
    triangle corner) for obj.data; `instance_of`: the shared mesh's name for a linked duplicate
    unwrapped as an instance (`core.unwrap.instances`). A collection instance's Member
    (`collection_instances`) is always an instance, placed with its collection (its bundle)."""
    mesh = obj.data
    mesh.calc_loop_triangles()
    n_tri, n_vert = len(mesh.loop_triangles), len(mesh.vertices)
    if n_tri == 0:
        raise BakeError(f"'{obj.name}' has no faces to unwrap")
    co = read_floats(mesh.vertices, "co", n_vert * 3)
    loops = triangle_corners(mesh, n_tri)
    tri = corner_vertices(mesh)[loops].astype(np.int64)
    polygons = triangle_polygons(mesh, n_tri)
    m = np.array(obj.matrix_world, dtype=np.float64)
    world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    tri, loops = tri.reshape(-1, 3), loops.reshape(-1, 3)
    if mirrors(m):
        tri, loops = tri[:, ::-1].copy(), loops[:, ::-1].copy()
    overrides = obj.hhd
    return UnwrapMesh(
        obj.name,
        world,
        tri,
        resolution=overrides.resolution or None,
        texel_density=overrides.texel_density or None,
        polygons=polygons,
        instance_of=obj.data.name if isinstance(obj, Member) else instance_of,
        bundle=obj.bundle() if isinstance(obj, Member) else None,
    ), loops


def mirrors(matrix) -> bool:
    """Whether a 4×4 object-to-world matrix turns space inside out (negative determinant: an odd
    number of negative scales, the usual way to model symmetric props). Its triangles' corners
    then wind the other way in world space, so the readers reverse them: the winding normal
    points out again, as Blender and Cycles shade a mirrored object."""
    return bool(np.linalg.det(np.asarray(matrix, dtype=np.float64)[:3, :3]) < 0.0)


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


def triangle_albedo(obj, mesh, loops, mat_index, cache: TextureCache, notes: list):
    """(albedo (T, 3), texture_index (T,), texture_uv (T, 3, 2)) of a mesh's triangles, each
    material's albedo as `materials.albedo_of` evaluates its node tree."""
    slots = [s.material for s in obj.material_slots] or [None]
    constant, texture, uv_name = [], [], []
    for mat in slots:
        value, index, uv = materials.albedo_of(mat, cache, notes)
        constant.append(value)
        texture.append(index)
        uv_name.append(uv)
    pick = np.minimum(mat_index, len(slots) - 1)
    texture_uv = np.zeros(loops.shape + (2,))
    for name in {n for n in uv_name if n is not None}:
        rows = np.isin(pick, [i for i, n in enumerate(uv_name) if n == name])
        texture_uv[rows] = materials.uv_layer(obj, mesh, name, "albedo")[loops[rows]]
    return np.array(constant)[pick], np.array(texture)[pick], texture_uv


def read_triangles(mesh, matrix_world):
    """World-space triangles of a mesh: (positions (T, 3, 3), loop indices (T, 3), material
    index (T,)), or None when it has no faces. Corners wind counter-clockwise about the outward
    normal in world space, also for a mirrored object (`mirrors`)."""
    mesh.calc_loop_triangles()
    n_tri = len(mesh.loop_triangles)
    if n_tri == 0:
        return None
    loops = triangle_corners(mesh, n_tri)
    verts = corner_vertices(mesh)[loops]
    mat_index = polygon_materials(mesh)[triangle_polygons(mesh, n_tri)]
    co = read_floats(mesh.vertices, "co", len(mesh.vertices) * 3)
    m = np.array(matrix_world, dtype=np.float64)
    world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    verts, loops = verts.reshape(-1, 3), loops.reshape(-1, 3)
    if mirrors(m):  # corners in reverse: the winding normal points out again (`mirrors`)
        verts, loops = verts[:, ::-1], loops[:, ::-1]
    return world[verts], np.ascontiguousarray(loops), mat_index


def read_shape(obj, depsgraph):
    """SurfaceTriangles of the evaluated mesh of `obj` for the shape alone (positions, corner
    normals, polygon per triangle, world space; no UVs or albedo: zeros), or None without faces.
    What `core.bakepoints.inward` needs, before any unwrap."""
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
    normals = read_floats(mesh.corner_normals, "vector", len(mesh.loops) * 3)
    n_world = normals.reshape(-1, 3) @ normal_matrix(matrix_world).T
    n_world /= np.maximum(np.linalg.norm(n_world, axis=1, keepdims=True), 1e-30)
    return n_world


def normal_matrix(matrix_world) -> np.ndarray:
    """(3, 3) what carries a 4×4 object-to-world matrix's normals to world space, up to a positive
    factor: the inverse transpose of its 3×3 part, computed as its cofactor matrix times the
    sign of its determinant, so an object scaled flat (determinant 0: a cube at Z scale 0 is a
    double-sided square) keeps the normals that survive (± the flattened axis) instead of
    failing to invert."""
    m = np.asarray(matrix_world, dtype=np.float64)[:3, :3]
    cofactor = np.cross(m[:, [1, 2, 0]].T, m[:, [2, 0, 1]].T).T  # columns c1×c2, c2×c0, c0×c1
    return cofactor * (-1.0 if np.linalg.det(m) < 0.0 else 1.0)


def triangle_polygons(mesh, count: int) -> np.ndarray:
    """(count,) int64: the polygon of each of the mesh's `count` loop triangles."""
    polygon = np.empty(count, np.int32)
    mesh.loop_triangle_polygons.foreach_get("value", polygon)  # a flat array; loop_triangles' is per item
    return polygon.astype(np.int64)


def triangle_corners(mesh, count: int) -> np.ndarray:
    """(count · 3,) int64: the corners (loop indices) of the mesh's `count` loop triangles, flat.
    A mesh of triangles only is its own triangulation: triangle k is polygon k, its corners
    3k, 3k + 1, 3k + 2 (polygons' corners follow one another). Others are read from
    `loop_triangles`, item by item inside Blender."""
    if len(mesh.loops) == 3 * len(mesh.polygons) == 3 * count:
        return np.arange(count * 3, dtype=np.int64)
    loops = np.empty(count * 3, np.int64)
    mesh.loop_triangles.foreach_get("loops", loops)
    return loops


def corner_vertices(mesh) -> np.ndarray:
    """(loops,) int32: each corner's vertex (a triangle's vertices are its corners':
    `corner_vertices(mesh)[loops]`). Read from the mesh's own array, its `.corner_vert`
    attribute, in one copy; `loops`' vertex_index (the fallback) goes through RNA item by item."""
    out = np.empty(len(mesh.loops), np.int32)
    attribute = _attribute(mesh, ".corner_vert", 'CORNER')
    if attribute is not None:
        attribute.data.foreach_get("value", out)
    else:
        mesh.loops.foreach_get("vertex_index", out)
    return out


def polygon_materials(mesh) -> np.ndarray:
    """(polygons,) int64: each polygon's material index, from its `material_index` attribute in
    one copy (polygons' property goes through RNA item by item); a mesh without the attribute
    has every polygon on slot 0."""
    index = np.zeros(len(mesh.polygons), np.int32)
    attribute = _attribute(mesh, "material_index", 'FACE')
    if attribute is not None:
        attribute.data.foreach_get("value", index)
    return index.astype(np.int64)


def _attribute(mesh, name: str, domain: str):
    """The mesh's integer attribute `name` on `domain`, or None where it has none."""
    attribute = mesh.attributes.get(name)
    if attribute is None or attribute.domain != domain or attribute.data_type != 'INT':
        return None
    return attribute


def no_faces_warning(name: str) -> str:
    """The warning for a receiver whose evaluated mesh has no faces."""
    return f"'{name}': its modifiers leave no faces; nothing baked for it, its texels stay empty"


def read_surface(
    objects, uv_layer: str, depsgraph, cache: TextureCache | None = None, notes: list | None = None, tick=None
):
    """SurfaceTriangles of the evaluated meshes of `objects` (modifiers applied, world space):
    positions, corner normals (smooth/flat/custom as Blender shades them), lightmap UVs (an
    instance's through its rectangle, `lightmap_rect`: atlas UVs for every object), object
    index and albedo (constant or image texture) per triangle. `notes` collects fallbacks;
    `tick` (a `core.progress.Tick`) is told the share of the objects read."""
    from ..core import progress
    from ..core.bakepoints import SurfaceTriangles

    cache = cache or TextureCache()
    notes = notes if notes is not None else []
    parts = []
    tick = progress.ticker(tick)
    for index, obj in enumerate(objects):
        tick.at(index / max(len(objects), 1))
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            if uv_layer not in mesh.uv_layers:
                raise BakeError(f"'{obj.name}' has no '{uv_layer}' UV layer: run Unwrap first")
            tris = read_triangles(mesh, evaluated.matrix_world)
            if tris is None:  # the base mesh has faces (`bake_session`): its modifiers removed them
                line = no_faces_warning(obj.name)
                if line not in notes:
                    notes.append(line)
                continue
            positions, loops, mat_index = tris
            n_world = world_corner_normals(mesh, evaluated.matrix_world)
            uv = read_floats(mesh.uv_layers[uv_layer].data, "uv", len(mesh.loops) * 2)
            rect = np.array(lightmap_rect(obj))  # an instance's rectangle in the atlas
            uv = (uv.reshape(-1, 2) * rect[:2] + rect[2:]).ravel()
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
        raise BakeError(
            "none of the objects has faces to bake: "
            + ", ".join(f"'{o.name}'" for o in objects)
            + (" (their modifiers leave no faces)" if objects else "")
        )
    *arrays, polygon = (np.concatenate(x) for x in zip(*parts))
    return SurfaceTriangles(*arrays, textures=cache.images, polygon=polygon)
