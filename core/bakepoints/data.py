"""The bake points' data: the triangles that receive a lightmap (`SurfaceTriangles`), and per
covered texel one bake point (`BakePoints`, its receiving triangles `SurfaceMesh`), with the
footprint sampling of ray origins the tracer calls. No bpy.

Arrays are compact over covered texels (P of them); `texel` maps them back into the
width × height image (flat index y · width + x, y = v · height). The receiving triangles
themselves (T of them) are `BakePoints.mesh` (`SurfaceMesh`). Bake points are plain numpy data:
they pickle, and hold no live object (the cover probe `build` flags texels with is shared with
the tracer through `covers.shared_probe`, not through them).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from .. import raster_kernels
from . import kernels

#: Tries at a sample point inside the texel's triangle, in the footprint and then in the whole
#: texel, before the sample falls back to the bake point (Cycles tries 10 times).
JITTER_TRIES = 10
#: Width of the square around the texel centre that a texel's samples cover, in texels: the
#: whole texel, the box the texel stands for, which is also what Cycles' Diffuse bake averages
#: from Blender 5.2.1 on (up to 5.2.0 its UV differentials were halved and it averaged the
#: central ½ × ½). Matching Cycles is what makes shadow-edge texels agree with it.
FOOTPRINT = 1.0


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
    near_cover (P,) bool (part of the texel may lie under a coplanar face: core.bakepoints.covers);
    crossed (P,) bool (geometry crosses the texel's footprint: `settle`; the tracer keeps only
    the samples the bake point sees; None when built without occluders); offset: ray origin offset, scene units; texel_size (P,)
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

    #: The per-texel arrays only tracing reads (those `for_files` empties).
    TRACING_ONLY: ClassVar[tuple[str, ...]] = (
        "position",
        "face_normal",
        "albedo",
        "texel_size",
        "triangle",
        "near_cover",
        "crossed",
        "others",
    )

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
        chosen one and `others` (`kernels.footprint_origins`; without `others`, the chosen one
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
        return kernels.get().footprint_origins(
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
