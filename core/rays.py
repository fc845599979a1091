"""Embree ray queries over world-space triangles. No bpy.

Rays start at their origin (tnear 0): callers offset origins themselves (`ray_offset`).
"""

from __future__ import annotations

import numpy as np

from . import embree

FLOAT32_EPS = float(np.finfo(np.float32).eps)


def ray_offset(positions: np.ndarray, origin: np.ndarray | None = None) -> float:
    """Origin offset (scene units) for rays leaving surfaces at `positions`: 1e-5 of their extent
    plus a margin of 32 float32 ulps at their largest coordinate in the ray scene's frame
    (`origin`: the `RayScene.origin` they are traced against; default `frame_origin` of the
    positions), so it works from millimetre to kilometre scenes, wherever the level sits."""
    lo, hi = bounds(positions)
    extent = float(np.linalg.norm(hi - lo))
    at = _frame_origin(positions, lo, hi) if origin is None else np.asarray(origin, np.float64)
    magnitude = float(np.maximum(np.abs(lo - at), np.abs(hi - at)).max())
    return 1e-5 * extent + 32.0 * FLOAT32_EPS * magnitude


def frame_origin(points: np.ndarray) -> np.ndarray:
    """(3,) float64: where a ray scene over `points` (..., 3) puts its origin. Embree holds
    corners as float32, whose spacing grows with the coordinates (6 cm at 10⁶ m): a level far
    from the world origin is traced about the centre of its bounds instead, so its precision is
    that of the same level at the origin. A scene whose bounds already reach about the origin
    (its centre no farther out than its extent) keeps the world origin (coordinates unchanged).
    Non-finite corners are left out."""
    if np.size(points) == 0:
        return np.zeros(3)
    return _frame_origin(points, *bounds(points))


def _frame_origin(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """`frame_origin(points)`, given `bounds(points)`: those bounds are the finite corners' own
    unless one is not finite (a NaN or an infinity among the corners), when they are found again
    without the non-finite corners (a copy: the rare case)."""
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        p = np.asarray(points, np.float64).reshape(-1, 3)
        p = p[np.isfinite(p).all(axis=1)]
        if not len(p):
            return np.zeros(3)
        lo, hi = bounds(p)
    centre = 0.5 * (lo + hi)
    return np.zeros(3) if np.abs(centre).max() <= np.linalg.norm(hi - lo) else centre


def bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box (lo (3,), hi (3,)) float64 of points (..., 3)."""
    p = np.asarray(points).reshape(-1, 3)
    # per column: a reduction along axis 0 of an (N, 3) array is much slower in numpy
    lo = np.array([p[:, i].min() for i in range(3)], dtype=np.float64)
    hi = np.array([p[:, i].max() for i in range(3)], dtype=np.float64)
    return lo, hi


class RayScene:
    """An Embree scene of triangles `(T, 3, 3)` (world space); primitive ids index them.
    Built through `core.embree` (Embree shares the corner array; its BVH builds on Embree's
    threads while the caller carries on; the first query waits for it). Queries take and give
    world space; Embree works about `origin` (`frame_origin`), which they subtract."""

    def __init__(self, triangles: np.ndarray, origin: np.ndarray | None = None):
        self.origin = frame_origin(triangles) if origin is None else np.asarray(origin, np.float64)
        self._scene = embree.Scene(triangles, self.origin)
        #: (T, 3, 3) float32: the corners as Embree holds them, world space minus `origin` (read-only)
        self.local_triangles = self._scene.triangles
        self.n_triangles = len(self.local_triangles)

    def intersect(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        tmax: np.ndarray | float | None = None,
        barycentrics: bool = False,
    ):
        """Closest hits. Returns (t (R,) float32 distance or inf, prim (R,) int32 or -1,
        ng (R, 3) float32 unnormalised geometric normal, CCW winding; zeros on a miss), plus
        (u, v) (R,) with hit = (1-u-v)·p0 + u·p1 + v·p2 when `barycentrics`."""
        o, d = _rays(origins), _rays(directions)
        t, prim, ng, u, v = self._scene.intersect(o, d, _reach(tmax, len(o)))
        return (t, prim, ng, u, v) if barycentrics else (t, prim, ng)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | float) -> np.ndarray:
        """Whether anything lies within `tmax` (R,) along each ray: (R,) bool. Embree's any-hit
        query (stops at the first hit found: cheaper than `intersect` for shadow rays)."""
        o, d = _rays(origins), _rays(directions)
        return self._scene.occluded(o, d, _reach(tmax, len(o)))

    def shadow(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        dist: np.ndarray,
        normals: np.ndarray,
        offset: float,
        scale: float = 1.0,
        cosine: bool = True,
        allowed: np.ndarray | None = None,
    ) -> tuple[np.ndarray, int]:
        """Next-event estimation's shadow rays in one pass: for the rows (R,) whose direction
        (R, 3) lies above their normal (R, 3) (c = direction · normal > 0) and that `allowed`
        (R,) bool permits (None: all), an any-hit query from the origin (R, 3) towards the
        light at distance dist (R,) (inf: a direction), stopping `offset` (scene units) and
        1e-4 of the way short of it. Returns the weights (R,) float64, scale·c (`cosine`) or
        scale where nothing is in the way, else 0, and how many rays were traced."""
        rows = np.zeros(0, bool) if allowed is None else np.ascontiguousarray(allowed, bool)
        return self._scene.shadow(
            _float64(origins), _float64(directions), _float64(dist), _float64(normals), offset, rows, scale, cosine
        )


def _float64(a: np.ndarray) -> np.ndarray:
    """a as float64 (no copy when it is already; broadcast views stay views)."""
    return np.asarray(a, np.float64)


def _rays(a: np.ndarray) -> np.ndarray:
    """(R, 3) origins or directions, C-contiguous float64 or float32 as given (the query
    kernels are compiled for both)."""
    a = np.asarray(a)
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    return np.ascontiguousarray(a.reshape(-1, 3))


def _reach(tmax, n: int) -> np.ndarray:
    """(n,) float32 ray lengths from None (unbounded), a scalar or an array (a ray of negative
    or NaN length finds nothing)."""
    if tmax is None:
        return np.full(n, np.inf, np.float32)
    return np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, dtype=np.float32), (n,)))
