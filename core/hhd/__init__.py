"""IrradZ encoding of L2 SH lighting into HHD / AHD, and its reconstruction. No bpy.

Sources: Roughton, Sloan, Silvennoinen, Shirley 2024, "Hemispherical Lighting Insights" (HHD,
hemispherical Gram matrix, searched direction, HHD from linear SH, self-bounce) and Sloan &
Silvennoinen 2018, "Directional Lightmap Encoding Insights" (IrradZ re-parameterisation,
luminance ambient ratio, non-negative fit in the null space of the I_z constraint).

Model, with n_v the vertex normal, n the shading normal, d the highlight direction (d·n_v > 0):
    HHD  I(n) = I_z [ w_a (1 + n·n_v)/2 + (1 - w_a) max(n·d, 0) / (d·n_v) ]
    AHD  I(n) = I_z [ w_a               + (1 - w_a) max(n·d, 0) / (d·n_v) ]

The package, by job (this module re-exports the public API):
  lobes      HHDParams, MIN_COS, the ambient and directional lobes in SH (direct and factorised),
             I_z (`irradz`), `reconstruct` (what a shader computes, with self-bounce)
  fit        the Gram-weighted fit at a given direction with its closed-form, clamped w_a
             (`Fit`, `FitAtPhi`), and the per-chunk set-up in the frame z = n_v
  search     optimal linear angles, the θ scan + golden-section search, the outer φ search
  encoder    `encode`: sanitising, CHUNK-sized chunks, the direction back to world space
  metrics    `fit_error`, `hemispherical_rmse`, `hemisphere_quadrature`
  linear_sh  `to_linear_sh`, `from_linear_sh` (closed form)
"""

from __future__ import annotations

from ..colour import LUMINANCE
from ..sh import IRRADZ_FROM_R10
from .encoder import CHUNK, encode
from .fit import channel_weights
from .linear_sh import from_linear_sh, to_linear_sh
from .lobes import MIN_COS, HHDParams, ambient_lobe, directional_lobe, irradz, reconstruct
from .metrics import fit_error, hemisphere_quadrature, hemispherical_rmse
from .search import GOLDEN_ITERATIONS, PHI_GOLDEN_ITERATIONS, PHI_SCAN_STEPS, SCAN_STEPS, optimal_linear_angles

__all__ = [
    "CHUNK",
    "GOLDEN_ITERATIONS",
    "IRRADZ_FROM_R10",
    "LUMINANCE",
    "MIN_COS",
    "PHI_GOLDEN_ITERATIONS",
    "PHI_SCAN_STEPS",
    "SCAN_STEPS",
    "HHDParams",
    "ambient_lobe",
    "channel_weights",
    "directional_lobe",
    "encode",
    "fit_error",
    "from_linear_sh",
    "hemisphere_quadrature",
    "hemispherical_rmse",
    "irradz",
    "optimal_linear_angles",
    "reconstruct",
    "to_linear_sh",
]
