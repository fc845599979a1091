"""EEVEE node groups for the preview's Specular / Both terms (`scene.hhd.preview_term`).

Groups (built by code from core's constants, the maths of core/encoding/hhd_specular.py and
core/encoding/ggx.py; units of docs/conventions.md, S = ∫ L f cos dω):
  "HHD Specular" / "AHD Specular": inputs Iz, Wa, Direction (as the HHD group's), then
      `_material_inputs`; S = π C_d F f_D(d, v) + C_a (F0·A + B)(n·v, α) · V (V = 1 for AHD),
      `core.encoding.hhd_specular.specular`.
  "L1 SH Specular" / "L2 SH Specular": inputs SH0 … SH3 (SH8), then `_material_inputs`;
      S = F0 ⊙ T(A) + T(B), T(g) = Σ_k g_k s_k with the GGX lobe's SH g (`ggx.sh_specular`) in
      the view frame (x along v's part ⊥ n, z = n), taken to world space by evaluating the
      radiance bands at directions (docs/format.md, "Specular"): band 0 g₀ s₀; band 1
      S₁(u)/c₁ with u = −g₃ x + g₂ z; band 2 (4π/5)[2c₂₀ g₆ S₂(z) − (c₂/3) g₇ (S₂(p) − S₂(q))
      + (2c₂₂/3) g₈ (S₂(x) − S₂(y))], p, q = (x ± z)/√2 (Funk–Hecke: ∫ S₂ P₂(ω·a) dω = (4π/5) S₂(a)).
  "SG5 Specular" … "SG12 Specular": inputs SG0 … SG{K−1} (lobe amplitudes), then
      `_material_inputs`; Σ_k of Baking Lab's anisotropic warp, `core.encoding.sg.asg_specular`:
      z = reflect(−v, n), x = n × z, y = z × x; the lobes' axes μ_k (constants of `sg.layout`) are
      in n_v's tangent frame (`node_groups._frame`), so x, y, z go into it and μ_k·x … are dot
      products with constants; S = F ⊙ Σ_k max(a_k, 0) max(μ_k·z, 0) exp(−c_x (μ_k·x)² − c_y
      (μ_k·y)²) · c_amp/(π α²) · V₁(n·z) V₁(n·v) · n·z (the per-lobe max(·, 0) of core on the
      amplitude: the rest of the product is ≥ 0).
Both output Specular and Both = Albedo (1 − Metallic) ⊙ Irradiance + Specular. F0 is the
Principled BSDF's: mix(((IOR − 1)/(IOR + 1))² · 2 · Specular IOR Level, Base Color, Metallic),
α = max(Roughness², LUT's α floor). A and B (Schlick's F0 factor and bias) of the lobe's SH
coefficients come from a lookup table (`ggx.table`) baked into three 32 × 32 RGBA float EXR
images in Blender's session temporaries (`ensure_lut`): image j holds coefficients LUT_LAYOUT[j]
as (A_k, B_k, A_k', B_k'), u = n·v, v = √α on the table's grid (texel centres on the grid
points, sampled bilinearly as the table is).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import bpy
import numpy as np

from ..core import sh
from ..core.encoding import ggx, sg
from ..core.encoding.hhd_specular import VISIBILITY_SLOPE
from ..core.files import exr
from ..core.hhd import MIN_COS
from .node_groups import (
    GROUP_VERSION,
    Builder,
    _fallback_tangent,
    _frame,
    _interface,
    _new_tree,
    _socket,
    _sum,
    _where,
    direction,
)

#: The SG layouts with a specular group (core.encoding.sg).
SG_COUNTS = (5, 6, 9, 12)
GROUPS = {
    "HHD": "HHD Specular",
    "AHD": "AHD Specular",
    "L1": "L1 SH Specular",
    "L2": "L2 SH Specular",
    **{f"SG{k}": f"SG{k} Specular" for k in SG_COUNTS},
}
#: Preview kinds with a specular group -> its key in GROUPS (none for SCALAR, HL2, H-basis:
#: those models have no specular, docs/format.md).
KINDS = {
    "HHD": "HHD",
    "AHD": "AHD",
    "L1": "L1",
    "L2": "L2",
    "SH_L1": "L1",
    "SH_L2": "L2",
    **{f"SG{k}": f"SG{k}" for k in SG_COUNTS},
}
#: SH coefficients (of ggx.LOBE_COEFFS) per LUT image, as (A_k, B_k, A_k', B_k') in RGBA.
LUT_LAYOUT = ((0, 2), (3, 6), (7, 8))
LUT_IMAGE = "HHD GGX LUT {}"
#: The α floor of the preview (the table's √α floor squared).
ALPHA_MIN = ggx.SQRT_ALPHA_MIN**2


def lut_pixels(j: int) -> np.ndarray:
    """Image j of the LUT `(TABLE_ROUGH rows from the bottom, TABLE_NV, 4)` float32."""
    t = ggx.table()  # (nv, √α, 6, 2): [..., 0] = A (× F0), [..., 1] = B
    cols = [t[:, :, ggx.LOBE_COEFFS.index(k), part] for k in LUT_LAYOUT[j] for part in (0, 1)]
    return np.stack(cols, -1).transpose(1, 0, 2).astype(np.float32)


def ensure_lut() -> list:
    """The three LUT images, written to the session temporaries and loaded (again when a saved
    .blend's temporary file is gone)."""
    folder = Path(bpy.app.tempdir or tempfile.gettempdir()) / "hhd_lut"
    folder.mkdir(parents=True, exist_ok=True)
    images = []
    for j in range(len(LUT_LAYOUT)):
        name = LUT_IMAGE.format(j)
        path = folder / f"ggx_lut_{j}.exr"
        if not path.is_file():
            rows = exr.to_exr_rows(lut_pixels(j))
            exr.write_file(path, {c: np.ascontiguousarray(rows[..., i]) for i, c in enumerate("RGBA")})
        image = bpy.data.images.get(name)
        if image is None:
            image = bpy.data.images.load(str(path))
            image.name = name
        elif Path(bpy.path.abspath(image.filepath)) != path:  # a saved .blend in a new session
            image.filepath = str(path)
            image.reload()
        image.colorspace_settings.is_data = True
        image.alpha_mode = 'CHANNEL_PACKED'  # four independent values: never (un)premultiplied
        images.append(image)
    return images


def _material_inputs():
    return [
        ("Normal", 'NodeSocketVector', None),
        ("Vertex Normal", 'NodeSocketVector', None),
        ("Incoming", 'NodeSocketVector', None),
        ("Albedo", 'NodeSocketColor', (0.8, 0.8, 0.8, 1)),
        ("Metallic", 'NodeSocketFloat', 0.0),
        ("Roughness", 'NodeSocketFloat', 0.5),
        ("IOR", 'NodeSocketFloat', 1.5),
        ("Specular IOR Level", 'NodeSocketFloat', 0.5),
        ("Irradiance", 'NodeSocketColor', (0, 0, 0, 1)),
    ]


class _Common:
    """The sockets every specular group shares: unit n, n_v, v, n·v, α, F0."""

    def __init__(self, b: Builder, i):
        self.n = b.vec("NORMALIZE", i["Normal"])
        self.nv = b.vec("NORMALIZE", i["Vertex Normal"])
        self.v = b.vec("NORMALIZE", i["Incoming"])
        self.n_v = b.vec("DOT_PRODUCT", self.n, self.v)
        self.alpha = b.math("MAXIMUM", b.math("MULTIPLY", i["Roughness"], i["Roughness"]), ALPHA_MIN)
        ratio = b.math("DIVIDE", b.math("SUBTRACT", i["IOR"], 1.0), b.math("ADD", i["IOR"], 1.0))
        dielectric = b.math(
            "MULTIPLY", b.math("MULTIPLY", ratio, ratio), b.math("MULTIPLY", i["Specular IOR Level"], 2.0)
        )
        mix = b.node("ShaderNodeMix", data_type='RGBA')
        b.tree.links.new(i["Metallic"], _socket(mix.inputs, "Factor_Float"))
        b.tree.links.new(b.combine(dielectric, dielectric, dielectric), _socket(mix.inputs, "A_Color"))
        b.tree.links.new(i["Albedo"], _socket(mix.inputs, "B_Color"))
        self.f0 = _socket(mix.outputs, "Result_Color")


def _lut(b: Builder, c: _Common, images) -> list:
    """[(A_k, B_k) sockets] for ggx.LOBE_COEFFS, read from the LUT at (n·v, √α)."""
    nt, nr = ggx.TABLE_NV, ggx.TABLE_ROUGH
    u = b.math("DIVIDE", b.math("ADD", b.math("MULTIPLY", b.math("MAXIMUM", c.n_v, 0.0), nt - 1.0), 0.5), float(nt))
    root = b.math("MINIMUM", b.math("MAXIMUM", b.math("SQRT", c.alpha), ggx.SQRT_ALPHA_MIN), 1.0)
    y = b.math("DIVIDE", b.math("SUBTRACT", root, ggx.SQRT_ALPHA_MIN), 1.0 - ggx.SQRT_ALPHA_MIN)
    v = b.math("DIVIDE", b.math("ADD", b.math("MULTIPLY", y, nr - 1.0), 0.5), float(nr))
    uv = b.combine(u, v, 0.0)
    out = {}
    for j, image in enumerate(images):
        node = b.node("ShaderNodeTexImage")
        node.image, node.interpolation, node.extension = image, 'Linear', 'EXTEND'
        b.tree.links.new(uv, node.inputs["Vector"])
        r, g, bl = b.xyz(node.outputs["Color"])
        first, second = LUT_LAYOUT[j]
        out[first], out[second] = (r, g), (bl, node.outputs["Alpha"])
    return out


def _finish(b: Builder, i, specular):
    out = b.node("NodeGroupOutput")
    b.tree.links.new(specular, out.inputs["Specular"])
    diffuse = b.vec(
        "SCALE", b.vec("MULTIPLY", i["Albedo"], i["Irradiance"]), scale=b.math("SUBTRACT", 1.0, i["Metallic"])
    )
    b.tree.links.new(b.vec("ADD", diffuse, specular), out.inputs["Both"])


def _g1(b: Builder, x, a2):
    """Smith GGX G1 = 2x / (x + √(α² + (1 − α²) x²)) at x = max(cos, 0)."""
    x = b.math("MAXIMUM", x, 0.0)
    root = b.math("SQRT", b.math("ADD", a2, b.math("MULTIPLY", b.math("SUBTRACT", 1.0, a2), b.math("MULTIPLY", x, x))))
    return b.math("DIVIDE", b.math("MULTIPLY", x, 2.0), b.math("ADD", x, root))


def _schlick_f0(b: Builder, f0, v_h):
    """F0 ⊙ (1 − p) + p, p = (1 − v·h)⁵ (colour)."""
    p = b.math("POWER", b.math("SUBTRACT", 1.0, b.math("MAXIMUM", v_h, 0.0)), 5.0)
    return b.vec("ADD", b.vec("SCALE", f0, scale=b.math("SUBTRACT", 1.0, p)), b.combine(p, p, p))


def build_hhd(model: str, images):
    """The HHD / AHD specular group (model 'HHD' | 'AHD')."""
    tree = _new_tree(GROUPS[model])
    _interface(
        tree,
        [
            ("Iz", 'NodeSocketColor', (0, 0, 0, 1)),
            ("Wa", 'NodeSocketColor', (1, 1, 1, 1)),
            ("Direction", 'NodeSocketVector', None),
            *_material_inputs(),
        ],
        ["Specular", "Both"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    c = _Common(b, i)
    d = direction(b, i["Direction"])
    a2 = b.math("MULTIPLY", c.alpha, c.alpha)
    # the directional light: π C_d F D G1 G1 / (4 n·v), C_d = (1 − w_a) I_z / max(d·n_v, MIN_COS/2)
    h = b.vec("NORMALIZE", b.vec("ADD", d, c.v))
    n_h = b.vec("DOT_PRODUCT", c.n, h)
    denom = b.math("ADD", b.math("MULTIPLY", b.math("MULTIPLY", n_h, n_h), b.math("SUBTRACT", a2, 1.0)), 1.0)
    ndf = b.math("DIVIDE", a2, b.math("MULTIPLY", b.math("MULTIPLY", denom, denom), np.pi))
    g = b.math("MULTIPLY", _g1(b, b.vec("DOT_PRODUCT", c.n, d), a2), _g1(b, c.n_v, a2))
    lobe = b.math("DIVIDE", b.math("MULTIPLY", ndf, g), b.math("MULTIPLY", b.math("MAXIMUM", c.n_v, 1e-4), 4.0 / np.pi))
    fresnel = _schlick_f0(b, c.f0, b.vec("DOT_PRODUCT", c.v, h))
    dz = b.math("MAXIMUM", b.vec("DOT_PRODUCT", d, c.nv), 0.5 * float(MIN_COS))
    c_d = b.vec(
        "SCALE",
        b.vec("MULTIPLY", b.vec("SUBTRACT", (1.0, 1.0, 1.0), i["Wa"]), i["Iz"]),
        scale=b.math("DIVIDE", 1.0, dz),
    )
    directional = b.vec("SCALE", b.vec("MULTIPLY", c_d, fresnel), scale=lobe)
    # the ambient: C_a (F0 A + B) V, zero where n·v ≤ 0; E = g₀ / Y₀₀ (the lobe's integral)
    a0, b0 = _lut(b, c, images)[0]
    albedo = b.vec("SCALE", b.vec("ADD", b.vec("SCALE", c.f0, scale=a0), b.combine(b0, b0, b0)), scale=1.0 / sh.Y00)
    weight = b.math("GREATER_THAN", c.n_v, 0.0)
    if model == "HHD":
        r = b.vec("SUBTRACT", b.vec("SCALE", c.n, scale=b.math("MULTIPLY", c.n_v, 2.0)), c.v)
        m = b.vec(
            "NORMALIZE",
            b.vec("ADD", b.vec("SCALE", r, scale=b.math("SUBTRACT", 1.0, c.alpha)), b.vec("SCALE", c.n, scale=c.alpha)),
        )
        slope = b.math("MAXIMUM", b.math("DIVIDE", VISIBILITY_SLOPE, c.alpha), 1.0)
        vis = b.math("ADD", b.math("MULTIPLY", b.math("MULTIPLY", slope, b.vec("DOT_PRODUCT", m, c.nv)), 0.5), 0.5)
        weight = b.math("MULTIPLY", weight, b.math("MINIMUM", b.math("MAXIMUM", vis, 0.0), 1.0))
    ambient = b.vec("SCALE", b.vec("MULTIPLY", b.vec("MULTIPLY", i["Wa"], i["Iz"]), albedo), scale=weight)
    _finish(b, i, b.vec("ADD", directional, ambient))
    return tree


def _y(b: Builder, d, band: int):
    """Sockets of Y_k(d) for the coefficients of `band` (1 or 2), core.sh's basis, at any d."""
    x, y, z = b.xyz(d)
    mul = lambda a, c: b.math("MULTIPLY", a, float(c))
    if band == 1:
        return [mul(y, -sh.C1), mul(z, sh.C1), mul(x, -sh.C1)]
    return [
        mul(b.math("MULTIPLY", x, y), sh.C2),
        mul(b.math("MULTIPLY", y, z), -sh.C2),
        mul(b.math("SUBTRACT", mul(b.math("MULTIPLY", z, z), 3.0), 1.0), sh.C20),
        mul(b.math("MULTIPLY", x, z), -sh.C2),
        mul(b.math("SUBTRACT", b.math("MULTIPLY", x, x), b.math("MULTIPLY", y, y)), sh.C22),
    ]


def _evaluate(b: Builder, coeffs, weights):
    total = None
    for s, w in zip(coeffs, weights):
        term = b.vec("SCALE", s, scale=w)
        total = term if total is None else b.vec("ADD", total, term)
    return total


def build_sh(order: int, images):
    """The L1 (order 1) or L2 (order 2) SH specular group."""
    count = (order + 1) ** 2
    tree = _new_tree(GROUPS[f"L{order}"])
    _interface(
        tree,
        [(f"SH{k}", 'NodeSocketColor', (0, 0, 0, 1)) for k in range(count)] + _material_inputs(),
        ["Specular", "Both"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    c = _Common(b, i)
    s = [i[f"SH{k}"] for k in range(count)]
    lut = _lut(b, c, images)
    # the view frame: x along v's part orthogonal to n, y = n × x, z = n
    x = b.vec("NORMALIZE", b.vec("SUBTRACT", c.v, b.vec("SCALE", c.n, scale=c.n_v)))
    y = b.vec("CROSS_PRODUCT", c.n, x)
    z = c.n
    if order == 2:
        s2 = s[4:9]
        p = b.vec("SCALE", b.vec("ADD", x, z), scale=float(np.sqrt(0.5)))
        q = b.vec("SCALE", b.vec("SUBTRACT", x, z), scale=float(np.sqrt(0.5)))
        at = {name: _evaluate(b, s2, _y(b, d, 2)) for name, d in (("z", z), ("p", p), ("q", q), ("x", x), ("y", y))}
        k = 4.0 * np.pi / 5.0
        zonal = at["z"]
        diag = b.vec("SUBTRACT", at["p"], at["q"])
        sect = b.vec("SUBTRACT", at["x"], at["y"])
    totals = []
    for part in (0, 1):  # A (× F0), B
        g = {key: value[part] for key, value in lut.items()}
        u = b.vec("ADD", b.vec("SCALE", x, scale=b.math("MULTIPLY", g[3], -1.0)), b.vec("SCALE", z, scale=g[2]))
        band1 = b.vec("SCALE", _evaluate(b, s[1:4], _y(b, u, 1)), scale=1.0 / sh.C1)
        t = b.vec("ADD", b.vec("SCALE", s[0], scale=g[0]), band1)
        if order == 2:
            terms = (
                b.vec("SCALE", zonal, scale=b.math("MULTIPLY", g[6], k * 2.0 * sh.C20)),
                b.vec("SCALE", diag, scale=b.math("MULTIPLY", g[7], -k * sh.C2 / 3.0)),
                b.vec("SCALE", sect, scale=b.math("MULTIPLY", g[8], k * 2.0 * sh.C22 / 3.0)),
            )
            for term in terms:
                t = b.vec("ADD", t, term)
        totals.append(t)
    specular = b.vec("ADD", b.vec("MULTIPLY", c.f0, totals[0]), totals[1])
    _finish(b, i, specular)
    return tree


def _v1(b: Builder, x, m2):
    """Baking Lab's GGX_V1: 1 / (x + √(α² + (1 − α²) x²))."""
    root = b.math("SQRT", b.math("ADD", m2, b.math("MULTIPLY", b.math("SUBTRACT", 1.0, m2), b.math("MULTIPLY", x, x))))
    return b.math("DIVIDE", 1.0, b.math("ADD", x, root))


def build_sg(count: int):
    """The SG`count` specular group: core.encoding.sg.asg_specular summed over the lobes."""
    axes, lam = sg.layout(count)
    tree = _new_tree(GROUPS[f"SG{count}"])
    _interface(
        tree,
        [(f"SG{k}", 'NodeSocketColor', (0, 0, 0, 1)) for k in range(count)] + _material_inputs(),
        ["Specular", "Both"],
    )
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    c = _Common(b, i)
    m2 = b.math("MULTIPLY", c.alpha, c.alpha)
    # the warp frame: z = reflect(−v, n), x = n × z, y = z × x; where |n × z| < 1e-3 (v within
    # 5e-4 rad of n) the float32 cross product is rounding noise and the warp isotropic to 1e-6:
    # x = t of tangent_frames(z) (core switches at 1e-8, in float64)
    z = b.vec("SUBTRACT", b.vec("SCALE", c.n, scale=b.math("MULTIPLY", c.n_v, 2.0)), c.v)
    cross = b.vec("CROSS_PRODUCT", c.n, z)
    x = _where(
        b, b.math("GREATER_THAN", b.vec("LENGTH", cross), 1e-3), b.vec("NORMALIZE", cross), _fallback_tangent(b, z)
    )
    y = b.vec("CROSS_PRODUCT", z, x)
    # the ASG of the warped NDF (λ_x = 2/α² / (8 o²), λ_y = 2/α² / 8) convolved with a lobe of λ/2
    o = b.math("MAXIMUM", c.n_v, 1e-4)
    ly = b.math("DIVIDE", 0.25, m2)
    lx = b.math("DIVIDE", ly, b.math("MULTIPLY", o, o))
    nu = 0.5 * lam
    cx, cy = (b.math("DIVIDE", b.math("MULTIPLY", l, nu), b.math("ADD", l, nu)) for l in (lx, ly))
    camp = b.math("DIVIDE", np.pi, b.math("SQRT", b.math("MULTIPLY", b.math("ADD", lx, nu), b.math("ADD", ly, nu))))
    # x, y, z in n_v's tangent frame, where the axes μ_k are constants
    t, bt = _frame(b, c.nv)
    local = {
        k: b.combine(*(b.vec("DOT_PRODUCT", w, e) for e in (t, bt, c.nv))) for k, w in (("x", x), ("y", y), ("z", z))
    }
    terms = []
    for k, mu in enumerate(axes):
        dx, dy, dz = (b.vec("DOT_PRODUCT", local[w], tuple(float(m) for m in mu)) for w in "xyz")
        exponent = b.math(
            "ADD",
            b.math("MULTIPLY", cx, b.math("MULTIPLY", dx, dx)),
            b.math("MULTIPLY", cy, b.math("MULTIPLY", dy, dy)),
        )
        weight = b.math("MULTIPLY", b.math("MAXIMUM", dz, 0.0), b.math("EXPONENT", b.math("MULTIPLY", exponent, -1.0)))
        # max(·, 0) per lobe and colour: the rest of the product is ≥ 0
        terms.append(b.vec("SCALE", b.vec("MAXIMUM", i[f"SG{k}"], (0.0, 0.0, 0.0)), scale=weight))
    nl = b.math("MINIMUM", b.math("MAXIMUM", b.vec("DOT_PRODUCT", c.n, z), 0.0), 1.0)
    nv = b.math("MINIMUM", b.math("MAXIMUM", c.n_v, 0.0), 1.0)
    vis = b.math("MULTIPLY", _v1(b, nl, m2), _v1(b, nv, m2))
    scale = b.math("MULTIPLY", b.math("MULTIPLY", camp, b.math("DIVIDE", 1.0 / np.pi, m2)), b.math("MULTIPLY", vis, nl))
    h = b.vec("NORMALIZE", b.vec("ADD", z, c.v))
    fresnel = _schlick_f0(b, c.f0, b.vec("DOT_PRODUCT", z, h))
    _finish(b, i, b.vec("MULTIPLY", fresnel, b.vec("SCALE", _sum(b, terms), scale=scale)))
    return tree


def ensure(kind: str):
    """The specular group of preview kind `kind` (a key of KINDS), built or rebuilt if stale;
    the LUT images are (re)loaded every time."""
    images = ensure_lut()
    key = KINDS[kind]
    tree = bpy.data.node_groups.get(GROUPS[key])
    if tree is not None and tree.get("hhd_version") == GROUP_VERSION:
        return tree
    if key.startswith("SG"):
        return build_sg(int(key[2:]))
    return build_hhd(key, images) if key in ("HHD", "AHD") else build_sh(int(key[-1]), images)
