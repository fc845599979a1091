"""The write stage: an atlas's files on disk, written and read back. No bpy.

lightmap_files  an atlas's files (`AtlasFiles`: names, docs/format.md is the contract), laying out
                and writing the encode stage's `EncodedAtlas` (EXRs, the sidecar, the seams file,
                the preview images), reading them back for a re-encode or a blend
exr             OpenEXR reading and writing, row order, `Staging` (every file of a bake renamed
                together), no non-finite value written
zip_exr         a scanline ZIP EXR laid out and its blocks deflated here, on the bake's threads
sparse_exr      an almost empty atlas's EXR written and read at the cost of its texels' window
preview         the preview images: which each EEVEE preview mode samples, the direction's image
                rewritten for this version, the B-spline coefficient images

The stages before hand over plain data only (`core.stages`, `core.encoding`); none of them
imports this package.
"""
