"""Show / hide the baked lighting on the objects' own materials, restorable exactly.

Show inserts, into every material of the baked objects, a frame of nodes named "HHD Preview …":
the preview images of the layers the mode samples (`core.files.preview`) sampled through the
lightmap UV map (linear filtering) into the node-group inputs of the same names, the chosen node group
fed by the Principled BSDF's Base Color and Normal links (image textures, normal maps; constants
when unlinked) and Geometry's Normal as n_v, an Emission shader of albedo × irradiance, and a
Mix Shader between the material's own surface (factor 0) and the preview (factor 1). The
direction's image holds its unit vector (`Channel.unpack`), never the octahedral pair the
bilinear filter would blend wrongly across the map's folds; Show rewrites one that a bake made
before holds as the pair (`files.preview.upgrade_direction`). The mix
factor is the object attribute `hhd_preview`, set to 1 on the baked objects only: a material shared
with objects that were not baked keeps its own look on them. A material shared by objects of
several atlases samples every atlas's images and picks the object's own by a second object
attribute, `hhd_preview_atlas`. The lightmap UV goes through the object's lightmap rectangle
(a third, `hhd.lightmap_rect`, read by RNA path): the instances of a mesh (linked duplicates,
`core.unwrap.instances`) share its UV layer and its materials, each showing its own part of the atlas.
The three are read by Attribute nodes of type Instancer, which read them on the Empty that shows
a collection (collection instances, `bridge.collection_instances`) and on the object itself
otherwise.

The Encoded mode (`core.files.preview.ENCODED`) shows each material in the model its atlases'
sidecar names (one model per material, else Show refuses before changing anything): HL2, H-basis,
SG and the SH encodings through their own layers' preview images and node groups, HHD/AHD as
those modes do.

Light sets (core.light_sets): in HHD mode, when an atlas's sidecar lists "light_sets", the group
is the live blend of them (`node_groups.build_blend`) instead of the HHD group: every set's preview
images (`<atlas>.<set>_preview/`) feed its inputs, and each set's RGB weight comes from a View Layer
Attribute node reading `scene.hhd.light_sets[<set>].weight` by RNA path (`bridge.light_sets.weight_path`),
so editing or animating a weight updates the viewport and renders without rebuilding anything.
Show adds the sets to `scene.hhd.light_sets` (weight 1) if they are missing there.

The material's original Surface link is recorded in the material (`hhd_preview` property); Hide
removes every preview node, restores that link and deletes the record and the object attributes,
so the node tree is exactly as before. Edits the artist makes to the material meanwhile are kept.
The views before a bake (shaders/texel_views.py) insert their nodes under the same prefix and
record, so Hide removes them too.
"""

from __future__ import annotations

import json

import bpy

from .. import blender_compat
from ..bridge.light_sets import sync_light_sets, weight_path
from ..core.errors import BakeError
from ..core.files.lightmap_files import read_sidecar
from ..core.files.preview import ENCODED, bspline_image, kind_of, sampled, upgrade_direction
from . import bicubic as bicubic_nodes
from . import node_groups, specular_nodes

PREFIX = "HHD Preview"
RECORD = "hhd_preview"
#: Object attribute: the index of the object's atlas among those of the preview, for materials
#: shared by objects of several atlases (a full atlas spills into Lightmap_1, …).
ATLAS = "hhd_preview_atlas"
#: Object attribute (an RNA path): the object's lightmap rectangle (scale u, scale v, offset u,
#: offset v) in its atlas, `properties.HHDObjectSettings.lightmap_rect`.
RECT = "hhd.lightmap_rect"
#: Object attribute (RNA path): an object's place in its collection's block, for the collection
#: instances that show it (`properties.HHDObjectSettings.collection_rect`).
INNER = "hhd.collection_rect"
#: Instancer attribute (RNA path): 1 on an Empty whose collection's objects were unwrapped as
#: collection instances (`properties.HHDObjectSettings.collection_instance`).
FLAG = "hhd.collection_instance"
#: The rectangle of an object with its own mesh: the whole atlas.
IDENTITY_RECT = (1.0, 1.0, 0.0, 0.0)


def _new(tree, kind, name, location, parent):
    node = tree.nodes.new(kind)
    node.name = node.label = f"{PREFIX} {name}"
    node.location = location
    node.parent = parent
    return node


def _principled(tree):
    output = _output(tree)
    if output is None or not output.inputs["Surface"].is_linked:
        return None
    node = output.inputs["Surface"].links[0].from_node
    return (
        node if node.type == 'BSDF_PRINCIPLED' else next((n for n in tree.nodes if n.type == 'BSDF_PRINCIPLED'), None)
    )


def _output(tree):
    return next((n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL' and n.is_active_output), None)


def _feed(tree, source_input, target_input):
    """Link what feeds `source_input` into `target_input`, or copy its constant."""
    if source_input.is_linked:
        tree.links.new(source_input.links[0].from_socket, target_input)
    else:
        value = source_input.default_value
        target_input.default_value = value if len(target_input.default_value) == len(value) else (*value[:3], 1.0)


#: `scene.hhd.preview_filter` → the bicubic kernel of shaders/bicubic.py ("": EEVEE's bilinear).
KERNELS = {'BILINEAR': "", 'BICUBIC': "catmull_rom", 'BSPLINE': "bspline"}


def _image(tree, path, name, uv, x, y, frame, bicubic: str = ""):
    """Colour socket of the preview image at `path` sampled at `uv`: one Image Texture node
    (EEVEE's 'Linear' filter), or with `bicubic` (a KERNELS value) the lookup of
    shaders/bicubic.py ("bspline": `path` holds the image's coefficients)."""
    image = bpy.data.images.load(str(path), check_existing=True)
    image.reload()
    image.colorspace_settings.is_data = True
    if bicubic:

        def new(t, kind, n, at):
            return _new(t, kind, n, at, frame)

        return bicubic_nodes.lookup(tree, new, image, name, uv, x, y, bicubic)
    node = _new(tree, "ShaderNodeTexImage", name, (x, y), frame)
    node.image, node.interpolation, node.extension = image, 'Linear', 'EXTEND'
    tree.links.new(uv, node.inputs["Vector"])
    return node.outputs["Color"]


def _socket(sockets, identifier):
    return next(s for s in sockets if s.identifier == identifier)


def _preview_path(files, key: str, bicubic: str):
    """The image the preview samples for layer `key` of atlas `files` (its coefficients for the
    prefiltered B-spline)."""
    return bspline_image(files, key) if bicubic == "bspline" else files.preview_image(key)


def _atlas_image(tree, key, atlases, uv, x, y, frame, bicubic: str = ""):
    """Colour output of preview image `key` for the atlases [(index, AtlasFiles)] whose objects
    use this material: the one atlas's image, or each further atlas's image mixed in where the
    object's ATLAS attribute equals that atlas's index."""
    (_, first), rest = atlases[0], atlases[1:]
    name = key if not rest and not first.parent else f"{key} {first.name}"  # a set's: "iz Lightmap.Lamp"
    colour = _image(tree, _preview_path(first, key, bicubic), name, uv, x, y, frame, bicubic)
    if not rest:
        return colour
    attribute = _new(tree, "ShaderNodeAttribute", f"Atlas {key}", (x - 200, y - 120), frame)
    attribute.attribute_type, attribute.attribute_name = 'INSTANCER', ATLAS
    for k, (index, files) in enumerate(rest, 1):
        path = _preview_path(files, key, bicubic)
        image = _image(tree, path, f"{key} {files.name}", uv, x + 250 * k, y, frame, bicubic)
        equal = _new(tree, "ShaderNodeMath", f"Is {key} {files.name}", (x + 250 * k, y + 120), frame)
        equal.operation = 'COMPARE'
        equal.inputs[1].default_value, equal.inputs[2].default_value = float(index), 0.5
        tree.links.new(attribute.outputs["Fac"], equal.inputs[0])
        mix = _new(tree, "ShaderNodeMix", f"Mix {key} {files.name}", (x + 250 * k + 120, y), frame)
        mix.data_type = 'RGBA'
        tree.links.new(equal.outputs["Value"], _socket(mix.inputs, "Factor_Float"))
        tree.links.new(colour, _socket(mix.inputs, "A_Color"))
        tree.links.new(image, _socket(mix.inputs, "B_Color"))
        colour = _socket(mix.outputs, "Result_Color")
    return colour


def light_sets_of(files) -> list[tuple[str, object]]:
    """[(set name, the set's AtlasFiles)] listed in the atlas's sidecar ("light_sets"); [] for an
    atlas baked without light sets (or without a sidecar). Raises BakeError when a listed set's
    preview images are missing."""
    if not files.sidecar.is_file():
        return []
    doc = read_sidecar(files.sidecar)
    sets = [(entry["name"], set_files) for entry, set_files in zip(doc.get("light_sets", []), files.light_sets(doc))]
    for name, set_files in sets:
        if not set_files.preview_image("iz").is_file():
            raise BakeError(
                f"atlas '{files.name}' lists light set '{name}' but {set_files.preview} is missing: bake again"
            )
        upgrade_direction(set_files)  # a bake made before the preview held d as a vector
    return sets


def _material_light_sets(atlases) -> tuple[list, str | None]:
    """The light sets a material shows: [(set name, [(index, the set's AtlasFiles)])] in the
    layout of `_atlas_image`'s atlases, [] without sets; and a note when its atlases were baked
    with different sets (it then shows their sums, the atlases' own files)."""
    per_atlas = [(index, light_sets_of(files)) for index, files in atlases]
    names = {tuple(name for name, _ in sets) for _, sets in per_atlas}
    if len(names) > 1:
        return [], "the atlases sharing a material were baked with different light sets: it shows their sum"
    return [(name, [(index, sets[k][1]) for index, sets in per_atlas]) for k, name in enumerate(names.pop())], None


def _link_light_sets(tree, gi, light_sets, uv, x, y, frame, bicubic: str = "") -> float:
    """Each set's preview images into the blend group's 'Iz k', 'Wa k', 'Direction k' and a View
    Layer Attribute of the set's weight (`bridge.light_sets.weight_path`) into 'Weight k'; returns the
    next free y."""
    for k, (name, atlases) in enumerate(light_sets, 1):
        for layer in sampled("HHD"):
            colour = _atlas_image(tree, layer.preview, atlases, uv, x, y, frame, bicubic)
            tree.links.new(colour, gi[node_groups.set_input(layer.name, k)])
            y -= 280
        weight = _new(tree, "ShaderNodeAttribute", f"Weight {name}", (x, y), frame)
        weight.attribute_type, weight.attribute_name = 'VIEW_LAYER', weight_path(name)
        tree.links.new(weight.outputs["Color"], gi[node_groups.set_input(node_groups.WEIGHT, k)])
        y -= 200
    return y


def _instance_uv(tree, uv, x, y, frame):
    """The atlas UV of the lightmap layer's `uv` socket: uv × rect.xy + rect.zw, rect the object's
    lightmap rectangle (RECT, an Attribute node of type Instancer: an instance's place in the atlas
    over its shared mesh, `core.unwrap.instances`; the identity for other objects, an exact no-op). For
    an object shown by a collection instance, the Instancer lookup reads the Empty's rectangle
    (where its copy of the collection's block lies), and uv first goes through the object's own
    place in that block (INNER, switched on by the Empty's FLAG: off for an object drawn itself)."""
    flag = _new(tree, "ShaderNodeAttribute", "Collection Instance", (x - 160, y + 200), frame)
    flag.attribute_type, flag.attribute_name = 'INSTANCER', FLAG
    inner = _rectangle(tree, 'OBJECT', INNER, "Collection Rectangle", x, y + 200, frame)
    one = _new(tree, "ShaderNodeCombineXYZ", "Collection Identity", (x + 320, y + 340), frame)
    one.inputs["X"].default_value = one.inputs["Y"].default_value = 1.0
    minus = _new(tree, "ShaderNodeVectorMath", "Collection Scale Step", (x + 480, y + 340), frame)
    minus.operation = 'SUBTRACT'
    tree.links.new(inner[0], minus.inputs[0])
    tree.links.new(one.outputs["Vector"], minus.inputs[1])
    scale = _new(tree, "ShaderNodeVectorMath", "Collection Scale", (x + 640, y + 340), frame)
    scale.operation = 'MULTIPLY_ADD'  # 1 + flag · (inner scale − 1)
    tree.links.new(minus.outputs["Vector"], scale.inputs[0])
    tree.links.new(flag.outputs["Fac"], scale.inputs[1])
    tree.links.new(one.outputs["Vector"], scale.inputs[2])
    offset = _new(tree, "ShaderNodeVectorMath", "Collection Offset", (x + 640, y + 200), frame)
    offset.operation = 'SCALE'  # flag · inner offset
    tree.links.new(inner[1], offset.inputs[0])
    tree.links.new(flag.outputs["Fac"], offset.inputs["Scale"])
    in_block = _new(tree, "ShaderNodeVectorMath", "Block UV", (x + 800, y + 200), frame)
    in_block.operation = 'MULTIPLY_ADD'
    tree.links.new(uv, in_block.inputs[0])
    tree.links.new(scale.outputs["Vector"], in_block.inputs[1])
    tree.links.new(offset.outputs["Vector"], in_block.inputs[2])
    outer = _rectangle(tree, 'INSTANCER', RECT, "Rectangle", x, y, frame)
    mapped = _new(tree, "ShaderNodeVectorMath", "Atlas UV", (x + 960, y), frame)
    mapped.operation = 'MULTIPLY_ADD'
    tree.links.new(in_block.outputs["Vector"], mapped.inputs[0])
    tree.links.new(outer[0], mapped.inputs[1])
    tree.links.new(outer[1], mapped.inputs[2])
    return mapped.outputs["Vector"]


def _rectangle(tree, kind: str, path: str, name: str, x, y, frame):
    """(scale (x, y, 0), offset (z, w, 0)) sockets of the rectangle an Attribute node of type
    `kind` reads at RNA path `path`."""
    rect = _new(tree, "ShaderNodeAttribute", name, (x, y), frame)
    rect.attribute_type, rect.attribute_name = kind, path
    split = _new(tree, "ShaderNodeSeparateXYZ", f"{name} XYZ", (x + 160, y), frame)
    tree.links.new(rect.outputs["Vector"], split.inputs[0])
    offset = _new(tree, "ShaderNodeCombineXYZ", f"{name} Offset", (x + 320, y), frame)
    tree.links.new(split.outputs["Z"], offset.inputs["X"])
    tree.links.new(rect.outputs["Alpha"], offset.inputs["Y"])
    scale = _new(tree, "ShaderNodeCombineXYZ", f"{name} Scale", (x + 320, y - 140), frame)
    tree.links.new(split.outputs["X"], scale.inputs["X"])
    tree.links.new(split.outputs["Y"], scale.inputs["Y"])
    return scale.outputs["Vector"], offset.outputs["Vector"]


def show_on_material(
    mat,
    files,
    kind: str,
    uv_layer: str,
    *,
    self_bounce: bool,
    light_sets=(),
    instanced: bool = False,
    bicubic: str = "",
    term: str = 'DIFFUSE',
) -> str | None:
    """Insert the preview into one material; returns a note when a fallback was used. `bicubic`:
    "catmull_rom" or "bspline" (KERNELS): the images through that lookup (shaders/bicubic.py),
    not EEVEE's bilinear. `files`:
    the AtlasFiles of the objects' atlas, or [(index, AtlasFiles)] when objects of several
    atlases share the material (index: the value of their ATLAS attribute). light_sets (HHD mode):
    [(set name, [(index, the set's AtlasFiles)])] to show the live blend of, () for none. `term`
    (`scene.hhd.preview_term`): 'DIFFUSE' (albedo × irradiance), 'SPECULAR' or 'BOTH' through the
    kind's specular group (shaders/specular_nodes.py; where there is none, HL2, H-basis, Scalar
    and light-set blends, diffuse and a note naming the model)."""
    atlases = files if isinstance(files, list) else [(0, files)]
    tree = mat.node_tree if mat.node_tree is not None else blender_compat.ensure_node_tree(mat)
    if RECORD in mat:
        hide_on_material(mat)
    output = _output(tree)
    if output is None:  # named with the prefix, so Hide removes it again
        output = _new(tree, "ShaderNodeOutputMaterial", "Output", (300, 0), None)
    note = None
    link = output.inputs["Surface"].links[0] if output.inputs["Surface"].is_linked else None
    mat[RECORD] = json.dumps(
        {
            "output": output.name,
            "from_node": link.from_node.name if link else None,
            "from_socket": link.from_socket.identifier if link else None,
        }
    )
    frame = _new(tree, "NodeFrame", "Frame", (output.location.x + 300, output.location.y), None)
    x0, y0 = output.location.x + 320, output.location.y - 40
    uv = _new(tree, "ShaderNodeUVMap", "UV", (x0, y0), frame)
    uv.uv_map = uv_layer
    # through the objects' rectangles only where an instance uses the material: elsewhere the UV
    # reaches the images as it did (the lookup's filtering is then exactly the bake-era preview's)
    atlas_uv = _instance_uv(tree, uv.outputs["UV"], x0, y0 - 180, frame) if instanced else uv.outputs["UV"]
    group = _new(tree, "ShaderNodeGroup", "Group", (x0 + 600, y0), frame)
    group.node_tree = node_groups.ensure_blend(len(light_sets)) if light_sets else node_groups.ensure(kind)
    geometry = _new(tree, "ShaderNodeNewGeometry", "Geometry", (x0 + 300, y0 - 500), frame)
    principled = _principled(tree)
    gi = group.inputs
    if principled is not None:
        _feed(tree, principled.inputs["Base Color"], gi["Albedo"])
        if "Normal" in gi:
            if principled.inputs["Normal"].is_linked:
                tree.links.new(principled.inputs["Normal"].links[0].from_socket, gi["Normal"])
            else:
                tree.links.new(geometry.outputs["Normal"], gi["Normal"])
    else:
        gi["Albedo"].default_value = tuple(mat.diffuse_color)
        if "Normal" in gi:
            tree.links.new(geometry.outputs["Normal"], gi["Normal"])
        note = f"material '{mat.name}' has no Principled BSDF: the preview uses its viewport colour as albedo"
    if "Vertex Normal" in gi:
        tree.links.new(geometry.outputs["Normal"], gi["Vertex Normal"])
    if "Self Bounce" in gi:
        gi["Self Bounce"].default_value = 1.0 if self_bounce else 0.0
    y = y0
    if light_sets:
        y = _link_light_sets(tree, gi, light_sets, atlas_uv, x0 + 250, y, frame, bicubic)
    colours = {}
    for layer in () if light_sets else sampled(kind):  # each layer's preview image into the input of its name
        colour = colours[layer.name] = _atlas_image(tree, layer.preview, atlases, atlas_uv, x0 + 250, y, frame, bicubic)
        tree.links.new(colour, gi[layer.name])
        y -= 280
    radiance = group.outputs["Radiance"]
    if term != 'DIFFUSE':
        if specular_nodes.KINDS.get(kind) is None or light_sets:
            fallback = (
                f"material '{mat.name}': {_no_specular(kind, light_sets)}, so its {term.title()} term shows diffuse"
            )
            note = f"{note}; {fallback}" if note else fallback
        else:
            spec = _specular(tree, kind, colours, group, geometry, principled, (x0 + 600, y0 - 400), frame)
            radiance = spec.outputs["Specular" if term == 'SPECULAR' else "Both"]
    emission = _new(tree, "ShaderNodeEmission", "Emission", (x0 + 850, y0), frame)
    tree.links.new(radiance, emission.inputs["Color"])
    attribute = _new(tree, "ShaderNodeAttribute", "Switch", (x0 + 850, y0 + 200), frame)
    attribute.attribute_type, attribute.attribute_name = 'INSTANCER', RECORD
    mix = _new(tree, "ShaderNodeMixShader", "Mix", (x0 + 1050, y0), frame)
    tree.links.new(attribute.outputs["Fac"], mix.inputs["Fac"])
    if link is not None:
        tree.links.new(link.from_socket, mix.inputs[1])
    tree.links.new(emission.outputs["Emission"], mix.inputs[2])
    tree.links.new(mix.outputs["Shader"], output.inputs["Surface"])
    return note


def _no_specular(kind: str, light_sets) -> str:
    """Why preview kind `kind` has no specular term (`specular_nodes.KINDS`), by name."""
    if light_sets:
        return "the light-set blend has no specular model"
    names = {"SCALAR": "Scalar (I_z only)", "HBASIS_L1": "L1 H-basis", "HBASIS_L2": "L2 H-basis"}
    return f"{names.get(kind, kind)} encodes no specular (docs/format.md)"


def _specular(tree, kind, colours, group, geometry, principled, at, frame):
    """The specular group of `kind` fed like the diffuse `group` (its images, normals, albedo),
    Geometry's Incoming as v, the Principled BSDF's Metallic, Roughness, IOR and Specular IOR
    Level (its defaults without one), and the group's Irradiance (for Both)."""
    node = _new(tree, "ShaderNodeGroup", "Specular", at, frame)
    node.node_tree = specular_nodes.ensure(kind)
    si, gi = node.inputs, group.inputs
    for name, colour in colours.items():
        tree.links.new(colour, si[name])
    for name in ("Normal", "Vertex Normal", "Albedo"):
        if name in gi and gi[name].is_linked:
            tree.links.new(gi[name].links[0].from_socket, si[name])
        elif name in gi:
            si[name].default_value = gi[name].default_value
        else:
            tree.links.new(geometry.outputs["Normal"], si[name])
    tree.links.new(geometry.outputs["Incoming"], si["Incoming"])
    for name in ("Metallic", "Roughness", "IOR", "Specular IOR Level"):
        source = principled.inputs.get(name) if principled is not None else None
        if source is not None and source.is_linked:
            tree.links.new(source.links[0].from_socket, si[name])
        elif source is not None:
            si[name].default_value = source.default_value
    tree.links.new(group.outputs["Irradiance"], si["Irradiance"])
    return node


def model_of(files) -> str:
    """The encoder model an atlas's sidecar names ("hhd" for a sidecar without one)."""
    return read_sidecar(files.sidecar).get("encoder", {}).get("model", "hhd")


def _kind(mat, mode: str, atlases) -> str:
    """The kind (`core.files.preview.MODES`) material `mat` shows in preview mode `mode` for
    its atlases (AtlasFiles): `mode` itself, or in the Encoded mode their model's kind. Raises
    BakeError when the Encoded mode meets atlases of different models in one material (a node
    tree has one reconstruction) or a model it cannot show."""
    if mode != ENCODED:
        return mode
    models = sorted({model_of(files) for files in atlases})
    if len(models) > 1:
        raise BakeError(
            f"material '{mat.name}' is shared by atlases encoded as {' and '.join(models)}: the Encoded preview "
            "shows one model per material; re-encode them alike or choose another Preview mode"
        )
    kind = kind_of(mode, models[0])
    if kind is None:
        raise BakeError(f"the EEVEE preview cannot show an atlas encoded as {models[0]}")
    return kind


def hide_on_material(mat) -> bool:
    """Remove the preview from a material and restore its Surface link; False if none was shown."""
    if RECORD not in mat or mat.node_tree is None:
        return False
    record = json.loads(mat[RECORD])
    tree = mat.node_tree
    for node in [n for n in tree.nodes if n.name.startswith(PREFIX)]:
        tree.nodes.remove(node)
    output = tree.nodes.get(record["output"])
    if output is not None and record["from_node"]:
        source = tree.nodes.get(record["from_node"])
        socket = next((s for s in source.outputs if s.identifier == record["from_socket"]), None) if source else None
        if socket is not None:
            tree.links.new(socket, output.inputs["Surface"])
    del mat[RECORD]
    return True


def show(objects, atlas_files: dict, kind: str, uv_layer: str, self_bounce: bool = False, scene=None) -> list[str]:
    """Preview on `objects` (each with `atlas_files[obj.name]`); returns notes for the report.
    A material shared by objects of several atlases samples each object's own atlas. `kind`: a
    preview mode (`core.files.preview`; 'ENCODED': each material shows its atlases' model). In HHD
    mode, atlases baked with light sets show their live blend, weighted by `scene.hhd.light_sets`
    (`scene`: the context's by default), to which missing sets are added. The images are filtered
    as `scene.hhd.preview_filter` says (KERNELS; shaders/bicubic.py); `scene.hhd.preview_term`
    picks the diffuse, specular or both terms (`show_on_material`)."""
    scene = scene if scene is not None else bpy.context.scene
    notes, set_names = [], []
    index = {name: i for i, name in enumerate(sorted({f.name for f in atlas_files.values()}))}
    materials: dict[str, tuple] = {}  # material name → (material, {atlas name: files})
    instanced: set[str] = set()  # materials an instance (an object with its own rectangle) uses
    for files in {f.name: f for f in atlas_files.values()}.values():
        upgrade_direction(files)  # a bake made before the preview held d as a vector
    for obj in objects:
        files = atlas_files[obj.name]
        for slot in obj.material_slots:
            if slot.material is not None:
                materials.setdefault(slot.material.name, (slot.material, {}))[1][files.name] = files
                if tuple(obj.hhd.lightmap_rect) != IDENTITY_RECT:
                    instanced.add(slot.material.name)
        if not obj.material_slots or all(s.material is None for s in obj.material_slots):
            notes.append(f"'{obj.name}' has no material: nothing to preview on it")
    # each material's reconstruction, before anything changes (the Encoded mode may refuse)
    kinds = {name: _kind(mat, kind, list(by_atlas.values())) for name, (mat, by_atlas) in materials.items()}
    for obj in objects:
        obj[RECORD], obj[ATLAS] = 1.0, float(index[atlas_files[obj.name].name])
    for mat, by_atlas in materials.values():
        atlases = [(index[name], by_atlas[name]) for name in sorted(by_atlas)]
        shown = kinds[mat.name]
        light_sets, sets_note = _material_light_sets(atlases) if shown == 'HHD' else ([], None)
        set_names += [name for name, _ in light_sets]
        files = atlases if len(atlases) > 1 else atlases[0][1]
        bicubic = KERNELS[scene.hhd.preview_filter]
        note = show_on_material(
            mat,
            files,
            shown,
            uv_layer,
            self_bounce=self_bounce,
            light_sets=light_sets,
            instanced=mat.name in instanced,
            bicubic=bicubic,
            term=scene.hhd.preview_term,
        )
        notes += [n for n in (sets_note, note) if n]
    sync_light_sets(scene, set_names)
    return notes


def hide(objects=None) -> int:
    """Remove the preview (or a view before a bake, shaders/texel_views.py) from every material
    that has one and the switch from the objects (all objects when None), and what a view added to
    meshes and images; returns how many materials were restored."""
    from . import texel_views  # it builds on this module

    restored = sum(hide_on_material(m) for m in bpy.data.materials)
    for obj in objects if objects is not None else bpy.data.objects:
        for key in (RECORD, ATLAS):
            if key in obj:
                del obj[key]
    texel_views.clear(objects)
    return restored
