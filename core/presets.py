"""Quality presets: the tracer knobs each sets. No bpy.

Derived from the measured Pareto front of bench/tradeoff.py (README "Speed vs accuracy" gives
each preset's time and error on the bench scenes): a preset is a maximum sample count, a
bounce count, a noise target (relative standard error of I_z at which a texel stops early,
0 = every texel takes every sample) and whether the denoiser runs (`core.post.denoise`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Preset:
    samples: int  # most samples per texel
    bounces: int
    noise_target: float  # relative standard error of I_z (0.05 = 5 %); 0 = off
    denoise: bool
    description: str

    def knobs(self) -> tuple[int, int, float, bool]:
        return self.samples, self.bounces, self.noise_target, self.denoise


PRESETS = {
    # cheapest measured setting whose worst-scene relative I_z RMSE is within 55 / 30 / 10 / 6 %,
    # denoised settings included except for the reference (bench/results/presets.json; times for
    # ~15-28k texels on 2 cores)
    "DRAFT": Preset(
        16,
        1,
        0.0,
        False,
        "Well under a second: placement and light direction checks; one bounce, so rooms are dark and noisy",
    ),
    "PREVIEW": Preset(
        16, 4, 0.0, True, "About a second, denoised: the lighting's look; 4 bounces leave rooms somewhat dark"
    ),
    "PRODUCTION": Preset(
        64, 8, 0.0, True, "A second or two, denoised: shipping quality, 8 bounces (fewer darken interiors)"
    ),
    "REFERENCE": Preset(
        2048, 8, 0.0, False, "Converged reference for comparisons, not denoised; about half a minute per 20k texels"
    ),
}


def get(name: str) -> Preset:
    """The preset called name (any case); raises ValueError naming the valid presets."""
    key = name.upper()
    if key not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(p.lower() for p in PRESETS)}")
    return PRESETS[key]
