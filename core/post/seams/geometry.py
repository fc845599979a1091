"""Seam sample pairs: the smooth seams of an atlas's mesh (`find_seams`) and their samples on
both sides (`Seams`, saved as the atlas's seams file). No bpy. Conventions: the package's docstring."""

from __future__ import annotations

import io
import os
import zipfile
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ...bakepoints import SurfaceMesh

#: Two corners' vertex normals are "equal" (the edge is smooth) within this angle, radians: split
#: normals of a smooth edge agree to rounding, a hard edge differs by tens of degrees.
NORMAL_TOLERANCE = np.radians(2.0)
#: Two sides' UVs are "equal" (not a seam) within this distance, texels.
UV_TOLERANCE = 1e-3
#: The date of every entry of a seams file (`Seams.save`): fixed, so the file is deterministic.
ZIP_DATE = (1980, 1, 1, 0, 0, 0)


@dataclass
class Seams:
    """Seam sample pairs of one atlas (S samples on E seam edges).

    a, b (S, 2) float64: the sample's position on the two sides, lightmap texel units (x = u·W,
    y = v·H; texel (i, j) covers [i, i+1] × [j, j+1]); weight (S,) float64: world length (metres)
    the sample stands for; normal (S, 3) float64: interpolated unit vertex normal there (equal on
    both sides); edge (S,) int64: id (0 … E-1) of the seam edge it lies on; width, height: atlas
    size. Added for the metric and the solver: position (S, 3) world point of the sample, metres;
    tangent (S, 3) unit direction of its 3D edge; inward_a, inward_b (S, 2) unit texel-space
    direction into the sample's triangle on each side, perpendicular to the edge (0 for an edge
    of no length in UV); span (S,) texels of edge the sample stands for (the longer side's)."""

    a: np.ndarray
    b: np.ndarray
    weight: np.ndarray
    normal: np.ndarray
    edge: np.ndarray
    width: int
    height: int
    position: np.ndarray
    tangent: np.ndarray
    inward_a: np.ndarray
    inward_b: np.ndarray
    span: np.ndarray

    def __len__(self) -> int:
        return len(self.weight)

    @property
    def edges(self) -> int:
        """Number of seam edges (E)."""
        return int(self.edge.max()) + 1 if len(self.edge) else 0

    def save(self, path) -> None:
        """Write to a compressed .npz file at `path` (a path, ".npz" appended as numpy does, or a
        binary file), byte for byte the same for the same seams: the zip entries carry a fixed
        date (`np.savez_compressed` stamps them with the time of writing)."""
        if isinstance(path, (str, os.PathLike)) and not os.fspath(path).endswith(".npz"):
            path = os.fspath(path) + ".npz"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            for f in fields(self):
                buffer = io.BytesIO()
                np.lib.format.write_array(buffer, np.asarray(getattr(self, f.name)), allow_pickle=False)
                info = zipfile.ZipInfo(f"{f.name}.npy", date_time=ZIP_DATE)
                info.compress_type, info.create_system, info.external_attr = zipfile.ZIP_DEFLATED, 3, 0o644 << 16
                z.writestr(info, buffer.getvalue())

    @classmethod
    def load(cls, path) -> Seams:
        """Read what `save` wrote."""
        with np.load(path) as z:
            values = {f.name: z[f.name] for f in fields(cls)}
        values["width"], values["height"] = int(values["width"]), int(values["height"])
        return cls(**values)

    def select(self, keep: np.ndarray) -> Seams:
        """The samples `keep` `(S,)` bool (edge ids unchanged)."""
        return replace(
            self, **{f.name: getattr(self, f.name)[keep] for f in fields(self) if f.name not in ("width", "height")}
        )

    def within(self, window) -> Seams:
        """These seams on the images of `window` (`stages.Window`, an atlas's rectangle: the
        texel images of an almost empty atlas) instead of the whole atlas's: the positions moved
        by its corner (exactly: whole texels), its size. None: these seams."""
        if window is None:
            return self
        corner = np.array([window.x0, window.y0], np.float64)
        return replace(self, a=self.a - corner, b=self.b - corner, width=int(window.w), height=int(window.h))

    @classmethod
    def empty(cls, width: int, height: int) -> Seams:
        z2, z3 = np.zeros((0, 2)), np.zeros((0, 3))
        return cls(z2, z2, np.zeros(0), z3, np.zeros(0, np.int64), width, height, z3, z3, z2, z2, np.zeros(0))


def find_seams(mesh: SurfaceMesh, width: int, height: int, samples_per_texel: float = 3.0) -> Seams:
    """The smooth seams of `mesh` (`core.bakepoints.SurfaceMesh`, UVs in texel units of a
    `width` × `height` atlas), sampled `samples_per_texel` times per texel of the longer side
    (at least once per edge, at the midpoints of equal parts). Edges are found by welded vertex
    ids (`mesh.vertex`: corners at equal positions, so also where two objects meet); an edge
    shared by more than two triangles is skipped, and so is one whose triangle has no area in UV."""
    pairs = _shared_edges(np.asarray(mesh.vertex))
    if len(pairs) == 0:
        return Seams.empty(width, height)
    t1, p1, q1, t2, p2, q2 = pairs.T
    uv = np.asarray(mesh.texel_uv, dtype=np.float64)
    nrm = _unit(np.asarray(mesh.normals, dtype=np.float64))
    pos = np.asarray(mesh.positions, dtype=np.float64)
    uv1p, uv1q, uv2p, uv2q = uv[t1, p1], uv[t1, q1], uv[t2, p2], uv[t2, q2]
    split = (np.abs(uv1p - uv2p).max(axis=1) > UV_TOLERANCE) | (np.abs(uv1q - uv2q).max(axis=1) > UV_TOLERANCE)
    cos_tol = np.cos(NORMAL_TOLERANCE)
    smooth = (np.einsum("ei,ei->e", nrm[t1, p1], nrm[t2, p2]) >= cos_tol) & (
        np.einsum("ei,ei->e", nrm[t1, q1], nrm[t2, q2]) >= cos_tol
    )
    live = (_uv_area(uv[t1]) > 0.0) & (_uv_area(uv[t2]) > 0.0)
    keep = np.flatnonzero(split & smooth & live)
    t1, p1, q1, t2, p2, q2 = (x[keep] for x in (t1, p1, q1, t2, p2, q2))
    uv1p, uv1q, uv2p, uv2q = uv1p[keep], uv1q[keep], uv2p[keep], uv2q[keep]
    texels = np.maximum(np.linalg.norm(uv1q - uv1p, axis=1), np.linalg.norm(uv2q - uv2p, axis=1))
    count = np.maximum(1, np.ceil(texels * samples_per_texel - 1e-9).astype(np.int64))
    edge = np.repeat(np.arange(len(keep), dtype=np.int64), count)
    first = np.repeat(np.cumsum(count) - count, count)
    t = ((np.arange(len(edge)) - first + 0.5) / count[edge])[:, None]
    pp, pq = pos[t1, p1], pos[t1, q1]
    normal = _unit((1 - t) * (nrm[t1, p1] + nrm[t2, p2])[edge] + t * (nrm[t1, q1] + nrm[t2, q2])[edge])
    length = np.linalg.norm(pq - pp, axis=1)
    return Seams(
        a=uv1p[edge] + t * (uv1q - uv1p)[edge],
        b=uv2p[edge] + t * (uv2q - uv2p)[edge],
        weight=(length / count)[edge],
        normal=normal,
        edge=edge,
        width=int(width),
        height=int(height),
        position=pp[edge] + t * (pq - pp)[edge],
        tangent=_unit(pq - pp)[edge],
        inward_a=_inward(uv1p, uv1q, uv[t1, 3 - p1 - q1])[edge],
        inward_b=_inward(uv2p, uv2q, uv[t2, 3 - p2 - q2])[edge],
        span=(texels / count)[edge],
    )


def _shared_edges(vertex: np.ndarray) -> np.ndarray:
    """Edges shared by exactly two triangles, `(E, 6)` int64 rows (t1, p1, q1, t2, p2, q2): the
    triangles and their corners at the edge's lower (p) and higher (q) welded vertex id, in the
    order of the edge's key (deterministic)."""
    t = np.repeat(np.arange(len(vertex), dtype=np.int64), 3)
    c0 = np.tile(np.arange(3, dtype=np.int64), len(vertex))
    c1 = (c0 + 1) % 3
    v0, v1 = vertex[t, c0].astype(np.int64), vertex[t, c1].astype(np.int64)
    good = v0 != v1
    t, c0, c1, v0, v1 = t[good], c0[good], c1[good], v0[good], v1[good]
    swap = v0 > v1
    p, q = np.where(swap, c1, c0), np.where(swap, c0, c1)
    key = np.minimum(v0, v1) * (int(vertex.max(initial=0)) + 1) + np.maximum(v0, v1)
    order = np.argsort(key, kind="stable")
    key = key[order]
    start = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
    size = np.diff(np.concatenate([start, [len(key)]]))
    two = start[size == 2]
    i, j = order[two], order[two + 1]
    return np.stack([t[i], p[i], q[i], t[j], p[j], q[j]], axis=1)


def _unit(v: np.ndarray) -> np.ndarray:
    """v / |v| along the last axis; zero vectors stay zero."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0.0, n, 1.0)


def _uv_area(tri: np.ndarray) -> np.ndarray:
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _inward(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Unit texel-space directions `(E, 2)` from edge p→q towards the opposite corner r,
    perpendicular to the edge (towards r itself where the edge has no length)."""
    e, to_r = q - p, r - p
    ee = np.einsum("ei,ei->e", e, e)
    along = np.where(ee > 0.0, np.einsum("ei,ei->e", to_r, e) / np.where(ee > 0.0, ee, 1.0), 0.0)
    return _unit(to_r - along[:, None] * e)
