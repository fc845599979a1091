"""Which one of the point, spot and area lights a shading point samples (`Choice`). No bpy."""

from __future__ import annotations

import numpy as np

from .. import light_kernels as _kernels
from .emitters import POWER_SHARE
from .light import Light, Strata, _rows, uniforms

#: Share of a shading point's choice among point, spot and area lights made by intensity alone
#: (`Choice`), as POWER_SHARE is the emitter clusters': the bound knows nothing of occlusion.
CHOICE_SHARE = POWER_SHARE


#: The dimension of `uniforms` the choice draws its number from (the lights' own use 0–3).
CHOICE_DIM = 4


class Choice:
    """Which one of the scene's point, spot and area lights (`Light.chosen`: lights rays never
    reach, at a place) a shading point samples, instead of every one of them: light l with
    probability ∝ its largest radiant intensity × a bound on the cosine at the light (0 behind
    a one-sided area light's plane) × the horizon bound at the point, over max(d², r²), mixed
    with CHOICE_SHARE of intensity alone among the lights that can light the point
    (`light_kernels.choose_lights`). Its sample is divided by that probability: unbiased. A light that
    cannot light a point (behind a one-sided lamp, outside a spot's cone, or wholly below the
    point's horizon) is never picked there, and a point no light can light samples none (no
    shadow ray)."""

    def __init__(self, lights: list[Light]):
        self.lights = lights
        self.table = np.array([light.choice_row() for light in lights], np.float64).reshape(-1, 13)

    def pick(self, rng, x: np.ndarray, normals: np.ndarray | None, strata: Strata) -> tuple[np.ndarray, np.ndarray]:
        """(choice (R,) int64: an index into `lights` or −1 for none, probability (R,)) at the
        points x (R, 3) with `normals` (R, 3) or None; the numbers from `uniforms` (strata)."""
        u = np.ascontiguousarray(uniforms(rng, len(x), strata, CHOICE_DIM), np.float64)
        return _kernels.get().choose_lights(_rows(x), _rows(normals), u, self.table, CHOICE_SHARE)
