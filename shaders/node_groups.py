"""EEVEE node groups reconstructing the baked lighting, built by code from core's constants.

The inputs that take baked data are named after the layers of the channel spec each preview mode
samples (`core.files.preview`), so shaders/preview.py links every preview image to the input
of its layer's name. Groups (all output `Irradiance` and `Radiance` = Albedo × Irradiance, in
the units of docs/conventions.md#irradiance-units):
  "HHD Lightmap" / "AHD Lightmap": inputs Iz, Wa (colour; equal channels in luminance mode),
      Direction (the highlight direction's unit vector x, y, z as its preview image holds it,
      bilinearly filtered: the group renormalises it), Normal (shading), Vertex Normal, Albedo,
      Self Bounce (0/1). The formula is docs/format.md's, d·n_v floored at core.hhd.MIN_COS.
      The preview images never hold the octahedral pair: filtering it across the map's folds
      blends unrelated directions (docs/format.md, "Filtering the direction").
  "L1 SH Lightmap" / "L2 SH Lightmap": inputs SH0 … SH3 (or SH8) radiance SH colours, Normal,
      Albedo; irradiance = Σ_k cosine_kernel_k · SH_k · Y_k(n) with core.sh's basis.
  "Scalar Lightmap": Iz only (no directional response), Albedo.
  "HL2 Lightmap", "L1 H-basis Lightmap", "L2 H-basis Lightmap", "SG5 Lightmap" … "SG12 Lightmap"
      (the Encoded mode of an atlas encoded in that model): inputs the encoding's layers
      (HL2_0 …, H0 …, SG0 …: colours), Normal, Vertex Normal, Albedo. Each builds the tangent
      frame of core.encoding.basis.frames (Duff et al. 2017) from Vertex Normal, n_t = n in it,
      and evaluates the model's `irradiance(c, n_v, n)`: HL2 Σ max(n_t·b_i, 0) H_i; H-basis
      Σ h_i H_i(n_t); SG Σ Hill's fitted cosine convolution of lobe k at n_t·μ_k × a_k / π.
      The sh_l1 / sh_l2 encodings' files use the L1 / L2 SH groups (their layers share names).
  "HHD Light Set Blend ×K": the live blend of K light sets (core.light_sets.blend per pixel):
      per set k inputs "Iz k", "Wa k", "Direction k", "Weight k" (RGB), then the HHD group's
      Normal, Vertex Normal, Albedo, Self Bounce; its reconstruction is the HHD group's.
  "HHD Texel Checker" (the views before a bake, shaders/texel_views.py): inputs UV (the lightmap
      UV), Atlas Size (width, height), Light, Dark (colours); outputs Color (Light on texels
      (i, j) = floor(UV × Atlas Size) with i + j even, else Dark) and Parity (1 there, else 0).
Each group carries GROUP_VERSION in a custom property and is rebuilt when it differs, so a .blend
made with an older extension gets the current maths.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core import hhd, sh
from ..core.colour import LUMINANCE
from ..core.encoding import hbasis, hl2, sg
from ..core.files.preview import sampled

GROUP_VERSION = 3  # 3: Direction inputs are unit vectors (2: octahedral pairs)
GROUPS = {
    "HHD": "HHD Lightmap",
    "AHD": "AHD Lightmap",
    "L1": "L1 SH Lightmap",
    "L2": "L2 SH Lightmap",
    "SCALAR": "Scalar Lightmap",
    "HL2": "HL2 Lightmap",
    "HBASIS_L1": "L1 H-basis Lightmap",
    "HBASIS_L2": "L2 H-basis Lightmap",
    "SG5": "SG5 Lightmap",
    "SG6": "SG6 Lightmap",
    "SG9": "SG9 Lightmap",
    "SG12": "SG12 Lightmap",
    "SH_L1": "L1 SH Lightmap",  # the L1 group: the sh_l1 file's layers are named SH0 … SH3 too
    "SH_L2": "L2 SH Lightmap",
}
#: The live light-set blend group of K sets (`build_blend`), one per K.
BLEND_GROUP = "HHD Light Set Blend ×{}"
#: The blend group's per-set weight input (RGB), `set_input(WEIGHT, k)`.
WEIGHT = "Weight"
#: The texel checker of the views before a bake (`build_checker`).
CHECKER_GROUP = "HHD Texel Checker"


class Builder:
    """Small expression helper: float/vector math nodes from sockets or constants."""

    def __init__(self, tree):
        self.tree = tree
        self.x = 0

    def node(self, kind: str, **props):
        n = self.tree.nodes.new(kind)
        for key, value in props.items():
            setattr(n, key, value)
        n.location = (self.x, 0)
        self.x += 40
        return n

    def _feed(self, socket_in, value):
        if isinstance(value, bpy.types.NodeSocket):
            self.tree.links.new(value, socket_in)
        else:
            socket_in.default_value = value

    def math(self, op: str, a, b=0.0):
        n = self.node("ShaderNodeMath", operation=op)
        self._feed(n.inputs[0], a)
        self._feed(n.inputs[1], b)
        return n.outputs[0]

    def vec(self, op: str, a, b=None, scale=None):
        n = self.node("ShaderNodeVectorMath", operation=op)
        self._feed(n.inputs[0], a)
        if b is not None:
            self._feed(n.inputs[1], b)
        if scale is not None:
            self._feed(n.inputs["Scale"], scale)
        out = n.outputs["Value"] if op in ("DOT_PRODUCT", "LENGTH", "DISTANCE") else n.outputs["Vector"]
        return out

    def xyz(self, v):
        n = self.node("ShaderNodeSeparateXYZ")
        self._feed(n.inputs[0], v)
        return n.outputs

    def combine(self, x, y, z):
        n = self.node("ShaderNodeCombineXYZ")
        for socket, value in zip(n.inputs, (x, y, z)):
            self._feed(socket, value)
        return n.outputs[0]


def _interface(tree, inputs, outputs):
    for name, kind, default in inputs:
        socket = tree.interface.new_socket(name, in_out='INPUT', socket_type=kind)
        if default is not None:
            socket.default_value = default
    for name in outputs:
        tree.interface.new_socket(name, in_out='OUTPUT', socket_type='NodeSocketColor')


def _new_tree(name: str, version: int = GROUP_VERSION):
    """The shader node group `name`, emptied (created if missing), marked with `version`."""
    tree = bpy.data.node_groups.get(name)
    if tree is None:
        tree = bpy.data.node_groups.new(name, 'ShaderNodeTree')
    tree.nodes.clear()
    tree.interface.clear()
    tree["hhd_version"] = version
    return tree


def _finish(b: Builder, irradiance, albedo):
    out = b.node("NodeGroupOutput")
    b.tree.links.new(irradiance, out.inputs["Irradiance"])
    b.tree.links.new(b.vec("MULTIPLY", irradiance, albedo), out.inputs["Radiance"])


def direction(b: Builder, sampled):
    """The highlight direction from its preview image's bilinear sample: the blend of the
    texels' unit vectors, renormalised (a blend of nearby unit vectors stays close to each)."""
    return b.vec("NORMALIZE", sampled)


def hhd_irradiance(b: Builder, iz, wa, d, n, nv, *, albedo, self_bounce, model: str = "HHD"):
    """I(n) of the HHD (or AHD) model as nodes, docs/format.md and core.hhd.reconstruct:
    Iz ⊙ [wa·(1 + n·n_v)/2 + (1 − wa)·max(n·d, 0)/max(d·n_v, MIN_COS/2)] + self_bounce·albedo ⊙ Iz·(1 − n·n_v)/2.
    iz, wa, albedo: colours (wa equal channels in luminance mode); d, n, nv: unit world vectors;
    self_bounce: 0/1. Returns the irradiance colour socket (docs/conventions.md#irradiance-units)."""
    n_nv = b.vec("DOT_PRODUCT", n, nv)
    dnv = b.math("MAXIMUM", b.vec("DOT_PRODUCT", d, nv), 0.5 * float(hhd.MIN_COS))
    directional = b.math("DIVIDE", b.math("MAXIMUM", b.vec("DOT_PRODUCT", n, d), 0.0), dnv)
    ambient = b.math("MULTIPLY", b.math("ADD", n_nv, 1.0), 0.5) if model == "HHD" else 1.0
    # Iz · [wa·ambient + (1 − wa)·directional] per channel
    one_minus_wa = b.vec("SUBTRACT", (1.0, 1.0, 1.0), wa)
    bracket = b.vec("ADD", b.vec("SCALE", wa, scale=ambient), b.vec("SCALE", one_minus_wa, scale=directional))
    irradiance = b.vec("MULTIPLY", iz, bracket)
    bounce = b.math("MULTIPLY", b.math("MULTIPLY", b.math("SUBTRACT", 1.0, n_nv), 0.5), self_bounce)
    return b.vec("ADD", irradiance, b.vec("SCALE", b.vec("MULTIPLY", albedo, iz), scale=bounce))


def _reconstruction_inputs():
    """The inputs every HHD-reconstructing group ends with (preview.py feeds them by name)."""
    return [
        ("Normal", 'NodeSocketVector', None),
        ("Vertex Normal", 'NodeSocketVector', None),
        ("Albedo", 'NodeSocketColor', (0.8, 0.8, 0.8, 1)),
        ("Self Bounce", 'NodeSocketFloat', 0.0),
    ]


def build_hhd(model: str):
    """HHD or AHD group (model 'HHD' | 'AHD')."""
    tree = _new_tree(GROUPS[model])
    iz_layer, wa_layer, dir_layer = sampled(model)
    _interface(
        tree,
        [
            (iz_layer.name, 'NodeSocketColor', (0, 0, 0, 1)),
            (wa_layer.name, 'NodeSocketColor', (1, 1, 1, 1)),
            (dir_layer.name, 'NodeSocketVector', None),
            *_reconstruction_inputs(),
        ],
        ["Irradiance", "Radiance"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    n = b.vec("NORMALIZE", i["Normal"])
    nv = b.vec("NORMALIZE", i["Vertex Normal"])
    d = direction(b, i[dir_layer.name])
    irradiance = hhd_irradiance(
        b, i[iz_layer.name], i[wa_layer.name], d, n, nv, albedo=i["Albedo"], self_bounce=i["Self Bounce"], model=model
    )
    _finish(b, irradiance, i["Albedo"])
    return tree


def blend_group_name(sets: int) -> str:
    """The name of the live light-set blend group of `sets` sets."""
    return BLEND_GROUP.format(sets)


def set_input(layer: str, k: int) -> str:
    """The blend group's input of layer `layer` ('Iz', 'Wa', 'Direction', WEIGHT) of set k (1-based)."""
    return f"{layer} {k}"


def _luminance(b: Builder, colour):
    """Rec.709 luminance (core.colour.LUMINANCE) of a colour socket, as a float socket."""
    return b.vec("DOT_PRODUCT", colour, tuple(float(c) for c in LUMINANCE))


def _set_terms(b: Builder, iz, wa, dir_xyz, weight, nv):
    """One set's share of the blend, in the b-space of core.hhd.to_linear_sh (b_c = 2C_a + C_d,
    b = C_a n_v + C_d d per channel, the linear SH up to constants that from_linear_sh undoes):
    returns (W⊙C_a, W⊙C_d, d, d·n_v) with C_a = wa⊙Iz, C_d = (1 − wa)⊙Iz / (d·n_v), W the set's
    RGB weight. d·n_v is floored at MIN_COS/2, as in to_linear_sh and reconstruct (the encoder
    keeps d·n_v ≥ MIN_COS; the floor guards the bilinear filter's mixes of directions)."""
    d = direction(b, dir_xyz)
    dz = b.math("MAXIMUM", b.vec("DOT_PRODUCT", d, nv), 0.5 * float(hhd.MIN_COS))
    weighted = b.vec("MULTIPLY", weight, iz)
    ca = b.vec("MULTIPLY", weighted, wa)
    cd = b.vec(
        "SCALE", b.vec("MULTIPLY", weighted, b.vec("SUBTRACT", (1.0, 1.0, 1.0), wa)), scale=b.math("DIVIDE", 1.0, dz)
    )
    return ca, cd, d, dz


def _sum(b: Builder, terms):
    """Σ of vector/colour sockets."""
    total = terms[0]
    for term in terms[1:]:
        total = b.vec("ADD", total, term)
    return total


def _where(b: Builder, condition, a, other):
    """condition (0/1 float socket) ? vector a : vector other."""
    return b.vec(
        "ADD", b.vec("SCALE", a, scale=condition), b.vec("SCALE", other, scale=b.math("SUBTRACT", 1.0, condition))
    )


def _fallback_tangent(b: Builder, nv):
    """t of core.sh.tangent_frames(n_v) (Duff et al. 2017): the tangent clamp_to_cone takes when
    d is ±n_v. sign = [n_z ≥ 0]·2 − 1, a = −1/(sign + n_z), t = (1 + sign·n_x²·a, sign·n_x·n_y·a, −sign·n_x)."""
    x, y, z = b.xyz(nv)
    sign = b.math("SUBTRACT", b.math("MULTIPLY", b.math("GREATER_THAN", z, -1e-30), 2.0), 1.0)
    a = b.math("DIVIDE", -1.0, b.math("ADD", sign, z))
    tx = b.math("ADD", 1.0, b.math("MULTIPLY", b.math("MULTIPLY", sign, b.math("MULTIPLY", x, x)), a))
    ty = b.math("MULTIPLY", sign, b.math("MULTIPLY", b.math("MULTIPLY", x, y), a))
    tz = b.math("MULTIPLY", b.math("MULTIPLY", sign, x), -1.0)
    return b.combine(tx, ty, tz)


def _clamp_to_cone(b: Builder, d, nv):
    """core.hhd.linear_sh.clamp_to_cone: d with d·n_v < MIN_COS tilted up to d·n_v = MIN_COS,
    keeping its azimuth."""
    cos = b.vec("DOT_PRODUCT", d, nv)
    tangent = b.vec("SUBTRACT", d, b.vec("SCALE", nv, scale=cos))
    has_tangent = b.math("GREATER_THAN", b.vec("LENGTH", tangent), 1e-12)
    tangent = _where(b, has_tangent, b.vec("NORMALIZE", tangent), _fallback_tangent(b, nv))
    min_cos = float(hhd.MIN_COS)
    clamped = b.vec("ADD", b.vec("SCALE", nv, scale=min_cos), b.vec("SCALE", tangent, scale=(1.0 - min_cos**2) ** 0.5))
    return _where(b, b.math("LESS_THAN", cos, min_cos), clamped, d)


def _solve(b: Builder, ca, cd, cdz, directional, nv):
    """core.hhd.from_linear_sh in b-space: the blended (I_z colour, w_a float, d unit) from
    ca = Σ W⊙C_a, cd = Σ W⊙C_d, cdz = Σ W⊙C_d·(d·n_v) (colours) and directional = Σ lum(W⊙C_d)·d.
    Per channel I_z = max(b·n_v, 0); on the luminance: p = 2b_c − I_z,
    C_a = clamp((p − √max(p² − 3(b_c² − |b|²), 0)) / 3, 0, I_z), d = (b − C_a n_v)/|…| (n_v when
    that is ~0), clamped to d·n_v ≥ MIN_COS; w_a = C_a / I_z (1 when I_z = 0), in [0, 1]."""
    iz = b.vec("MAXIMUM", b.vec("ADD", ca, cdz), (0.0, 0.0, 0.0))
    bc_l = _luminance(b, b.vec("ADD", b.vec("SCALE", ca, scale=2.0), cd))
    iz_l = _luminance(b, iz)
    b_l = b.vec("ADD", b.vec("SCALE", nv, scale=_luminance(b, ca)), directional)
    p = b.math("SUBTRACT", b.math("MULTIPLY", bc_l, 2.0), iz_l)
    b_sq = b.vec("DOT_PRODUCT", b_l, b_l)
    disc = b.math(
        "SUBTRACT",
        b.math("MULTIPLY", p, p),
        b.math("MULTIPLY", b.math("SUBTRACT", b.math("MULTIPLY", bc_l, bc_l), b_sq), 3.0),
    )
    root = b.math("SQRT", b.math("MAXIMUM", disc, 0.0))
    c_a = b.math("MINIMUM", b.math("MAXIMUM", b.math("DIVIDE", b.math("SUBTRACT", p, root), 3.0), 0.0), iz_l)
    dvec = b.vec("SUBTRACT", b_l, b.vec("SCALE", nv, scale=c_a))
    has_d = b.math("GREATER_THAN", b.vec("LENGTH", dvec), b.math("MULTIPLY", iz_l, 1e-12))
    d = _clamp_to_cone(b, _where(b, has_d, b.vec("NORMALIZE", dvec), nv), nv)
    lit = b.math("GREATER_THAN", iz_l, 0.0)
    ratio = b.math("DIVIDE", c_a, iz_l)  # Blender's DIVIDE gives 0 for a zero divisor
    wa = b.math("ADD", b.math("MULTIPLY", ratio, lit), b.math("SUBTRACT", 1.0, lit))
    wa = b.math("MINIMUM", b.math("MAXIMUM", wa, 0.0), 1.0)
    return iz, wa, d


def build_blend(sets: int):
    """The live light-set blend of `sets` sets (core.light_sets.blend per pixel, then the HHD
    reconstruction): inputs per set k = 1 … sets 'Iz k', 'Wa k' (colours as the preview images hold
    them), 'Direction k' (unit vector), 'Weight k' (RGB), then Normal, Vertex Normal, Albedo, Self
    Bounce as the HHD group. Each set's HHD → b-space linear SH (to_linear_sh), weighted sum, the
    closed-form solve back to HHD (from_linear_sh, `_solve`), reconstruction at the shading normal
    (`hhd_irradiance`, shared with the HHD group). Wa is used per channel as to_linear_sh does:
    exact for the luminance mode (equal channels) and the rgb mode alike."""
    tree = _new_tree(blend_group_name(sets))
    iz_layer, wa_layer, dir_layer = sampled("HHD")
    per_set = [
        (iz_layer.name, 'NodeSocketColor', (0, 0, 0, 1)),
        (wa_layer.name, 'NodeSocketColor', (1, 1, 1, 1)),
        (dir_layer.name, 'NodeSocketVector', None),
        (WEIGHT, 'NodeSocketColor', (1, 1, 1, 1)),
    ]
    inputs = [(set_input(name, k), kind, default) for k in range(1, sets + 1) for name, kind, default in per_set]
    _interface(tree, inputs + _reconstruction_inputs(), ["Irradiance", "Radiance"])
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    n = b.vec("NORMALIZE", i["Normal"])
    nv = b.vec("NORMALIZE", i["Vertex Normal"])
    terms = [
        _set_terms(b, *(i[set_input(name, k)] for name, _, _ in per_set[:3]), i[set_input(WEIGHT, k)], nv)
        for k in range(1, sets + 1)
    ]
    ca = _sum(b, [t[0] for t in terms])
    cd = _sum(b, [t[1] for t in terms])
    cdz = _sum(b, [b.vec("SCALE", t[1], scale=t[3]) for t in terms])
    directional = _sum(b, [b.vec("SCALE", t[2], scale=_luminance(b, t[1])) for t in terms])
    iz, wa, d = _solve(b, ca, cd, cdz, directional, nv)
    wa_colour = b.combine(wa, wa, wa)
    irradiance = hhd_irradiance(
        b, iz, wa_colour, d, n, nv, albedo=i["Albedo"], self_bounce=i["Self Bounce"], model="HHD"
    )
    _finish(b, irradiance, i["Albedo"])
    return tree


def ensure_blend(sets: int):
    """The live blend group of `sets` light sets, built or rebuilt if stale."""
    tree = bpy.data.node_groups.get(blend_group_name(sets))
    if tree is not None and tree.get("hhd_version") == GROUP_VERSION:
        return tree
    return build_blend(sets)


def _basis(b: Builder, n):
    """Sockets of Y_k(n) · cosine_kernel_k for k = 0 … 8 (core.sh's basis and convolution)."""
    x, y, z = b.xyz(n)
    k = sh.COSINE_KERNEL
    mul = lambda a, c: b.math("MULTIPLY", a, float(c))
    return [
        float(sh.Y00 * k[0]),
        mul(y, -sh.C1 * k[1]),
        mul(z, sh.C1 * k[2]),
        mul(x, -sh.C1 * k[3]),
        mul(b.math("MULTIPLY", x, y), sh.C2 * k[4]),
        mul(b.math("MULTIPLY", y, z), -sh.C2 * k[5]),
        mul(b.math("SUBTRACT", mul(b.math("MULTIPLY", z, z), 3.0), 1.0), sh.C20 * k[6]),
        mul(b.math("MULTIPLY", x, z), -sh.C2 * k[7]),
        mul(b.math("SUBTRACT", b.math("MULTIPLY", x, x), b.math("MULTIPLY", y, y)), sh.C22 * k[8]),
    ]


def build_sh(order: int):
    """L1 (order 1, 4 coefficients) or L2 (order 2, 9) SH irradiance group."""
    layers = sampled(f"L{order}")  # SH0 … in coefficient order
    tree = _new_tree(GROUPS[f"L{order}"])
    _interface(
        tree,
        [(layer.name, 'NodeSocketColor', (0, 0, 0, 1)) for layer in layers]
        + [("Normal", 'NodeSocketVector', None), ("Albedo", 'NodeSocketColor', (0.8, 0.8, 0.8, 1))],
        ["Irradiance", "Radiance"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    weights = _basis(b, b.vec("NORMALIZE", i["Normal"]))
    total = None
    for k, layer in enumerate(layers):
        term = b.vec("SCALE", i[layer.name], scale=weights[k])
        total = term if total is None else b.vec("ADD", total, term)
    _finish(b, total, i["Albedo"])
    return tree


def build_scalar():
    tree = _new_tree(GROUPS["SCALAR"])
    (iz_layer,) = sampled("SCALAR")
    _interface(
        tree,
        [(iz_layer.name, 'NodeSocketColor', (0, 0, 0, 1)), ("Albedo", 'NodeSocketColor', (0.8, 0.8, 0.8, 1))],
        ["Irradiance", "Radiance"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    _finish(b, i[iz_layer.name], i["Albedo"])
    return tree


def _frame(b: Builder, nv):
    """(t, b) of core.sh.tangent_frames(n_v) (Duff et al. 2017), the frame of the tangent-space
    encodings (core.encoding.basis.frames): s = [n_z ≥ 0]·2 − 1, a = −1/(s + n_z),
    t = (1 + s·n_x²·a, s·n_x·n_y·a, −s·n_x), b = (n_x·n_y·a, s + n_y²·a, −n_y)."""
    x, y, z = b.xyz(nv)
    sign = b.math("SUBTRACT", b.math("MULTIPLY", b.math("GREATER_THAN", z, -1e-30), 2.0), 1.0)
    a = b.math("DIVIDE", -1.0, b.math("ADD", sign, z))
    xya = b.math("MULTIPLY", b.math("MULTIPLY", x, y), a)
    tx = b.math("ADD", 1.0, b.math("MULTIPLY", b.math("MULTIPLY", sign, b.math("MULTIPLY", x, x)), a))
    ty = b.math("MULTIPLY", sign, xya)
    tz = b.math("MULTIPLY", b.math("MULTIPLY", sign, x), -1.0)
    by = b.math("ADD", sign, b.math("MULTIPLY", b.math("MULTIPLY", y, y), a))
    return b.combine(tx, ty, tz), b.combine(xya, by, b.math("MULTIPLY", y, -1.0))


def _tangent_normal(b: Builder, n, nv):
    """(x, y, z) float sockets of the unit shading normal n in the tangent frame of n_v."""
    t, bt = _frame(b, nv)
    return b.vec("DOT_PRODUCT", n, t), b.vec("DOT_PRODUCT", n, bt), b.vec("DOT_PRODUCT", n, nv)


def _weighted_sum(b: Builder, i, layers, weights):
    """Σ_k weights[k] · layer k's colour input (weights: float sockets or constants)."""
    return _sum(b, [b.vec("SCALE", i[layer.name], scale=w) for layer, w in zip(layers, weights)])


def _dot_const(b: Builder, nt, direction):
    """n_t · d for a constant tangent-space direction d (3 floats) as a float socket."""
    terms = [b.math("MULTIPLY", c, float(d)) for c, d in zip(nt, direction)]
    return b.math("ADD", b.math("ADD", terms[0], terms[1]), terms[2])


def _hl2_weights(b: Builder, nt, count):
    """max(n_t · b_i, 0) for HL2's directions b_i (core.encoding.hl2.DIRECTIONS)."""
    return [b.math("MAXIMUM", _dot_const(b, nt, d), 0.0) for d in hl2.DIRECTIONS]


def _hbasis_weights(b: Builder, nt, count):
    """H_0 … H_{count−1} at n_t (core.encoding.hbasis.evaluate)."""
    x, y, z = nt
    k1, k2 = float(hbasis._K1), float(hbasis._K2)
    mul = lambda a, c: b.math("MULTIPLY", a, float(c))
    return [
        float(1.0 / np.sqrt(2.0 * np.pi)),
        mul(y, -k1),
        mul(b.math("SUBTRACT", mul(z, 2.0), 1.0), k1),
        mul(x, -k1),
        mul(b.math("MULTIPLY", x, y), k2),
        mul(b.math("SUBTRACT", b.math("MULTIPLY", x, x), b.math("MULTIPLY", y, y)), 0.5 * k2),
    ][:count]


def _sg_weights(b: Builder, nt, count):
    """Hill's fitted irradiance of each unit lobe at n, / π (core.encoding.sg._hill_irradiance
    with cos = n_t · μ_k): y = (c0·cos + c1·x)²/x where |c0·cos| ≤ c1·x, else clamp(cos, 0, 1);
    (scale·y + bias)·2/λ. scale, bias, x depend on the layout's λ only: constants."""
    axes, lam = sg.layout(count)
    c0 = 0.36
    c1 = 1.0 / (4.0 * c0)
    eml = float(np.exp(-lam))
    em2l = eml * eml
    scale = 1.0 + 2.0 * em2l - 1.0 / lam
    bias = (eml - em2l) / lam - em2l
    x = float(np.sqrt(1.0 - scale))
    out = []
    for axis in axes:
        cos = _dot_const(b, nt, axis)
        x0 = b.math("MULTIPLY", cos, c0)
        inside = b.math("SUBTRACT", 1.0, b.math("GREATER_THAN", b.math("ABSOLUTE", x0), c1 * x))  # |x0| ≤ x1
        shifted = b.math("ADD", x0, c1 * x)
        near = b.math("DIVIDE", b.math("MULTIPLY", shifted, shifted), x)
        far = b.math("MINIMUM", b.math("MAXIMUM", cos, 0.0), 1.0)
        y = b.math("ADD", b.math("MULTIPLY", near, inside), b.math("MULTIPLY", far, b.math("SUBTRACT", 1.0, inside)))
        out.append(b.math("MULTIPLY", b.math("ADD", b.math("MULTIPLY", y, scale), bias), 2.0 / lam))
    return out


#: Coefficient kinds → (their weights at n_t, count).
_TANGENT = {
    "HL2": (_hl2_weights, 3),
    "HBASIS_L1": (_hbasis_weights, 4),
    "HBASIS_L2": (_hbasis_weights, 6),
    "SG5": (_sg_weights, 5),
    "SG6": (_sg_weights, 6),
    "SG9": (_sg_weights, 9),
    "SG12": (_sg_weights, 12),
}


def build_tangent(kind: str):
    """The group of a tangent-frame coefficient encoding (kind 'HL2', 'HBASIS_L1', 'HBASIS_L2',
    'SG5' … 'SG12'): I(n) = Σ_k w_k(n_t) c_k, its basis' `irradiance(c, n_v, n)` (module
    docstring); inputs its layers, Normal, Vertex Normal, Albedo."""
    weights, count = _TANGENT[kind]
    layers = sampled(kind)
    tree = _new_tree(GROUPS[kind])
    _interface(
        tree,
        [(layer.name, 'NodeSocketColor', (0, 0, 0, 1)) for layer in layers] + _reconstruction_inputs()[:3],
        ["Irradiance", "Radiance"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    n = b.vec("NORMALIZE", i["Normal"])
    nv = b.vec("NORMALIZE", i["Vertex Normal"])
    total = _weighted_sum(b, i, layers, weights(b, _tangent_normal(b, n, nv), count))
    _finish(b, total, i["Albedo"])
    return tree


def ensure(kind: str):
    """The node group of `kind` (a key of `core.files.preview.MODES`: 'HHD', 'AHD', 'L1',
    'L2', 'SCALAR', 'HL2', 'HBASIS_L1', …, 'SG12', 'SH_L1', 'SH_L2'), built or rebuilt if stale."""
    tree = bpy.data.node_groups.get(GROUPS[kind])
    if tree is not None and tree.get("hhd_version") == GROUP_VERSION:
        return tree
    if kind in ("HHD", "AHD"):
        return build_hhd(kind)
    if kind in ("L1", "L2", "SH_L1", "SH_L2"):
        return build_sh(int(kind[-1]))
    if kind in _TANGENT:
        return build_tangent(kind)
    return build_scalar()


def build_checker():
    """The texel checker (module docstring): cells exactly one texel of the atlas,
    parity = (floor(u·w) + floor(v·h)) mod 2 = 0, so texel (0, 0) is Light."""
    tree = _new_tree(CHECKER_GROUP)
    for name, kind, default in (
        ("UV", 'NodeSocketVector', None),
        ("Atlas Size", 'NodeSocketVector', (256.0, 256.0, 0.0)),
        ("Light", 'NodeSocketColor', (0.8, 0.8, 0.8, 1.0)),
        ("Dark", 'NodeSocketColor', (0.2, 0.2, 0.2, 1.0)),
    ):
        socket = tree.interface.new_socket(name, in_out='INPUT', socket_type=kind)
        if default is not None:
            socket.default_value = default
    tree.interface.new_socket("Color", in_out='OUTPUT', socket_type='NodeSocketColor')
    tree.interface.new_socket("Parity", in_out='OUTPUT', socket_type='NodeSocketFloat')
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    x, y, _ = b.xyz(b.vec("FLOOR", b.vec("MULTIPLY", i["UV"], i["Atlas Size"])))
    odd = b.math("FLOORED_MODULO", b.math("ADD", x, y), 2.0)
    parity = b.math("SUBTRACT", 1.0, odd)
    mix = b.node("ShaderNodeMix", data_type='RGBA')
    tree.links.new(parity, _socket(mix.inputs, "Factor_Float"))
    tree.links.new(i["Dark"], _socket(mix.inputs, "A_Color"))
    tree.links.new(i["Light"], _socket(mix.inputs, "B_Color"))
    out = b.node("NodeGroupOutput")
    tree.links.new(_socket(mix.outputs, "Result_Color"), out.inputs["Color"])
    tree.links.new(parity, out.inputs["Parity"])
    return tree


def ensure_checker():
    """The texel checker group, built or rebuilt if stale."""
    tree = bpy.data.node_groups.get(CHECKER_GROUP)
    if tree is not None and tree.get("hhd_version") == GROUP_VERSION:
        return tree
    return build_checker()


def _socket(sockets, identifier):
    return next(s for s in sockets if s.identifier == identifier)
