"""The scene's fingerprints for incremental bakes (`core.incremental.fingerprints.Fingerprints`), read from
the evaluated depsgraph without changing anything.

Per mesh object visible to render (as `scene_data.read_bake_scene` takes them; an instance is
keyed "<instancer>/<object>/<persistent id>"): its evaluated vertices, corners, corner normals
and material indices, its world transform, and its materials' node trees (every node's inputs,
properties and links, images by file, size and source, not by pixels: a texture painted in place
and not saved is not seen); per light its data block's settings, its transform and Light Group;
the world's node tree and colour. Receivers also get their lightmap UVs' digest, and each atlas
its layout (`core.incremental.fingerprints.layout_digest`).
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import blender_compat
from ..core.incremental.fingerprints import Fingerprints, digest, layout_digest
from . import collection_instances
from .mesh_data import corner_vertices, polygon_materials

#: RNA property types hashed by value (pointers and collections are walked where they matter).
_PLAIN = {"BOOLEAN", "INT", "FLOAT", "ENUM", "STRING"}
#: Properties that change without changing the light (names, users, UI state).
_SKIP = {
    "rna_type",
    "name",
    "name_full",
    "users",
    "use_fake_user",
    "is_evaluated",
    "session_uid",
    "tag",
    "is_missing",
    "is_runtime_data",
    "is_embedded_data",
    "is_library_indirect",
    "library_weak_reference",
    "original",
    "id_type",
    "select",
    "show_expanded",
    "location",
    "width",
    "height",
    "dimensions",
    "hide",
    "mute_ui",
    "label",
    "use_custom_color",
    "color_tag",
    "warning_propagation",
    "bl_icon",
    "bl_label",
    "bl_description",
    "bl_idname",
    "bl_static_type",
    "bl_width_default",
    "bl_width_min",
    "bl_width_max",
    "bl_height_default",
    "bl_height_min",
    "bl_height_max",
    "show_options",
    "show_preview",
    "show_texture",
    "internal_links",
    "is_active_output",
    "is_editor_compatible",
    "use_nodes",
    "animation_data",
    "asset_data",
    "preview",
    "override_library",
    "cycles",
}


def _rna_values(block) -> list:
    """(name, value) of every plain RNA property of `block` (sorted), arrays as tuples."""
    out = []
    for prop in block.bl_rna.properties:
        key = prop.identifier
        if key in _SKIP or prop.type not in _PLAIN or getattr(prop, "is_deprecated", False):
            continue
        try:
            with warnings.catch_warnings():  # a property Blender deprecates: its value still counts
                warnings.simplefilter("ignore", DeprecationWarning)
                value = getattr(block, key)
        except (AttributeError, TypeError):
            continue
        if hasattr(value, "__len__") and not isinstance(value, str):
            value = tuple(value) if not hasattr(value, "to_list") else tuple(value.to_list())
        out.append((key, value))
    return out


def _socket_value(socket):
    value = getattr(socket, "default_value", None)
    if value is None:
        return None
    return tuple(value) if hasattr(value, "__len__") and not isinstance(value, str) else value


def _image(image) -> tuple:
    if image is None:
        return ()
    return (
        image.name,
        image.filepath,
        tuple(image.size),
        image.source,
        bool(image.packed_file),
        image.colorspace_settings.name,
    )


def _tree(tree, seen: set) -> list:
    """Everything of a node tree a material's bake reads: nodes (type, inputs, plain
    properties, image, group tree) and links, in name order."""
    if tree is None or tree.name in seen:
        return []
    seen = seen | {tree.name}
    out: list = []
    for node in sorted(tree.nodes, key=lambda n: n.name):
        item = [node.name, node.bl_idname, _rna_values(node), [(s.identifier, _socket_value(s)) for s in node.inputs]]
        item.append(_image(getattr(node, "image", None)))
        if getattr(node, "node_tree", None) is not None:
            item.append(_tree(node.node_tree, seen))
        out.append(item)
    out.append(
        sorted(
            (lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier, lk.is_muted)
            for lk in tree.links
        )
    )
    return out


def _emits(material) -> bool:
    """Whether a material may emit light: an Emission node, or a node whose Emission Strength
    and Emission Color are both non-zero (conservative: links into them count as emitting)."""
    tree = blender_compat.node_tree_of(material) if material is not None else None
    if tree is None:
        return False
    for node in tree.nodes:
        if node.bl_idname == "ShaderNodeEmission":
            return True
        strength, colour = node.inputs.get("Emission Strength"), node.inputs.get("Emission Color")
        if strength is None or colour is None:
            continue
        if (strength.is_linked or strength.default_value > 0.0) and (colour.is_linked or any(colour.default_value[:3])):
            return True
    return False


def material_digest(material, cache: dict) -> str:
    """A material's digest (`cache`d by name): its node tree, or its base colour without one."""
    if material is None:
        return "none"
    if material.name not in cache:
        tree = blender_compat.node_tree_of(material)
        cache[material.name] = digest(tuple(material.diffuse_color), _tree(tree, set()))
    return cache[material.name]


def _mesh_arrays(mesh) -> list[np.ndarray]:
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    corners = corner_vertices(mesh)
    starts = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_start", starts)
    mats = polygon_materials(mesh).astype(np.int32)
    normals = np.empty(len(mesh.loops) * 3, np.float32)
    mesh.corner_normals.foreach_get("vector", normals)
    return [co, corners, starts, mats, normals]


def _bounds(co: np.ndarray, matrix: np.ndarray) -> list | None:
    """The world-space box [min, max] of a mesh's flat vertex coordinates `co` under `matrix`."""
    if not len(co):
        return None
    world = co.reshape(-1, 3).astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
    # per column: numpy reduces an (N, 3) array along axis 0 several times slower
    return [[float(world[:, i].min()) for i in range(3)], [float(world[:, i].max()) for i in range(3)]]


def instance_key(instance) -> str:
    """The name an object instance is fingerprinted under: its object's; a collection instance's
    object is "<instancer>/<object>", a receiver's name (`collection_instances.Member`), other
    instances add their persistent id."""
    if instance.is_instance and instance.parent is not None:
        parent, original = instance.parent.original, instance.object.original
        if collection_instances.shows_collection(parent) and original.name in parent.instance_collection.all_objects:
            return f"{parent.name}{collection_instances.SEPARATOR}{original.name}"
        return f"{instance.parent.name}/{instance.object.name}/{tuple(instance.persistent_id)}"
    return instance.object.name


def scene_fingerprints(context, atlases: list[tuple[str, int, int, list]], uv_layer: str, tick=None) -> Fingerprints:
    """The fingerprints of the scene now: every render-visible mesh object and light, the world,
    and the layout of each atlas of `atlases` ([(name, width, height, receiver objects)], as
    `bake_session.atlas_groups` gives them) from the receivers' `uv_layer`. `tick` (a
    `core.progress.Tick`) is told the share of the scene's objects read. A bake reads them with
    its scene instead (`Reader`, `scene_data.read_bake_scene(visit=)`): each mesh evaluated once."""
    from ..core import progress

    depsgraph = context.evaluated_depsgraph_get()
    reader = Reader(atlases, uv_layer)
    tick, total = progress.ticker(tick), max(len(depsgraph.objects), 1)
    for k, instance in enumerate(depsgraph.object_instances):
        tick.at(min(k / total, 1.0))
        obj = instance.object
        if obj.type == 'MESH' and not obj.hide_render:
            mesh = obj.to_mesh()
            try:
                reader.visit(instance, mesh)
            finally:
                obj.to_mesh_clear()
        else:
            reader.visit(instance)
    return reader.finish(depsgraph)


class Reader:
    """`scene_fingerprints` instance by instance: `visit(instance, mesh)` for every object
    instance of the evaluated depsgraph, in its order (mesh: the render-visible mesh instance's
    evaluated mesh, `instance.object.to_mesh()`, while it exists; None for other instances),
    then `finish(depsgraph)`."""

    def __init__(self, atlases: list[tuple[str, int, int, list]], uv_layer: str):
        self.atlases, self.uv_layer = atlases, uv_layer
        self.receivers = {o.name: o for _, _, _, members in atlases for o in members}
        self.found = Fingerprints()
        self.materials: dict = {}
        self.uv: dict[str, str] = {}

    def visit(self, instance, mesh=None) -> None:
        obj = instance.object
        key = instance_key(instance)
        if obj.type == 'LIGHT':
            matrix = np.array(instance.matrix_world, dtype=np.float64)
            light = obj.data
            position = None if light.type == 'SUN' else matrix[:3, 3].tolist()
            self.found.lights[key] = {
                "hash": digest(matrix, _rna_values(light), str(getattr(obj, "lightgroup", ""))),
                "position": position,
                "power": float(light.energy) * float(max(light.color)),
            }
        elif mesh is not None:
            matrix = np.array(instance.matrix_world, dtype=np.float64)
            mats = [material_digest(slot.material, self.materials) for slot in obj.material_slots]
            arrays = _mesh_arrays(mesh)
            entry = {
                "hash": digest(matrix, *arrays, mats, str(getattr(obj, "lightgroup", ""))),
                "bounds": _bounds(arrays[0], matrix),
                "emits": any(_emits(slot.material) for slot in obj.material_slots),
            }
            if key in self.receivers:
                rect = tuple(self.receivers[key].hhd.lightmap_rect)  # an instance's place (part 2)
                entry["uv"] = digest(_uv_digest(mesh, self.uv_layer), rect)
                self.uv[key] = entry["uv"]
            self.found.objects[key] = entry

    def finish(self, depsgraph) -> Fingerprints:
        """The fingerprints: the visited instances', the layouts (receivers hidden from render
        read here) and the world's."""
        uv = self.uv
        for _, _, _, members in self.atlases:  # receivers hidden from render keep their layout
            for obj in members:
                if obj.name not in uv:
                    evaluated = obj.evaluated_get(depsgraph)
                    mesh = evaluated.to_mesh()
                    try:
                        rect = tuple(getattr(obj.hhd, "lightmap_rect", ()))
                        uv[obj.name] = digest(_uv_digest(mesh, self.uv_layer), rect)
                    finally:
                        evaluated.to_mesh_clear()
        world = depsgraph.scene.world
        if world is not None:
            tree = blender_compat.node_tree_of(world)
            self.found.world = digest(tuple(world.color), _tree(tree, set()), str(getattr(world, "lightgroup", "")))
        for name, width, height, members in self.atlases:
            self.found.layout[name] = layout_digest(width, height, {o.name: uv.get(o.name, "") for o in members})
        return self.found


def _uv_digest(mesh, uv_layer: str) -> str:
    """The digest of a receiver's lightmap UVs and the corners they belong to ("" without the layer)."""
    if uv_layer not in mesh.uv_layers:
        return ""
    uvs = np.empty(len(mesh.loops) * 2, np.float32)
    mesh.uv_layers[uv_layer].data.foreach_get("uv", uvs)
    return digest(uvs, corner_vertices(mesh))
