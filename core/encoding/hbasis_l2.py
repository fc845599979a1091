"""L2 H-basis encoding: 6 RGB coefficients of the irradiance over n_v's tangent-frame
hemisphere (`hbasis`), file `<name>_hbasis_l2.exr`. No bpy."""

from __future__ import annotations

from . import hbasis

BASIS = hbasis.HBasis(6)
FILE = hbasis.file_of(6, "hbasis_l2")


def basis(settings=None) -> hbasis.HBasis:
    return BASIS


def encoding(settings):
    return hbasis.encoding_of(BASIS, FILE, settings)
