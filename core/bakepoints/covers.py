"""Surfaces hidden behind coplanar geometry ("covers"). No bpy.

A box standing on a floor has its bottom face in the floor's plane, facing down; a ceiling
bulkhead's back face can lie in a wall's plane, facing the wall. Cycles starts a bake ray on the
surface itself, so it hits such a face at distance 0 and the covered part of a texel stays dark.
Our rays start `offset` off the surface (rays.ray_offset), past a face at distance 0, and would
see what lies behind it: light leaking into the covered part (on the classroom, most of the
difference to Cycles beyond noise came from a few wall texels behind a bulkhead's open-topped
box).

The probe: every triangle pushed back along its own normal by COVER_PUSH × offset. A face
opposite a receiver then lies in front of it and the receiver itself behind, so a short ray
from a sample origin back to the surface finds any cover, and nothing else, without the tie two
coplanar triangles give a ray. Geometry within the offset in front of a surface (thinner than
the offset) counts too: a ray starting behind it is just as wrong.

`shared_probe` keeps the probes built over one RayScene's triangles (keyed by offset and the
receivers' content), so the bake points (which flag texels near a cover) and the tracer (which
probes those texels' samples) build one probe between them.
"""

from __future__ import annotations

import hashlib
import threading
import weakref

import numpy as np

from ..rays import RayScene, bounds, frame_origin
from . import kernels as _kernels

#: How far every triangle is pushed back for the probe, as a fraction of the ray offset: far
#: enough to break the coplanar tie at float32 precision (the offset is ≥ 32 ulps), near enough
#: that the probe (length: the offset) never reaches the receiver itself.
COVER_PUSH = 0.25


class CoverProbe:
    """Finds sample origins whose surface point is covered.

    triangles (T, 3, 3): all geometry (receivers included), world space minus `origin` (3,)
    (the frame of the ray scene they come from: `RayScene.local_triangles`; no origin: world
    space, traced about `rays.frame_origin` of them); offset: the distance
    (scene units) sample origins sit off their surface along the face normal; receivers
    (R, 3, 3), optional, world space: the surfaces whose points will be probed. Only triangles
    whose bounding box comes within 2 × offset of the receivers' bounding box can cover one of
    their points, so only those are kept (a ground plane under a million-triangle field keeps
    the few that touch it): a smaller probe scene builds faster (Embree's BVH build is linear in
    triangles). The probe works in the same frame, so its push is measured against the corners
    the tracer's rays meet."""

    def __init__(
        self,
        triangles: np.ndarray,
        offset: float,
        receivers: np.ndarray | None = None,
        origin: np.ndarray | None = None,
    ):
        self.offset = offset
        tri = np.asarray(triangles).reshape(-1, 3, 3)
        if origin is None:
            origin = frame_origin(tri)
            tri = tri - origin if origin.any() else tri
        self.origin = np.asarray(origin, np.float64)
        if receivers is not None:  # filter first: convert only what is kept
            tri = tri[_near_box(tri, np.asarray(receivers, np.float64) - self.origin, 2.0 * offset)]
        tri = tri.astype(np.float64)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.divide(n, length, out=np.zeros_like(n), where=length > 0.0)  # degenerate: no push
        pushed = tri - n[:, None, :] * (COVER_PUSH * offset)
        self.scene = RayScene(pushed, origin=np.zeros(3)) if len(tri) else None

    def covered(self, origins: np.ndarray, face_normals: np.ndarray) -> np.ndarray:
        """(R,) bool: a face lies on, or within the offset in front of, the surface point below
        each origin (world space: surface point + face normal × offset)."""
        if self.scene is None:
            return np.zeros(len(origins), bool)
        local = np.asarray(origins, np.float64) - self.origin if self.origin.any() else origins
        return self.scene.occluded(local, -np.asarray(face_normals), self.offset)


_shared: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # RayScene -> {key: CoverProbe}
_shared_lock = threading.Lock()


def shared_probe(scene: RayScene, offset: float, receivers: np.ndarray) -> CoverProbe:
    """The probe over `scene.local_triangles` (float32, Embree's own) for `offset` and `receivers`
    (R, 3, 3), built on first request and kept as long as `scene` lives: the same object for
    every request with the same offset and receivers of equal content (shape, dtype, values)."""
    key = (float(offset), content_key(receivers))
    with _shared_lock:
        probes = _shared.setdefault(scene, {})
        if key not in probes:
            probes[key] = CoverProbe(scene.local_triangles, offset, receivers=receivers, origin=scene.origin)
        return probes[key]


def content_key(a: np.ndarray) -> str:
    """A digest of an array's shape, dtype and values: equal for equal arrays, whatever object holds them."""
    a = np.ascontiguousarray(a)
    digest = hashlib.blake2b(f"{a.shape}{a.dtype.str}".encode(), digest_size=16)
    digest.update(a.view(np.uint8).ravel() if a.size else b"")
    return digest.hexdigest()


def _near_box(tri: np.ndarray, points: np.ndarray, margin: float) -> np.ndarray:
    """(T,) bool: triangles whose bounding box overlaps that of `points` (..., 3) grown by `margin`."""
    lo, hi = bounds(points)
    return _kernels.get().near_box(np.ascontiguousarray(tri), lo - margin, hi + margin)
