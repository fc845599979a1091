"""The encodings a bake can write, by `EncoderSettings.model`. No bpy.

An encoding is a module with `FILE` (the FileSpec of every layer it may write) and
`encoding(settings) -> Encoding` (see `spec.Encoding`). Adding one (say plain L1 SH) is that
module plus its line in ENCODINGS; the CLI's choices, the sidecar and docs/format.md's tables
(`doc_tables`) follow from here.
"""

from __future__ import annotations

from . import hhd
from .raw import FILES as RAW_FILES
from .spec import Encoding, FileSpec

ENCODINGS = {
    "hhd": hhd,
    "ahd": hhd,
}
MODELS = tuple(ENCODINGS)


def for_settings(settings) -> Encoding:
    """The Encoding of `settings.model` with `settings` (an `EncoderSettings`)."""
    module = ENCODINGS.get(settings.model)
    if module is None:
        raise ValueError(f"encoder model must be one of {', '.join(MODELS)}, not {settings.model!r}")
    return module.encoding(settings)


def documented_files() -> list[FileSpec]:
    """Every file an atlas may have: each encoding's file (once), then the raw files."""
    files = list({m.FILE.key: m.FILE for m in ENCODINGS.values()}.values())
    return files + list(RAW_FILES)
