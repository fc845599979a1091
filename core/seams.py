"""Lightmap seams: where a smooth surface crosses from one chart to another. No bpy.

A *seam* is a 3D edge shared by two triangles whose lightmap UVs differ on it and whose vertex
normals agree at both ends (a smooth edge cut by the unwrap); a hard edge (different normals)
or an edge with the same UVs on both sides is not one. Along a seam the two charts hold their
own texels, so the bilinear reads on the two sides of one 3D point differ: a visible line.

  find_seams   sample pairs along every seam (`Seams`: positions on both sides, texel units)
  bilinear     the GPU's bilinear read (texel centres at i + ½, clamp to edge)
  seam_metric  how visible the seams are, read as the preview reads the lightmap (radiance SH,
               or the encoded HHD/AHD images), against the texel-to-texel step inside the charts
  stitch       least-squares seam stitching of the SH (Sylvan 2015, "Fixing texture seams with
               linear least-squares"), a post stage: the texels the seam samples read are moved
               so both sides read alike, each pulled towards its baked value (covered texels
               firmly, gutter texels weakly, from their dilated value); one sparse system, 27
               right-hand sides, Jacobi-preconditioned CG; the result bounded to a plausible
               radiance (L0, I_z ≥ 0, within the range of the texels it is tied to). Stitched
               gutter and buried texels are handed to the encoder as sources of their own
               (`TexelData.extra_sources`), so dilation does not overwrite them. Seams into a
               surface inside closed geometry (buried texels left black) are hidden: neither
               measured nor stitched (`hidden_texels`, `reads_hidden`).
  stitch_encoded  the same on an HHD/AHD atlas's encoded layers (I_z, w_a, packed direction),
               after encoding: the encoding is not linear in the SH, so a stitched SH seam
               reopens a little in the preview; this closes it as the preview reads it.

Texel space (as `core.raster`): x = u · W, y = v · H; texel (i, j) covers [i, i+1] × [j, j+1],
its centre is (i + ½, j + ½); images are `(H, W, ...)` with rows bottom-up, row index floor(y).
Unlike ands/seamoptimizer, reads use exactly this convention (no half-texel offset), an edge
shorter than a texel still gets one sample (no division by its length: no NaN), and an edge
whose two sides share their UVs is not a seam.
"""

from __future__ import annotations

import io
import os
import time
import zipfile
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from . import parallel
from .colour import LUMINANCE
from .progress import Tick, ticker

if TYPE_CHECKING:
    from .bakepoints import SurfaceMesh
    from .encoding import EncodedAtlas, TexelData

#: Two corners' vertex normals are "equal" (the edge is smooth) within this angle, radians: split
#: normals of a smooth edge agree to rounding, a hard edge differs by tens of degrees.
NORMAL_TOLERANCE = np.radians(2.0)
#: Two sides' UVs are "equal" (not a seam) within this distance, texels.
UV_TOLERANCE = 1e-3
#: Relative errors divide by max(mean luminance of the two reads, REL_FLOOR × the mean over all
#: samples): near-black samples, whose relative noise nobody can see, do not dominate.
REL_FLOOR = 0.1
#: Normals tilted by this angle (towards ± the edge and ± across it) show directional seams.
TILT = np.radians(30.0)
#: Least-squares weights: each seam sample's equation per texel of edge it stands for, and the
#: pull of a covered texel and of a gutter texel towards its value (a gutter texel is free to take
#: what the seam needs; a covered texel moves only where no gutter texel can close the seam).
SEAM_WEIGHT = 50.0
COVERED_WEIGHT = 1.0
GUTTER_WEIGHT = 0.1
#: Conjugate gradient: stop when every channel's residual is below CG_TOLERANCE of its
#: right-hand side, or after CG_MAX_ITERATIONS.
CG_TOLERANCE = 1e-3
CG_MAX_ITERATIONS = 2000
#: `stitch_encoded` stitches the packed direction only where its two sides' reads differ by at
#: most this much (each coordinate): farther apart, the two reads straddle the octahedral fold.
FOLD_GAP = 0.25
#: The stitched SH's bound (`_bounded`) reaches this fraction of the tied texels' spread beyond
#: them on either side: a gutter texel half a texel past the chart's edge extends a gradient.
BOUND_SLACK = 0.5
#: A stitched texel's I_z that rounding takes below 0 is lifted to this fraction of the size of
#: its L0 and band 1 (`_bounded`): far above float32 rounding, so it is ≥ 0 as stored.
IZ_MARGIN = 1e-4
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


# ---------------------------------------------------------------------------------------------
# finding seams


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


# ---------------------------------------------------------------------------------------------
# reading the lightmap as the GPU does


def bilinear_taps(xy: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The four texels a bilinear read at `xy (S, 2)` (texel units) takes and their weights:
    flat indices `(S, 4)` int64 (row · width + column) and weights `(S, 4)` float64 summing to 1.
    Texel centres at i + ½, clamp to edge (indices clamped into the image)."""
    f = np.asarray(xy, dtype=np.float64) - 0.5
    base = np.floor(f)
    fx, fy = (f - base).T
    i0 = base[:, 0].astype(np.int64)
    j0 = base[:, 1].astype(np.int64)
    xs = np.clip(np.stack([i0, i0 + 1], 1), 0, width - 1)
    ys = np.clip(np.stack([j0, j0 + 1], 1), 0, height - 1)
    index = np.stack(
        [
            ys[:, 0] * width + xs[:, 0],
            ys[:, 0] * width + xs[:, 1],
            ys[:, 1] * width + xs[:, 0],
            ys[:, 1] * width + xs[:, 1],
        ],
        1,
    )
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return index, weight


def bilinear(image, xy: np.ndarray) -> np.ndarray:
    """GPU bilinear read of `image (H, W, ...)` (an array, or `FilledRows` of one) at texel-unit
    points `xy (S, 2)` -> `(S, ...)` float64 (texel centres at i + ½, clamp to edge; see
    `bilinear_taps`)."""
    flat: Any
    if isinstance(image, (FilledRows, _Stacked)):
        (h, w), flat, tail = image.grid, image, image.shape[1:]
    else:
        h, w = image.shape[:2]
        tail = image.shape[2:]
        flat = np.asarray(image).reshape((h * w,) + tail)
    index, weight = bilinear_taps(xy, w, h)
    out = np.zeros((len(index),) + tail)
    for k in range(4):
        out += weight[:, k].reshape((-1,) + (1,) * len(tail)) * flat[index[:, k]]
    return out


class FilledRows:
    """The rows of `fill.apply(image, keep_black)` read on demand, without the filled copy of
    the image (memory: an atlas's SH image is its largest array; stitching reads a few of its
    texels). `flat` `(H·W, ...)`: the image's texels (a view; not written), `fill` the
    `dilate.Fill` of its atlas, `grid` (H, W). `rows[index]` (int array of any shape) gives
    exactly what the filled copy's rows would hold (the same gather, the same mean of the
    sources for texels out of the dilation's reach, the same zeros for black texels) in the
    image's dtype, `(*index.shape, ...)`; `put(index, values)` overrides rows (later reads see
    them)."""

    def __init__(self, flat: np.ndarray, fill, grid: tuple[int, int], keep_black: bool = False):
        self.flat, self.fill, self.grid, self.keep_black = flat, fill, tuple(grid), keep_black
        self.shape, self.dtype = flat.shape, flat.dtype
        self._mean: np.ndarray | None = None
        self._put_index = np.zeros(0, np.int64)
        self._put_values = np.zeros((0,) + flat.shape[1:], flat.dtype)

    def _source_mean(self) -> np.ndarray:
        """`Fill.apply`'s mean of the sources (float64 over them in order, as one `mean`), cast
        as its assignment casts it; summed a block of sources at a time (no gather of them all)."""
        if self._mean is None:
            valid = self.fill.valid
            if not len(valid):
                self._mean = np.zeros(self.flat.shape[1:], self.dtype)
            else:
                total = self.flat[valid[: 1 << 16]].astype(np.float64).sum(axis=0)
                for s in range(1 << 16, len(valid), 1 << 16):
                    part = self.flat[valid[s : s + (1 << 16)]].astype(np.float64)
                    total = np.concatenate([total[None], part]).sum(axis=0)
                self._mean = np.asarray(total / len(valid)).astype(self.dtype)
        return self._mean

    def __getitem__(self, index) -> np.ndarray:
        index = np.asarray(index)
        flat_index = index.reshape(-1).astype(np.int64, copy=False)
        empty, source = self.fill.empty, self.fill.source
        pos = np.minimum(np.searchsorted(empty, flat_index), max(len(empty) - 1, 0))
        is_empty = (empty[pos] == flat_index) if len(empty) else np.zeros(len(flat_index), bool)
        src = flat_index.copy()
        src[is_empty] = source[pos[is_empty]]
        far = src < 0
        out = self.flat[np.where(far, 0, src)]
        if far.any():
            out[far] = self._source_mean()
        if self.keep_black and len(self.fill.black):
            black = self.fill.black
            at = np.minimum(np.searchsorted(black, flat_index), len(black) - 1)
            out[black[at] == flat_index] = 0.0
        if len(self._put_index):
            at = np.minimum(np.searchsorted(self._put_index, flat_index), len(self._put_index) - 1)
            hit = self._put_index[at] == flat_index
            out[hit] = self._put_values[at[hit]]
        return out.reshape(index.shape + self.flat.shape[1:])

    def put(self, index: np.ndarray, values: np.ndarray) -> None:
        """Rows `index` (unique flat indices) read `values` `(len(index), ...)` from now on."""
        order = np.argsort(index, kind="stable")
        self._put_index = np.asarray(index, np.int64)[order]
        self._put_values = np.asarray(values, self.dtype).reshape((len(index),) + self.flat.shape[1:])[order]


#: A way of reading a lightmap: points `xy (S, 2)` (texel units) -> a function of the unit vertex
#: normal `n_v (S, 3)` and shading normal `n (S, 3)` there giving irradiance `(S, 3)`
#: (docs/conventions.md#irradiance-units). The filtered texels are read once per set of points, the
#: normals applied after.
Reader = Callable[[np.ndarray], Callable[[np.ndarray, np.ndarray], np.ndarray]]


def sh_reader(sh_image: np.ndarray | FilledRows) -> Reader:
    """Irradiance read from a radiance SH image `(H, W, 9, 3)` (already filled, or `FilledRows`
    of one: `(H·W, 9, 3)` rows filled as they are read), as the L2
    preview does: bilinear SH, bands × 1, 2/3, 1/4, evaluated at n."""
    from . import sh as _sh

    def read(xy):
        irradiance_sh = _sh.convolve_cosine(bilinear(sh_image, xy))
        return lambda n_v, n: np.einsum("sk,skc->sc", _sh.evaluate(n), irradiance_sh)

    return read


def hhd_reader(images: Mapping[str, np.ndarray], model: str = "hhd") -> Reader:
    """Irradiance read from an HHD/AHD file's channel images {EXR name: `(H, W)`} (Iz.R/G/B,
    Wa.V or Wa.R/G/B, Direction.X/Y) as the preview's node group does (shaders/node_groups.py):
    each layer bilinear, the octahedral direction decoded per texel before filtering and
    renormalised after (filtering the encoded pair across the map's fold turns it: docs/format.md,
    "Filtering the direction"), d·n_v floored at core.hhd.MIN_COS,
    I = I_z [w_a (1 + n·n_v)/2 + (1 − w_a) max(n·d, 0)/(d·n_v)] (AHD: w_a + …)."""
    from .hhd import MIN_COS

    wa_names = [k for k in ("Wa.R", "Wa.G", "Wa.B") if k in images] or ["Wa.V"]
    plain = _Stacked([images[k] for k in ["Iz.R", "Iz.G", "Iz.B", *wa_names]])
    packed = _Stacked([images["Direction.X"], images["Direction.Y"]], np.float64)
    # the layers at the texels a read takes (memory: no image of all the atlas's decoded layers)
    layers = _Stacked(
        [],
        grid=plain.grid,
        width=plain.shape[1] + 3,
        rows=lambda i: np.concatenate([plain[i], _decoded(packed[i])], -1),
    )
    hhd = model.lower() == "hhd"

    def read(xy):
        values = bilinear(layers, xy)
        iz, wa, d = values[:, :3], values[:, 3:-3], values[:, -3:]
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)

        def at(n_v, n):
            cos_nv = np.einsum("si,si->s", n, n_v)[:, None]
            dnv = np.maximum(np.einsum("si,si->s", d, n_v), MIN_COS)[:, None]
            lobe = np.maximum(np.einsum("si,si->s", n, d), 0.0)[:, None] / dnv
            ambient = (1.0 + cos_nv) * 0.5 if hhd else 1.0
            return iz * (wa * ambient + (1.0 - wa) * lobe)

        return at

    return read


def _decoded(packed: np.ndarray) -> np.ndarray:
    """`octahedral.decode` of packed directions `(..., 2)` -> `(..., 3)`."""
    from . import octahedral

    return octahedral.decode(packed.reshape(-1, 2)).reshape(packed.shape[:-1] + (3,))


class _Stacked:
    """The rows of `np.stack([image.reshape(-1) for image in images], -1)` (in `dtype`, default
    the stack's) read on demand, `[index]` -> `(*index.shape, len(images))`, without stacking the
    atlas's images (memory). Or, with `rows` (a function of a flat index array) and `width`, the
    rows that gives. `grid`: the images' (H, W)."""

    def __init__(self, images, dtype=None, grid=None, width: int = 0, rows=None):
        self.images = [np.asarray(image) for image in images]  # (H, W), views of a layer's image: not copied
        self.grid = tuple(grid) if grid is not None else self.images[0].shape[:2]
        if rows is None:
            self.dtype = np.result_type(*self.images) if dtype is None else np.dtype(dtype)
            width = len(self.images)
        self.rows = rows
        self.shape = (self.grid[0] * self.grid[1], width)

    def __getitem__(self, index) -> np.ndarray:
        index = np.asarray(index)
        if self.rows is not None:
            flat = index.reshape(-1)
            return self.rows(flat).reshape(index.shape + (self.shape[1],))
        at = np.divmod(index, self.grid[1])  # (row, column): a strided image is gathered, not flattened
        out = np.stack([image[at] for image in self.images], -1)
        return out.astype(self.dtype, copy=False)


def reader_for(source) -> Reader:
    """The Reader of `source`: `encoding.TexelData` (its SH filled as the SH file is),
    `encoding.EncodedAtlas` (its encoding's file), a mapping of HHD channel images, or a radiance
    SH image `(H, W, 9, 3)`."""
    from .encoding import EncodedAtlas, TexelData

    if isinstance(source, TexelData):
        return sh_reader(source.fill().apply(source.sh, keep_black=True))
    if isinstance(source, EncodedAtlas):
        return hhd_reader(encoded_images(source), source.settings.get("model", "hhd"))
    if isinstance(source, Mapping):
        return hhd_reader(source)
    return sh_reader(np.asarray(source))


def hidden_texels(coverage: np.ndarray) -> np.ndarray:
    """The texels no one sees, `(H·W,)` bool of `coverage (H, W)` (0 outside charts, -1 buried):
    buried texels with no covered texel of their own chart to take a value from, which the
    encoder leaves black (`TexelData.fill`): a surface inside closed geometry. A seam sample
    that reads one is hidden (`reads_hidden`): its black side is not a seam anyone sees, and
    stitching towards it would darken the side in the open."""
    from .dilate import Fill

    cov = np.asarray(coverage)
    out = np.zeros(cov.size, bool)
    if (cov < 0.0).any():
        out[Fill(cov > 0.0, 1, black=cov < 0.0, chart=cov != 0.0).black] = True
    return out


def reads_hidden(seams: Seams, hidden: np.ndarray) -> np.ndarray:
    """`(S,)` bool: the samples whose bilinear read on either side takes a `hidden (H·W,)` texel."""
    out = np.zeros(len(seams), bool)
    for xy in (seams.a, seams.b):
        index, weight = bilinear_taps(xy, seams.width, seams.height)
        out |= ((weight > 0.0) & hidden[index]).any(axis=1)
    return out


def encoded_images(atlas: EncodedAtlas) -> dict[str, np.ndarray]:
    """The channel images `(H, W)` of `atlas`'s encoding file (filled and packed, as written)."""
    return atlas.files[atlas.encoding_file.key][1]


# ---------------------------------------------------------------------------------------------
# the seam metric

#: Where the metric reads, texels inward from the seam: the noise floor between reads at
#: INTERIOR (one texel apart, clear of the border texels stitching moves), the step next to the
#: border between reads at EDGE_STEP.
INTERIOR = (1.5, 2.5)
EDGE_STEP = (0.5, 1.5)


def seam_metric(source, seams: Seams, worst: int = 10, tilt: float = TILT, coverage: np.ndarray | None = None) -> dict:
    """How visible the seams of `source` are (a TexelData, an EncodedAtlas, HHD channel images
    or an SH image: see `reader_for`). With the atlas's `coverage (H, W)` (a TexelData's own
    by default) the hidden samples (`reads_hidden`: one side is inside closed geometry, read
    black) are left out; `hidden` counts them.

    At every seam sample, the irradiance read on side a and on side b at the sample's normal,
    to luminance (Rec.709), relative difference |L_a − L_b| / max(their mean, REL_FLOOR × the
    mean over all samples): `mean` (weighted by the world length of the samples) and `p95`.
    The noise floor `interior` is the same statistic between two reads of one chart one texel
    apart, one texel inside the border (at 1½ and 2½ texels inward, on both sides): the step
    every texel shows its neighbour, which a seam is judged against; `ratio` = mean / interior
    (≤ 1: the seam is no more visible than the texel grid). `edge_step`: the same between ½ and
    1½ texels inward (the border texels, which stitching moves). `worst_edges`: the `worst`
    seam edges by mean error ({"edge", "error", "length" in metres}). `tilted`: mean, p95,
    interior, edge_step and ratio with the normal tilted by `tilt` towards ± the edge and
    ± across it (four reads pooled): a mismatch of the directional part shows there.
    Samples whose reads are not finite are left out (`invalid` counts them)."""
    from .encoding import TexelData

    if coverage is None and isinstance(source, TexelData):
        coverage = source.coverage
    hidden = np.zeros(len(seams), bool) if coverage is None else reads_hidden(seams, hidden_texels(coverage))
    return {**_metric(reader_for(source), seams.select(~hidden), worst, tilt), "hidden": int(hidden.sum())}


def _metric(read: Reader, seams: Seams, worst: int = 10, tilt: float = TILT) -> dict:
    keys = ("mean", "p95", "interior", "interior_p95", "edge_step", "ratio")
    if len(seams) == 0:
        empty = dict.fromkeys(keys, 0.0)
        return {**empty, "samples": 0, "edges": 0, "invalid": 0, "worst_edges": [], "tilted": dict(empty)}
    n = seams.normal
    t = _unit(seams.tangent - np.einsum("si,si->s", seams.tangent, n)[:, None] * n)
    across = _unit(np.cross(n, t))
    tilted = [_unit(np.cos(tilt) * n + sign * np.sin(tilt) * v) for v in (t, across) for sign in (1.0, -1.0)]
    lum = _luminances(read, seams, [n, *tilted])
    seam_err, seam_w, inner, edge, valid = _errors(lum[0], seams)
    out: dict = {"samples": len(seams), "edges": seams.edges, "invalid": int(np.count_nonzero(~valid))}
    out.update(_summary(seam_err, seam_w, inner, edge))
    out["worst_edges"] = _worst_edges(seams, seam_err, seam_w, valid, worst)
    parts = [_errors(at_normal, seams) for at_normal in lum[1:]]
    pooled = [np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])]
    inner_t = tuple(np.concatenate([p[2][k] for p in parts]) for k in range(2))
    edge_t = tuple(np.concatenate([p[3][k] for p in parts]) for k in range(2))
    out["tilted"] = _summary(pooled[0], pooled[1], inner_t, edge_t)
    return out


def _placed(read: Reader, window) -> Reader:
    """`read` (of a window's images, `stages.Window`) reading at atlas positions: the window's
    corner taken off each point once it is made (exactly: whole texels), so the reads are those
    of the whole atlas's images. `read` itself without a window."""
    if window is None:
        return read
    corner = np.array([window.x0, window.y0], np.float64)
    return lambda xy: read(xy - corner)


def _luminances(read: Reader, seams: Seams, normals: list[np.ndarray]) -> list[dict]:
    """The luminance of the irradiance the metric reads, per shading normal of `normals` (each
    `(S, 3)`; n_v is the seams' normal), by place: 'a', 'b' (the seam) and (side, offset)
    inward: `[{place: (S,)}]`, one dict per normal. Each place is read once and evaluated at
    every normal before the next is read (memory: one place's filtered texels at a time)."""
    places: list[tuple[Any, np.ndarray]] = [("a", seams.a), ("b", seams.b)]
    for side, xy, inward in (("a", seams.a, seams.inward_a), ("b", seams.b, seams.inward_b)):
        for offset in sorted(set(INTERIOR + EDGE_STEP)):
            places.append(((side, offset), xy + offset * inward))
    out: list[dict] = [{} for _ in normals]
    for key, xy in places:
        at = read(xy)
        for lum, n in zip(out, normals):
            lum[key] = at(seams.normal, n) @ LUMINANCE
        del at
    return out


def _errors(lum: dict, seams: Seams):
    """Relative luminance errors from the luminances `lum` at one normal (`_luminances`): across
    the seam (errors, weights), the interior and edge steps ((errors, weights) over both sides),
    and the (S,) mask of finite seam reads."""
    valid = np.isfinite(lum["a"]) & np.isfinite(lum["b"])
    seam_err, seam_w = _relative(lum["a"], lum["b"], seams.weight, valid)
    steps = []
    for near, far in (INTERIOR, EDGE_STEP):
        x = np.concatenate([lum["a", near], lum["b", near]])
        y = np.concatenate([lum["a", far], lum["b", far]])
        steps.append(_relative(x, y, np.concatenate([seams.weight, seams.weight]), np.isfinite(x) & np.isfinite(y)))
    return seam_err, seam_w, steps[0], steps[1], valid


def _relative(x: np.ndarray, y: np.ndarray, weight: np.ndarray, valid: np.ndarray):
    """|x − y| / max(½|x + y|, REL_FLOOR × weighted mean of ½|x + y|) over the `valid` rows, and their weights."""
    x, y, w = x[valid], y[valid], weight[valid]
    level = np.abs(0.5 * (x + y))
    mean = _weighted_mean(level, w)
    denominator = np.maximum(level, REL_FLOOR * mean)
    err = np.abs(x - y) / np.where(denominator > 0.0, denominator, 1.0)
    return err, w


def _summary(seam_err, seam_w, inner: tuple, edge: tuple) -> dict:
    mean = _weighted_mean(seam_err, seam_w)
    interior = _weighted_mean(inner[0], inner[1])
    return {
        "mean": mean,
        "p95": _weighted_quantile(seam_err, seam_w, 0.95),
        "interior": interior,
        "interior_p95": _weighted_quantile(inner[0], inner[1], 0.95),
        "edge_step": _weighted_mean(edge[0], edge[1]),
        "ratio": mean / interior if interior > 0.0 else (0.0 if mean == 0.0 else float("inf")),
    }


def _worst_edges(seams: Seams, err: np.ndarray, w: np.ndarray, valid: np.ndarray, worst: int) -> list[dict]:
    e = seams.edge[valid]
    total = np.bincount(e, weights=w, minlength=seams.edges)
    mean = np.bincount(e, weights=err * w, minlength=seams.edges) / np.where(total > 0, total, 1.0)
    length = np.bincount(seams.edge, weights=seams.weight, minlength=seams.edges)
    top = np.argsort(-mean, kind="stable")[:worst]
    return [{"edge": int(k), "error": float(mean[k]), "length": float(length[k])} for k in top]


def _weighted_mean(x: np.ndarray, w: np.ndarray) -> float:
    total = float(w.sum())
    return float((x * w).sum() / total) if total > 0 else 0.0


def _weighted_quantile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    if len(x) == 0 or w.sum() <= 0:
        return 0.0
    order = np.argsort(x, kind="stable")
    cum = np.cumsum(w[order])
    return float(x[order][min(int(np.searchsorted(cum, q * cum[-1])), len(x) - 1)])


# ---------------------------------------------------------------------------------------------
# stitching


def stitch(
    data: TexelData, seams: Seams, check=None, threads: int = 0, in_place: bool = False
) -> tuple[TexelData, dict]:
    """Least-squares seam stitching of `data`'s SH (the post stage's body; `check()` raises to
    cancel, called between solver iterations; `threads`: workers of the solver, 0 = every core,
    `parallel.resolve_threads`; the result does not depend on it). `in_place`: the stitched
    texels are written into `data.sh` and `data.normal` themselves (a caller whose `data` is
    spent: no copy of the atlas's SH); they are written only after everything else is done.

    Unknowns: the texels the seam samples read, each starting from the value the SH file shows
    there (a gutter texel its dilated SH, a buried texel the SH it takes from its own chart).
    Left out: hidden samples (`reads_hidden`: a side inside closed geometry, left black) and
    samples reading a texel whose SH is not finite (so NaN does not spread). Equations: per
    sample, the bilinear SH read on side a equals that on side b (weight SEAM_WEIGHT × span),
    and per unknown texel its value equals its starting value (COVERED_WEIGHT for a covered
    texel, GUTTER_WEIGHT for a gutter or buried one: an invalid texel's value is a copy). All
    27 SH channels are solved at once (one matrix, 27 right-hand sides): Jacobi-preconditioned
    conjugate gradients on the normal equations. The solution is then bounded (`_bounded`):
    each texel's L0 and I_z at its normal stay in the range of the covered texels it is tied to
    and ≥ 0.

    Returns new TexelData: the SH of the unknown texels replaced; the gutter and buried texels
    among them are listed in `extra_sources` (the gutter ones with the dilated normal), so the
    encoder encodes them (and dilates from them) rather than overwriting them; coverage is
    unchanged. And the sidecar record: enabled, seams (samples), edges, texels (changed),
    groups (groups of texels tied together by seams, solved together), iterations,
    samples_dropped (not finite), samples_hidden, texels_bounded, seconds, and the SH-read
    `seam_metric` before and after, hidden samples left out (mean, p95, interior, edge_step,
    ratio; `tilted` likewise)."""
    start = time.perf_counter()
    tick = ticker(check)
    h, w = data.coverage.shape
    if (seams.height, seams.width) != tuple(data.atlas_shape):
        raise ValueError(f"seams of a {seams.width}×{seams.height} atlas, texel images of {w}×{h}")
    atlas_seams, seams = seams, seams.within(data.window)  # on the images (a window: `TexelData.window`)
    if len(seams) == 0:  # nothing to stitch: the same TexelData and record, without the image copies
        empty = {"seams": 0, "edges": 0, "texels": 0, "groups": 0, "iterations": 0}
        record0: dict[str, Any] = {"enabled": True, **empty, "samples_dropped": 0, "samples_hidden": 0}
        return data, {**record0, "texels_bounded": 0, "seconds": time.perf_counter() - start}
    fill = data.fill()
    coverage = data.coverage.reshape(-1)
    # the SH and n_v as the SH file holds them (filled), read only where stitching reads (memory)
    prior = FilledRows(data.sh.reshape(h * w, -1), fill, (h, w), keep_black=True)
    filled_normal = FilledRows(data.normal.reshape(h * w, 3), fill, (h, w))
    hidden = np.zeros(h * w, bool)
    hidden[fill.black] = True
    shown = ~reads_hidden(seams, hidden)
    del hidden
    setup, solving, rest = tick.split([0.15, 0.7, 0.15])
    setup.at(0.0, f"setting up {len(seams)} seam samples")
    system = _system(seams, coverage, prior, shown)
    delta, iterations = _solve(system, prior, solving, parallel.resolve_threads(threads))
    rest.at(0.0, "bounding the stitched texels")
    texels = system.texels
    outside = coverage[texels] == 0.0
    normal = np.where(outside[:, None], filled_normal[texels], data.normal.reshape(h * w, 3)[texels])
    new, bounded = _bounded(system, prior, delta, normal, data.sh.dtype)
    del delta
    sh = data.sh.reshape(h * w, -1)
    changed = int(np.count_nonzero((new != sh[texels]).any(axis=1)))
    extra = np.zeros(h * w, bool) if data.extra_sources is None else data.extra_sources.reshape(-1).copy()
    extra[texels[coverage[texels] <= 0.0]] = True
    record: dict[str, Any] = {
        "enabled": True,
        "seams": len(seams),
        "edges": seams.edges,
        "texels": changed,
        "groups": _groups(system),
        "iterations": iterations,
        "samples_dropped": system.dropped,
        "samples_hidden": int(np.count_nonzero(~shown)),
        "texels_bounded": bounded,
    }
    # As the SH file will read (the stitched texels are sources; no other texel the metric
    # reads changes, up to gutter texels of thin charts whose nearest source moved).
    visible = atlas_seams.select(shown)
    image = FilledRows(data.sh.reshape(h * w, 9, -1), fill, (h, w), keep_black=True)
    read = _placed(sh_reader(image), data.window)
    rest.at(0.3, "measuring the seams")
    record["before"] = _brief(_metric(read, visible, worst=0))
    image.put(texels, new)  # the stitched SH, as the filled copy would read it
    rest.at(0.65, "measuring the seams")
    record["after"] = _brief(_metric(read, visible, worst=0))
    # the images: written into `data`'s own (`in_place`: the caller's data is spent), else copies
    sh = sh if in_place else sh.copy()
    normals = data.normal.reshape(h * w, 3)
    normals = normals if in_place else normals.copy()
    gutter = outside.nonzero()[0]
    normals[texels[gutter]] = normal[gutter]
    sh[texels] = new
    out = replace(
        data, sh=sh.reshape(data.sh.shape), normal=normals.reshape(data.normal.shape), extra_sources=extra.reshape(h, w)
    )
    record["seconds"] = time.perf_counter() - start
    return out, record


def _bounded(s: _System, prior, delta: np.ndarray, normal: np.ndarray, dtype=np.float32) -> tuple[np.ndarray, int]:
    """The stitched SH of the unknowns `(N, 9·C)` in `dtype` (the texels'), kept a plausible
    radiance, and how many texels it held back. `prior (H·W, 9·C)` the starting SH (an array or
    `FilledRows`), `delta (N, 9·C)` the solve's change, `normal (N, 3)` each unknown's n_v.

    The least squares has no bound: a gutter texel a seam read takes with a small weight can be
    driven to whatever closes the seam, negative or far brighter than anything around it. So
    per texel and colour channel the change is scaled back (x0 + t·δ, t in [0, 1], the largest
    allowed) until its L0 (radiance, SH band 0) and I_z (irradiance at its n_v, `hhd.irradz`;
    both linear in the SH) lie in [max(lo − m, 0), hi + m]: lo, hi the smallest and largest
    starting value among the texels the samples tying it read (itself included: baked values,
    or for gutter and buried texels copies of baked ones), m = BOUND_SLACK × (hi − lo).
    Scaling the whole change back keeps the SH a blend of two consistent ones (clamping L0
    and I_z on their own leaves bands 2 moved without them: it opens the seams far more). An
    I_z that rounding to `dtype` takes below 0 (or a starting one below 0, which t = 0 cannot
    mend) is lifted to IZ_MARGIN × (|L0| + |band 1|) by the smallest change of the SH that
    does (band 1 along its gradient), so it is ≥ 0 as stored."""
    from .hhd import irradz

    n, c = len(s.texels), prior.shape[1] // 9
    if n == 0:
        return np.zeros((0, prior.shape[1]), dtype), 0
    x0 = prior[s.texels].astype(np.float64).reshape(n, 9, c)
    step = delta.reshape(n, 9, c)
    nrm = _unit(np.asarray(normal, np.float64))

    def quantities(x):  # (N, 2, C): L0 and I_z per colour channel
        return np.stack([x[:, 0], irradz(x, nrm)], 1)

    q0 = quantities(x0)
    lo, hi = _tied_range(s, q0.reshape(n, -1))
    lo, hi = np.minimum(lo.reshape(q0.shape), q0), np.maximum(hi.reshape(q0.shape), q0)
    slack = BOUND_SLACK * (hi - lo)
    lo = np.maximum(lo - slack, 0.0)
    hi = np.maximum(hi + slack, lo)
    q1 = quantities(x0 + step)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(q1 > hi, (hi - q0) / (q1 - q0), np.where(q1 < lo, (lo - q0) / (q1 - q0), 1.0))
    t = np.clip(np.nan_to_num(t, nan=0.0), 0.0, 1.0).min(axis=1)  # (N, C)
    x = x0 + t[:, None, :] * step
    x[:, 0] = np.maximum(x[:, 0], 0.0)
    x = x.astype(dtype).astype(np.float64)  # as stored: the lift below sees its rounding
    grad = irradz(np.broadcast_to(np.eye(9), (n, 9, 9)), nrm)  # (N, 9): dI_z / d coefficient
    gg = np.einsum("nk,nk->n", grad, grad)[:, None]
    iz = irradz(x, nrm)  # (N, C)
    scale = x[:, 0] + np.linalg.norm(x[:, 1:4], axis=1)  # (N, C): the size of L0 and band 1
    short = np.where(iz < 0.0, IZ_MARGIN * scale - iz, 0.0)
    x += grad[:, :, None] * np.where(gg > 0.0, short / np.where(gg > 0.0, gg, 1.0), 0.0)[:, None, :]
    held = (t < 1.0).any(axis=1) | (short > 0.0).any(axis=1) | (x0[:, 0] + step[:, 0] < 0.0).any(axis=1)
    return x.reshape(n, -1).astype(dtype), int(np.count_nonzero(held))


def _tied_range(s: _System, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per unknown, the smallest and largest `q (N, K)` (at their starting values) among the
    texels read by the samples that take it, `(N, K)` each."""
    live = (s.coeff != 0.0)[:, :, None]  # (8, R, 1); fixed taps have coefficient 0
    values = q[s.taps]  # (8, R, K)
    row_lo = np.where(live, values, np.inf).min(axis=0)  # (R, K)
    row_hi = np.where(live, values, -np.inf).max(axis=0)
    lo, hi = np.full(q.shape, np.inf), np.full(q.shape, -np.inf)
    if len(s.starts):
        lo[s.owner] = np.minimum.reduceat(row_lo[s.entry_row], s.starts, axis=0)
        hi[s.owner] = np.maximum.reduceat(row_hi[s.entry_row], s.starts, axis=0)
    return lo, hi


def _brief(metric: dict) -> dict:
    keys = ("mean", "p95", "interior", "edge_step", "ratio")
    return {**{k: metric[k] for k in keys}, "tilted": {k: metric["tilted"][k] for k in keys}}


def stitch_encoded(
    atlas: EncodedAtlas,
    seams: Seams,
    coverage: np.ndarray,
    check=None,
    threads: int = 0,
    window=None,
    in_place: bool = False,
) -> tuple[EncodedAtlas, dict]:
    """Least-squares seam stitching of an HHD/AHD atlas's encoded layers, as the preview filters
    them: I_z, w_a and the octahedral direction (packed: the GPU interpolates the packed values),
    each read bilinearly on both sides of every seam sample and made equal, the texels pulled
    towards their encoded values (covered texels, `coverage (H, W)` > 0, firmly; gutter and
    buried ones weakly; hidden samples, `reads_hidden`, left out). After the SH
    stitch the encoding's non-linearity (each texel's own n_v in I_z, the fitted w_a and d)
    leaves a small step; this closes it for every shading normal. The direction is stitched only
    at samples whose two packed reads lie within FOLD_GAP of each other (across the octahedral
    fold, packed values of nearby directions are far apart and averaging them would be wrong).
    Values stay in range (I_z ≥ 0, w_a in [0, 1], packed direction in [-1, 1]).
    Returns the atlas with the encoding file's images replaced, and a record: enabled, texels
    (changed), iterations, seconds, and the HHD-read `seam_metric` before and after.
    `window` (`stages.Window`): the images and `coverage` are that rectangle of the atlas
    `seams` are of (`TexelData.window`). `in_place`: the stitched texels are written into
    `atlas`'s own images (a caller that does not keep the unstitched ones), after the "before"
    measure; else into copies."""
    start = time.perf_counter()
    tick = ticker(check)
    atlas_seams, seams = seams, seams.within(window)
    if len(seams) == 0:  # nothing to stitch: the same atlas and record, without the image copies
        nothing = _brief(_metric(lambda xy: None, seams))  # type: ignore[arg-type, return-value]
        record0 = {"enabled": True, "texels": 0, "iterations": 0, "before": nothing, "after": dict(nothing)}
        return atlas, {**record0, "seconds": time.perf_counter() - start}
    key = atlas.encoding_file.key
    spec, images = atlas.files[key]
    names = [n for n in ("Iz.R", "Iz.G", "Iz.B", "Wa.V", "Wa.R", "Wa.G", "Wa.B") if n in images]
    directions = ["Direction.X", "Direction.Y"]
    h, w = images[names[0]].shape
    cover = np.asarray(coverage).reshape(-1)
    # the stitched layers: written into the atlas's own images (`in_place`) or copies
    out = dict(images) if in_place else {name: np.array(image, copy=True) for name, image in images.items()}
    model = atlas.settings.get("model", "hhd")
    shown = ~reads_hidden(seams, hidden_texels(np.asarray(coverage)))
    visible = atlas_seams.select(shown)
    measure, *solves, after = tick.split([0.1, 0.4, 0.4, 0.1])
    measure.at(0.0, "measuring the seams")
    before = _metric(_placed(hhd_reader(images, model), window), visible, worst=0)
    packed = _Stacked([images[n] for n in directions], np.float64)
    gap = np.abs(bilinear(packed, seams.a) - bilinear(packed, seams.b)).max(axis=1)
    iterations, changed = 0, np.zeros(h * w, bool)
    workers = parallel.resolve_threads(threads)
    layers: list[tuple[list[str], np.ndarray]] = [(list(names), shown), (list(directions), shown & (gap <= FOLD_GAP))]
    for part, (layer, use) in zip(solves, layers):
        part.at(0.0, "setting up")
        prior = _Stacked([images[n] for n in layer], np.float64)  # read where the system reads (memory)
        system = _system(seams, cover, prior, use)
        delta, k = _solve(system, prior, part, workers)
        iterations = max(iterations, k)
        new = prior[system.texels] + delta
        at = np.divmod(system.texels, w)  # (row, column): the images may be strided views
        for i, n in enumerate(layer):
            low, high = (-1.0, 1.0) if n in directions else (0.0, 1.0 if n.startswith("Wa.") else np.inf)
            values = np.clip(new[:, i], low, high).astype(out[n].dtype)
            changed[system.texels] |= values != out[n][at]
            out[n][at] = values
    files = dict(atlas.files)
    files[key] = (spec, out)
    after.at(0.0, "measuring the seams")
    record = {
        "enabled": True,
        "texels": int(np.count_nonzero(changed)),
        "iterations": iterations,
        "before": _brief(before),
        "after": _brief(_metric(_placed(hhd_reader(out, model), window), visible, worst=0)),
        "seconds": time.perf_counter() - start,
    }
    return replace(atlas, files=files), record


@dataclass
class _System:
    """The stitching least squares, R sample rows over N unknowns. texels (N,) flat indices of
    the unknowns; taps (8, R) the unknown each row's read difference takes (fixed texels point
    at unknown 0 with coefficient 0), coeff (8, R) its coefficients (side a +, side b −),
    seam_weight (R,), constant (C, R) the fixed texels' part of each difference; data_weight
    (N,); for Aᵀ the row-major entries sorted by unknown: entry_row, entry_coeff, and the start
    of each unknown's run (starts) with its unknown (owner); dropped: samples left out."""

    texels: np.ndarray
    taps: np.ndarray
    coeff: np.ndarray
    seam_weight: np.ndarray
    constant: np.ndarray
    data_weight: np.ndarray
    entry_row: np.ndarray
    entry_coeff: np.ndarray
    starts: np.ndarray
    owner: np.ndarray
    dropped: int


def _system(seams: Seams, coverage: np.ndarray, prior, use: np.ndarray | None = None) -> _System:
    """Set up the least squares of `stitch` over the flat images `coverage (HW,)`, `prior (HW, C)`
    (an array or rows read on demand: `FilledRows`, `_Stacked`),
    with the samples `use` `(S,)` bool (default all; the caller leaves hidden samples out) that
    read only finite texels. Every texel such a sample reads (with a weight > 0) is an unknown."""
    ia, wa = bilinear_taps(seams.a, seams.width, seams.height)
    ib, wb = bilinear_taps(seams.b, seams.width, seams.height)
    index = np.concatenate([ia, ib], axis=1)  # (S, 8)
    coeff = np.concatenate([wa, -wb], axis=1)
    finite = np.isfinite(prior[index]).all(axis=(1, 2))  # only the rows read (prior may be `FilledRows`)
    good = finite if use is None else finite & use
    index, coeff, span = index[good], coeff[good], seams.span[good]
    free = coeff != 0.0  # a zero weight reads nothing
    texels = np.unique(index[free])
    lookup = np.full(len(coverage), -1, np.int64)
    lookup[texels] = np.arange(len(texels))
    taps = np.where(coeff != 0.0, lookup[index], -1)
    fixed = taps < 0
    constant = np.zeros((prior.shape[1], len(index)))
    some = np.flatnonzero(fixed.any(axis=1))  # rows with a tap of weight 0
    constant[:, some] = np.einsum(
        "rk,rkc->cr", np.where(fixed, coeff, 0.0)[some], prior[index[some]].astype(np.float64)
    )
    coeff = np.where(fixed, 0.0, coeff)
    taps = np.where(fixed, 0, taps)
    flat = np.where(fixed, -1, taps).T.reshape(-1)  # tap-major, like taps.T
    order = np.argsort(flat, kind="stable")
    order = order[flat[order] >= 0]
    sorted_taps = flat[order]
    starts = np.flatnonzero(np.concatenate([[True], sorted_taps[1:] != sorted_taps[:-1]])) if len(order) else order
    return _System(
        texels=texels,
        taps=np.ascontiguousarray(taps.T),
        coeff=np.ascontiguousarray(coeff.T, dtype=np.float32),
        seam_weight=SEAM_WEIGHT * span,
        constant=constant,
        data_weight=np.where(coverage[texels] > 0.0, COVERED_WEIGHT, GUTTER_WEIGHT),
        entry_row=order % len(index) if len(index) else order,
        entry_coeff=coeff.T.reshape(-1)[order].astype(np.float32),
        starts=starts,
        owner=sorted_taps[starts],
        dropped=int(np.count_nonzero(~finite)),
    )


def _apply_a(s: _System, x: np.ndarray) -> np.ndarray:
    """A x: each row's read difference `(C, R)` of the unknowns `x (C, N)` (in x's dtype)."""
    out = np.zeros((x.shape[0], s.taps.shape[1]), x.dtype)
    for k in range(len(s.taps)):
        out += np.take(x, s.taps[k], axis=1) * s.coeff[k]
    return out


def _apply_at(s: _System, r: np.ndarray) -> np.ndarray:
    """Aᵀ r: row values `r (C, R)` summed onto the unknowns -> `(C, N)` (in r's dtype)."""
    out = np.zeros((r.shape[0], len(s.texels)), r.dtype)
    if len(s.starts):
        out[:, s.owner] = np.add.reduceat(np.take(r, s.entry_row, axis=1) * s.entry_coeff, s.starts, axis=1)
    return out


def _solve(s: _System, prior, check=None, threads: int = 1) -> tuple[np.ndarray, int]:
    """The change `(N, C)` of the unknowns minimising Σ λ (A(x0 + δ) + c)² + Σ μ δ²: the normal
    equations (AᵀΛA + M) δ = −AᵀΛ(A x0 + c), solved by Jacobi-preconditioned CG from δ = 0,
    each channel on its own (the channels vectorised, split over `threads` workers). Returns δ
    and the most iterations a channel took. `check`: cancels (and, a `core.progress.Tick`,
    reports how far the residuals are towards the tolerance) every few iterations."""
    n, c = len(s.texels), prior.shape[1]
    if n == 0:
        return np.zeros((0, c)), 0
    tick = ticker(check)
    x0 = np.ascontiguousarray(prior[s.texels].T, dtype=np.float64)
    b = -_apply_at(s, (_apply_a(s, x0) + s.constant) * s.seam_weight)
    parts = np.array_split(np.arange(c), max(1, min(threads, c)))
    if len(parts) == 1:
        x, iterations = _cg(s, b, tick, _on_step(tick, n, [(0.0, 0)], 0))
        return x.T, iterations
    reached = [(0.0, 0)] * len(parts)  # each worker's fraction (its channels' mean) and iterations
    with ThreadPoolExecutor(max_workers=len(parts)) as pool:
        done = list(pool.map(lambda k: _cg(s, b[parts[k]], tick, _on_step(tick, n, reached, k)), range(len(parts))))
    return np.concatenate([x for x, _ in done]).T, max(k for _, k in done)


def _on_step(tick: Tick, unknowns: int, reached: list[tuple[float, int]], k: int):
    """`_cg`'s `on_step(fraction, iterations)` for worker `k` of `_solve`: the mean of the
    workers' fractions to `tick`, with the most iterations any has done (None when `tick`
    reports nothing: `_cg` then only checks)."""
    if not tick.reports:
        return None

    def on_step(fraction: float, iterations: int) -> None:
        reached[k] = (fraction, iterations)
        mean = sum(f for f, _ in reached) / len(reached)
        tick.at(mean, f"{unknowns} texels, iteration {max(i for _, i in reached)}")

    return on_step


def _cg(s: _System, b: np.ndarray, check=None, on_step=None) -> tuple[np.ndarray, int]:
    """Jacobi-preconditioned conjugate gradients for (AᵀΛA + M) x = b, `b (C, N)`, one
    independent solve per row of b (vectorised), in float32 (the texels' precision; the
    tolerance is far above its rounding): x `(C, N)` float64 and the iterations taken.
    Every 8 iterations `check()` (cancel), or `on_step(fraction, iterations)` if given (which
    checks too): the fraction is how far the residuals have come from ‖b‖ towards the tolerance
    (on a log scale, the channels' mean; at least iterations / CG_MAX_ITERATIONS)."""
    lam = s.seam_weight.astype(np.float32)
    mu = s.data_weight.astype(np.float32)

    def matvec(x):
        return _apply_at(s, _apply_a(s, x) * lam) + x * mu

    diag = s.data_weight + np.bincount(
        s.taps.reshape(-1), weights=(s.coeff.astype(np.float64) ** 2 * s.seam_weight).reshape(-1), minlength=len(mu)
    )
    inv_diag = (1.0 / diag).astype(np.float32)
    r = b.astype(np.float32)
    x = np.zeros_like(r)
    target = CG_TOLERANCE * np.linalg.norm(b, axis=1)
    z = r * inv_diag
    p = z.copy()
    rz = np.einsum("cn,cn->c", r, z, dtype=np.float64)
    iterations = 0
    norm = np.linalg.norm(r, axis=1)
    active = norm > target
    while iterations < CG_MAX_ITERATIONS and active.any():
        if on_step is not None and iterations % 8 == 0:
            on_step(_cg_fraction(norm, target, active, iterations), iterations)
        elif check is not None and iterations % 8 == 0:
            check()
        q = matvec(p)
        pq = np.einsum("cn,cn->c", p, q, dtype=np.float64)
        # a converged channel stops (alpha 0): each channel's result is its own, whatever it is solved with
        alpha = np.divide(rz, pq, out=np.zeros_like(rz), where=active & (pq > 0.0)).astype(np.float32)
        x += alpha[:, None] * p
        r -= alpha[:, None] * q
        z = r * inv_diag
        rz_new = np.einsum("cn,cn->c", r, z, dtype=np.float64)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0.0).astype(np.float32)
        p = z + beta[:, None] * p
        rz = rz_new
        norm = np.linalg.norm(r, axis=1)
        active &= norm > target
        iterations += 1
    return x.astype(np.float64), iterations


def _cg_fraction(norm: np.ndarray, target: np.ndarray, active: np.ndarray, iterations: int) -> float:
    """How far `_cg` is: per channel log(‖r‖ / ‖b‖) / log(CG_TOLERANCE) (1 once converged), their
    mean, at least iterations / CG_MAX_ITERATIONS (progress only: nothing computed depends on it)."""
    start = target / CG_TOLERANCE  # ‖b‖
    with np.errstate(divide="ignore", invalid="ignore"):
        gone = np.log(np.maximum(norm, 1e-300) / start) / np.log(CG_TOLERANCE)
    per = np.where(active & (start > 0.0), np.clip(np.nan_to_num(gone, nan=0.0), 0.0, 1.0), 1.0)
    return max(float(per.mean()) if len(per) else 1.0, iterations / CG_MAX_ITERATIONS)


def _groups(s: _System) -> int:
    """Groups of unknowns tied together by seam samples (connected components; hook and
    pointer-jumping union-find, vectorised over the samples)."""
    n = len(s.texels)
    if n == 0:
        return 0
    live = s.coeff != 0.0  # (8, R); fixed taps have coefficient 0
    anchor = np.where(live, s.taps, n).min(axis=0)  # each row's first unknown
    u = np.broadcast_to(anchor, s.taps.shape)[live]
    v = s.taps[live]
    parent = np.arange(n)
    while True:
        pu, pv = parent[u], parent[v]
        if np.array_equal(pu, pv):
            break
        np.minimum.at(parent, np.maximum(pu, pv), np.minimum(pu, pv))
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    return int(len(np.unique(parent)))
