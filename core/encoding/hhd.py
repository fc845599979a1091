"""The HHD / AHD encoding (`core.hhd`): its file `<name>_hhd.exr` and its channels. No bpy.

Layers: Iz (I_z, RGB), Wa (w_a: one channel V with ambient "luminance", R/G/B with "rgb") and
Direction (the highlight direction, world space, octahedral X/Y). The encoding returns the
direction as a unit vector; it is filled (dilated) as a vector and packed afterwards. Its preview
image holds the unit vector (x, y, z), never the octahedral pair: a bilinear filter blends
vectors safely, not octahedral pairs across the map's folds (docs/format.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import hhd as _hhd
from .. import octahedral
from ..colour import LUMINANCE
from .settings import EncoderSettings
from .spec import DILATE, DILATE_BURIED_BLACK, HALF, HALF_OR_FLOAT, Channel, Encoded, FileSpec

IZ = Channel(
    "Iz",
    tuple("RGB"),
    HALF_OR_FLOAT,
    "I_z: irradiance at the vertex normal n_v, linear RGB, I = (1/π) ∫ L max(n·ω, 0) dω (albedo × I = radiance)",
    fill=DILATE_BURIED_BLACK,
    preview="iz",
)
_WA_MEANING = "w_a: ambient weight in [0, 1] (luminance mode: one channel V; RGB mode: per channel)"
WA = Channel("Wa", ("V",), HALF, _WA_MEANING, fill=DILATE, preview="wa", when=("ambient", "luminance"))
WA_RGB = Channel("Wa", tuple("RGB"), HALF, _WA_MEANING, fill=DILATE, preview="wa", when=("ambient", "rgb"))
DIRECTION = Channel(
    "Direction",
    tuple("XY"),
    HALF,
    "highlight direction d, world space, octahedral X/Y in [-1, 1]",
    fill=DILATE,
    preview="dir",
    width=3,
    pack=octahedral.encode,
    unpack=octahedral.decode,
)

#: Every layer the HHD file may hold (the file of one setting: `FILE.for_settings`).
FILE = FileSpec("hhd", "_hhd.exr", (IZ, WA, WA_RGB, DIRECTION))


@dataclass
class HHDEncoding:
    """The Encoding of `FILE`: `core.hhd.encode` with the fit options of `options` (model "hhd"
    or "ahd"); `file` has the Wa layer of its ambient mode."""

    options: EncoderSettings
    file: FileSpec = field(init=False)
    settings: dict = field(init=False)

    def __post_init__(self):
        self.file = FILE.for_settings(self.options)
        self.settings = self.options.kwargs()

    def encode(self, sh: np.ndarray, n_v: np.ndarray) -> Encoded:
        """Iz `(N, 3)`, Wa `(N, 1 | 3)`, Direction `(N, 3)` (unit, world space), float64; stats:
        texels_invalid, irradz_max and the sum of I_z's luminance (for the mean)."""
        p = _hhd.encode(sh, n_v, **self.settings)
        values = {IZ.name: p.irradz, WA.name: p.ambient_weight.reshape(len(p.irradz), -1), DIRECTION.name: p.direction}
        stats = {
            "texels_invalid": p.n_invalid,
            "irradz_max": float(p.irradz.max(initial=0.0)),
            "irradz_luminance_sum": float((p.irradz @ LUMINANCE).sum()),
        }
        return Encoded(values, stats)

    def summary(self, stats: list[dict], texels: int) -> dict:
        """texels_invalid, irradz_max and irradz_mean_luminance over the calls' `stats`."""
        invalid, iz_max, lum_sum = 0, 0.0, 0.0
        for s in stats:  # in call order: the same float sums for the same chunks
            invalid += s["texels_invalid"]
            iz_max = max(iz_max, s["irradz_max"])
            lum_sum += s["irradz_luminance_sum"]
        return {
            "texels_invalid": invalid,
            "irradz_max": iz_max,
            "irradz_mean_luminance": lum_sum / texels if texels else 0.0,
        }


def encoding(settings: EncoderSettings) -> HHDEncoding:
    return HHDEncoding(settings)
