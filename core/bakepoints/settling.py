"""Bake points moved out of solids onto the visible side of their texel (`settle`), and the texels
some geometry crosses flagged. No bpy."""

from __future__ import annotations

import numpy as np

from .. import raster_kernels
from ..rays import RayScene
from . import data
from .covers import CoverProbe
from .data import BakePoints
from .flags import _for_chunks

#: How far past a back face a bake point is moved, in ray offsets (measured square to the face).
SETTLE_CLEARANCE = 4.0
#: Reach of the spoke opposite a back-face hit, in texels: a bake point is inside a solid (and
#: moved out of it) when back faces lie on both sides within this reach, or when a coplanar face
#: covers it (core.bakepoints.covers). A lone back face is not enough: a room whose walls face outwards
#: shows its inside nothing but back faces, and its floor must not be moved through them.
SETTLE_THICKNESS = 8.0
#: Footprint points, in texel units from the texel's corner, that `settle` casts its spokes to
#: from the bake point: the footprint's corners and the middles of its sides.
_SPOKES = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0.5, 0], [0.5, 1], [0, 0.5], [1, 0.5]], float)


def settle(
    points: BakePoints, scene: RayScene, probe: CoverProbe, check=None, chunk: int = 1 << 15, threads: int = 0
) -> np.ndarray:
    """Bake points moved out from under back faces, as Godot's lightmapper does: from each bake
    point (its ray origin, `offset` off the surface) a short ray (a spoke) to each of the
    footprint's corners and side middles (`_SPOKES`, clamped into the texel's triangle), on to
    one texel away; where spokes hit the back of a triangle and the bake point is inside a solid
    (a coplanar face covers it, `probe`: under a box resting on the surface; or back faces lie
    on both sides within SETTLE_THICKNESS texels: inside a wall standing in the surface), the
    bake point moves along the nearest such spoke to SETTLE_CLEARANCE offsets past that face,
    onto the part of the texel one can see. Updates `points.position` in place; returns (P,)
    bool: texels whose footprint some geometry crosses (a spoke hits it before the footprint's
    edge), whose samples the tracer checks against the bake point. Chunks of `chunk` texels on
    `threads` workers (0 = every core), `check()` between chunks."""
    crossed = np.zeros(len(points.texel), bool)
    k = len(_SPOKES)

    def settle_chunk(sl: slice):
        idx = np.arange(sl.start, sl.stop)
        target = _spoke_targets(points, idx, _SPOKES * data.FOOTPRINT + 0.5 * (1.0 - data.FOOTPRINT))
        # from each bake point's ray origin (the anchor) to its targets: unit directions, lengths,
        # reach at least a texel (`raster_kernels.spoke_rays`: numpy's arithmetic compiled)
        anchor, origin, direction, length, reach = raster_kernels.get().spoke_rays(
            points.position, points.face_normal, points.texel_size, points.offset, sl.start, target
        )
        near = scene.occluded(origin, direction.reshape(-1, 3), reach.reshape(-1)).reshape(-1, k)
        rows = np.flatnonzero((near & (length > 0.0)).any(axis=1))  # the few texels near geometry
        if len(rows) == 0:
            return
        spokes = _Spokes(scene, anchor[rows], direction[rows], reach[rows])
        moved = _push_out(points, idx[rows], spokes, probe)
        crossed[idx[rows]] = (spokes.t < length[rows]).any(axis=1) | moved

    _for_chunks(settle_chunk, len(crossed), chunk, check, threads)
    return crossed


def _spoke_targets(points: BakePoints, idx: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Ray origins (len(idx), k, 3) at `offsets` (k, 2) texel units from each texel's corner: on
    the first of the texel's triangles holding the point (its own, then `BakePoints.others`,
    whose parts of the footprint its samples cover too), else clamped into its own triangle
    (`BakePoints.texel_points`)."""
    target = points.texel_points(idx, offsets)
    if points.others is None:
        return target
    raster_kernels.get().spoke_targets(  # numpy's arithmetic compiled (scenekit/raster_reference.py)
        target,
        np.asarray(idx, np.int64),
        points.texel,
        points.width,
        points.triangle,
        points.others,
        points.mesh.texel_uv,
        points.mesh.positions,
        points.face_normal,
        points.offset,
        np.ascontiguousarray(offsets, np.float64),
    )
    return target


class _Spokes:
    """Closest hits of k spokes per bake point: anchor (n, 3), direction (n, k, 3) unit, reach
    (n, k). t (n, k) hit distance (inf: none), back (n, k) bool: the hit is a triangle's back,
    cos (n, k): the cosine between the spoke and that face's normal."""

    def __init__(self, scene: RayScene, anchor, direction, reach):
        n, k = reach.shape
        self.scene, self.anchor, self.direction = scene, anchor, direction
        t, prim, ng = scene.intersect(np.repeat(anchor, k, axis=0), direction.reshape(-1, 3), reach.reshape(-1))
        ng = ng.astype(np.float64)
        ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
        cos = np.einsum("ri,ri->r", ng, direction.reshape(-1, 3)).reshape(n, k)
        self.t = np.where(prim >= 0, t, np.inf).reshape(n, k).astype(np.float64)
        self.back = (prim.reshape(n, k) >= 0) & (cos > 0.0)
        self.cos = cos


def _between_back_faces(points: BakePoints, idx, anchor, scene: RayScene, k: int = 8) -> np.ndarray:
    """(n,) bool: along some line in the surface's plane through `anchor` (n, 3), back faces lie
    on both sides within SETTLE_THICKNESS texels (k directions, opposite pairs)."""
    from ..sh import tangent_frames

    angle = np.arange(k) * (2.0 * np.pi / k)
    local = np.stack([np.cos(angle), np.sin(angle), np.zeros(k)], axis=1)
    direction = np.einsum("pij,kj->pki", tangent_frames(points.face_normal[idx]), local)
    reach = np.repeat(SETTLE_THICKNESS * points.texel_size[idx][:, None], k, axis=1)
    back = _Spokes(scene, anchor, direction, reach).back
    return (back[:, : k // 2] & back[:, k // 2 :]).any(axis=1)


def _push_out(points: BakePoints, idx, spokes: _Spokes, probe: CoverProbe) -> np.ndarray:
    """Moves the bake points `idx` past the nearest back face their spokes hit, where they are
    inside a solid (`settle`); position updated in place. Returns (len(idx),) bool: moved."""
    n, k = spokes.t.shape
    moved = np.zeros(n, bool)
    back_t = np.where(spokes.back, spokes.t, np.inf)
    best = np.argmin(back_t, axis=1)
    rows = np.flatnonzero(np.isfinite(back_t[np.arange(n), best]))
    if len(rows) == 0:
        return moved
    inside = probe.covered(spokes.anchor[rows], points.face_normal[idx[rows]])
    if not inside.all():  # not covered: back faces on two opposite sides within SETTLE_THICKNESS texels?
        inside[~inside] = _between_back_faces(points, idx[rows[~inside]], spokes.anchor[rows[~inside]], spokes.scene)
    rows = rows[inside]
    b = best[rows]
    past = spokes.t[rows, b] + SETTLE_CLEARANCE * points.offset / np.maximum(spokes.cos[rows, b], 0.1)
    to = spokes.anchor[rows] + spokes.direction[rows, b] * past[:, None]
    points.position[idx[rows]] = to - points.face_normal[idx[rows]] * points.offset
    moved[rows] = True
    return moved
