"""The views before a bake: texel density, texel checker, problems; restorable exactly (issue 57).

They need only the lightmap UV layer (after Unwrap), no bake. Show inserts, into every material
of the objects that have the layer, a frame of nodes named like the lighting preview's
("HHD Preview View …", shaders/preview.py), recording the material's Surface link in the same
record, so Hide Preview (`preview.hide`) removes them and restores every node tree exactly; one
preview or view is shown at a time (Show hides whatever was shown first). The nodes: the lightmap
UV map, the object's atlas size from an object attribute (`SIZE` = (width, height, 0), from the
unwrap's record, `bridge.bake_session.atlas_groups`; read through the Instancer, so on the Empty
for a collection instance), the layer's UV through the object's lightmap rectangle
(`preview._instance_uv`: an instance's own part of the atlas, `core.unwrap.instances`), the
"HHD Texel Checker" group (shaders/node_groups.py: cells exactly one texel), an Emission of

- Texel Density: the heat colour of each face's texels per metre against the atlas's target
  (`core.unwrap.texel_density`: blue half, green on target, red double) × a faint texel checker;
- Texel Checker: the checker alone (light and dark grey);
- Problems (`core.unwrap.uv_problems`): a grey checker × each face's problem colour (flipped, degenerate,
  objects with too few texels), and magenta on exactly the texels two charts share: a mask image
  per atlas sampled with Closest filtering (1 × 1 and empty when there are none);

and the preview's Mix Shader switched by the object (or Instancer) attribute `hhd_preview` (1 on the viewed
objects: other users of a shared material keep their look). Per-face colours are a face
attribute of the mesh (`bridge.view_data.COLOUR`); the masks are EXR files in Blender's session
temporary folder, loaded as images marked `IMAGE_KEY`. Hide removes the attribute, the object
properties and those images. Objects without the layer are reported by name and left alone.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from .. import blender_compat
from ..bridge import bake_session, view_data
from ..core import unwrap
from ..core.errors import BakeError
from ..core.files import exr
from ..core.unwrap import texel_density, uv_problems
from . import node_groups, preview

MODES = ('DENSITY', 'CHECKER', 'PROBLEMS')
#: Object attribute: the object's atlas size (width, height, 0) in texels.
SIZE = "hhd_view_size"
#: Custom property marking the images a view loaded (Hide removes them).
IMAGE_KEY = "hhd_view"
#: Node names: the lighting preview's prefix, so its Hide removes them.
PREFIX = f"{preview.PREFIX} View"
#: Light and dark cells of the checker per mode (linear grey levels).
CHECKER_LEVELS = {'DENSITY': (1.0, 0.75), 'CHECKER': (0.8, 0.2), 'PROBLEMS': (0.7, 0.5)}
#: The preview image key of the shared-texel masks (`preview._atlas_image`'s key).
MASK_KEY = "View Shared"


@dataclass
class ViewAtlas:
    """One atlas of the viewed objects: name, size, setting (the texel density it was unwrapped
    at, None for a fixed resolution), objects [(object, ViewMesh)] viewed, and others: the
    atlas's further objects (their UVs count for the shared texels only)."""

    name: str
    width: int
    height: int
    setting: float | None
    objects: list
    others: list


@dataclass
class _Mask:
    """The shared-texel mask of an atlas, shaped as `preview._atlas_image` wants an atlas."""

    name: str
    path: Path
    parent: object = None

    def preview_image(self, _key):
        return self.path


def _density_setting(obj, settings) -> float | None:
    """The texel density `obj` was unwrapped at: its own override, else the scene's unless it has
    its own resolution; None for a fixed resolution."""
    if obj.hhd.texel_density:
        return float(obj.hhd.texel_density)
    if obj.hhd.resolution:
        return None
    return float(settings.texel_density) or None


def gather(objects, settings, others: bool = False) -> tuple[list[ViewAtlas], list[str]]:
    """The viewed objects' atlases (`bake_session.atlas_groups`) with their ViewMeshes, and the
    names of objects without the lightmap UV layer (or faces). others: also read the atlases'
    objects not among `objects` (the Problems view's shared texels)."""
    readable, skipped = [], []
    meshes = {}
    for obj in objects:
        mesh = view_data.read_view_mesh(obj, settings.uv_layer)
        if mesh is None:
            skipped.append(obj.name)
        else:
            readable.append(obj)
            meshes[obj.name] = mesh
    groups, _ = bake_session.atlas_groups(readable, settings) if readable else ([], [])
    atlases = []
    for name, width, height, members in groups:
        settings_of = {_density_setting(o, settings) for o in members}
        rest = []
        if others:
            for o in bpy.data.objects:
                if o.type == 'MESH' and o.hhd.atlas == name and o.name not in meshes:
                    mesh = view_data.read_view_mesh(o, settings.uv_layer)
                    if mesh is not None and (o.hhd.atlas_width, o.hhd.atlas_height) == (width, height):
                        rest.append((o, mesh))
        atlases.append(
            ViewAtlas(
                name,
                width,
                height,
                settings_of.pop() if len(settings_of) == 1 else None,
                [(o, meshes[o.name]) for o in members],
                rest,
            )
        )
    return atlases, skipped


def _mask_folder() -> Path:
    folder = Path(bpy.app.tempdir or tempfile.gettempdir()) / "hhd_views"  # Blender's session temporaries
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def write_mask(atlas: ViewAtlas, problems: uv_problems.AtlasProblems) -> Path:
    """The atlas's shared texels as an EXR (1 on them, 0 elsewhere; 1 × 1 and 0 without any)."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in atlas.name)
    path = _mask_folder() / f"{safe}_{atlas.width}x{atlas.height}_shared.exr"
    mask = problems.mask().astype(np.float16) if len(problems.shared) else np.zeros((1, 1), np.float16)
    rows = exr.to_exr_rows(mask, copy=False)
    exr.write_file(path, {c: rows for c in "RGB"})
    return path


def measure(atlas: ViewAtlas) -> tuple[list[texel_density.Density], float]:
    """The densities of the atlas's viewed objects and the target they are compared with (the
    views' and `report`'s one computation): the atlas's Texel Density setting, else the density
    the unwrap reached; 1 when there is no texel or no area at all (every density is then 0)."""
    densities = [texel_density.density(m, atlas.width, atlas.height) for _, m in atlas.objects]
    target = texel_density.target_density(densities, atlas.setting)
    return densities, target if target > 0 else 1.0


def find_problems(atlas: ViewAtlas, target: float) -> uv_problems.AtlasProblems:
    """`core.unwrap.uv_problems.find` over the atlas's viewed objects, then its other objects (whose UVs
    count for the shared texels): `found.objects` starts with the viewed ones, in order."""
    meshes = [m for _, m in atlas.objects] + [m for _, m in atlas.others]
    return uv_problems.find(meshes, atlas.width, atlas.height, target)


def _source(atlas: ViewAtlas) -> str:
    return "its Texel Density setting" if atlas.setting else "the density the unwrap reached"


def shared_mesh_notes(objects, densities, target: float) -> list[str]:
    """Instances share their mesh and so its face colours: one line per mesh whose viewed users'
    per-face density ratios differ by more than 2% (e.g. scaled instances), naming whose colours
    the heat map shows (the last written, `objects`' order) and that the report lines give each
    one's. objects [(object, ViewMesh)], densities: their `texel_density.Density`s."""
    users: dict[str, list] = {}
    for (obj, _), d in zip(objects, densities):
        users.setdefault(obj.data.name, []).append((obj.name, d.density / target))
    notes = []
    for mesh, ratios in users.items():
        first = ratios[0][1]
        if any(np.max(np.abs(r - first) / np.maximum(first, 1e-12), initial=0.0) > 0.02 for _, r in ratios[1:]):
            names = ", ".join(f"'{n}'" for n, _ in ratios)
            notes.append(
                f"{names} share the mesh '{mesh}' but not one texel density (scaled instances): its face "
                f"colours show '{ratios[-1][0]}''s; the density line gives each one's"
            )
    return notes


def _view_atlas(atlas: ViewAtlas, mode: str, lines: list[str]) -> Path | None:
    """Compute `mode` for one atlas: write the face colours of its objects, add report lines,
    and return the Problems view's mask file."""
    densities, target = measure(atlas)
    size = f"atlas '{atlas.name}' {atlas.width}×{atlas.height}"
    source = _source(atlas)
    if mode == 'DENSITY':
        for (obj, _), d in zip(atlas.objects, densities):
            view_data.write_face_colours(obj, texel_density.heat(d.density / target))
        per_object = ", ".join(
            f"'{o.name}' {d.mean_density:.3g} ({d.mean_density / target:.2f}×)"
            for (o, _), d in zip(atlas.objects, densities)
        )
        lines.append(f"Texel density, {size}: target {target:.3g} texels/m ({source}); {per_object}")
        lines.extend(shared_mesh_notes(atlas.objects, densities, target))
        return None
    if mode == 'CHECKER':
        lines.append(f"Texel checker, {size}: a cell is one texel, {100.0 / target:.3g} cm at {target:.3g} texels/m")
        return None
    found = find_problems(atlas, target)
    for (obj, mesh), problems in zip(atlas.objects, found.objects):
        view_data.write_face_colours(obj, uv_problems.face_colours(mesh, problems))
        lines.append(problems.line())
    lines.append(f"Problems, {size}: {len(found.shared)} texels shared by two charts")
    return write_mask(atlas, found)


def show(objects, mode: str, settings) -> tuple[list[str], list[str]]:
    """Show view `mode` ('DENSITY', 'CHECKER', 'PROBLEMS') on `objects`; returns (report lines,
    warnings). Whatever preview or view was shown is hidden first. Raises BakeError when no
    object has the lightmap UV layer."""
    if mode not in MODES:
        raise BakeError(f"unknown view {mode!r}: one of {', '.join(MODES)}")
    preview.hide()
    atlases, skipped = gather(objects, settings, others=mode == 'PROBLEMS')
    notes = [
        f"'{name}' has no lightmap UV layer '{settings.uv_layer}' (or no faces): unwrap it first; left as it is"
        for name in skipped
    ]
    if not atlases:
        raise BakeError(
            f"no selected object has the lightmap UV layer '{settings.uv_layer}': unwrap them first"
            + (f" ({', '.join(repr(n) for n in skipped)})" if skipped else "")
        )
    lines: list[str] = []
    index = {a.name: i for i, a in enumerate(sorted(atlases, key=lambda a: a.name))}
    materials: dict[str, tuple] = {}  # material name → (material, {atlas name: mask})
    for atlas in atlases:
        path = _view_atlas(atlas, mode, lines)
        for obj, _ in atlas.objects:
            obj[preview.RECORD], obj[preview.ATLAS] = 1.0, float(index[atlas.name])
            obj[SIZE] = [float(atlas.width), float(atlas.height), 0.0]
            for slot in obj.material_slots:
                if slot.material is not None:
                    materials.setdefault(slot.material.name, (slot.material, {}))[1][atlas.name] = _Mask(
                        atlas.name, path
                    )
            if not obj.material_slots or all(s.material is None for s in obj.material_slots):
                notes.append(f"'{obj.name}' has no material: nothing to show the view on")
    for mat, masks in materials.values():
        show_on_material(mat, mode, settings.uv_layer, [(index[name], masks[name]) for name in sorted(masks)])
    if mode == 'DENSITY':
        lines.append("Legend: " + texel_density.legend_text())
    elif mode == 'PROBLEMS':
        lines.append("Legend: " + uv_problems.legend_text())
    return lines, notes


def report(objects, settings) -> tuple[dict, list[str]]:
    """What the Texel Density and Problems views show, as figures, changing nothing (no node,
    attribute, image or property): the CLI's `uv-report` and Python's way to check lightmap UVs
    before a bake. Same reading (`gather`, `bridge.view_data`) and math (`measure`,
    `find_problems`) as the views. Returns (document, report lines): the document is
    JSON-ready (finite numbers only): per atlas its size, target texels per metre and where it
    comes from, the texels two charts share, and per object its texels per metre, the ratio to
    the target, texels, m², shared texels, flipped and degenerate faces (polygons), too few
    texels, and its problem count (`uv_problems.ObjectProblems.count`); `missing_uv_layer`
    names the objects without the layer (or faces). Raises BakeError when no object has it."""
    atlases, skipped = gather(objects, settings, others=True)
    if not atlases:
        raise BakeError(
            f"no receiver has the lightmap UV layer '{settings.uv_layer}': unwrap them first"
            + (f" ({', '.join(repr(n) for n in skipped)})" if skipped else "")
        )
    document = {"uv_layer": settings.uv_layer, "min_texels": float(unwrap.FEW_TEXELS), "atlases": []}
    lines: list[str] = []
    totals = dict.fromkeys(("objects", "shared_texels", "flipped_faces", "degenerate_faces", "too_few_texels"), 0)
    for atlas in sorted(atlases, key=lambda a: a.name):
        densities, target = measure(atlas)
        found = find_problems(atlas, target)
        entries = []
        for (obj, _), d, problems in zip(atlas.objects, densities, found.objects):
            entries.append(
                {
                    "name": obj.name,
                    "texels_per_metre": d.mean_density,
                    "ratio": d.mean_density / target,
                    "texels": d.total_texels,
                    "area_m2": d.total_area,
                    "shared_texels": int(problems.shared),
                    "flipped_faces": int(problems.flipped_faces),
                    "degenerate_faces": int(problems.degenerate_faces),
                    "too_few_texels": bool(problems.few),
                    "problems": int(problems.count),
                }
            )
            lines.append(
                f"  {problems.line()}: {d.mean_density:.3g} texels/m, {d.mean_density / target:.2f}× the target"
            )
            totals["objects"] += 1
            totals["flipped_faces"] += int(problems.flipped_faces)
            totals["degenerate_faces"] += int(problems.degenerate_faces)
            totals["too_few_texels"] += int(problems.few)
        totals["shared_texels"] += len(found.shared)
        lines.insert(
            len(lines) - len(entries),
            f"atlas '{atlas.name}' {atlas.width}×{atlas.height}: target {target:.3g} texels/m ({_source(atlas)}), "
            f"{len(found.shared)} texels shared by two charts",
        )
        document["atlases"].append(
            {
                "name": atlas.name,
                "width": atlas.width,
                "height": atlas.height,
                "target_texels_per_metre": target,
                "target_source": "setting" if atlas.setting else "reached",
                "shared_texels": len(found.shared),
                "objects": entries,
            }
        )
    document["missing_uv_layer"] = list(skipped)
    document["totals"] = totals
    return document, lines


def _new(tree, kind, name, location, parent):
    return preview._new(tree, kind, f"View {name}", location, parent)


def show_on_material(mat, mode: str, uv_layer: str, masks=None) -> None:
    """Insert view `mode` into one material (module docstring). masks (Problems): [(atlas index,
    _Mask)] of the atlases whose objects use the material."""
    tree = mat.node_tree if mat.node_tree is not None else blender_compat.ensure_node_tree(mat)
    if preview.RECORD in mat:
        preview.hide_on_material(mat)
    output = preview._output(tree)
    if output is None:  # named with the prefix, so Hide removes it again
        output = preview._new(tree, "ShaderNodeOutputMaterial", "Output", (300, 0), None)
    link = output.inputs["Surface"].links[0] if output.inputs["Surface"].is_linked else None
    mat[preview.RECORD] = json.dumps(
        {
            "output": output.name,
            "from_node": link.from_node.name if link else None,
            "from_socket": link.from_socket.identifier if link else None,
            "view": mode,
        }
    )
    frame = _new(tree, "NodeFrame", "Frame", (output.location.x + 300, output.location.y), None)
    x0, y0 = output.location.x + 320, output.location.y - 40
    uv = _new(tree, "ShaderNodeUVMap", "UV", (x0, y0), frame)
    uv.uv_map = uv_layer
    atlas_uv = preview._instance_uv(tree, uv.outputs["UV"], x0, y0 - 400, frame)  # instances: their rectangle
    size = _new(tree, "ShaderNodeAttribute", "Atlas Size", (x0, y0 - 200), frame)
    size.attribute_type, size.attribute_name = 'INSTANCER', SIZE  # an Empty's, for collection instances
    checker = _new(tree, "ShaderNodeGroup", "Checker", (x0 + 250, y0), frame)
    checker.node_tree = node_groups.ensure_checker()
    tree.links.new(atlas_uv, checker.inputs["UV"])
    tree.links.new(size.outputs["Vector"], checker.inputs["Atlas Size"])
    light, dark = CHECKER_LEVELS[mode]
    checker.inputs["Light"].default_value = (light, light, light, 1.0)
    checker.inputs["Dark"].default_value = (dark, dark, dark, 1.0)
    colour = checker.outputs["Color"]
    if mode in ('DENSITY', 'PROBLEMS'):
        face = _new(tree, "ShaderNodeAttribute", "Face Colour", (x0 + 250, y0 - 250), frame)
        face.attribute_type, face.attribute_name = 'GEOMETRY', view_data.COLOUR
        multiply = _new(tree, "ShaderNodeVectorMath", "Tint", (x0 + 500, y0), frame)
        multiply.operation = 'MULTIPLY'
        tree.links.new(colour, multiply.inputs[0])
        tree.links.new(face.outputs["Vector"], multiply.inputs[1])
        colour = multiply.outputs["Vector"]
    if mode == 'PROBLEMS' and masks:
        shared = preview._atlas_image(tree, MASK_KEY, masks, atlas_uv, x0 + 250, y0 - 500, frame)
        for node in tree.nodes:
            if node.type == 'TEX_IMAGE' and node.name.startswith(f"{preview.PREFIX} {MASK_KEY}"):
                node.interpolation = 'Closest'  # exactly the texels
                node.image[IMAGE_KEY] = 1
        separate = _new(tree, "ShaderNodeSeparateColor", "Shared", (x0 + 750, y0 - 300), frame)
        tree.links.new(shared, separate.inputs["Color"])
        mix = _new(tree, "ShaderNodeMix", "Mark Shared", (x0 + 750, y0), frame)
        mix.data_type = 'RGBA'
        tree.links.new(separate.outputs[0], preview._socket(mix.inputs, "Factor_Float"))
        tree.links.new(colour, preview._socket(mix.inputs, "A_Color"))
        preview._socket(mix.inputs, "B_Color").default_value = (*uv_problems.SHARED_COLOUR, 1.0)
        colour = preview._socket(mix.outputs, "Result_Color")
    emission = _new(tree, "ShaderNodeEmission", "Emission", (x0 + 1000, y0), frame)
    tree.links.new(colour, emission.inputs["Color"])
    switch = _new(tree, "ShaderNodeAttribute", "Switch", (x0 + 1000, y0 + 200), frame)
    switch.attribute_type, switch.attribute_name = 'INSTANCER', preview.RECORD
    mix_shader = _new(tree, "ShaderNodeMixShader", "Mix", (x0 + 1200, y0), frame)
    tree.links.new(switch.outputs["Fac"], mix_shader.inputs["Fac"])
    if link is not None:
        tree.links.new(link.from_socket, mix_shader.inputs[1])
    tree.links.new(emission.outputs["Emission"], mix_shader.inputs[2])
    tree.links.new(mix_shader.outputs["Shader"], output.inputs["Surface"])


def clear(objects=None) -> None:
    """Remove what the views added besides nodes: the face attribute and SIZE from the objects
    (all when None) and the mask images. `preview.hide` calls it."""
    for obj in objects if objects is not None else bpy.data.objects:
        if SIZE in obj:
            del obj[SIZE]
        if obj.type == 'MESH':
            view_data.remove_face_colours(obj)
    for image in [i for i in bpy.data.images if IMAGE_KEY in i]:
        bpy.data.images.remove(image)
