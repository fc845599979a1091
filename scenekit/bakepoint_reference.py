"""The bake points as they were before the leak fixes moved them out of solids: the reference
the leak fixes are measured against (tests/test_leaks.py, tests/test_unwrap_raster.py,
tests/test_raster_compiled.py, bench/leaks.py). Not shipped; no bpy.

`bakepoints.build` settles every bake point it probes (`bakepoints.settling.settle`): a bake
point inside a wall standing on the surface moves out, and the texels such geometry crosses
(`BakePoints.crossed`) average only the part of their footprint their bake point sees. Here
the same stages run without that one: the bake points stay at their overlap's centroid."""

from __future__ import annotations

import numpy as np

from hhd_lightmapper.core import bakepoints, tracer
from hhd_lightmapper.core.bakepoints import covers
from hhd_lightmapper.core.bakepoints.flags import find_buried, find_near_cover
from hhd_lightmapper.core.rays import RayScene, ray_offset
from hhd_lightmapper.core.scene import BakeScene
from hhd_lightmapper.core.stages import TracedAtlas


def unsettled(
    surface: bakepoints.SurfaceTriangles,
    width: int,
    height: int,
    occluders: RayScene,
    check=None,
    threads: int = 0,
    **build,
) -> bakepoints.BakePoints:
    """Bake points of `surface` in a width × height atlas as `bakepoints.build(..., occluders=
    occluders)` makes them, but not settled: every bake point at its overlap's centroid, no
    texel `crossed` (None: the tracer averages every texel's whole footprint, both sides of a
    wall standing on it included), the buried and near-cover probes run from there, and a bake
    point under a coplanar face leaves its texel valid. `check`, `threads` and `build` (chunk,
    albedo): as `bakepoints.build` takes them."""
    points = bakepoints.build(surface, width, height, check=check, threads=threads, **build)  # nothing probed
    points.offset = ray_offset(np.asarray(surface.positions, np.float64), occluders.origin)
    probe = covers.shared_probe(occluders, points.offset, points.mesh.positions)
    points.buried = find_buried(points, occluders, check=check, threads=threads)
    points.near_cover = find_near_cover(points, probe, check=check, threads=threads)
    return points


def trace_unsettled(
    surface: bakepoints.SurfaceTriangles, width: int, height: int, scene: BakeScene, settings: tracer.BakeSettings
) -> TracedAtlas:
    """`core.bake.trace_surface` (stages 1–2) with the bake points `unsettled`."""
    ray_scene = RayScene(scene.triangles)
    points = unsettled(surface, width, height, ray_scene, threads=settings.threads, albedo=False)
    return tracer.bake(points, scene, settings, ray_scene=ray_scene)
