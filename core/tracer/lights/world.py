"""The HDRI world as a light (`Environment`): importance-sampled by its map, reached by rays
leaving the scene, combined with the power heuristic. No bpy."""

from __future__ import annotations

import numpy as np

from ...colour import LUMINANCE
from ...environment import EnvironmentMap
from .light import Light, RayPdf, Sample


class Environment(Light):
    """An HDRI world (`environment.EnvironmentMap`): importance-sampled, and reached by every
    ray that leaves the scene."""

    reachable = True
    at_infinity = True

    def __init__(self, environment: EnvironmentMap, group: str = ""):
        self.map, self.group = environment, group

    def sample(self, rng, x, ray_pdf: RayPdf, strata=1, normals=None) -> Sample:
        dirs, p_env = self.map.sample(rng, len(x))
        p_other = ray_pdf(dirs)
        return (
            dirs,
            self.map.radiance(dirs) * (p_env / (p_env * p_env + p_other * p_other))[:, None],
            np.full(len(x), np.inf),
        )

    def pdf(self, d, t=None, prim=None, origins=None, normals=None) -> np.ndarray:
        return self.map.pdf(d)

    def evaluate(self, d, t, prim, pdf, origins=None, normals=None) -> np.ndarray:
        p_env = self.map.pdf(d)
        return self.map.radiance(d) * (pdf * pdf / (pdf * pdf + p_env * p_env))[:, None]

    @property
    def power(self) -> float:
        h, w = self.map.pixels.shape[:2]
        theta = np.pi * (1.0 - (np.arange(h) + 0.5) / h)
        solid_angle = (2.0 * np.pi / w) * (np.pi / h) * np.sin(theta)
        return float(((self.map.pixels @ LUMINANCE) * solid_angle[:, None]).sum())
