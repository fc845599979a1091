"""Quality presets: samples per texel and bounces. No bpy.

Provisional values until bench/tradeoff.py (issue 8) derives them from the measured Pareto
front; the README's speed/accuracy section gives what each costs on the bench scenes.
"""
from __future__ import annotations

#: name -> (samples per texel, bounces, one-line description)
PRESETS = {
    "DRAFT": (16, 1, "Seconds: placement and light direction checks; visible noise"),
    "PREVIEW": (64, 2, "Quick look at the lighting; slight noise in dark corners"),
    "PRODUCTION": (256, 3, "Shipping quality for most scenes"),
    "REFERENCE": (2048, 6, "Converged reference for comparisons; slow"),
}


def settings(name: str) -> tuple[int, int]:
    """(samples, bounces) of a preset; raises ValueError naming the valid presets."""
    key = name.upper()
    if key not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(p.lower() for p in PRESETS)}")
    samples, bounces, _ = PRESETS[key]
    return samples, bounces
