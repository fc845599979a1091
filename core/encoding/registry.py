"""The encodings a bake can write, by `EncoderSettings.model`. No bpy.

An encoding is a module with `FILE` (the FileSpec of every layer it may write) and
`encoding(settings) -> Encoding` (see `spec.Encoding`). Adding one (say plain L1 SH) is that
module plus its line in ENCODINGS; the CLI's choices, the sidecar and docs/format.md's tables
(`doc_tables`) follow from here. The coefficient encodings (Baking Lab's set) also have
`basis(settings)`, their reconstruction math (`encoding.basis`): `basis_of`.
"""

from __future__ import annotations

from . import hbasis_l1, hbasis_l2, hhd, hl2, sg5, sg6, sg9, sg12, sh_l1, sh_l2
from .raw import FILES as RAW_FILES
from .spec import Encoding, FileSpec

ENCODINGS = {
    "hhd": hhd,
    "ahd": hhd,
    "sh_l1": sh_l1,
    "sh_l2": sh_l2,
    "hl2": hl2,
    "hbasis_l1": hbasis_l1,
    "hbasis_l2": hbasis_l2,
    "sg5": sg5,
    "sg6": sg6,
    "sg9": sg9,
    "sg12": sg12,
}
MODELS = tuple(ENCODINGS)


def for_settings(settings) -> Encoding:
    """The Encoding of `settings.model` with `settings` (an `EncoderSettings`)."""
    module = ENCODINGS.get(settings.model)
    if module is None:
        raise ValueError(f"encoder model must be one of {', '.join(MODELS)}, not {settings.model!r}")
    return module.encoding(settings)


def basis_of(settings):
    """The reconstruction math (`encoding.basis.Basis`) of `settings.model`, for the coefficient
    encodings (not HHD/AHD: `core.hhd.reconstruct`)."""
    module = ENCODINGS.get(settings.model)
    if module is None or not hasattr(module, "basis"):
        raise ValueError(f"{settings.model!r} has no coefficient basis")
    return module.basis(settings)


def documented_files() -> list[FileSpec]:
    """Every file an atlas may have: each encoding's file (once), then the raw files."""
    files = list({m.FILE.key: m.FILE for m in ENCODINGS.values()}.values())
    return files + list(RAW_FILES)
