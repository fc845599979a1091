"""The emissive triangles as one light per light group (`EmissiveTriangles`): a light tree over
their clusters, then a triangle by power, then a point by area or a direction by solid angle
(spherical triangles, Arvo 1995). No bpy."""

from __future__ import annotations

import numpy as np

from ...colour import LUMINANCE
from .. import light_kernels as _kernels
from .light import Light, RayPdf, Sample, _rows, uniforms

#: Most spatial clusters the emitting triangles of one light group are split into.
CLUSTERS = 32


#: Split clusters of more than one emitting triangle again into at most FANOUT clusters each, down
#: to single triangles (or MAX_LEAVES leaves): a light tree, descended at each shading point by
#: the same weights one level at a time, so a scene with thousands of emitters picks the one
#: beside the point, not a cluster's triangle by power alone (`tree.light_tree`; ≤ 1: no tree,
#: the top clusters alone).
FANOUT = 8


MAX_LEAVES = 4096


#: Below a node a shading point lies this many of its bounding radii or more from, the tree is
#: descended by power alone (no weights to evaluate): its leaves' weights differ little there.
DESCEND_RADII = 4.0


#: Share of the cluster choice made by power alone, whatever the distance: the distance bound
#: knows nothing of occlusion, so a bright emitter behind a wall keeps some samples.
POWER_SHARE = 0.1


#: A cluster of one triangle is weighed by the solid angle the triangle subtends (times its
#: luminance) instead of power over distance² at points within this many of its bounding radii:
#: power over distance² sees the two triangles of a lamp's quad alike from a point beside one of
#: them, though that one subtends nearly all the quad. 1: inside the bounding sphere, where
#: distance² says least (README, "Speed vs accuracy"); 0: never.
NEAR_RADII = 1.0


class EmissiveTriangles(Light):
    """The emitting triangles of one light group. triangles (T, 3, 3) world space (all of the
    scene's: primitive ids index them; kept for the emitting ones only, the others' rows zero);
    emission (T, 3) radiance, zero for triangles that do not emit or belong to another group.
    Empty (`len` 0) when nothing emits. Sampling: the module docstring (a cluster, a triangle ∝
    power, then a uniform point on it or a uniform direction in its solid angle)."""

    reachable = True

    def __init__(self, triangles: np.ndarray, emission: np.ndarray, group: str = ""):
        self.group = group
        self.emission = np.asarray(emission, np.float64)
        # per triangle (T rows: primitive ids index them), filled for those with emission only:
        # nothing reads the others', and a scene has far more triangles than emitters
        n = len(self.emission)
        lit = np.flatnonzero(self.emission @ LUMINANCE > 0.0)
        self.triangles = np.zeros((n, 3, 3))
        self.triangles[lit] = np.asarray(triangles)[lit]
        corners = self.triangles[lit]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        self.area = np.zeros(n)
        self.area[lit] = 0.5 * np.linalg.norm(cross, axis=1)
        power = np.zeros(n)
        power[lit] = self.area[lit] * (self.emission[lit] @ LUMINANCE)
        self.index = np.flatnonzero(power > 0.0)
        self.normal = np.zeros((n, 3))
        self.normal[lit] = cross / np.maximum(2.0 * self.area[lit], 1e-300)[:, None]
        # (T + 1,): does triangle t emit; the last entry, False, is what prim −1 (a miss) reads
        self.emits = np.zeros(len(self.triangles) + 1, bool)
        self.emits[self.index] = True
        # each emitter's bounding sphere (T, 4): centroid, farthest corner (light_kernels._surely_small)
        self.bound = np.zeros((len(self.triangles), 4))
        corners = self.triangles[self.index]
        centroid = corners.mean(axis=1)
        self.bound[self.index, :3] = centroid
        self.bound[self.index, 3] = np.linalg.norm(corners - centroid[:, None], axis=2).max(axis=1) * (1 + 1e-12)
        self._cluster(power)

    def _cluster(self, power: np.ndarray) -> None:
        """The light tree over the emitters `index` (`light_tree`) and per node (N columns, in
        breadth-first order: a node's children are consecutive) its power `cluster_power` (N,),
        bounding-box centre `centre` (N, 3) and squared radius `radius2` (N,), the tree's links
        `child_first`, `child_count` (N + 1,: the last entry is the root, above the top clusters)
        and `parent` (N,: N for a top cluster); per triangle (T,) its leaf `cluster_of` and its
        probability within it `within`; the emitters sorted by leaf `order` and `key` (E,):
        leaf + cumulative share within it, each leaf's rows `first` .. `last`."""
        t = len(self.triangles)
        self.cluster_of = np.zeros(t, np.int64)
        self.within = np.zeros(t)
        if not len(self.index):
            self.cluster_power = np.zeros(0)
            self.centre, self.radius2 = np.zeros((0, 3)), np.zeros(0)
            self.order, self.key = self.index, np.zeros(0)
            self.first = self.last = self.lone = np.zeros(0, np.int64)
            self.child_first = self.child_count = np.zeros(1, np.int64)
            self.parent = np.zeros(0, np.int64)
            self.luminance = np.zeros(0)
            return
        corners = self.triangles[self.index]
        # compiled: `tree.light_tree` is its specification
        leaf, self.child_first, self.child_count, self.parent = _kernels.get().light_tree(
            np.ascontiguousarray(corners.mean(axis=1), np.float64), CLUSTERS, FANOUT, MAX_LEAVES
        )
        k = len(self.parent)
        self.cluster_of[self.index] = leaf
        power_of_leaf = np.bincount(leaf, power[self.index], minlength=k)
        self.within[self.index] = power[self.index] / power_of_leaf[leaf]
        lo = np.full((k, 3), np.inf)
        hi = np.full((k, 3), -np.inf)
        np.minimum.at(lo, leaf, corners.min(axis=1))
        np.maximum.at(hi, leaf, corners.max(axis=1))
        self.cluster_power = power_of_leaf
        _kernels.get().node_sums(lo, hi, self.cluster_power, self.child_first, self.child_count)  # `tree.node_sums`
        self.centre = 0.5 * (lo + hi)
        self.radius2 = np.maximum(0.25 * np.square(hi - lo).sum(axis=1), 1e-12)
        self.order = self.index[np.argsort(leaf, kind="stable")]
        sorted_leaf = self.cluster_of[self.order]
        share = self.within[self.order]
        cum = np.cumsum(share)
        count = np.bincount(sorted_leaf, minlength=k)
        first = np.searchsorted(sorted_leaf, np.arange(k))  # each leaf's first row in order
        last = first + count - 1
        is_leaf = count > 0
        self.key = sorted_leaf + (cum - (cum - share)[first[sorted_leaf]])
        self.key[last[is_leaf]] = np.flatnonzero(is_leaf) + 1.0  # each leaf's segment ends exactly at c + 1
        self.first, self.last = first, np.where(is_leaf, last, first)
        # a leaf of one triangle: its id and emitted luminance (`cluster_probability`)
        self.lone = np.where(count == 1, self.order[np.minimum(first, len(sorted_leaf) - 1)], -1)
        self.luminance = np.where(self.lone >= 0, self.cluster_power / np.maximum(self.area[self.lone], 1e-300), 0.0)

    def __len__(self) -> int:
        return len(self.index)

    def cluster_probability(self, x: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(R, N): the probability of picking each node of the light tree (a leaf, or any leaf
        below an inner node) at the points x (R, 3); the leaves' sum to 1 per row. Among the
        children of a node, each is picked ∝ its weight: its power over max(distance², radius²)
        to its bounding box's centre, times (given the points' `normals` (R, 3)) the largest
        cosine of a direction into the box's bounding sphere (0 below the horizon), mixed with
        POWER_SHARE ∝ power alone (power alone where every child is below the horizon); a leaf
        of one triangle seen from within NEAR_RADII of its radius weighs its luminance × the
        triangle's solid angle instead of power over distance² (where that is finite). numpy:
        the spec of the compiled choice (`light_kernels.sample_emitters`, `light_kernels.emitter_pdf`), the
        tests compare them."""
        phi = self.cluster_power
        if len(phi) == 1:
            return np.ones((len(x), 1))
        w = self._weights(x, normals)
        prob = np.zeros_like(w)
        root = len(phi)
        # below a node x lies DESCEND_RADII of its radius or more from: by power alone
        far = np.square(self.centre[None] - x[:, None, :]).sum(axis=2) >= DESCEND_RADII**2 * self.radius2
        far_above = np.zeros((len(x), root + 1), bool)
        for c in [root, *range(root)]:  # breadth first: a node's probability before its children's
            a, m = self.child_first[c], self.child_count[c]
            if m == 0:
                continue
            above = 1.0 if c == root else prob[:, c : c + 1]
            part, power = w[:, a : a + m], phi[a : a + m]
            total = part.sum(axis=1, keepdims=True)
            power_only = np.broadcast_to(power / power.sum(), part.shape)
            mixed = (1.0 - POWER_SHARE) * part / np.where(total > 0.0, total, 1.0) + POWER_SHARE * power_only
            by_power = (total <= 0.0) | far_above[:, c : c + 1]
            prob[:, a : a + m] = above * np.where(by_power, power_only, mixed)
            far_above[:, a : a + m] = far_above[:, c : c + 1] | far[:, a : a + m]
        return prob

    def _weights(self, x: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
        """(R, N): every node's weight at the points x (`cluster_probability`)."""
        phi = self.cluster_power
        to = self.centre[None] - x[:, None, :]
        d2 = np.square(to).sum(axis=2)
        w = phi / np.maximum(d2, self.radius2)
        if normals is not None:
            d = np.sqrt(d2)
            cos_t = np.einsum("rki,ri->rk", to, normals) / np.maximum(d, 1e-300)
            sin_a = np.sqrt(np.minimum(self.radius2 / np.maximum(d2, 1e-300), 1.0))
            cos_a = np.sqrt(1.0 - sin_a * sin_a)
            edge = np.maximum(cos_t * cos_a + np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0)) * sin_a, 0.0)
            w *= np.where((d2 > self.radius2) & (cos_t < cos_a), edge, 1.0)
        for c in np.flatnonzero(self.lone >= 0):
            omega = spherical_triangles(x, np.broadcast_to(self.triangles[self.lone[c]], (len(x), 3, 3)))[-1]
            near = (d2[:, c] < NEAR_RADII**2 * self.radius2[c]) & np.isfinite(omega) & (w[:, c] > 0.0)
            by_angle = w[:, c] * (self.luminance[c] * omega * np.maximum(d2[:, c], self.radius2[c]) / phi[c])
            w[:, c] = np.where(near, by_angle, w[:, c])
        return w

    def sample(self, rng, x, ray_pdf: RayPdf, strata=1, normals=None) -> Sample:
        dirs, dist, emitted, p_light = self._sample_points(rng, x, strata, normals)
        p_other = ray_pdf(dirs)
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(p_light > 0.0, p_light / (p_light * p_light + p_other * p_other), 0.0)
        return dirs, emitted * weight[:, None], dist

    def _sample_points(self, rng, x, strata=1, normals=None, u=None):
        """One point per shading point x (R, 3) (normals (R, 3) or None): directions (R, 3),
        distances (R,), emitted radiance (R, 3) and the pdf per steradian (R,) (0: no sample, a
        grazing or coincident point). Compiled (`light_kernels.sample_emitters`); its random numbers
        u (4, R): cluster, triangle, then two for the point or direction, from `uniforms`
        (strata) unless given."""
        r = len(x)
        if u is None:
            u = np.stack([uniforms(rng, r, strata, dim) for dim in range(4)])
        tri = (self.triangles, self.normal, self.area, self.within)
        dirs, dist, pick, pdf = _kernels.get().sample_emitters(
            _rows(x), _rows(normals), u, *tri, self._emitters(), POWER_SHARE, SOLID_ANGLE_RANGE
        )
        return dirs, dist, self.emission[pick], pdf

    def _emitters(self) -> tuple:
        """The cluster arrays the kernels take (`light_kernels.sample_emitters`), made once."""
        if getattr(self, "_kernel_arrays", None) is None:
            radius2 = self.radius2
            rows = [self.centre.T, radius2, np.sqrt(radius2), self.cluster_power, self.lone, self.luminance]
            rows += [NEAR_RADII**2 * radius2, DESCEND_RADII**2 * radius2]
            rows += [_kernels.get().sibling_shares(self.cluster_power, self.child_first, self.child_count)]
            clusters = np.ascontiguousarray(np.vstack(rows), np.float64)
            tree = (self.child_first, self.child_count, self.parent)
            self._kernel_arrays = (clusters, self.key, self.order, self.first, self.last, self.bound, *tree)
        return self._kernel_arrays

    def pdf(self, d, t=None, prim=None, origins=None, normals=None) -> np.ndarray:
        """Density per steradian of sampling, from `origins` (R, 3) with `normals` (R, 3) or
        None, the point at distance t (float64) along d on triangle prim (an emitter or not: 0
        for non-emitters). Compiled (`light_kernels.emitter_pdf`)."""
        if origins is None:
            raise ValueError("the emitters' density depends on where the ray starts: pass origins")
        if not len(self.index):
            return np.zeros(len(d))
        tri = (self.triangles, self.normal, self.area, self.within, self.cluster_of)
        return _kernels.get().emitter_pdf(
            _rows(origins),
            _rows(normals),
            _rows(d),
            np.ascontiguousarray(t, np.float64),
            np.ascontiguousarray(prim, np.int64),
            *tri,
            self._emitters(),
            POWER_SHARE,
            SOLID_ANGLE_RANGE,
        )

    def reached(self, prim: np.ndarray) -> np.ndarray:
        """The rows (int64) of the rays, ending on triangles prim (R,) (−1: a miss), that reached
        one of these emitters: the only ones `evaluate` gives light."""
        return np.flatnonzero(self.emits[prim])

    def evaluate(self, d, t, prim, pdf, origins=None, normals=None) -> np.ndarray:
        p_light = self.pdf(d, t.astype(np.float64), prim, origins, normals)
        weight = pdf * pdf / np.maximum(pdf * pdf + p_light * p_light, 1e-300)
        return self.emission[prim] * weight[:, None]

    @property
    def power(self) -> float:
        """Both sides of a Lambertian emitter: 2π · Σ area × emitted luminance."""
        return float(2.0 * np.pi * (self.area * np.maximum(self.emission @ LUMINANCE, 0.0)).sum())


def sibling_shares(power: np.ndarray, child_first: np.ndarray, child_count: np.ndarray) -> np.ndarray:
    """(N,): each light tree node's power over the summed power of its siblings (its parent's
    children, `light_tree`'s links), the sum taken one node at a time in index order, as a
    kernel's loop would: the kernels read these shares instead of summing and dividing per
    sample, the same numbers to the bit. numpy: the specification of the compiled
    `light_kernels.sibling_shares` (which `EmissiveTriangles` uses)."""
    share = np.ones(len(power))
    for node in range(len(child_count)):
        a, m = int(child_first[node]), int(child_count[node])
        total = 0.0
        for c in range(a, a + m):
            total += float(power[c])
        with np.errstate(divide="ignore", invalid="ignore"):
            share[a : a + m] = power[a : a + m] / total
    return share


#: Solid angles (sr) within which an emitting triangle is sampled by a uniform direction in it
#: (`sample_spherical_triangles`) rather than a uniform point on it: below, the spherical
#: formulas lose precision and the two agree anyway; above, a triangle fills most of a
#: hemisphere (PBRT-v4's bounds).
SOLID_ANGLE_RANGE = (3e-4, 6.22)


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def spherical_triangles(x: np.ndarray, tri: np.ndarray):
    """(numpy: the spec of the compiled `light_kernels._spherical`, the tests compare them.)
    The spherical triangles triangles tri (R, 3, 3) make seen from points x (R, 3): unit
    directions a, b, c (R, 3) to their corners, the cosine and sine of the angle at a (R,) and
    the solid angle (R,) in steradians (0 seen edge-on, NaN from a corner). With D = |a·(b×c)|:
    the solid angle is 2·atan2(D, 1 + a·b + b·c + c·a) (Van Oosterom & Strackee 1983) and the
    angle at a is atan2(D, b·c − (a·b)(c·a)) (the spherical laws of cosines and sines)."""
    a, b, c = (_unit(tri[:, i] - x) for i in range(3))
    ab, bc, ca = (np.einsum("ri,ri->r", p, q) for p, q in ((a, b), (b, c), (c, a)))
    det = np.abs(np.einsum("ri,ri->r", a, np.cross(b, c)))
    y = bc - ab * ca
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.sqrt(det * det + y * y)
        return a, b, c, y / h, det / h, 2.0 * np.arctan2(det, 1.0 + ab + bc + ca)


def sample_spherical_triangles(x: np.ndarray, tri: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Unit directions (R, 3) from x (R, 3) uniform in the solid angle of triangles tri (R, 3, 3)
    for uniform numbers u1, u2 (R,) (Arvo 1995, in PBRT-v4's SampleSphericalTriangle form).
    numpy: the spec of the compiled `light_kernels._spherical_direction`, the tests compare them."""
    a, b, c, cos_a, sin_a, area = spherical_triangles(x, tri)
    s, q = -np.sin(u1 * area), -np.cos(u1 * area)  # sine and cosine of π + the sub-triangle's area
    sin_phi = s * cos_a - q * sin_a
    cos_phi = q * cos_a + s * sin_a
    k1 = cos_phi + cos_a
    k2 = sin_phi - sin_a * np.einsum("ri,ri->r", a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_bp = np.clip((k2 + (k2 * cos_phi - k1 * sin_phi) * cos_a) / ((k2 * sin_phi + k1 * cos_phi) * sin_a), -1, 1)
    sin_bp = np.sqrt(np.maximum(1.0 - cos_bp * cos_bp, 0.0))
    cp = cos_bp[:, None] * a + sin_bp[:, None] * _unit(c - np.einsum("ri,ri->r", c, a)[:, None] * a)
    cos_t = 1.0 - u2 * (1.0 - np.einsum("ri,ri->r", cp, b))
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    return _unit(cos_t[:, None] * b + sin_t[:, None] * _unit(cp - np.einsum("ri,ri->r", cp, b)[:, None] * b))


def _emission_groups(emission: np.ndarray, groups: np.ndarray | None) -> list[tuple[str, np.ndarray]]:
    """(group, emission (T, 3) with the other groups' triangles zeroed) per group of the emitting
    triangles, sorted by name; `groups` (T,) str or None (all "")."""
    if groups is None:
        return [("", emission)]
    group = np.asarray(groups).astype(str)
    names = sorted(set(group[np.flatnonzero(emission.any(axis=1))].tolist()))
    if len(names) <= 1:
        return [(names[0] if names else "", emission)]
    return [(name, np.where((group == name)[:, None], emission, 0.0)) for name in names]
