"""The bake points stage: lightmap texels turned into bake points. No bpy.

For every texel any triangle overlaps (`raster`), one bake point: the world position at the
overlap's centroid, the interpolated and normalised vertex normal n_v (the hemisphere the bake
integrates over), the face normal (oriented to n_v's side, used to offset ray origins), the
albedo there, and the texel's coverage. When several triangles overlap one texel the largest
overlap wins (ties: the lowest triangle index), so the choice is deterministic.

The modules: this one builds them (`build`: raster → chosen triangle per texel → the points, the
footprint's other triangles, then the probes); `data` (`SurfaceTriangles` in, `BakePoints` and
`SurfaceMesh` out, the footprint sampling of ray origins), `flags` (the buried and near-cover
probes), `settling` (bake points moved out of solids, `crossed`), `covers` (the cover probe),
`kernels` (the compiled footprint origins and cover-probe queries; the rasteriser's and the
probes' own are `core.raster_kernels`), `inward` (faces that point into their own object,
checked before any bake point).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .. import parallel, progress, raster, raster_kernels
from ..errors import BakeError
from ..rays import RayScene, ray_offset
from . import covers
from .data import BakePoints, SurfaceMesh, SurfaceTriangles
from .flags import _for_chunks, find_buried, find_near_cover
from .settling import settle

#: Most triangles whose parts of a texel's footprint its samples cover (the texel's own, then the
#: largest other overlaps): a texel straddling a triangle edge averages its whole footprint,
#: centred on the texel, not only its own triangle's part (whose centre lies up to half a texel
#: away: a shadow or contact edge there shifted into the texel, measured on the classroom's
#: walls against Cycles at 4× the resolution). 1: only the texel's own triangle.
FOOTPRINT_TRIANGLES = 4
#: Another triangle joins a texel's footprint only if its face normal is within this cosine of the
#: texel's own triangle's: every sample is pushed off along the texel's face normal, which must
#: also take it off that triangle's surface (a sharper fold inside one texel keeps its own part).
FOOTPRINT_MIN_COS = 0.9


#: The parts of `build` and their shares of its time (measured on a 1.35M-triangle level at 4096²:
#: bench/end_to_end.py), for its progress: rasterising and filling the points, the cover probe's
#: scene, settling, the buried texels, the near-cover texels.
PHASES = (("rasterising", 2.1), ("cover probe", 0.6), ("settling", 1.6), ("buried texels", 0.8), ("near cover", 0.6))


def build(
    surface: SurfaceTriangles,
    width: int,
    height: int,
    occluders: RayScene | None = None,
    check=None,
    chunk: int = 1 << 18,
    threads: int = 0,
    albedo: bool = True,
) -> BakePoints:
    """Bake points of every covered texel. `occluders` (all geometry that casts shadows, the
    receivers included) enables the probes: bake points move out of solids and keep every
    texel's samples on their side of geometry crossing its footprint (`settle`: `crossed`; the
    tracer drops samples hidden from the bake point), then the buried-texel test; without it
    nothing is flagged or moved.
    `check()`, if given, is called between chunks of work (it raises to stop: a cancel); a
    `core.progress.Tick` is also told how far each part (`PHASES`) has come.
    Per-texel quantities are computed `chunk` texels at a time, so the temporaries stay small
    next to the result (~170 bytes per texel). `threads`: workers of the probe passes (buried,
    near cover), 0 = every core (`parallel.resolve_threads`); the result does not depend on it.
    The cover probe comes from `covers.shared_probe(occluders, ...)`, where the tracer finds it.
    `albedo`: each bake point's albedo (`BakePoints.albedo`; None without it: neither the tracer
    nor the files read it, and it is 24 bytes a texel)."""
    pos = np.asarray(surface.positions, dtype=np.float64)
    if not np.isfinite(pos).all() or not np.isfinite(surface.uv).all():
        raise BakeError("lightmap bake points: NaN or infinite positions or UVs in the input")
    uv = np.asarray(surface.uv, dtype=np.float64)
    tick = progress.ticker(check)
    names = [f"{tick.name}: {name}" if tick.name else name for name, _ in PHASES]
    rasterising, probing, settling, burying, covering = tick.split([w for _, w in PHASES], names)
    rasterising.at(0.0)
    mesh = SurfaceMesh.from_surface(surface, width, height)
    cov = raster.rasterise(uv, width, height, rasterising.part(0.0, 0.7), threads)
    chosen, coverage = raster.choose_per_texel(cov)
    # indices as int32 where they fit (memory: 4 bytes a texel each; the same values)
    tri = cov.triangle[chosen].astype(_index_dtype(len(pos)), copy=False)
    texel = cov.texel[chosen].astype(_index_dtype(width * height), copy=False)
    centroid = cov.point[chosen]
    others = other_triangles(cov, chosen, _face_normals(pos), threads) if FOOTPRINT_TRIANGLES > 1 else None
    del cov
    n = len(tri)
    objects = np.asarray(surface.object_index)
    points = BakePoints(
        width=width,
        height=height,
        texel=texel,
        position=np.empty((n, 3)),
        normal=np.empty((n, 3)),
        face_normal=np.empty((n, 3)),
        albedo=np.empty((n, 3)) if albedo else None,
        coverage=coverage,
        triangle=tri,
        object_index=objects[tri].astype(_index_dtype(int(objects.max(initial=0)) + 1), copy=False),
        texel_size=np.empty(n),
        offset=ray_offset(pos, None if occluders is None else occluders.origin),
        buried=np.zeros(n, bool),
        mesh=mesh,
        near_cover=np.zeros(n, bool),
        others=others,
    )

    def fill_chunk(rows: slice) -> None:  # each chunk writes its own rows: the same whatever the threads
        _fill_points(points, surface, rows, centroid[rows])

    _for_chunks(fill_chunk, n, chunk, rasterising.part(0.9, 1.0), threads)
    if occluders is not None:
        probing.at(0.0)
        probe = covers.shared_probe(occluders, points.offset, mesh.positions)
        points.crossed = settle(points, occluders, probe, check=settling, threads=threads)
        points.buried = find_buried(points, occluders, check=burying, threads=threads)
        points.near_cover = find_near_cover(points, probe, check=covering.part(0.0, 0.7), threads=threads)
        covering.at(0.7)
        # a bake point still under a coplanar face: the whole texel is hidden
        rows = np.flatnonzero(points.near_cover & ~points.buried)
        points.buried[rows] = probe.covered(points.origins(rows), points.face_normal[rows])
    return points


def _index_dtype(count: int) -> type:
    """int32 for indices below `count` when they fit (every real atlas and mesh), else int64."""
    return np.int32 if count <= np.iinfo(np.int32).max else np.int64


def other_triangles(
    cov: raster.Coverage, chosen: np.ndarray, face_normals: np.ndarray | None = None, threads: int = 0
) -> np.ndarray:
    """(P, FOOTPRINT_TRIANGLES - 1) int32: for each chosen pair's texel (`chosen`, sorted by
    texel as `raster.choose_per_texel` returns them) the other triangles overlapping it, largest
    overlap first (ties: lowest index), -1 where there are fewer. All lie in the texel's own
    chart: charts never share a texel. `face_normals` (T, 3) unit (0 for degenerate triangles):
    if given, only triangles within FOOTPRINT_MIN_COS of the texel's own triangle count.
    `raster_kernels.other_triangles` (one pass over the pairs, compiled) on `threads` workers
    (0 = every core), each over its own range of texels: the result does not depend on it."""
    m = FOOTPRINT_TRIANGLES - 1
    out = np.full((len(chosen), m), -1, np.int32)
    if len(chosen) == 0 or m == 0:
        return out
    chosen = np.asarray(chosen, np.int64)
    best = np.zeros(out.shape)  # the areas of out's triangles
    ranks, _ = raster.texel_ranks(cov.texel)  # an almost empty atlas: the covered texels' ranks
    point = np.zeros(int(ranks[chosen[-1]]) + 1, np.int32)  # sorted by texel: the last is the largest
    use_normals = face_normals is not None
    normals = np.asarray(face_normals, np.float64) if use_normals else np.zeros((1, 3))
    kernel = raster_kernels.get().other_triangles
    workers = parallel.resolve_threads(threads)
    bounds = [len(chosen) * k // workers for k in range(workers + 1)]

    def work(k: int) -> None:
        texel, triangle, area = ranks, cov.triangle, cov.area
        kernel(
            texel, triangle, area, chosen, normals, use_normals, FOOTPRINT_MIN_COS, point, out, best, *bounds[k : k + 2]
        )

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(work, range(workers)))
    return out


def _face_normals(positions: np.ndarray) -> np.ndarray:
    """(T, 3) unit face normals of triangles `positions` (T, 3, 3) (counter-clockwise), 0 where
    a triangle has no area."""
    n = np.cross(positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _fill_points(points: BakePoints, surface: SurfaceTriangles, rows: slice, centroid: np.ndarray) -> None:
    """Position, n_v, face normal, albedo and texel size of the texels `rows` (a slice), whose
    overlap centroids (texel space) are `centroid`."""
    tri = points.triangle[rows]
    bary = np.empty((len(tri), 3))
    mesh = points.mesh
    # barycentric coordinates clamped to the triangle, position, n_v (normalised; a vertex normal
    # of zero length, degenerate input, falls back to the face normal), face normal on n_v's
    # side, texel size: `raster_kernels.fill_points`, the numpy arithmetic compiled, written
    # straight into the rows (`rows` is a slice: views, no copies)
    raster_kernels.get().fill_points(
        tri,
        np.asarray(centroid, np.float64),
        mesh.texel_uv,
        mesh.positions,
        mesh.normals,
        points.position[rows],
        points.normal[rows],
        points.face_normal[rows],
        points.texel_size[rows],
        bary,
    )
    if points.albedo is not None:
        points.albedo[rows] = _albedo(surface, tri, bary)


def _barycentric_grouped(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of k points per triangle: p (n, k, 2), tri (n, 3, 2) ->
    (n, k, 3), not clamped (a point outside the triangle has a negative coordinate)."""
    a = tri[:, None, 0]
    v0, v1, v2 = tri[:, None, 1] - a, tri[:, None, 2] - a, p - a
    den = v0[..., 0] * v1[..., 1] - v1[..., 0] * v0[..., 1]
    den = np.where(den == 0.0, 1.0, den)
    w1 = (v2[..., 0] * v1[..., 1] - v1[..., 0] * v2[..., 1]) / den
    w2 = (v0[..., 0] * v2[..., 1] - v2[..., 0] * v0[..., 1]) / den
    return np.stack([1.0 - w1 - w2, w1, w2], axis=-1)


def _albedo(surface: SurfaceTriangles, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    albedo = np.asarray(surface.albedo)[tri].astype(np.float64)  # gather first: called per chunk
    if surface.texture_index is None or not surface.textures:
        return albedo
    tex_index = np.asarray(surface.texture_index)[tri]
    uv = np.einsum("pk,pki->pi", bary, np.asarray(surface.texture_uv)[tri].astype(np.float64))
    for k, image in enumerate(surface.textures):
        rows = np.nonzero(tex_index == k)[0]
        if len(rows):
            albedo[rows] = image.sample(uv[rows])
    return albedo
