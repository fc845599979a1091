"""Quality presets: the tracer knobs each sets. No bpy.

Derived from the measured Pareto front of bench/tradeoff.py (README "Speed vs accuracy" gives
each preset's time and error on the bench scenes): a preset is a maximum sample count, a
bounce count and a noise target (relative standard error of I_z at which a texel stops early,
0 = every texel takes every sample).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Preset:
    samples: int  # most samples per texel
    bounces: int
    noise_target: float  # relative standard error of I_z (0.05 = 5 %); 0 = off
    description: str

    def knobs(self) -> tuple[int, int, float]:
        return self.samples, self.bounces, self.noise_target


PRESETS = {
    # cheapest measured setting whose worst-scene relative I_z RMSE is within 55 / 30 / 16 / 6 %
    # (bench/results/presets.json; times for ~15-28k texels on 2 cores)
    "DRAFT": Preset(16, 1, 0.0, "About a second: placement and light direction checks; visibly noisy indoors"),
    "PREVIEW": Preset(64, 4, 0.0, "A few seconds: the lighting's look; noticeable noise indoors"),
    "PRODUCTION": Preset(256, 8, 0.0, "Shipping quality: 8 bounces (fewer darken interiors), moderate noise"),
    "REFERENCE": Preset(2048, 8, 0.0, "Converged reference for comparisons; about a minute per 20k texels"),
}


def get(name: str) -> Preset:
    """The preset called name (any case); raises ValueError naming the valid presets."""
    key = name.upper()
    if key not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(p.lower() for p in PRESETS)}")
    return PRESETS[key]
