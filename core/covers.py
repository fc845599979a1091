"""Surfaces hidden behind coplanar geometry ("covers"). No bpy.

A box standing on a floor has its bottom face in the floor's plane, facing down; a ceiling
bulkhead's back face can lie in a wall's plane, facing the wall. Cycles starts a bake ray on the
surface itself, so it hits such a face at distance 0 and the covered part of a texel stays dark.
Our rays start `offset` off the surface (rays.ray_offset), past a face at distance 0, and would
see what lies behind it: light leaking into the covered part (measured on the classroom: 96% of
the difference to Cycles beyond noise came from 0.4% of the texels, wall texels behind a
bulkhead's open-topped box).

The probe: every triangle pushed back along its own normal by COVER_PUSH × offset. A face
opposite a receiver then lies in front of it and the receiver itself behind, so a short ray
from a sample origin back to the surface finds any cover, and nothing else, without the tie two
coplanar triangles give a ray. Geometry within the offset in front of a surface (thinner than
the offset) counts too: a ray starting behind it is just as wrong.
"""
from __future__ import annotations

import numpy as np

from .rays import RayScene

#: How far every triangle is pushed back for the probe, as a fraction of the ray offset: far
#: enough to break the coplanar tie at float32 precision (the offset is ≥ 32 ulps), near enough
#: that the probe (length: the offset) never reaches the receiver itself.
COVER_PUSH = 0.25


class CoverProbe:
    """Finds sample origins whose surface point is covered.

    triangles (T, 3, 3) world space: all geometry (receivers included); offset: the distance
    (scene units) sample origins sit off their surface along the face normal."""

    def __init__(self, triangles: np.ndarray, offset: float):
        tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.divide(n, length, out=np.zeros_like(n), where=length > 0.0)   # degenerate: no push
        self.scene = RayScene(tri - n[:, None, :] * (COVER_PUSH * offset))
        self.offset = offset

    def covered(self, origins: np.ndarray, face_normals: np.ndarray) -> np.ndarray:
        """(R,) bool: a face lies on, or within the offset in front of, the surface point below
        each origin (origins = surface point + face normal × offset)."""
        return self.scene.occluded(origins, -np.asarray(face_normals), self.offset)
