"""The EEVEE node group "HHD Probe Lighting": irradiance of a probe's L2 radiance SH, plain or
with the talk's HLSH hemisphere / cone multiply (core.hlsh), built by code from core's maths.

Inputs (all world space):
  SH0 … SH8   the object's radiance SH (docs/conventions.md#sh-basis), one RGB colour each; the
              preview reads them per object (Attribute nodes of type OBJECT, shaders/probe_preview.py)
  Normal      the shading normal n (normal maps), Geometry Normal the normal N the hemisphere
              or cone is taken around (the interpolated vertex normal)
  AO          cosine-weighted visibility v ∈ [0, 1] (EEVEE's Ambient Occlusion node) for the cone:
              cos α = √(1 − v), core.hlsh.cone_cos_from_visibility with cos θ = 1 (EEVEE's AO
              node gives no bent normal: the cone is centred on N, as the talk assumes)
  Mode        0 plain SH: core.sh.irradiance(sh, n) (cosine convolution, no occlusion);
              1 HLSH: core.hlsh.project(sh, N, 0).evaluate(n) (hemisphere of N);
              2 HLSH + cone: core.hlsh.project(sh, N, cos α).evaluate(n)
  Albedo      the base colour
Outputs: Irradiance (docs/conventions.md#irradiance-units, not clamped, as numpy) and
Radiance = Albedo × Irradiance.

`project_hlsh` ports `core.hlsh.project` term by term (world space, no SH rotation); colours are
carried through vector math nodes, one channel per component. Its intermediate sockets are
labelled (LABELS) so tests can evaluate the graph and compare each with numpy. The group carries
GROUP_VERSION in a custom property and is rebuilt when it differs.
"""

from __future__ import annotations

import bpy
import numpy as np
from numpy.polynomial import Polynomial

from ..core import sh
from .node_groups import Builder

GROUP = "HHD Probe Lighting"
GROUP_VERSION = 1
SH_INPUTS = tuple(f"SH{k}" for k in range(9))
#: node labels of the intermediates of `project_hlsh` (per colour channel unless noted)
LABELS = ("l1_dot", "pz2", "iz", "ca", "tangent0", "tangent1", "tangent2", "hlsh", "sh", "cos_alpha")

SQRT_PI = np.sqrt(np.pi)
SQRT_3PI = np.sqrt(3.0 * np.pi)
_C = Polynomial([0.0, 1.0])  # cos α
# The polynomials in cos α of SH_ProjectToHLSHConeMultiplyRGB (2024 talk), written as the listing
# nests them; core.hlsh.project evaluates the same expressions.
IZ_L0 = (1.0 - _C**2) * sh.Y00
IZ_L1 = 2.0 / 3.0 * (1.0 - _C**3) * np.sqrt(0.75 / np.pi)
IZ_PZ2 = 0.25 * (1.0 + 2.0 * _C**2 - 3.0 * _C**4) * 0.5 * np.sqrt(5.0 / np.pi)
CA_L0 = (1024.0 + _C * (-1767.0 + _C * (512.0 + 21.0 * _C * (10.0 + _C**2)))) / (4096.0 * SQRT_PI)
CA_L1 = (2203.0 + _C**2 * (-5301.0 + _C * (2048.0 + 105.0 * _C * (9.0 + _C**2)))) / (8192.0 * SQRT_3PI)
CA_PZ2 = (
    np.sqrt(5.0)
    / (8192.0 * SQRT_PI)
    * (-448.0 + _C * (1767.0 + _C * (-512.0 + 3.0 * _C * (-659.0 + _C * (256.0 + 119.0 * _C + 15.0 * _C**3)))))
)
L1_SCALE = (_C - 1.0) ** 2 * (2573.0 + _C * (2074.0 + 105.0 * _C * (6.0 + _C * (2.0 + _C)))) / (4096.0 * SQRT_3PI)
L2_SCALE = (
    np.sqrt(15.0)
    / (2048.0 * SQRT_PI)
    * (176.0 + _C**2 * (-256.0 + _C * (-105.0 + _C * (128.0 + 42.0 * _C + 15.0 * _C**3))))
)


def _label(socket, name: str):
    """Label the node of `socket` (an intermediate tests can find); returns the socket."""
    socket.node.label = name
    return socket


def _poly(b: Builder, c, p: Polynomial):
    """p(c) as nodes, c a float socket: Horner, a_0 + c·(a_1 + c·(… + c·a_d)); degree ≥ 1."""
    coef = [float(x) for x in p.coef]
    total = b.math("MULTIPLY", c, coef[-1])
    for a in reversed(coef[1:-1]):
        total = b.math("MULTIPLY", b.math("ADD", total, a), c)
    return b.math("ADD", total, coef[0])


def _sum(b: Builder, terms):
    """Σ of (colour socket, float socket or constant) products: vector SCALE then ADD."""
    total = None
    for colour, weight in terms:
        term = b.vec("SCALE", colour, scale=weight)
        total = term if total is None else b.vec("ADD", total, term)
    return total


def _basis(b: Builder, n):
    """[Y_0(n) … Y_8(n)] as float sockets (Y_0 a constant), core.sh.basis."""
    x, y, z = b.xyz(n)
    mul = lambda a, c: b.math("MULTIPLY", a, float(c))  # noqa: E731
    return [
        float(sh.Y00),
        mul(y, -sh.C1),
        mul(z, sh.C1),
        mul(x, -sh.C1),
        mul(b.math("MULTIPLY", x, y), sh.C2),
        mul(b.math("MULTIPLY", y, z), -sh.C2),
        mul(b.math("SUBTRACT", mul(b.math("MULTIPLY", z, z), 3.0), 1.0), sh.C20),
        mul(b.math("MULTIPLY", x, z), -sh.C2),
        mul(b.math("SUBTRACT", b.math("MULTIPLY", x, x), b.math("MULTIPLY", y, y)), sh.C22),
    ]


def sh_irradiance(b: Builder, coeffs, n):
    """core.sh.irradiance: Σ_k cosine_kernel_k · SH_k · Y_k(n), n unit; coeffs 9 colour sockets."""
    y = _basis(b, n)
    kernel = [float(k) for k in sh.COSINE_KERNEL]
    weights = [y[0] * kernel[0]] + [b.math("MULTIPLY", y[k], kernel[k]) for k in range(1, 9)]
    return _label(_sum(b, zip(coeffs, weights)), "sh")


def _l2_components(b: Builder, s, nx, ny, nz):
    """The listing's l2Components[0..2] (colours) from the 9 SH colours `s` (SH4 … SH8 used) and N's components."""
    m = lambda a, c: b.math("MULTIPLY", a, c)  # noqa: E731
    nxyz2 = m(m(m(nx, ny), nz), 2.0)
    ny2_nx2 = b.math("SUBTRACT", m(ny, ny), m(nx, nx))
    two_sq_minus_1 = lambda a: b.math("SUBTRACT", m(m(a, a), 2.0), 1.0)  # noqa: E731
    sqrt3 = float(np.sqrt(3.0))
    c0 = _sum(
        b,
        [
            (s[7], m(nxyz2, -1.0)),
            (s[6], m(m(ny, m(nz, nz)), sqrt3)),
            (s[5], m(m(two_sq_minus_1(ny), nz), -1.0)),
            (s[4], m(two_sq_minus_1(ny), nx)),
            (s[8], m(m(b.math("SUBTRACT", ny2_nx2, 1.0), ny), -1.0)),
        ],
    )
    c1 = _sum(
        b,
        [
            (s[4], m(nxyz2, -1.0)),
            (s[6], m(m(nz, b.math("SUBTRACT", 1.0, m(nz, nz))), sqrt3)),
            (s[7], m(two_sq_minus_1(nz), nx)),
            (s[5], m(two_sq_minus_1(nz), ny)),
            (s[8], m(ny2_nx2, nz)),
        ],
    )
    c2 = _sum(
        b,
        [
            (s[5], m(nxyz2, -1.0)),
            (s[6], m(m(nx, m(nz, nz)), sqrt3)),
            (s[7], m(m(two_sq_minus_1(nx), nz), -1.0)),
            (s[4], m(two_sq_minus_1(nx), ny)),
            (s[8], m(m(b.math("ADD", ny2_nx2, 1.0), nx), -1.0)),
        ],
    )
    return c0, c1, c2


def project_hlsh(b: Builder, s, geom_n, n, c):
    """core.hlsh.project(s, N, c).evaluate(n) as nodes: s 9 colour sockets (radiance SH), geom_n
    (N) and n unit vector sockets, c the float socket cos α. Returns the irradiance colour."""
    nx, ny, nz = b.xyz(geom_n)
    nsh = (b.math("MULTIPLY", ny, -1.0), nz, b.math("MULTIPLY", nx, -1.0))  # (-N.y, N.z, -N.x)
    l1_dot = _label(_sum(b, zip(s[1:4], nsh)), "l1_dot")
    l1_tangent = [b.vec("SUBTRACT", s[1 + i], b.vec("SCALE", l1_dot, scale=nsh[i])) for i in range(3)]
    y = _basis(b, geom_n)
    pz2 = _label(
        _sum(b, [(s[k], b.math("MULTIPLY", y[k], float(np.sqrt(4.0 * np.pi / 5.0)))) for k in range(4, 9)]), "pz2"
    )
    iz = _label(_sum(b, [(s[0], _poly(b, c, IZ_L0)), (l1_dot, _poly(b, c, IZ_L1)), (pz2, _poly(b, c, IZ_PZ2))]), "iz")
    ca = _label(_sum(b, [(s[0], _poly(b, c, CA_L0)), (l1_dot, _poly(b, c, CA_L1)), (pz2, _poly(b, c, CA_PZ2))]), "ca")
    l2 = _l2_components(b, s, nx, ny, nz)
    l1_scale, l2_scale = _poly(b, c, L1_SCALE), _poly(b, c, L2_SCALE)
    iz_minus_ca = b.vec("SUBTRACT", iz, ca)
    tangent = [
        _label(_sum(b, [(l1_tangent[i], l1_scale), (l2[i], l2_scale), (iz_minus_ca, nsh[i])]), f"tangent{i}")
        for i in range(3)
    ]
    # world vector (cx, cy, cz) = (-tangent2, -tangent0, tangent1); E(n) = C_a + c·n
    sx, sy, sz = b.xyz(n)
    weights = (b.math("MULTIPLY", sy, -1.0), sz, b.math("MULTIPLY", sx, -1.0))  # on tangent0, 1, 2
    return _label(b.vec("ADD", ca, _sum(b, zip(tangent, weights))), "hlsh")


def cone_cos(b: Builder, ao):
    """cos α = √(1 − v) clamped to [0, 1] (core.hlsh.cone_cos_from_visibility, cos θ = 1)."""
    return b.math("SQRT", b.math("MINIMUM", b.math("MAXIMUM", b.math("SUBTRACT", 1.0, ao), 0.0), 1.0))


def build():
    """(Re)build the group and return it."""
    tree = bpy.data.node_groups.get(GROUP) or bpy.data.node_groups.new(GROUP, 'ShaderNodeTree')
    tree.nodes.clear()
    tree.interface.clear()
    tree["hhd_version"] = GROUP_VERSION
    inputs = [(name, 'NodeSocketColor', (0.0, 0.0, 0.0, 1.0)) for name in SH_INPUTS] + [
        ("Normal", 'NodeSocketVector', None),
        ("Geometry Normal", 'NodeSocketVector', None),
        ("AO", 'NodeSocketFloat', 1.0),
        ("Mode", 'NodeSocketFloat', 1.0),
        ("Albedo", 'NodeSocketColor', (0.8, 0.8, 0.8, 1.0)),
    ]
    for name, kind, default in inputs:
        socket = tree.interface.new_socket(name, in_out='INPUT', socket_type=kind)
        if default is not None:
            socket.default_value = default
    for name in ("Irradiance", "Radiance"):
        tree.interface.new_socket(name, in_out='OUTPUT', socket_type='NodeSocketColor')
    b = Builder(tree)
    i = b.node("NodeGroupInput").outputs
    s = [i[name] for name in SH_INPUTS]
    n = b.vec("NORMALIZE", i["Normal"])
    geom_n = b.vec("NORMALIZE", i["Geometry Normal"])
    mode = i["Mode"]
    cone = b.math("GREATER_THAN", mode, 1.5)  # 1 in mode 2
    c = _label(b.math("MULTIPLY", cone_cos(b, i["AO"]), cone), "cos_alpha")
    plain = b.math("LESS_THAN", mode, 0.5)  # 1 in mode 0
    hlsh = project_hlsh(b, s, geom_n, n, c)
    irradiance = b.vec(
        "ADD",
        b.vec("SCALE", sh_irradiance(b, s, n), scale=plain),
        b.vec("SCALE", hlsh, scale=b.math("SUBTRACT", 1.0, plain)),
    )
    out = b.node("NodeGroupOutput")
    tree.links.new(irradiance, out.inputs["Irradiance"])
    tree.links.new(b.vec("MULTIPLY", irradiance, i["Albedo"]), out.inputs["Radiance"])
    return tree


def ensure():
    """The group, built or rebuilt if missing or stale."""
    tree = bpy.data.node_groups.get(GROUP)
    if tree is not None and tree.get("hhd_version") == GROUP_VERSION:
        return tree
    return build()
