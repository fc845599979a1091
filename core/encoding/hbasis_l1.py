"""L1 H-basis encoding: 4 RGB coefficients of the irradiance over n_v's tangent-frame
hemisphere (`hbasis`), file `<name>_hbasis_l1.exr`. No bpy."""

from __future__ import annotations

from . import hbasis

BASIS = hbasis.HBasis(4)
FILE = hbasis.file_of(4, "hbasis_l1")


def basis(settings=None) -> hbasis.HBasis:
    return BASIS


def encoding(settings):
    return hbasis.encoding_of(BASIS, FILE, settings)
