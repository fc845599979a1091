"""Incremental bakes: fingerprints of what a bake's lighting depends on, what is stale since the
last bake, which receivers a change influences, and re-tracing a subset of an atlas's receivers
into its existing files. No bpy.

Fingerprints (`Fingerprints`, the sidecar's "fingerprints"): a 128-bit BLAKE2b digest (`digest`)
per mesh object (evaluated geometry, corner normals, world transform, the material inputs: the
bpy side hashes what the bake reads, `bridge/fingerprints.py`), per light (its settings and
transform), of the world, and per atlas of its layout (atlas size, the receivers and their
lightmap UVs). Per object its world bounds (metres) and per light its position and power, which
the influence rule reads. `compare` gives what changed (`Stale`).

A subset bake (`bake_subset`): bake points of the chosen receivers only (same atlas, same
layout), traced with the bake's settings and seed (a texel's own sequences are keyed by its place
in the atlas, `tracer.hemisphere`: it draws what a full bake draws for it, up to the deeper
bounces, which come per work unit), then the atlas's previous SH and texels
files are read whole, the new texels written into them, and the post stages (denoise, stitch)
and the encoder run as a re-encode does (`bake.reencode`), on the region of the touched texels
and of the charts they lie in or fill from (`merge_region`: tiles grown by WINDOW_HALO; every
other texel emptied: the stages' cost follows the region) or, where that region holds more
than WINDOW_SHARE_MAX of the atlas's chart texels, on the whole atlas; on the written texels
the region gives the whole atlas's encode, fill and stitch bit for bit, and the denoiser's
result up to its pages' composition (`_region_encode`); of every file
(raw SH, texels, the encoded file, their preview images, each light set's) only the touched
texels are replaced (`touched_mask`: the re-traced texels, the texels bilinear reads along their
seams take on both sides, and the texels outside charts filled from those), every other texel
keeps its stored value bit for bit. The seams file stays (same layout). Staged: a failure or a
cancel replaces nothing. No earlier bake, a changed layout, other bake settings or other light
sets: `FullBakeNeeded`, nothing written.

The modules: `fingerprints` (the fingerprints, what is stale, the influence rule, the last
bake's record in a folder), `subset` (the subset bake: `bake_subset`, the touched texels) and
`merge` (its merge into the atlas's files, the post stages and encoder on the touched region).
"""
