"""L1 SH encoding: the first 4 **radiance** SH coefficients (RGB, world space), file
`<name>_sh_l1.exr`. No bpy.

Irradiance: bands × 1, 2/3 evaluated at n (approximate even at n = n_v: `sh_l2`);
specular: the GGX lobe's SH truncated to L1 dotted with them (`ggx.sh_specular`, bands=2).
"""

from __future__ import annotations

from .basis import CoefficientEncoding, layers
from .sh_l2 import MEANING, SHBasis
from .spec import FileSpec

BASIS = SHBasis(2)
FILE = FileSpec("sh_l1", "_sh_l1.exr", layers("SH", 4, MEANING, "sh_l1"))


def basis(settings=None) -> SHBasis:
    return BASIS


def encoding(settings) -> CoefficientEncoding:
    return CoefficientEncoding(BASIS, FILE, {"model": settings.model})
