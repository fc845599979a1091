"""Encodings of the traced SH and the channel spec of every file an atlas has. No bpy.

spec        Channel (one EXR layer: names, storage type, meaning, fill, preview image, packing),
            FileSpec (one file's layers), the Encoding interface and what it returns (Encoded)
settings    EncoderSettings (which encoding, and the HHD fit's options)
hhd         the HHD / AHD encoding and its file `<name>_hhd.exr`
raw         the raw SH file and the texels file
registry    encodings by `EncoderSettings.model`; adding one = a module + a line there
stage       the encode stage: TexelData → EncodedAtlas (encode, fill, pack)
doc_tables  docs/format.md's channel tables from the spec
"""

from __future__ import annotations

from .conventions import CONVENTIONS
from .hhd import FILE as HHD_FILE
from .raw import FILES as RAW_FILES
from .raw import SH_FILE, TEXELS_FILE
from .registry import ENCODINGS, MODELS, documented_files, for_settings
from .settings import AMBIENTS, DIRECTIONS, SOLVES, EncoderSettings
from .spec import DILATE, DILATE_BURIED_BLACK, FLOAT, HALF, HALF_OR_FLOAT, NO_FILL, Channel, Encoded, Encoding, FileSpec
from .stage import DILATE_RINGS, ENCODE_CHUNK, EncodedAtlas, TexelData, encode_atlas, raw_files

__all__ = [
    "CONVENTIONS",
    "HHD_FILE",
    "RAW_FILES",
    "AMBIENTS",
    "DILATE",
    "DILATE_BURIED_BLACK",
    "DILATE_RINGS",
    "DIRECTIONS",
    "SOLVES",
    "ENCODE_CHUNK",
    "ENCODINGS",
    "FLOAT",
    "HALF",
    "HALF_OR_FLOAT",
    "MODELS",
    "NO_FILL",
    "SH_FILE",
    "TEXELS_FILE",
    "Channel",
    "Encoded",
    "EncodedAtlas",
    "Encoding",
    "EncoderSettings",
    "FileSpec",
    "TexelData",
    "documented_files",
    "encode_atlas",
    "for_settings",
    "raw_files",
]
