"""HLSH: quadratic radiance SH -> hemisphere- or cone-occluded irradiance in the HLSH basis. No bpy.

2024 paper, "PIXEL SHADER OCCLUSION: HLSH" and the SH_ProjectToHLSHConeMultiplyRGB listing.
HLSH basis [z, 1 - z, x, y] in the frame of the normal N:
    I(n) = I_z n_z + C_a (1 - n_z) + c_x n_x + c_y n_y   (= C_a + c·n, c a world vector)
with the z weight fixed to I_z, the irradiance at N of the radiance masked to the cone of
half-angle α around N (cos α = 0: the hemisphere). The remaining weights are the least-squares
fit, over the whole hemisphere of N, of the cone-occluded irradiance band-limited to L ≤ 4
(fitting over the cone instead does not reproduce the listing's polynomials; verified in
tests/test_hlsh.py; at cos α = 0 the matrix entries are 1/(4√π), 2203/(8192√(3π)),
-7√5/(128√π), -2573/(4096√(3π)), -11√15/(128√π)).

Cone angle from runtime AO (cosine-weighted visibility v, cone tilted θ from N): the slide's
cos α = √(1 - v)/cos θ is an extraction typo; from v = sin²α cos θ it is cos α = √(1 - v/cos θ)
(`cone_cos_from_visibility`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import sh as _sh

SQRT_PI = np.sqrt(np.pi)
SQRT_3PI = np.sqrt(3.0 * np.pi)


@dataclass
class HLSH:
    """irradz (N, C): I_z;  ambient (N, C): C_a;  vector (N, 3, C): world-space c with c·N = I_z - C_a."""

    irradz: np.ndarray
    ambient: np.ndarray
    vector: np.ndarray

    def evaluate(self, n: np.ndarray) -> np.ndarray:
        """Irradiance `(N, C)` at shading normals n `(N, 3)`: C_a + c·n."""
        return self.ambient + np.einsum("nic,ni->nc", self.vector, n)


def project(sh: np.ndarray, normals: np.ndarray, cos_alpha=0.0) -> HLSH:
    """World-space radiance SH `(N, 9, C)` -> HLSH around unit normals `(N, 3)`, occluded by the
    cone cos α (scalar or `(N,)`; 0 = hemisphere). A line-by-line vectorised port of the paper's
    shader, working in world space without rotating the SH."""
    sh = np.asarray(sh, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    c = np.broadcast_to(np.asarray(cos_alpha, dtype=np.float64), (len(n),))[:, None]  # (N, 1)
    c2, c3 = c * c, c * c * c
    c4 = c2 * c2
    nsh = np.stack([-n[:, 1], n[:, 2], -n[:, 0]], axis=1)  # (N, 3)
    l1 = sh[:, 1:4]  # (N, 3, C)
    l1_dot = np.einsum("ni,nic->nc", nsh, l1)
    l1_tangent = l1 - l1_dot[:, None, :] * nsh[:, :, None]
    y = _sh.evaluate(n)  # "inDirection"
    pz2 = np.einsum("nk,nkc->nc", y[:, 4:9], sh[:, 4:9]) * np.sqrt(4.0 * np.pi / 5.0)

    iz = (
        sh[:, 0] * (1.0 - c2) * y[:, :1]
        + 2.0 / 3.0 * (1.0 - c3) * np.sqrt(0.75 / np.pi) * l1_dot
        + 0.25 * (1.0 + 2.0 * c2 - 3.0 * c4) * 0.5 * np.sqrt(5.0 / np.pi) * pz2
    )
    ca = (
        1.0 / (4096.0 * SQRT_PI) * (1024.0 + c * (-1767.0 + c * (512.0 + 21.0 * c * (10.0 + c2)))) * sh[:, 0]
        + 1.0 / (8192.0 * SQRT_3PI) * (2203.0 + c2 * (-5301.0 + c * (2048.0 + 105.0 * c * (9.0 + c2)))) * l1_dot
        + np.sqrt(5.0)
        / (8192.0 * SQRT_PI)
        * (-448.0 + c * (1767.0 + c * (-512.0 + 3.0 * c * (-659.0 + c * (256.0 + 119.0 * c + 15.0 * c3)))))
        * pz2
    )

    nx, ny, nz = n[:, 0:1], n[:, 1:2], n[:, 2:3]
    nxyz2 = 2.0 * nx * ny * nz
    ny2_nx2 = ny * ny - nx * nx
    s = sh
    l2 = [
        -nxyz2 * s[:, 7]
        + ny * nz * nz * np.sqrt(3.0) * s[:, 6]
        - (2.0 * ny * ny - 1.0) * (nz * s[:, 5] - nx * s[:, 4])
        - (ny2_nx2 - 1.0) * ny * s[:, 8],
        -nxyz2 * s[:, 4]
        + nz * (1.0 - nz * nz) * np.sqrt(3.0) * s[:, 6]
        + (2.0 * nz * nz - 1.0) * (nx * s[:, 7] + ny * s[:, 5])
        + ny2_nx2 * nz * s[:, 8],
        -nxyz2 * s[:, 5]
        + nx * nz * nz * np.sqrt(3.0) * s[:, 6]
        - (2.0 * nx * nx - 1.0) * (nz * s[:, 7] - ny * s[:, 4])
        - (ny2_nx2 + 1.0) * nx * s[:, 8],
    ]
    l1_scale = (
        1.0 / (4096.0 * SQRT_3PI) * (c - 1.0) * (c - 1.0) * (2573.0 + c * (2074.0 + 105.0 * c * (6.0 + c * (2.0 + c))))
    )
    l2_scale = (
        np.sqrt(15.0) / (2048.0 * SQRT_PI) * (176.0 + c2 * (-256.0 + c * (-105.0 + c * (128.0 + 42.0 * c + 15.0 * c3))))
    )
    tangent = [l1_scale * l1_tangent[:, i] + l2_scale * l2[i] + (iz - ca) * nsh[:, i : i + 1] for i in range(3)]
    # SH band-1 order (-y, z, -x) back to world (x, y, z).
    vector = np.stack([-tangent[2], -tangent[0], tangent[1]], axis=1)
    return HLSH(irradz=iz, ambient=ca, vector=vector)


def cone_cos_from_visibility(visibility, cos_theta=1.0):
    """cos α of the visibility cone from cosine-weighted visibility v (v = sin²α cos θ):
    cos α = √(1 - v / cos θ), clamped to [0, 1]."""
    v = np.asarray(visibility, dtype=np.float64) / np.maximum(np.asarray(cos_theta, dtype=np.float64), 1e-6)
    return np.sqrt(np.clip(1.0 - v, 0.0, 1.0))
