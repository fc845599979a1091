"""Lightmap texels turned into bake points. No bpy.

For every texel any triangle overlaps (`raster`), one bake point: the world position at the
overlap's centroid, the interpolated and normalised vertex normal n_v (the hemisphere the bake
integrates over), the face normal (oriented to n_v's side, used to offset ray origins), the
albedo there, and the texel's coverage. When several triangles overlap one texel the largest
overlap wins (ties: the lowest triangle index), so the choice is deterministic.

Arrays are compact over covered texels (P of them); `texel` maps them back into the
width × height image (flat index y · width + x, y = v · height). The receiving triangles
themselves (T of them) are `BakePoints.mesh` (`SurfaceMesh`). Bake points are plain numpy data:
they pickle, and hold no live object (the cover probe `build` flags texels with is shared with
the tracer through `covers.shared_probe`, not through them).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from . import bakepoint_kernels, covers, parallel, raster, raster_kernels
from .covers import CoverProbe
from .errors import BakeError
from .rays import RayScene, ray_offset

#: Fraction of a texel's short probe rays that must hit back faces for it to count as buried
#: (its hemisphere is closed by geometry, e.g. a wall pushed into the floor).
BURIED_FRACTION = 0.5
#: Tries at a sample point inside the texel's triangle, in the footprint and then in the whole
#: texel, before the sample falls back to the bake point (Cycles tries 10 times).
JITTER_TRIES = 10
#: Width of the square around the texel centre that a texel's samples cover, in texels: the
#: whole texel, the box the texel stands for, which is also what Cycles' Diffuse bake averages
#: from Blender 5.2.1 on (up to 5.2.0 its UV differentials were halved and it averaged the
#: central ½ × ½). Matching Cycles is what makes shadow-edge texels agree with it.
FOOTPRINT = 1.0
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
#: Probe directions per texel for the buried test (fixed, rotated per texel).
BURIED_PROBES = 12
#: Move bake points out from under back faces and keep every texel's samples on the side of
#: any geometry crossing its footprint where its bake point lies (`settle`; the tracer drops
#: samples hidden from the bake point). Off: the texel averages its whole footprint, as
#: Cycles does, both sides of a wall standing on it included.
SETTLE = True
#: How far past a back face a bake point is moved, in ray offsets (measured square to the face).
SETTLE_CLEARANCE = 4.0
#: Reach of the spoke opposite a back-face hit, in texels: a bake point is inside a solid (and
#: moved out of it) when back faces lie on both sides within this reach, or when a coplanar face
#: covers it (core.covers). A lone back face is not enough: a room whose walls face outwards
#: shows its inside nothing but back faces, and its floor must not be moved through them.
SETTLE_THICKNESS = 8.0
#: Footprint points, in texel units from the texel's corner, that `settle` casts its spokes to
#: from the bake point: the footprint's corners and the middles of its sides.
_SPOKES = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0.5, 0], [0.5, 1], [0, 0.5], [1, 0.5]], float)


@dataclass
class SurfaceTriangles:
    """Triangles that receive a lightmap, all in one atlas.

    positions (T, 3, 3) world space, metres;  normals (T, 3, 3) vertex normals, world space;
    uv (T, 3, 2) lightmap UVs in [0, 1]²;  object_index (T,) int;  albedo (T, 3) constant
    albedo per triangle (linear RGB); optional textures: texture_index (T,) int (-1: constant),
    texture_uv (T, 3, 2) the material's own UVs, textures [core.textures.Texture]; polygon (T,)
    int, optional: the mesh polygon each triangle comes from (messages count faces by it).
    """

    positions: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    object_index: np.ndarray
    albedo: np.ndarray
    texture_index: np.ndarray | None = None
    texture_uv: np.ndarray | None = None
    textures: list = field(default_factory=list)
    polygon: np.ndarray | None = None


@dataclass
class SurfaceMesh:
    """The receiving triangles of one atlas (T of them), indexed by `BakePoints.triangle`.

    positions (T, 3, 3) float64 world space, metres; texel_uv (T, 3, 2) float64 lightmap UVs in
    texel units (u · width, v · height); normals (T, 3, 3) float64 vertex normals, world space;
    object_index (T,) int; vertex (T, 3) int64 welded corner ids: corners at exactly equal
    positions share an id (`weld`), so triangles sharing an edge in space can be found even
    where the lightmap UVs split it (a seam)."""

    positions: np.ndarray
    texel_uv: np.ndarray
    normals: np.ndarray
    object_index: np.ndarray
    vertex: np.ndarray

    @classmethod
    def from_surface(cls, surface: SurfaceTriangles, width: int, height: int) -> SurfaceMesh:
        positions = np.asarray(surface.positions, dtype=np.float64)
        return cls(
            positions=positions,
            texel_uv=np.asarray(surface.uv, dtype=np.float64) * [width, height],
            normals=np.asarray(surface.normals, dtype=np.float64),
            object_index=np.asarray(surface.object_index),
            vertex=weld(positions),
        )


def weld(positions: np.ndarray) -> np.ndarray:
    """Ids (T, 3) int64 of the corners of triangles `positions (T, 3, 3)`: equal for corners at
    exactly equal positions (0.0 and -0.0 alike), distinct otherwise; ids count up in the order
    of a hash of the position (deterministic). Sorted by a 64-bit hash of each corner's bits
    (one sort of T·3 keys); corners whose hashes collide but whose positions differ make it
    fall back to a lexicographic sort of the coordinates."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3) + 0.0  # -0.0 -> 0.0
    if len(p) == 0:
        return np.zeros((0, 3), np.int64)
    bits = p.view(np.uint64)
    key = bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)
    key ^= bits[:, 1] * np.uint64(0xBF58476D1CE4E5B9)
    key ^= bits[:, 2] * np.uint64(0x94D049BB133111EB)
    key ^= key >> np.uint64(31)
    order = np.argsort(key)
    same = key[order][1:] == key[order][:-1]
    ordered = np.take(p, order, axis=0)
    if (same & (ordered[1:] != ordered[:-1]).any(axis=1)).any():  # a collision: sort the values
        order = np.lexsort(p.T[::-1])
        ordered = np.take(p, order, axis=0)
        same = (ordered[1:] == ordered[:-1]).all(axis=1)
    ids = np.empty(len(p), np.int64)
    ids[order] = np.concatenate([[0], np.cumsum(~same)])
    return ids.reshape(-1, 3)


@dataclass
class BakePoints:
    """position, normal (n_v), face_normal, albedo: (P, 3) float64 (albedo None when `build` was
    asked for none); coverage (P,) in (0, 1]; texel, triangle, object_index (P,) int (int32 from
    `build`, int64 past 2³¹); buried (P,) bool (invalid: the hemisphere is closed
    by geometry, or the bake point stays under a coplanar face);
    near_cover (P,) bool (part of the texel may lie under a coplanar face: core.covers);
    crossed (P,) bool (geometry crosses the texel's footprint: `settle`; the tracer keeps only
    the samples the bake point sees; None when not settled); offset: ray origin offset, scene units; texel_size (P,)
    world size of a texel, metres; mesh: the receiving triangles `triangle` indexes (`SurfaceMesh`)."""

    width: int
    height: int
    texel: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    face_normal: np.ndarray
    albedo: np.ndarray | None
    coverage: np.ndarray
    triangle: np.ndarray
    object_index: np.ndarray
    texel_size: np.ndarray
    offset: float
    buried: np.ndarray
    mesh: SurfaceMesh
    near_cover: np.ndarray
    crossed: np.ndarray | None = None
    #: (P, FOOTPRINT_TRIANGLES - 1) int32: the other triangles overlapping each texel, largest
    #: overlap first (-1: none), whose parts of the footprint its samples cover too (None: only
    #: the texel's own triangle, as before)
    others: np.ndarray | None = None

    def for_files(self) -> BakePoints:
        """These bake points as an atlas's files take them once it is traced (`tracer.bake(...,
        compact=True)`): texel, normal, coverage, buried, object_index, mesh and the sizes, the
        same arrays (no copy); the arrays only tracing reads (position, face normal, albedo,
        texel size, triangle, near cover, crossed, others) empty (no rows). Memory: 41 bytes a
        texel of the 139 of `build`'s (115 without albedo), once the caller drops the full ones."""
        return replace(
            self,
            position=_none_of(self.position),
            face_normal=_none_of(self.face_normal),
            albedo=None if self.albedo is None else _none_of(self.albedo),
            texel_size=_none_of(self.texel_size),
            triangle=_none_of(self.triangle),
            near_cover=_none_of(self.near_cover),
            crossed=None if self.crossed is None else _none_of(self.crossed),
            others=None if self.others is None else _none_of(self.others),
        )

    def origins(self, rows=slice(None)) -> np.ndarray:
        """Ray origins `(P, 3)` (of the texels `rows`, if given): positions pushed off the
        surface along the face normal."""
        return self.position[rows] + self.face_normal[rows] * self.offset

    def sample_origins(
        self,
        rng: np.random.Generator,
        idx: np.ndarray,
        k: int,
        footprint: float | None = None,
        first: int | None = None,
        seed: int = 0,
    ) -> np.ndarray:
        """k ray origins `(len(idx)·k, 3)` per texel, uniform over the part of the texel's
        footprint (`footprint` texels wide, default FOOTPRINT) covered by its triangles: its
        chosen one and `others` (`bakepoint_kernels.footprint_origins`; without `others`, the chosen one
        alone, as Cycles bakes a texel): rejection sampling,
        JITTER_TRIES tries, then as many over the whole texel, then the bake point (the centroid
        of texel ∩ triangle); offset along the face normal. A texel's first tries cover the
        footprint evenly: a randomly shifted Hammersley set per call, or, given the pass's
        first sample index `first` (pass × k) and the bake's `seed`, the texel's own scrambled
        (0,2)-sequence, stratified across all its passes."""
        tri = self.triangle[idx]
        corner = np.stack([self.texel[idx] % self.width, self.texel[idx] // self.width], 1).astype(np.float64)
        if self.others is None:  # the texel's own triangle alone
            tris, count = tri[:, None], np.ones(len(tri), np.int64)
        else:  # the whole footprint, over every triangle of the texel
            tris = np.concatenate([tri[:, None], self.others[idx]], axis=1)
            count = 1 + (tris[:, 1:] >= 0).sum(axis=1)
            tris = np.maximum(tris, 0)
        return bakepoint_kernels.get().footprint_origins(
            corner,
            self.mesh.texel_uv[tris],
            self.mesh.positions[tris],
            count,
            self.position[idx],
            self.face_normal[idx],
            self.offset,
            k,
            FOOTPRINT if footprint is None else footprint,
            JITTER_TRIES,
            int(rng.integers(1 << 63)),
            self.texel[idx].astype(np.int64) if first is not None else np.zeros(0, np.int64),  # keyed by atlas texel
            0 if first is None else first,
            seed,
        )

    def texel_points(self, idx: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Ray origins `(len(idx), k, 3)` at `offsets` (k, 2) texel units from each texel's corner,
        clamped into the texel's triangle."""
        idx = np.asarray(idx)
        idx = np.flatnonzero(idx) if idx.dtype == bool else idx.astype(np.int64, copy=False)
        return raster_kernels.get().texel_points(  # numpy's arithmetic, compiled (identical floats)
            self.texel,
            self.triangle,
            self.width,
            self.mesh.texel_uv,
            self.mesh.positions,
            self.face_normal,
            self.offset,
            idx,
            np.asarray(offsets, dtype=np.float64).reshape(-1, 2),
        )

    def image(self, values: np.ndarray, fill=0.0, dtype=np.float64) -> np.ndarray:
        """Scatter per-point values `(P, ...)` into a `(height, width, ...)` image of `dtype`."""
        values = np.asarray(values)
        out = np.full((self.height * self.width,) + values.shape[1:], fill, dtype=dtype)
        out[self.texel] = values
        return out.reshape((self.height, self.width) + values.shape[1:])


def _none_of(a: np.ndarray) -> np.ndarray:
    """An empty array (no rows) of `a`'s dtype and row shape."""
    return np.empty((0,) + a.shape[1:], a.dtype)


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
    receivers included) enables the buried-texel test; without it nothing is flagged.
    `check()`, if given, is called between chunks of work (it raises to stop: a cancel).
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
    mesh = SurfaceMesh.from_surface(surface, width, height)
    cov = raster.rasterise(uv, width, height, check, threads)
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

    _for_chunks(fill_chunk, n, chunk, check, threads)
    if occluders is not None:
        probe = covers.shared_probe(occluders, points.offset, mesh.positions)
        if SETTLE:  # else `crossed` stays None: the tracer averages whole footprints
            points.crossed = settle(points, occluders, probe, check=check, threads=threads)
        points.buried = find_buried(points, occluders, check=check, threads=threads)
        points.near_cover = find_near_cover(points, probe, check=check, threads=threads)
        if SETTLE:  # a bake point still under a coplanar face: the whole texel is hidden
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


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates `(P, 3)` of 2D points in 2D triangles `(P, 3, 2)`, clamped to
    the triangle (the centroid is inside up to rounding)."""
    bary = np.clip(_barycentric_grouped(p[:, None, :], tri)[:, 0], 0.0, 1.0)
    return bary / bary.sum(axis=1, keepdims=True)


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


def _normalise(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=1, keepdims=True)


def _texel_world_size(pos: np.ndarray, texel_uv: np.ndarray) -> np.ndarray:
    """World-space edge length of one texel on each triangle `pos (n, 3, 3)` whose UVs in texel
    units are `texel_uv (n, 3, 2)`: √(world area / texel area)."""
    world = 0.5 * np.linalg.norm(np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0]), axis=1)
    t = texel_uv
    texels = 0.5 * np.abs(
        (t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1]) - (t[:, 2, 0] - t[:, 0, 0]) * (t[:, 1, 1] - t[:, 0, 1])
    )
    return np.sqrt(world / np.maximum(texels, 1e-12))


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


def find_near_cover(
    points: BakePoints, probe: CoverProbe, check=None, chunk: int = 1 << 15, threads: int = 0
) -> np.ndarray:
    """Texels part of whose samples may start under a coplanar face (core.covers): the bake point,
    the footprint's corners and the texel's corners (where the samples' fallback can reach),
    mapped into the texel's triangle, are probed (each distinct ray once: neighbouring texels on
    one triangle share their corners, `raster_kernels.cover_rays`). The tracer probes every sample
    of the texels flagged here, so the flag only has to be conservative at the scale of a texel.
    (P,) bool."""
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    offsets = np.concatenate([0.5 + FOOTPRINT * (corners - 0.5), corners])  # texel units from its corner
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
    """work(rows) for consecutive slices of range(n), `chunk` long, on `threads` workers (0 = every
    core; Embree releases the GIL); `check()` before each chunk's result is taken (it raises to
    stop: the chunks not started are dropped). Each chunk writes only its own rows, so the result
    does not depend on the thread count."""
    with ThreadPoolExecutor(max_workers=parallel.resolve_threads(threads)) as pool:
        futures = [pool.submit(work, slice(s, min(s + chunk, n))) for s in range(0, n, chunk)]
        try:
            for future in futures:
                if check is not None:
                    check()
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
        target = _spoke_targets(points, idx, _SPOKES * FOOTPRINT + 0.5 * (1.0 - FOOTPRINT))
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
    from .sh import tangent_frames

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
