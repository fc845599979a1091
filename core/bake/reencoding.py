"""A re-encode's job for one atlas's (or light set's) files: read → post stages → encode → stage
(`bake.reencode` runs it for an atlas and each of its light sets). No bpy."""

from __future__ import annotations

import functools

from .. import encoding, post
from ..files import lightmap_files
from .data import PipelineSettings


def _reencode_files(staging, files: lightmap_files.AtlasFiles, settings: PipelineSettings, threads: int) -> list[str]:
    """Read → post stages → encode → stage the encoded file and sidecar of one atlas (or light set)."""
    sidecar = lightmap_files.read_sidecar(files.sidecar)
    sidecar.pop("blend", None)
    data = lightmap_files.read_texel_data(files, crop=True)  # an almost empty atlas: its texels' window
    sidecar["reencoded_from_sh"] = True
    sidecar["reencode_threads"] = threads
    atlas_seams = lightmap_files.read_seams(files, data.atlas_shape) if settings.stitch_seams else None
    # the post stages write into the images read (memory: no second copy of the atlas's SH), a
    # denoiser failing half-way reading the SH back from the file
    raw_sh = functools.partial(lightmap_files.read_sh, files.sh)
    data, sidecar["post"] = post.apply(data, settings, seams=atlas_seams, raw_sh=raw_sh)
    encoded = encoding.encode_atlas(data, encoding.for_settings(settings.encoder), raw=False, threads=threads)
    encoded = post.stitch_encoded(encoded, data.coverage, settings, atlas_seams, sidecar["post"])
    del data
    lightmap_files.write_atlas(staging, files, encoded, sidecar)
    return post.warnings(sidecar["post"])
