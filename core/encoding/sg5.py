"""SG5 encoding: 5 fixed Spherical Gaussian lobes over n_v's tangent-frame hemisphere, their
RGB amplitudes fitted by `EncoderSettings.solve` (`sg`), file `<name>_sg5.exr`. No bpy."""

from __future__ import annotations

from . import sg

COUNT = 5
FILE = sg.file_of(COUNT)


def basis(settings=None) -> sg.SGBasis:
    return sg.SGBasis(COUNT, settings.solve if settings is not None else "nnls")


def encoding(settings):
    return sg.encoding_of(COUNT, FILE, settings)
