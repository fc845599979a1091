"""L2 SH encoding: the texel's **radiance** SH (9 × RGB, world space), file `<name>_sh_l2.exr`.
No bpy.

The layers hold the traced radiance SH as they are (not irradiance): irradiance is the cosine
convolution (bands × 1, 2/3, 1/4, `core.sh.irradiance`), specular the dot product with the
GGX lobe's SH (`ggx.sh_specular`, Baking Lab's "convolution" SH specular through a lookup).
Unlike `<name>_sh.exr` (float32, kept for re-encoding) it is stored as half floats where the
values allow, what an engine would ship. Frame-free: world space.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import sh as _sh
from . import ggx
from .basis import CoefficientEncoding, layers
from .spec import FileSpec

MEANING = "radiance SH coefficient k (order of docs/conventions.md#sh-basis), world space, RGB"


@dataclass
class SHBasis:
    """Radiance SH truncated to `bands` bands (2: L1, 4 coefficients; 3: L2, 9)."""

    bands: int = 3
    SPECULAR = True

    def __post_init__(self):
        self.count = self.bands * self.bands
        self.name = f"sh_l{self.bands - 1}"

    def coefficients(self, sh: np.ndarray, n_v: np.ndarray) -> np.ndarray:
        return np.asarray(sh, np.float64)[:, : self.count]

    def _full(self, c: np.ndarray) -> np.ndarray:
        out = np.zeros((len(c), 9, c.shape[2]))
        out[:, : self.count] = c
        return out

    def irradiance(self, c: np.ndarray, n_v: np.ndarray, n: np.ndarray) -> np.ndarray:
        """I(n) = Σ_k (band factor) s_k Y_k(n): exact for radiance band-limited to these bands.
        Not exact at n = n_v for a texel's hemisphere radiance (I_z = 2/√(3π) r_1^0 is; the
        clamped cosine's bands 0 and 2 add the truncation error of the masked radiance)."""
        return _sh.irradiance(self._full(c), n)

    def specular(self, c, n_v, n, v, alpha, f0=1.0) -> np.ndarray:
        return ggx.sh_specular(self._full(c), n, v, alpha, f0, bands=self.bands)


BASIS = SHBasis(3)
FILE = FileSpec("sh_l2", "_sh_l2.exr", layers("SH", 9, MEANING, "sh_l2"))


def basis(settings=None) -> SHBasis:
    return BASIS


def encoding(settings) -> CoefficientEncoding:
    return CoefficientEncoding(BASIS, FILE, {"model": settings.model})
