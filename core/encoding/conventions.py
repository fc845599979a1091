"""The conventions every file of an atlas follows, as the sidecar states them. No bpy.

The same text as docs/format.md and docs/conventions.md, with the constants taken from where
they are defined (the encoder's direction cone, Rec.709 luminance).
"""

from __future__ import annotations

from ..colour import LUMINANCE
from ..hhd import MIN_COS

CONVENTIONS = {
    "world": "Blender world space: right-handed, Z up, metres",
    "uv": "lightmap UV (0,0) is the bottom-left texel corner; EXR scanline 0 is the top row (v = 1); "
    "texel (x, y) counted from the bottom sits in scanline height-1-y",
    "sh_basis": "real L2 SH, order (0,0),(1,-1),(1,0),(1,1),(2,-2),(2,-1),(2,0),(2,1),(2,2); "
    "Y1 ∝ (-y, z, -x), Y2 ∝ (xy, -yz, 3z²-1, -xz, x²-y²); orthonormal over the sphere",
    "sh_quantity": "incident radiance over the hemisphere of n_v (zero below it), linear RGB",
    "irradiance": "I(n) = (1/π) ∫ L(ω) max(n·ω, 0) dω, so diffuse outgoing radiance = albedo × I",
    "hhd": "I(n) = Iz · [ wa·(1 + n·nv)/2 + (1 − wa)·max(n·d, 0)/(d·nv) ]",
    "ahd": "I(n) = Iz · [ wa + (1 − wa)·max(n·d, 0)/(d·nv) ]",
    "self_bounce": "optional: + albedo · Iz · (1 − n·nv)/2",
    "direction": "d in world space, octahedral: encode p = d.xy/(|x|+|y|+|z|); if d.z < 0: "
    f"p = (1 − |p.yx|)·sign(p); d·nv ≥ {MIN_COS} guaranteed",
    "luminance": "Rec.709 ({}, {}, {})".format(*(float(w) for w in LUMINANCE)),
}
