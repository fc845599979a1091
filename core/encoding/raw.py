"""The files an atlas keeps besides its encoding: the raw SH and the texels. No bpy.

With them an atlas can be encoded again (`core.bake.reencode`) or blended without tracing.
"""

from __future__ import annotations

from .spec import DILATE_BURIED_BLACK, FLOAT, NO_FILL, Channel, FileSpec

#: SH0 … SH8: radiance SH coefficient k in the order of docs/conventions.md#sh-basis, RGB.
SH_LAYERS = tuple(
    Channel(
        f"SH{k}",
        tuple("RGB"),
        FLOAT,
        "radiance SH coefficient k (SHk.R/G/B), world space",
        fill=DILATE_BURIED_BLACK,
        preview=f"sh{k}",
    )
    for k in range(9)
)
SH_FILE = FileSpec("sh", "_sh.exr", SH_LAYERS)

NORMAL = Channel("Normal", tuple("XYZ"), FLOAT, "vertex normal n_v, world space, unit", fill=NO_FILL)
COVERAGE = Channel(
    "Coverage",
    ("V",),
    FLOAT,
    "fraction of the texel covered by triangles; 0 outside charts (dilated), -1 buried",
    fill=NO_FILL,
)
NOISE = Channel(
    "Noise",
    ("V",),
    FLOAT,
    "standard error of the texel's luminance SH0 (radiance) from the spread between the tracer's "
    "p passes, widened by sqrt(nu / (nu - 2)), nu = p - 1, for the uncertainty of that estimate; "
    "-1 where unknown (fewer than 4 passes) and outside charts",
    fill=NO_FILL,
)
#: `NOISE`'s value in the files where a texel's noise is unknown (a standard error is ≥ 0; files
#: hold no NaN). In memory (`TexelData.noise`) unknown is NaN.
NOISE_UNKNOWN = -1.0
TEXELS_FILE = FileSpec("texels", "_texels.exr", (NORMAL, COVERAGE, NOISE))

#: The raw files, in the order they are written after the encoding's file.
FILES = (SH_FILE, TEXELS_FILE)
