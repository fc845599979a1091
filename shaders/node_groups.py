"""EEVEE node groups reconstructing the baked lighting, built by code from core's constants.

The inputs that take baked data are named after the layers of the channel spec each preview mode
samples (`core.encoding.preview`), so shaders/preview.py links every preview image to the input
of its layer's name. Groups (all output `Irradiance` and `Radiance` = Albedo × Irradiance, in
DESIGN.md units):
  "HHD Lightmap" / "AHD Lightmap": inputs Iz, Wa (colour; equal channels in luminance mode),
      Direction (octahedral X, Y in the vector's x, y), Normal (shading), Vertex Normal, Albedo,
      Self Bounce (0/1). The formula and octahedral decode are docs/format.md's, d·n_v floored at
      core.hhd.MIN_COS.
  "L1 SH Lightmap" / "L2 SH Lightmap": inputs SH0 … SH3 (or SH8) radiance SH colours, Normal,
      Albedo; irradiance = Σ_k cosine_kernel_k · SH_k · Y_k(n) with core.sh's basis.
  "Scalar Lightmap": Iz only (no directional response), Albedo.
Each group carries GROUP_VERSION in a custom property and is rebuilt when it differs, so a .blend
made with an older extension gets the current maths.
"""

from __future__ import annotations

import bpy

from ..core import hhd, sh
from ..core.encoding.preview import sampled

GROUP_VERSION = 1
GROUPS = {
    "HHD": "HHD Lightmap",
    "AHD": "AHD Lightmap",
    "L1": "L1 SH Lightmap",
    "L2": "L2 SH Lightmap",
    "SCALAR": "Scalar Lightmap",
}


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


def _new_tree(name: str):
    tree = bpy.data.node_groups.get(name)
    if tree is None:
        tree = bpy.data.node_groups.new(name, 'ShaderNodeTree')
    tree.nodes.clear()
    tree.interface.clear()
    tree["hhd_version"] = GROUP_VERSION
    return tree


def _finish(b: Builder, irradiance, albedo):
    out = b.node("NodeGroupOutput")
    b.tree.links.new(irradiance, out.inputs["Irradiance"])
    b.tree.links.new(b.vec("MULTIPLY", irradiance, albedo), out.inputs["Radiance"])


def octahedral_decode(b: Builder, oct_xy):
    """The inverse octahedral map (docs/format.md), as nodes: unit direction."""
    x, y, _ = b.xyz(oct_xy)
    z = b.math("SUBTRACT", b.math("SUBTRACT", 1.0, b.math("ABSOLUTE", x)), b.math("ABSOLUTE", y))
    t = b.math("MAXIMUM", b.math("MULTIPLY", z, -1.0), 0.0)

    def fold(c):  # c − t·sign_not_zero(c), sign_not_zero(c) = 1 − 2·[c < 0]
        sign = b.math("SUBTRACT", 1.0, b.math("MULTIPLY", b.math("LESS_THAN", c, 0.0), 2.0))
        return b.math("SUBTRACT", c, b.math("MULTIPLY", t, sign))

    return b.vec("NORMALIZE", b.combine(fold(x), fold(y), z))


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
            ("Normal", 'NodeSocketVector', None),
            ("Vertex Normal", 'NodeSocketVector', None),
            ("Albedo", 'NodeSocketColor', (0.8, 0.8, 0.8, 1)),
            ("Self Bounce", 'NodeSocketFloat', 0.0),
        ],
        ["Irradiance", "Radiance"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    n = b.vec("NORMALIZE", i["Normal"])
    nv = b.vec("NORMALIZE", i["Vertex Normal"])
    d = octahedral_decode(b, i[dir_layer.name])
    n_nv = b.vec("DOT_PRODUCT", n, nv)
    dnv = b.math("MAXIMUM", b.vec("DOT_PRODUCT", d, nv), float(hhd.MIN_COS))
    directional = b.math("DIVIDE", b.math("MAXIMUM", b.vec("DOT_PRODUCT", n, d), 0.0), dnv)
    ambient = b.math("MULTIPLY", b.math("ADD", n_nv, 1.0), 0.5) if model == "HHD" else 1.0
    # Iz · [wa·ambient + (1 − wa)·directional] per channel
    wa = i[wa_layer.name]
    one_minus_wa = b.vec("SUBTRACT", (1.0, 1.0, 1.0), wa)
    bracket = b.vec("ADD", b.vec("SCALE", wa, scale=ambient), b.vec("SCALE", one_minus_wa, scale=directional))
    irradiance = b.vec("MULTIPLY", i[iz_layer.name], bracket)
    bounce = b.math("MULTIPLY", b.math("MULTIPLY", b.math("SUBTRACT", 1.0, n_nv), 0.5), i["Self Bounce"])
    irradiance = b.vec(
        "ADD", irradiance, b.vec("SCALE", b.vec("MULTIPLY", i["Albedo"], i[iz_layer.name]), scale=bounce)
    )
    _finish(b, irradiance, i["Albedo"])
    return tree


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


def ensure(kind: str):
    """The node group of `kind` ('HHD', 'AHD', 'L1', 'L2', 'SCALAR'), built or rebuilt if stale."""
    tree = bpy.data.node_groups.get(GROUPS[kind])
    if tree is not None and tree.get("hhd_version") == GROUP_VERSION:
        return tree
    if kind in ("HHD", "AHD"):
        return build_hhd(kind)
    if kind in ("L1", "L2"):
        return build_sh(int(kind[1]))
    return build_scalar()
