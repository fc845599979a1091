"""The bake points' flags from probe rays: buried texels (their hemisphere closed by back faces)
and texels near a cover (part of the texel may lie under a coplanar face). No bpy."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .. import parallel, progress, raster_kernels
from ..rays import RayScene
from . import data
from .covers import CoverProbe
from .data import BakePoints

#: Fraction of a texel's short probe rays that must hit back faces for it to count as buried
#: (its hemisphere is closed by geometry, e.g. a wall pushed into the floor).
BURIED_FRACTION = 0.5
#: Probe directions per texel for the buried test (fixed, rotated per texel).
BURIED_PROBES = 12
#: `_for_chunks` gives each worker at least this many chunks (balance) of at least MIN_CHUNK rows.
CHUNKS_PER_WORKER = 4
MIN_CHUNK = 1 << 10


def find_near_cover(
    points: BakePoints, probe: CoverProbe, check=None, chunk: int = 1 << 15, threads: int = 0
) -> np.ndarray:
    """Texels part of whose samples may start under a coplanar face (core.bakepoints.covers): the bake point,
    the footprint's corners and the texel's corners (where the samples' fallback can reach),
    mapped into the texel's triangle, are probed (each distinct ray once: neighbouring texels on
    one triangle share their corners, `raster_kernels.cover_rays`). The tracer probes every sample
    of the texels flagged here, so the flag only has to be conservative at the scale of a texel.
    (P,) bool."""
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    offsets = np.concatenate([0.5 + data.FOOTPRINT * (corners - 0.5), corners])  # texel units from its corner
    offsets = np.unique(offsets, axis=0)  # FOOTPRINT 1: the footprint's corners are the texel's
    flags = np.zeros(len(points.texel), bool)
    # which texel corner each offset is (neighbouring texels on one triangle share its point there)
    corner = np.array([int(x + 2 * y) if {x, y} <= {0.0, 1.0} else -1 for x, y in offsets], np.int64)

    def probe_chunk(rows: slice):
        texel_points = np.ascontiguousarray(points.texel_points(np.arange(rows.start, rows.stop), offsets), np.float64)
        face_normal = np.ascontiguousarray(points.face_normal[rows], dtype=np.float64)
        # the bake point's origin, then the texel points; a ray equal to one already probed is not probed again
        origins, normals, ray = raster_kernels.get().cover_rays(
            points.texel[rows],
            points.width,
            points.position[rows],
            face_normal,
            points.offset,
            texel_points,
            texel_points.view(np.int64),
            face_normal.view(np.int64),
            corner,
        )
        flags[rows] = probe.covered(origins, normals)[ray].any(axis=1)

    _for_chunks(probe_chunk, len(flags), chunk, check, threads)
    return flags


def _for_chunks(work, n: int, chunk: int, check=None, threads: int = 0) -> None:
    """work(rows) for consecutive slices of range(n), `chunk` long (shorter when that leaves a
    worker fewer than CHUNKS_PER_WORKER of them, down to MIN_CHUNK: a small atlas's few chunks
    would leave a core idle), on `threads` workers (0 = every core; Embree releases the GIL);
    `check()` before each chunk's result is taken (it raises to stop: the chunks not started
    are dropped; a `core.progress.Tick` also reports the share of chunks done). Each chunk writes
    only its own rows, so the result depends on neither the thread count nor the chunks."""
    workers = parallel.resolve_threads(threads)
    chunk = max(1, min(chunk, max(MIN_CHUNK, -(-n // (CHUNKS_PER_WORKER * workers)))))
    tick = progress.ticker(check)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(work, slice(s, min(s + chunk, n))) for s in range(0, n, chunk)]
        try:
            for k, future in enumerate(futures):
                tick.at(k / len(futures))
                future.result()
        finally:
            for future in futures:
                future.cancel()


def _probe_directions(n: int) -> np.ndarray:
    """n fixed directions over the upper hemisphere (z up), cosine-spread (Fibonacci spiral)."""
    k = np.arange(n) + 0.5
    r = np.sqrt(k / n) * 0.95  # stay ~18° off the horizon: grazing probes are useless
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r * r)], axis=1)


def find_buried(
    points: BakePoints, scene: RayScene, probes: int = BURIED_PROBES, check=None, chunk: int = 1 << 15, threads: int = 0
) -> np.ndarray:
    """Texels whose hemisphere is closed by nearby geometry seen from behind (the inside of a
    box pushed into the floor): at least BURIED_FRACTION of short probe rays (length 4 texels)
    hit back faces. Such texels are invalid: the traced SH is 0 there, never a dilation source,
    and the files fill them from the nearest valid texel of their chart (`TexelData.fill`). (Deeper inside a closed volume texels are dark anyway: all
    their rays end on the volume's inner faces.) Returns (P,) bool. Works in chunks of texels
    (bounded memory) on `threads` workers (0 = every core), calling `check()` between chunks. Every texel gets
    the first probes − need + 1 probes, only those with a back-face hit among them the rest:
    the same answer (the others cannot reach `need`) for most of the rays on open surfaces."""
    buried = np.zeros(len(points.texel), bool)
    local = _probe_directions(probes)
    need = int(np.ceil(BURIED_FRACTION * probes))  # back-face hits that make a texel buried
    first = probes - need + 1  # with none in these, the rest cannot add up to `need`: not buried
    compiled = raster_kernels.get()

    def back_hits(sl, rows, directions):
        """Back-face hits (len(rows),) of the probes `directions` from the texels sl[rows]:
        origins, directions in the face normal's tangent frame (`sh.tangent_frames`) and reach
        4 texels + 4 offsets (`raster_kernels.buried_rays`), closest hits, back faces counted."""
        origins, dirs, reach = compiled.buried_rays(
            points.position[sl], points.face_normal[sl], points.texel_size[sl], points.offset, rows, directions
        )
        t, prim, ng = scene.intersect(origins, dirs, reach)
        return compiled.back_hits(dirs, prim, ng, len(directions))

    def probe_chunk(sl: slice):
        hits = back_hits(sl, np.arange(sl.stop - sl.start), local[:first])
        rows = np.flatnonzero(hits > 0)  # most texels (open surfaces) stop here
        if len(rows) and first < probes:
            hits[rows] += back_hits(sl, rows, local[first:])
        buried[sl] = hits >= need

    _for_chunks(probe_chunk, len(buried), chunk, check, threads)
    return buried
