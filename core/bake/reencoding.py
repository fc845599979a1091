"""A re-encode's job for one atlas's (or light set's) files: read → post stages → encode → stage
(`bake.reencode` runs it for an atlas and each of its light sets). No bpy."""

from __future__ import annotations

import functools

import numpy as np

from .. import encoding, post
from ..files import lightmap_files
from .data import PipelineSettings
from .finishing import _restore_sh


class _RawFiles:
    """The raw files a re-encode read, as `_restore_sh` asks for the traced SH (`Staged.traced_sh`)."""

    def __init__(self, files: lightmap_files.AtlasFiles):
        self.files = files

    def traced_sh(self, name: str, parent: str) -> np.ndarray:
        return lightmap_files.read_sh(self.files.sh)


def _reencode_files(staging, files: lightmap_files.AtlasFiles, settings: PipelineSettings, threads: int) -> list[str]:
    """Read → post stages → encode → stage the encoded file and sidecar of one atlas (or light set)."""
    sidecar = lightmap_files.read_sidecar(files.sidecar)
    sidecar.pop("blend", None)
    data = lightmap_files.read_texel_data(files, crop=True)  # an almost empty atlas: its texels' window
    sidecar["reencoded_from_sh"] = True
    sidecar["reencode_threads"] = threads
    atlas_seams = lightmap_files.read_seams(files, data.atlas_shape) if settings.stitch_seams else None
    # the post stages write into the images read (memory: no second copy of the atlas's SH)
    restore = functools.partial(_restore_sh, data.sh, np.flatnonzero(data.baked), _RawFiles(files), "", "", data.window)
    data, sidecar["post"] = post.apply(data, settings, seams=atlas_seams, in_place=True, restore=restore)
    del restore
    encoded = encoding.encode_atlas(data, encoding.for_settings(settings.encoder), raw=False, threads=threads)
    encoded = post.stitch_encoded(encoded, data.coverage, settings, atlas_seams, sidecar["post"], in_place=True)
    del data
    lightmap_files.write_atlas(staging, files, encoded, sidecar)
    return post.warnings(sidecar["post"])
