"""Material node trees → what the bake reads of a surface: its diffuse albedo and its emitted
radiance (the bpy boundary for materials).

A small evaluation of the shader tree Cycles renders: from the Material Output Cycles uses
(`get_output_node('CYCLES')`), its Surface input is walked through Reroute and muted nodes,
Mix Shader (Fac clamped to [0, 1] as Cycles does; the weighted sum of both branches) and Add
Shader (the sum), down to the shaders:

* Principled BSDF: albedo Base Color × (1 − Metallic) × (1 − Transmission Weight) (the diffuse
  part Cycles' Diffuse bake sees), emission Emission Color × Emission Strength;
* Diffuse BSDF: Color; Emission: Color × Strength (reflects nothing);
* the other shaders by the approximations of `APPROXIMATED`, each with a note;
* an unlinked Surface (or no output): no closure, black, as Cycles renders it (a note);
* no material: Cycles' default surface, a grey (0.8) diffuse; a 4.x material without nodes:
  its Viewport Display colour as a diffuse, as Cycles does.

Colour inputs: unlinked → their value; an Image Texture's Color → the image (albedo: per texel
through `TextureCache`, emission: averaged over each triangle, `triangle_emission`); RGB,
Value → their value; anything else → the material's Viewport Display colour, with a note.
Scalar inputs (strengths, Fac, Metallic...) linked from anything but a Value node → their own
value, with a note. Every note is one line naming the material.

Refused (BakeError naming the source): negative emission (the tracer samples lights by power and
cannot subtract light) and non-finite or absurd values (`checked`: Blender stores "inf" as
3.4e38, which would write inf/NaN into the lightmaps).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import blender_compat
from ..core.errors import BakeError

#: Magnitude from which an input is refused as absurd (`checked`): Blender stores an "inf"
#: typed into a field as FLT_MAX (3.4e38); no light or colour of a real scene comes near.
LIMIT = 1e30

#: Cycles' surface for an object without a material: a diffuse of this grey.
DEFAULT_GREY = (0.8, 0.8, 0.8)

#: Emission textures are averaged over each triangle at the centroids of its N × N sub-triangles
#: (equal areas, so the plain mean is the area mean).
EMISSION_SUBDIVISIONS = 4

#: Shaders the bake approximates: node type → (the input read as a diffuse albedo, None: black;
#: what the note says was done).
APPROXIMATED = {
    'BSDF_GLOSSY': (None, "reflects no diffuse light: baked black (albedo 0; specular light is not baked)"),
    'BSDF_ANISOTROPIC': (None, "reflects no diffuse light: baked black (albedo 0; specular light is not baked)"),
    'BSDF_METALLIC': (None, "reflects no diffuse light: baked black (albedo 0; specular light is not baked)"),
    'BSDF_GLASS': (None, "reflects no diffuse light and the bake traces no light through surfaces: baked black"),
    'BSDF_REFRACTION': (None, "the bake traces no light through surfaces: baked black (albedo 0)"),
    'BSDF_TRANSLUCENT': (None, "the bake traces no light through surfaces: baked black (albedo 0)"),
    'BSDF_TRANSPARENT': (None, "the bake traces no light through surfaces: baked opaque black (a full shadow)"),
    'BSDF_RAY_PORTAL': (None, "the bake traces no light through surfaces: baked opaque black (a full shadow)"),
    'HOLDOUT': (None, "baked opaque black (albedo 0)"),
    'BSDF_HAIR': (None, "hair shading on a surface: baked black (albedo 0)"),
    'BSDF_HAIR_PRINCIPLED': (None, "hair shading on a surface: baked black (albedo 0)"),
    'PRINCIPLED_VOLUME': (None, "a volume shader on the Surface: baked black (albedo 0)"),
    'VOLUME_ABSORPTION': (None, "a volume shader on the Surface: baked black (albedo 0)"),
    'VOLUME_SCATTER': (None, "a volume shader on the Surface: baked black (albedo 0)"),
    'VOLUME_COEFFICIENTS': (None, "a volume shader on the Surface: baked black (albedo 0)"),
    'SUBSURFACE_SCATTERING': ("Color", "baked as a diffuse surface of its Color"),
    'BSDF_SHEEN': ("Color", "baked as a diffuse surface of its Color"),
    'BSDF_VELVET': ("Color", "baked as a diffuse surface of its Color"),
    'BSDF_TOON': ("Color", "baked as a diffuse surface of its Color"),
}


def checked(value, source: str) -> np.ndarray:
    """`value` as float64, or a BakeError naming `source` if any of it is not finite or ≥ LIMIT
    in magnitude (Blender's "inf" is FLT_MAX)."""
    a = np.asarray(value, dtype=np.float64)
    bad = ~np.isfinite(a) | (np.abs(np.where(np.isfinite(a), a, 0.0)) >= LIMIT)
    if bad.any():
        shown = a.ravel()[bad.ravel()][0]
        raise BakeError(
            f"{source} is {shown:g}, not a usable value (Blender stores an 'inf' typed into a field as "
            "3.4e38): the bake would write inf/NaN into the lightmaps; give it a finite value"
        )
    return a


@dataclass(frozen=True)
class ImageRef:
    """An Image Texture node's Color, sampled through the UV map `uv_map` ('' = the render UV map)."""

    node: object
    uv_map: str


@dataclass
class Colour:
    """A linear RGB value: `constant` (3,) + Σ weight (3,) × image, for the (weight, ImageRef)
    pairs of `images`."""

    constant: np.ndarray = field(default_factory=lambda: np.zeros(3))
    images: list = field(default_factory=list)

    def scaled(self, s) -> Colour:
        s = np.asarray(s, dtype=np.float64)
        return Colour(self.constant * s, [(w * s, ref) for w, ref in self.images])

    def plus(self, other: Colour) -> Colour:
        return Colour(self.constant + other.constant, self.images + other.images)

    @property
    def is_zero(self) -> bool:
        return not self.constant.any() and not any(w.any() for w, _ in self.images)


@dataclass
class Surface:
    """What the bake reads of a material: diffuse albedo, emitted radiance (W/(m²·sr)), the notes
    its evaluation made (`evaluate` fills them), and whether an Add Shader summed albedos."""

    albedo: Colour = field(default_factory=Colour)
    emission: Colour = field(default_factory=Colour)
    notes: list = field(default_factory=list)
    added: bool = False

    def scaled(self, s: float) -> Surface:
        return Surface(self.albedo.scaled(s), self.emission.scaled(s), self.notes, self.added)

    def plus(self, other: Surface) -> Surface:
        return Surface(
            self.albedo.plus(other.albedo), self.emission.plus(other.emission), self.notes, self.added or other.added
        )


def _label(node) -> str:
    """'Node name' (Type label) as the user sees it in the editor."""
    kind = getattr(node, "bl_label", "") or node.type.replace("_", " ").title()
    return f"'{node.name}'" if node.name == kind else f"'{node.name}' ({kind})"


def _source(socket):
    """(node, output socket, None) feeding the input `socket` through Reroute and muted nodes, or
    (None, None, last input socket reached) when nothing feeds it (unlinked, a muted link, a
    muted node passing nothing)."""
    for _ in range(1000):  # a reroute cycle is impossible in Blender; never loop forever anyway
        if not socket.is_linked:
            return None, None, socket
        link = socket.links[0]
        if getattr(link, "is_muted", False) or not link.is_valid:
            return None, None, socket
        node, out = link.from_node, link.from_socket
        if node.type == 'REROUTE':
            socket = node.inputs[0]
            continue
        if node.mute:
            through = next((l for l in node.internal_links if l.to_socket.identifier == out.identifier), None)
            if through is None:
                return None, None, None
            socket = through.from_socket
            continue
        return node, out, None
    return None, None, None


def output_node(mat):
    """The Material Output Cycles renders `mat` with (active, target All or Cycles), or None."""
    tree = mat.node_tree
    node = tree.get_output_node('CYCLES') if hasattr(tree, "get_output_node") else None
    if node is None:
        node = next((n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL' and n.is_active_output), None)
    return node


def evaluate(mat) -> Surface:
    """The Surface (albedo, emission, notes) the bake reads of material `mat` (None: no
    material). Raises BakeError for negative emission and for non-finite or absurd values."""
    if mat is None:
        return Surface(Colour(np.array(DEFAULT_GREY)))
    if blender_compat.node_tree_of(mat) is None:  # 4.x without nodes: Cycles' diffuse of this colour
        return Surface(Colour(checked(mat.diffuse_color[:3], f"material '{mat.name}': Viewport Display colour")))
    walk = _Walk(mat)
    output = output_node(mat)
    if output is None:
        surface = Surface()
        walk.note("has no Material Output: Cycles renders it black (no surface), and so does the bake")
    elif not _source(output.inputs["Surface"])[0]:
        surface = Surface()
        walk.note(
            f"nothing is linked to the Surface of {_label(output)}: Cycles renders it black "
            "(no surface), and so does the bake (albedo 0, no emission)"
        )
    else:
        surface = walk.shader(output.inputs["Surface"], 1.0)
    surface.notes = walk.notes
    _check_albedo(mat, surface)
    return surface


def _check_albedo(mat, surface: Surface) -> None:
    """Clamp a constant albedo outside [0, 1] (a surface cannot reflect more light than it
    receives: Cycles' Add Shader can), with a note."""
    albedo = surface.albedo.constant
    if (albedo > 1.0).any() or (albedo < 0.0).any():
        clamped = np.clip(albedo, 0.0, 1.0)
        why = " (an Add Shader sums its shaders' albedos)" if surface.added else ""
        surface.notes.append(
            f"material '{mat.name}': its albedo {_rgb(albedo)} is outside [0, 1]{why}: clamped to {_rgb(clamped)}"
        )
        surface.albedo = Colour(clamped, surface.albedo.images)


def _rgb(c) -> str:
    return "(" + ", ".join(f"{float(x):.3g}" for x in c) + ")"


class _Walk:
    """One material's evaluation: the shader walk, the inputs' values and the notes it makes."""

    def __init__(self, mat):
        self.mat = mat
        self.name = mat.name
        self.notes: list[str] = []

    def note(self, text: str) -> None:
        line = f"material '{self.name}': {text}"
        if line not in self.notes:
            self.notes.append(line)

    def viewport(self) -> np.ndarray:
        return checked(self.mat.diffuse_color[:3], f"material '{self.name}': Viewport Display colour")

    # shaders -----------------------------------------------------------------------------------

    def shader(self, socket, weight: float) -> Surface:
        """The Surface of what feeds the shader input `socket`, × `weight` (skipped at 0: a
        branch a Mix Shader gives no weight makes no notes)."""
        if weight <= 0.0:
            return Surface()
        node, _out, _ = _source(socket)
        if node is None:
            return Surface()  # an unlinked shader input: no closure
        kind = node.type
        if kind == 'MIX_SHADER':
            fac = float(np.clip(self.scalar(node, node.inputs[0]), 0.0, 1.0))  # Cycles clamps Fac
            return self.shader(node.inputs[1], weight * (1.0 - fac)).plus(self.shader(node.inputs[2], weight * fac))
        if kind == 'ADD_SHADER':
            both = self.shader(node.inputs[0], weight).plus(self.shader(node.inputs[1], weight))
            both.added = True
            return both
        if kind == 'BSDF_PRINCIPLED':
            surface = self.principled(node)
        elif kind == 'BSDF_DIFFUSE':
            surface = Surface(self.colour(node, "Color"))
        elif kind == 'EMISSION':
            surface = Surface(emission=self.emission(node, "Color", "Strength"))
        elif kind in APPROXIMATED:
            albedo_input, what = APPROXIMATED[kind]
            if kind == 'BSDF_TOON' and getattr(node, "component", 'DIFFUSE') != 'DIFFUSE':
                albedo_input, what = None, "glossy toon reflects no diffuse light: baked black (albedo 0)"
            self.note(f"{_label(node)} {what}")
            surface = Surface(self.colour(node, albedo_input) if albedo_input else Colour())
        else:
            colour = self.viewport()
            self.note(
                f"{_label(node)} is not a shader the bake reads: baked as a diffuse of the material's "
                f"Viewport Display colour {_rgb(colour)}, without emission"
            )
            surface = Surface(Colour(colour))
        return surface.scaled(weight)

    def principled(self, node) -> Surface:
        albedo = self.colour(node, "Base Color")
        metallic = float(np.clip(self.scalar(node, node.inputs["Metallic"]), 0.0, 1.0))
        transmission = node.inputs.get("Transmission Weight") or node.inputs.get("Transmission")
        transmission = float(np.clip(self.scalar(node, transmission), 0.0, 1.0)) if transmission else 0.0
        diffuse = (1.0 - metallic) * (1.0 - transmission)
        if diffuse < 1.0:
            self.note(
                f"{_label(node)} is {metallic:.0%} metallic and {transmission:.0%} transmissive: its diffuse "
                f"albedo is Base Color × {diffuse:.3g} (as Cycles' diffuse); its specular light is not baked"
            )
            albedo = albedo.scaled(diffuse)
        alpha = node.inputs.get("Alpha")
        if alpha is not None and (alpha.is_linked or alpha.default_value < 1.0):
            self.note(f"{_label(node)}: its Alpha is not read: the bake treats the surface as opaque")
        return Surface(albedo, self.emission(node, "Emission Color", "Emission Strength"))

    def emission(self, node, colour_input: str, strength_input: str) -> Colour:
        strength = self.scalar(node, node.inputs[strength_input])
        if strength == 0.0:
            return Colour()  # not emitting: its colour (even a texture) is not read
        colour = self.colour(node, colour_input).scaled(strength)
        checked(
            colour.constant,
            f"material '{self.name}': the emission of {_label(node)} ({colour_input} × {strength_input})",
        )
        if strength < 0.0 or (colour.constant < 0.0).any() or any((w < 0.0).any() for w, _ in colour.images):
            raise BakeError(
                f"material '{self.name}': {_label(node)} has a negative emission ({strength_input} "
                f"{strength:g}): the bake cannot subtract light; give it a positive {strength_input} "
                "or hide its objects from render"
            )
        return colour

    # inputs ------------------------------------------------------------------------------------

    def scalar(self, node, socket) -> float:
        """A scalar input's value: its own, a Value node's, or (linked from anything else) its
        own with a note."""
        source = f"material '{self.name}': {socket.name} of {_label(node)}"
        feeding, _out, unlinked = _source(socket)
        if feeding is None:
            target = unlinked if unlinked is not None and hasattr(unlinked, "default_value") else socket
            value = getattr(target, "default_value", 0.0)
            return float(checked(value if np.ndim(value) == 0 else value[0], source))
        if feeding.type == 'VALUE':
            return float(checked(feeding.outputs[0].default_value, source))
        value = float(checked(socket.default_value, source))
        self.note(
            f"{socket.name} of {_label(node)} comes from {_label(feeding)}, which the bake does not "
            f"evaluate: baked with the input's own value {value:g}"
        )
        return value

    def colour(self, node, name: str) -> Colour:
        """A colour input's value (see the module doc)."""
        socket = node.inputs[name]
        source = f"material '{self.name}': {name} of {_label(node)}"
        feeding, out, unlinked = _source(socket)
        if feeding is None:
            value = getattr(unlinked, "default_value", None) if unlinked is not None else None
            if value is None:
                return Colour()
            value = [value] * 3 if np.ndim(value) == 0 else value[:3]
            return Colour(checked(value, source))
        if feeding.type == 'RGB':
            return Colour(checked(feeding.outputs[0].default_value[:3], source))
        if feeding.type == 'VALUE':
            return Colour(checked([feeding.outputs[0].default_value] * 3, source))
        if feeding.type == 'TEX_IMAGE' and out.name == "Color" and feeding.image is not None:
            return Colour(np.zeros(3), [(np.ones(3), ImageRef(feeding, self.uv_map(feeding)))])
        colour = self.viewport()
        why = "has no image" if feeding.type == 'TEX_IMAGE' and feeding.image is None else "is not evaluated"
        self.note(
            f"{name} of {_label(node)} comes from {_label(feeding)}, which {why} by the bake: "
            f"baked with the material's Viewport Display colour {_rgb(colour)}"
        )
        return Colour(colour)

    def uv_map(self, node) -> str:
        """The UV map an Image Texture node samples through ('' = the render UV map)."""
        if getattr(node, "projection", 'FLAT') != 'FLAT':
            self.note(
                f"{_label(node)}: its {node.projection.title()} projection is not read: sampled flat through its UV map"
            )
        feeding, out, _ = _source(node.inputs["Vector"])
        if feeding is None:
            return ''
        if feeding.type == 'UVMAP':
            return feeding.uv_map
        if feeding.type == 'TEX_COORD' and out.name == "UV":
            return ''
        self.note(
            f"the Vector of {_label(node)} comes from {_label(feeding)}, which the bake does not read: "
            "sampled through the render UV map"
        )
        return ''


class TextureCache:
    """Image Texture nodes read once as core Textures (linear pixels, interpolation, extension),
    shared by every triangle using them, and each material's evaluation (`surface`), done once
    per bake."""

    def __init__(self):
        self.images: list = []
        self._index: dict = {}
        self._surfaces: dict = {}

    def surface(self, mat, notes: list) -> Surface:
        """`evaluate(mat)`, once per material; its notes go into `notes` (each once)."""
        key = None if mat is None else mat.name_full
        if key not in self._surfaces:
            self._surfaces[key] = evaluate(mat)
        surface = self._surfaces[key]
        notes.extend(n for n in surface.notes if n not in notes)
        return surface

    def texture(self, node):
        """The core Texture of an Image Texture node (its index: `add`)."""
        return self.images[self.add(node)]

    def add(self, node, weight=None, offset=None) -> int:
        """Index in `images` of the node's Texture, or of weight × it + offset (a Mix Shader's
        share of a texture beside a constant), clamped to [0, 1] as an albedo."""
        from ..core.textures import Texture, srgb_to_linear

        image = node.image
        key = (image.name_full, node.interpolation, node.extension)
        if key not in self._index:
            w, h = image.size
            if w == 0 or h == 0:
                raise BakeError(f"image '{image.name}' has no pixels (missing file?)")
            px = np.zeros(w * h * image.channels, dtype=np.float32)
            image.pixels.foreach_get(px)
            rgb = px.reshape(h, w, image.channels)[..., :3].astype(np.float64)
            if rgb.shape[2] < 3:
                rgb = np.repeat(rgb[..., :1], 3, axis=2)
            if image.colorspace_settings.name == 'sRGB' and not image.is_float:
                rgb = srgb_to_linear(rgb)
            checked(rgb, f"image '{image.name}'")
            self._index[key] = len(self.images)
            self.images.append(Texture(rgb, node.interpolation, node.extension))
        if weight is None and offset is None:
            return self._index[key]
        weight = np.ones(3) if weight is None else np.asarray(weight, np.float64)
        offset = np.zeros(3) if offset is None else np.asarray(offset, np.float64)
        derived = key + (tuple(weight.round(9)), tuple(offset.round(9)))
        if derived not in self._index:
            base = self.images[self._index[key]]
            # CLIP extension: outside [0, 1]² the texture part is 0 and the offset is lost (rare)
            pixels = np.clip(base.pixels * weight + offset, 0.0, 1.0)
            self._index[derived] = len(self.images)
            self.images.append(Texture(pixels, base.interpolation, base.extension))
        return self._index[derived]


def albedo_of(mat, cache: TextureCache, notes: list) -> tuple[tuple, int, str | None]:
    """(constant albedo (3,), texture index in `cache.images` or -1, UV map name of the texture
    ('' = render) or None) of material `mat`."""
    surface = cache.surface(mat, notes)
    albedo = surface.albedo
    if not albedo.images:
        return tuple(np.clip(albedo.constant, 0.0, 1.0)), -1, None
    (weight, ref), rest = albedo.images[0], albedo.images[1:]
    constant = albedo.constant.copy()
    for w, other in rest:
        mean = cache.texture(other.node).pixels.reshape(-1, 3).mean(axis=0)
        constant += w * mean
        line = (
            f"material '{mat.name}': several textures make its albedo: {_label(other.node)} is baked at "
            f"its mean colour {_rgb(mean)}"
        )
        if line not in notes:
            notes.append(line)
    plain = np.allclose(weight, 1.0) and not constant.any()
    index = cache.add(ref.node) if plain else cache.add(ref.node, weight, constant)
    if plain and cache.images[index].pixels.max() > 1.0:
        index = cache.add(ref.node, np.ones(3), np.zeros(3))  # the clamped copy
    return (0.8, 0.8, 0.8), index, ref.uv_map


def uv_layer(obj, mesh, name: str, what: str) -> np.ndarray:
    """(loops, 2) the UVs of the mesh's layer `name` ('' = the render UV map)."""
    layer = mesh.uv_layers.get(name) if name else next((l for l in mesh.uv_layers if l.active_render), None)
    if layer is None:
        raise BakeError(f"'{obj.name}' has no UV map '{name or '(render)'}' for its {what} texture")
    uv = np.empty(len(mesh.loops) * 2, np.float32)  # the property's own type: foreach_get's fast path
    layer.data.foreach_get("uv", uv)
    return uv.reshape(-1, 2).astype(np.float64)


def _subtriangle_centroids(n: int) -> np.ndarray:
    """(n², 3) barycentric centroids of the n × n equal sub-triangles of a triangle."""
    out = []
    for i in range(n):
        for j in range(n - i):
            out.append(((i + 1 / 3) / n, (j + 1 / 3) / n))  # the upright sub-triangles
            if i + j < n - 1:
                out.append(((i + 2 / 3) / n, (j + 2 / 3) / n))  # the inverted ones
    b = np.array(out)
    return np.column_stack([1.0 - b.sum(axis=1), b])


def triangle_emission(obj, mesh, loops, mat_index, cache: TextureCache, notes: list) -> np.ndarray:
    """(T, 3) emitted radiance of a mesh's triangles: each material's constant emission plus its
    emission textures averaged over each triangle's UV footprint (the bake's emission is one value
    per triangle; a note says so)."""
    slots = [s.material for s in obj.material_slots] or [None]
    surfaces = [cache.surface(mat, notes).emission for mat in slots]
    pick = np.minimum(mat_index, len(slots) - 1)
    emission = np.array([s.constant for s in surfaces])[pick]
    bary = _subtriangle_centroids(EMISSION_SUBDIVISIONS)
    for k, (mat, colour) in enumerate(zip(slots, surfaces)):
        if not colour.images:
            continue
        rows = np.flatnonzero(pick == k)
        if len(rows) == 0:
            continue
        line = f"material '{mat.name}': emission texture averaged per triangle (the bake emits one colour per triangle)"
        if line not in notes:
            notes.append(line)
        for weight, ref in colour.images:
            uv = uv_layer(obj, mesh, ref.uv_map, "emission")[loops[rows]]  # (R, 3, 2)
            points = np.einsum("sk,rki->rsi", bary, uv).reshape(-1, 2)
            mean = cache.texture(ref.node).sample(points).reshape(len(rows), len(bary), 3).mean(axis=1)
            emission[rows] += weight * mean
    return emission
