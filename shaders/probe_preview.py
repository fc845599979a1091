"""Show / hide the baked light probes on objects without a lightmap, restorable exactly (issue 25).

Show inserts, into every material of the chosen objects, a frame of nodes named "HHD Probe …":
the "HHD Probe Lighting" group (shaders/probe_nodes.py) fed by seven Attribute nodes of type
OBJECT reading the object's custom properties `hhd_probe_pack0` … `hhd_probe_pack6` (4 floats
each: its radiance SH, 27 floats coefficient by coefficient, then 1.0; `pack`, `read_sh`), so a
material shared by several objects shows each its own (seven, not nine 3-float properties: 4.2's
EEVEE reads at most 8 object attributes per material, the others as 0), the Principled BSDF's
Base Color and Normal links (constants / Geometry's Normal when unlinked), Geometry's Normal as the
HLSH normal, an Ambient Occlusion node (around that normal) for the cone, and the mode from a View
Layer Attribute reading the scene's custom property `hhd_probe_mode` (0 plain SH, 1 HLSH, 2 HLSH +
cone; editing it relights every material without rebuilding). An Emission of albedo × irradiance
goes through a Mix Shader with the material's own surface, its factor the packed properties' last
float (1 on the previewed objects, 0 on objects without them); `hhd_probe_preview` = 1 marks the
previewed objects for the handler and Hide.

The material's original Surface link is recorded in the material (`hhd_probe_preview`); Hide
relinks that source into every socket the preview's Mix fed (the Surface, or another preview's
Mix shown after this one), removes every "HHD Probe" node and deletes the record and the
object properties, so the node tree is exactly as before.

SH per object: the SH of its world origin, `core.probes.sample` of the volume whose local cube
[-1, 1]³ contains it (the smallest when several do), else of the nearest volume, over every
volume of `probes.json` in the folder recorded at Show (`scene["hhd_probe_folder"]`). An app
handler (`on_depsgraph_update`, `on_frame_change`; `register_handlers`) rewrites the properties
of every previewed object when its SH changed, so a moving object is relit as it moves; values
equal to the stored ones are not written again (no update loop).
"""

from __future__ import annotations

import json
from pathlib import Path

import bpy
import numpy as np
from bpy.app.handlers import persistent

from .. import blender_compat
from ..bridge import probe_mode
from ..core import probes
from ..core.errors import BakeError
from . import probe_nodes
from .preview import _output, _principled  # the material lookups the lightmap preview uses

PREFIX = "HHD Probe"
#: material record of the original Surface link; object property marking the previewed objects
RECORD = "hhd_probe_preview"
#: scene custom property: the folder of probes.json (the mode's is `bridge.probe_mode.MODE`)
FOLDER = "hhd_probe_folder"
#: relative change of an SH coefficient (of the largest) below which a property is not rewritten
EPSILON = 1e-6
#: 4-float object properties holding an object's SH: 27 floats + the switch (`pack`)
PACKED = 7


def pack_property(j: int) -> str:
    """The object custom property holding floats 4j … 4j + 3 of the packed SH (`pack`)."""
    return f"hhd_probe_pack{j}"


def pack(coeffs: np.ndarray) -> np.ndarray:
    """Radiance SH (9, 3) → (PACKED, 4): the 27 floats coefficient by coefficient (R, G, B),
    then 1.0, the shader's switch (the preview's Mix factor: 0 on objects without the property)."""
    return np.append(np.asarray(coeffs, dtype=np.float64).ravel(), 1.0).reshape(PACKED, 4)


def read_sh(obj) -> np.ndarray | None:
    """The SH (9, 3) stored on `obj`, or None when it holds none."""
    values = [obj.get(pack_property(j)) for j in range(PACKED)]
    if any(v is None or len(v) != 4 for v in values):
        return None
    return np.array([list(v) for v in values], dtype=np.float64).ravel()[:27].reshape(9, 3)


# ---- probe data -------------------------------------------------------------------------------

_cache: dict = {}


def _stamp(paths) -> tuple:
    return tuple(p.stat().st_mtime_ns if p.is_file() else 0 for p in paths)


def load_volumes(folder) -> list[tuple[probes.ProbeGrid, np.ndarray]]:
    """[(grid, sh (N, 9, 3))] of every volume in `folder`'s probes.json, cached until the sidecar
    or a volume's EXR changes (modification times: a handler calls this on every update).
    Raises BakeError without probes.json."""
    folder = Path(folder)
    sidecar = folder / probes.SIDECAR
    if not sidecar.is_file():
        raise BakeError(f"no probes baked: {sidecar} does not exist (bake with an Irradiance Volume)")
    cached = _cache.get(str(folder))
    if cached is not None and cached["stamp"] == _stamp(cached["files"]):
        return cached["volumes"]
    doc = json.loads(sidecar.read_text(encoding="utf-8"))
    names = [v["name"] for v in doc.get("volumes", [])]
    files = [sidecar] + [folder / v["file"] for v in doc.get("volumes", [])]
    stamp = _stamp(files)
    volumes = [probes.read(folder, name)[:2] for name in names]
    _cache.clear()
    _cache[str(folder)] = {"stamp": stamp, "files": files, "volumes": volumes}
    return volumes


def choose_volume(grids, point) -> int:
    """Index of the grid for world `point` (3,): the smallest whose local cube contains it, else
    the one whose box is nearest (world distance)."""
    point = np.asarray(point, dtype=np.float64)
    best, best_key = 0, None
    for i, grid in enumerate(grids):
        m, t = grid.to_world[:3, :3], grid.to_world[:3, 3]
        local = np.linalg.solve(m, point - t)
        inside = bool(np.all(np.abs(local) <= 1.0))
        distance = 0.0 if inside else float(np.linalg.norm(m @ np.clip(local, -1.0, 1.0) + t - point))
        key = (not inside, distance, abs(np.linalg.det(m)))
        if best_key is None or key < best_key:
            best, best_key = i, key
    return best


def sh_at(volumes, point) -> np.ndarray:
    """Radiance SH (9, 3) at world `point` from [(grid, sh)] (`choose_volume`, `probes.sample`)."""
    grid, sh = volumes[choose_volume([g for g, _ in volumes], point)]
    return probes.sample(grid, sh, np.asarray(point, dtype=np.float64)[None])[0]


def write_sh(obj, coeffs: np.ndarray) -> bool:
    """Store SH (9, 3) in the object's properties (`pack`) if it differs from what they hold
    (relative EPSILON of the largest coefficient); returns whether it wrote."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    old = read_sh(obj)
    if old is not None and np.abs(old - coeffs).max() <= EPSILON * max(float(np.abs(coeffs).max()), 1e-30):
        return False
    for j, values in enumerate(pack(coeffs)):
        obj[pack_property(j)] = [float(v) for v in values]
    obj.update_tag()
    return True


def update_objects(scene, depsgraph=None) -> int:
    """Rewrite the SH properties of the scene's previewed objects whose origin SH changed;
    returns how many changed. `depsgraph`: where the objects' evaluated positions are read."""
    if FOLDER not in scene:  # no probe preview shown in this scene: every update stays cheap
        return 0
    objects = [o for o in scene.objects if RECORD in o]
    if not objects:
        return 0
    volumes = load_volumes(scene[FOLDER])
    if not volumes:
        return 0
    changed = 0
    for obj in objects:
        evaluated = obj.evaluated_get(depsgraph) if depsgraph is not None else obj
        changed += write_sh(obj, sh_at(volumes, np.array(evaluated.matrix_world.translation)))
    return changed


def _safe_update(scene, depsgraph):
    try:
        update_objects(scene, depsgraph)
    except (BakeError, OSError, KeyError, ValueError) as exc:  # a handler must never raise
        print(f"HHD probe preview: {exc}")


@persistent
def on_depsgraph_update(scene, depsgraph=None):
    """depsgraph_update_post: relight the previewed objects that moved."""
    _safe_update(scene, depsgraph)


@persistent
def on_frame_change(scene, depsgraph=None):
    """frame_change_post: relight the previewed objects at the new frame."""
    _safe_update(scene, depsgraph)


_HANDLERS = (
    (bpy.app.handlers.depsgraph_update_post, on_depsgraph_update),
    (bpy.app.handlers.frame_change_post, on_frame_change),
)


def register_handlers():
    """Install the handlers once (any previous copy of them, e.g. from a reloaded module, goes)."""
    unregister_handlers()
    for handlers, function in _HANDLERS:
        handlers.append(function)


def unregister_handlers():
    for handlers, function in _HANDLERS:
        for h in [
            h
            for h in handlers
            if getattr(h, "__name__", None) == function.__name__ and h.__module__ == function.__module__
        ]:
            handlers.remove(h)


# ---- materials --------------------------------------------------------------------------------


def _new(tree, kind, name, location, parent):
    node = tree.nodes.new(kind)
    node.name = node.label = f"{PREFIX} {name}"
    node.location = location
    node.parent = parent
    return node


def _attribute(tree, kind, name, location, frame, label):
    node = _new(tree, "ShaderNodeAttribute", label, location, frame)
    node.attribute_type, node.attribute_name = kind, name
    return node


def _feed_group(tree, mat, group, geometry, principled) -> str | None:
    """Albedo and shading normal from the Principled BSDF (its links or constants); a note when
    the material has none (its viewport colour is the albedo)."""
    gi = group.inputs
    tree.links.new(geometry.outputs["Normal"], gi["Geometry Normal"])
    if principled is None:
        gi["Albedo"].default_value = tuple(mat.diffuse_color)
        tree.links.new(geometry.outputs["Normal"], gi["Normal"])
        return f"material '{mat.name}' has no Principled BSDF: the probe preview uses its viewport colour as albedo"
    colour, normal = principled.inputs["Base Color"], principled.inputs["Normal"]
    if colour.is_linked:
        tree.links.new(colour.links[0].from_socket, gi["Albedo"])
    else:
        gi["Albedo"].default_value = (*colour.default_value[:3], 1.0)
    tree.links.new(normal.links[0].from_socket if normal.is_linked else geometry.outputs["Normal"], gi["Normal"])
    return None


def _link_sh(tree, group, x0, y0, frame):
    """The PACKED object attributes (`pack`) into the group's SH0 … SH8; returns the switch
    socket (the last float). 7 attributes: Blender 4.2's EEVEE reads at most 8 uniform
    attributes per material (GPU_MAX_UNIFORM_ATTR) and returns 0 for the others."""
    floats = []
    for j in range(PACKED):
        attribute = _attribute(tree, 'OBJECT', pack_property(j), (x0 - 400, y0 - 220 * j), frame, f"SH Pack {j}")
        split = _new(tree, "ShaderNodeSeparateXYZ", f"SH Split {j}", (x0 - 200, y0 - 220 * j), frame)
        tree.links.new(attribute.outputs["Vector"], split.inputs[0])
        floats += [*split.outputs, attribute.outputs["Alpha"]]
    for k in range(9):
        combine = _new(tree, "ShaderNodeCombineXYZ", f"SH{k}", (x0, y0 - 160 * k), frame)
        for c in range(3):
            tree.links.new(floats[3 * k + c], combine.inputs[c])
        tree.links.new(combine.outputs[0], group.inputs[f"SH{k}"])
    return floats[27]


def show_on_material(mat) -> str | None:
    """Insert the probe preview into one material; returns a note when a fallback was used."""
    tree = mat.node_tree if mat.node_tree is not None else blender_compat.ensure_node_tree(mat)
    if RECORD in mat:
        hide_on_material(mat)
    output = _output(tree)
    if output is None:  # named with the prefix, so Hide removes it again
        output = _new(tree, "ShaderNodeOutputMaterial", "Output", (300, 0), None)
    link = output.inputs["Surface"].links[0] if output.inputs["Surface"].is_linked else None
    mat[RECORD] = json.dumps(
        {
            "output": output.name,
            "from_node": link.from_node.name if link else None,
            "from_socket": link.from_socket.identifier if link else None,
        }
    )
    x0, y0 = output.location.x + 320, output.location.y - 40
    frame = _new(tree, "NodeFrame", "Frame", (x0 - 20, y0 + 40), None)
    group = _new(tree, "ShaderNodeGroup", "Group", (x0 + 400, y0), frame)
    group.node_tree = probe_nodes.ensure()
    switch = _link_sh(tree, group, x0, y0, frame)
    geometry = _new(tree, "ShaderNodeNewGeometry", "Geometry", (x0 + 200, y0 - 1500), frame)
    ao = _new(tree, "ShaderNodeAmbientOcclusion", "AO", (x0 + 200, y0 - 1800), frame)
    tree.links.new(geometry.outputs["Normal"], ao.inputs["Normal"])
    tree.links.new(ao.outputs["AO"], group.inputs["AO"])
    mode = _attribute(tree, 'VIEW_LAYER', probe_mode.MODE, (x0 + 200, y0 - 2000), frame, "Mode")
    tree.links.new(mode.outputs["Fac"], group.inputs["Mode"])
    note = _feed_group(tree, mat, group, geometry, _principled(tree))
    emission = _new(tree, "ShaderNodeEmission", "Emission", (x0 + 650, y0), frame)
    tree.links.new(group.outputs["Radiance"], emission.inputs["Color"])
    mix = _new(tree, "ShaderNodeMixShader", "Mix", (x0 + 850, y0), frame)
    tree.links.new(switch, mix.inputs["Fac"])
    if link is not None:
        tree.links.new(link.from_socket, mix.inputs[1])
    tree.links.new(emission.outputs["Emission"], mix.inputs[2])
    tree.links.new(mix.outputs["Shader"], output.inputs["Surface"])
    return note


def hide_on_material(mat) -> bool:
    """Remove the probe preview from a material, relinking its original Surface source where
    the preview's Mix fed; False if none was shown."""
    if RECORD not in mat or mat.node_tree is None:
        return False
    record = json.loads(mat[RECORD])
    tree = mat.node_tree
    mix = tree.nodes.get(f"{PREFIX} Mix")
    targets = [l.to_socket for l in mix.outputs["Shader"].links] if mix is not None else []
    if mix is None and tree.nodes.get(record["output"]) is not None:
        targets = [tree.nodes[record["output"]].inputs["Surface"]]
    targets = [(t.node.name, t.identifier) for t in targets if not t.node.name.startswith(PREFIX)]
    for node in [n for n in tree.nodes if n.name.startswith(PREFIX)]:
        tree.nodes.remove(node)
    source = tree.nodes.get(record["from_node"]) if record["from_node"] else None
    socket = next((s for s in source.outputs if s.identifier == record["from_socket"]), None) if source else None
    for node_name, identifier in targets:
        target = next(s for s in tree.nodes[node_name].inputs if s.identifier == identifier)
        if socket is not None:
            tree.links.new(socket, target)
    del mat[RECORD]
    return True


def show(objects, folder, scene=None) -> list[str]:
    """Probe preview on `objects` (meshes) lit by the volumes baked in `folder`: every material
    of theirs gets the preview, each object its switch and SH properties; the scene records the
    folder and the mode (`scene.hhd.probe_mode` as a number). Returns notes for the report. Raises
    BakeError when `folder` holds no probes."""
    scene = scene if scene is not None else bpy.context.scene
    volumes = load_volumes(folder)
    if not volumes:
        raise BakeError(f"{Path(folder) / probes.SIDECAR} lists no probe volume")
    scene[FOLDER] = str(folder)
    settings = getattr(scene, "hhd", None)  # the panel's Probe Lighting mode, mirrored for the nodes
    if settings is not None:
        probe_mode.mirror(scene, settings.probe_mode)
    else:
        scene[probe_mode.MODE] = scene.get(probe_mode.MODE, probe_mode.DEFAULT_MODE)
    notes, materials = [], {}
    for obj in objects:
        obj[RECORD] = 1.0
        write_sh(obj, sh_at(volumes, np.array(obj.matrix_world.translation)))
        for slot in obj.material_slots:
            if slot.material is not None:
                materials[slot.material.name] = slot.material
        if not obj.material_slots or all(s.material is None for s in obj.material_slots):
            notes.append(f"'{obj.name}' has no material: nothing to preview on it")
    for mat in materials.values():
        note = show_on_material(mat)
        if note:
            notes.append(note)
    return notes


def hide(objects=None) -> int:
    """Remove the probe preview from every material that has one and the switch and SH
    properties from the objects (all objects when None); returns how many materials were
    restored."""
    restored = sum(hide_on_material(m) for m in bpy.data.materials)
    for obj in objects if objects is not None else bpy.data.objects:
        for key in (RECORD, *(pack_property(j) for j in range(PACKED))):
            if key in obj:
                del obj[key]
    return restored
