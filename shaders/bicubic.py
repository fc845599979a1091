"""Bicubic lookups of a preview image in EEVEE: the preview's Filters Bicubic (Catmull-Rom) and
B-spline (prefiltered).

EEVEE's own Image Texture 'Cubic' interpolation is a cubic B-spline (it blurs: measured in
bench/results/bicubic.md), not the interpolating Catmull-Rom kernel of
`core.textures.sample_bicubic` the runtime option uses, so the preview builds Catmull-Rom from
16 'Closest' lookups of the 4 × 4 texels around the point (exact texel values: no GPU filter
weights, no mip level) weighted in nodes:
  "HHD Catmull-Rom Taps": inputs UV (the lightmap UV), Size (image width, height, 0); outputs
      "UV k" (the centre of tap k = 4 j + i, texel (floor(p) + (i − 1, j − 1)), p = UV · Size − ½)
      and "Weight k" (w_i(fx) · w_j(fy), `core.textures.catmull_rom_weights`).
  "HHD Catmull-Rom Sum": inputs "Color k", "Weight k" (16 each); output Color = Σ weight · colour.
  "HHD B-spline Taps": the taps with the cubic B-spline's weights (`bspline_weights`), for the
      Filter 'B-spline (prefiltered)', whose images hold the coefficients of the B-spline whose
      texel means are the texels (`core.files.preview.bspline_image`).
The taps read one texel further each way than bilinear: a chart needs 2 texels of filled gutter
(the unwrap's padding ≥ 4, i.e. Mip Levels ≥ 1). Catmull-Rom's negative lobes overshoot next to
a step: `lookup` clamps I_z at 0 and w_a to [0, 1]; directions are renormalised by the groups.
"""

from __future__ import annotations

import bpy

from .node_groups import Builder, _new_tree

VERSION = 1
TAPS_GROUP = "HHD Catmull-Rom Taps"
#: The taps of the B-spline (the Filter 'B-spline (prefiltered)': the image holds coefficients,
#: `core.files.preview.bspline_image`).
BSPLINE_TAPS_GROUP = "HHD B-spline Taps"
SUM_GROUP = "HHD Catmull-Rom Sum"
TAPS = 16
#: The preview layers clamped after the blend: (low, high) (I_z ≥ 0, w_a in [0, 1]).
CLAMPED = {"iz": (0.0, None), "wa": (0.0, 1.0)}


#: Per kernel, the cubic polynomials (c3, c2, c1, c0) of the weights of offsets −1 … 2 at
#: fraction t, times `scale` (`core.textures.catmull_rom_weights`, `bspline_weights`).
POLYNOMIALS = {
    "catmull_rom": (0.5, ((-1, 2, -1, 0), (3, -5, 0, 2), (-3, 4, 1, 0), (1, -1, 0, 0))),
    "bspline": (1 / 6, ((-1, 3, -3, 1), (3, -6, 0, 4), (-3, 3, 3, 1), (1, 0, 0, 0))),
}


def _weights(b: Builder, t, kernel: str = "catmull_rom") -> list:
    """`kernel`'s weights of offsets −1 … 2 at fraction t (a float socket), as float sockets."""
    t2 = b.math("MULTIPLY", t, t)
    t3 = b.math("MULTIPLY", t2, t)
    scale, polynomials = POLYNOMIALS[kernel]

    def poly(c3, c2, c1, c0):  # scale (c3 t³ + c2 t² + c1 t + c0)
        s = b.math("MULTIPLY", t3, scale * c3)
        s = b.math("ADD", s, b.math("MULTIPLY", t2, scale * c2)) if c2 else s
        s = b.math("ADD", s, b.math("MULTIPLY", t, scale * c1)) if c1 else s
        return b.math("ADD", s, scale * c0) if c0 else s

    return [poly(*c) for c in polynomials]


def build_taps(kernel: str = "catmull_rom"):
    tree = _new_tree(TAPS_GROUP if kernel == "catmull_rom" else BSPLINE_TAPS_GROUP, VERSION)
    tree.interface.new_socket("UV", in_out='INPUT', socket_type='NodeSocketVector')
    size = tree.interface.new_socket("Size", in_out='INPUT', socket_type='NodeSocketVector')
    size.default_value = (256.0, 256.0, 1.0)
    for k in range(TAPS):
        tree.interface.new_socket(f"UV {k}", in_out='OUTPUT', socket_type='NodeSocketVector')
        tree.interface.new_socket(f"Weight {k}", in_out='OUTPUT', socket_type='NodeSocketFloat')
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    p = b.vec("SUBTRACT", b.vec("MULTIPLY", i["UV"], i["Size"]), (0.5, 0.5, 0.0))
    base = b.vec("FLOOR", p)
    fx, fy, _ = b.xyz(b.vec("SUBTRACT", p, base))
    wx, wy = _weights(b, fx, kernel), _weights(b, fy, kernel)
    out = b.node("NodeGroupOutput")
    for j in range(4):
        for k in range(4):
            centre = b.vec("ADD", base, (k - 0.5, j - 0.5, 0.0))
            tree.links.new(b.vec("DIVIDE", centre, i["Size"]), out.inputs[f"UV {4 * j + k}"])
            tree.links.new(b.math("MULTIPLY", wx[k], wy[j]), out.inputs[f"Weight {4 * j + k}"])
    return tree


def build_sum():
    tree = _new_tree(SUM_GROUP, VERSION)
    for k in range(TAPS):
        tree.interface.new_socket(f"Color {k}", in_out='INPUT', socket_type='NodeSocketColor')
        tree.interface.new_socket(f"Weight {k}", in_out='INPUT', socket_type='NodeSocketFloat')
    tree.interface.new_socket("Color", in_out='OUTPUT', socket_type='NodeSocketColor')
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    total = b.vec("SCALE", i["Color 0"], scale=i["Weight 0"])
    for k in range(1, TAPS):
        total = b.vec("ADD", total, b.vec("SCALE", i[f"Color {k}"], scale=i[f"Weight {k}"]))
    tree.links.new(total, b.node("NodeGroupOutput").inputs["Color"])
    return tree


def _ensure(name: str, build):
    tree = bpy.data.node_groups.get(name)
    if tree is not None and tree.get("hhd_version") == VERSION:
        return tree
    return build()


def lookup(tree, new, image, key: str, uv, x: float, y: float, kernel: str = "catmull_rom"):
    """Colour socket of the bicubic lookup (`kernel`: "catmull_rom", or "bspline" of an image of
    coefficients) of `image` (a bpy Image) at the `uv` socket in material `tree`: the taps and
    sum groups and 16 'Closest' Image Texture nodes, made by `new(tree, kind, name, location)`
    (named after `key`), clamped per CLAMPED[key]."""
    taps = new(tree, "ShaderNodeGroup", f"{key} Taps", (x, y))
    group = TAPS_GROUP if kernel == "catmull_rom" else BSPLINE_TAPS_GROUP
    taps.node_tree = _ensure(group, lambda: build_taps(kernel))
    tree.links.new(uv, taps.inputs["UV"])
    width, height = image.size
    taps.inputs["Size"].default_value = (float(width), float(height), 1.0)
    blend = new(tree, "ShaderNodeGroup", f"{key} Sum", (x + 500, y))
    blend.node_tree = _ensure(SUM_GROUP, build_sum)
    for k in range(TAPS):
        node = new(tree, "ShaderNodeTexImage", f"{key} Tap {k}", (x + 250, y - 30 * k))
        node.image, node.interpolation, node.extension = image, 'Closest', 'EXTEND'
        node.hide = True
        tree.links.new(taps.outputs[f"UV {k}"], node.inputs["Vector"])
        tree.links.new(node.outputs["Color"], blend.inputs[f"Color {k}"])
        tree.links.new(taps.outputs[f"Weight {k}"], blend.inputs[f"Weight {k}"])
    colour = blend.outputs["Color"]
    low, high = CLAMPED.get(key.split()[0], (None, None))
    for op, bound in (("MAXIMUM", low), ("MINIMUM", high)):
        if bound is not None:
            node = new(tree, "ShaderNodeVectorMath", f"{key} {op.title()}", (x + 650, y))
            node.operation = op
            tree.links.new(colour, node.inputs[0])
            node.inputs[1].default_value = (bound, bound, bound)
            colour = node.outputs["Vector"]
    return colour
