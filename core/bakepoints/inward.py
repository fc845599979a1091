"""Faces that point into their own object (inside-out meshes). No bpy.

Cycles and EEVEE shade both sides of a surface, so an object whose normals point into its own
closed shell looks right in Blender, but its lightmap hemisphere (around n_v) looks into the
shell and bakes black. The rule (docs/format.md, "Faces that point in"):

    A face points in when its closed surface (and any of the object's closed surfaces whose
    bounds hold it) encloses the side its normal points to (rays from just off that side cross
    them an odd number of times, whichever way they go),
    unless a light or an emitter lies inside that shell: then it is a room seen from inside.

Only closed shells count: connected triangles whose every edge (corners welded by position) is
shared by exactly two triangles. Open surfaces (a single plane) have no inside and are never
flagged; the parity test does not depend on the winding, so a mesh with half its faces flipped
is found patch by patch (faces facing alike across their shared edges: `PATCH_SAMPLES` of each
are tested, and the majority decides the patch), a thick wall (two nested shells) is not
flagged, a shell poking into another of the same object is judged by itself, and a mirrored
object's winding does not matter (the side is the one the vertex normals point to).

`find` works on an atlas's `SurfaceTriangles` before the bake points (the panel's check and
the bake call it); `flip` turns the flagged triangles' normals round (the setting "bake from
the open side"), so their texels' n_v and hemisphere are those of the side light reaches.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, replace

import numpy as np

from .. import parallel, progress, raster_kernels
from ..rays import RayScene, ray_offset
from .data import SurfaceTriangles, weld

#: What a bake does with faces that point in (scene `inward_faces`, CLI `--inward-faces`).
OPEN_SIDE, AS_MODELLED, REFUSE = "OPEN_SIDE", "AS_MODELLED", "REFUSE"
MODES = (OPEN_SIDE, AS_MODELLED, REFUSE)
#: Parity rays per face, in opposite pairs. A face points in when all of them but one cross the
#: shells an odd number of times: a ray through an edge or a vertex may miscount, and a sheet
#: modelled twice back to back (a two-sided wall: two coincident surfaces, crossed as one) gives
#: odd on one side only, so exactly half.
PARITY_RAYS = 6
#: Faces tested per patch (faces facing alike across shared edges, `facing_patches`).
PATCH_SAMPLES = 16
#: Most crossings followed along one parity ray.
MAX_CROSSINGS = 256
#: How far off its face (in ray offsets, `rays.ray_offset`) a face's parity rays start.
START_OFFSETS = 4.0

#: What the bake did, as the warnings say it (and, before a bake, what it will do).
ACTIONS = {
    OPEN_SIDE: ("baked from the open side (n_v turned round, as Cycles shades them)", "the bake takes the open side"),
    AS_MODELLED: ("baked as modelled: black there", "the bake keeps them as modelled: black there"),
    REFUSE: ("bake refused", "the bake refuses them"),
}
#: The fix the warnings name.
FIX = "Mesh > Normals > Recalculate Outside, or bake with Faces Pointing In = Bake from the Open Side"


@dataclass
class InwardObject:
    """One object with faces that point in: name; faces (Blender polygons, or triangles when the
    surface has no polygon ids); triangles: their indices into the atlas's surface; texels: the
    covered texels on them (-1: not known yet, before the bake points)."""

    name: str
    faces: int
    triangles: np.ndarray
    texels: int = -1

    def message(self, mode: str | None = None, done: bool = True) -> str:
        """The warning naming the object (docs/format.md, "Faces that point in"): what `mode`
        did (`done`) or will do with the faces, and the fix."""
        texels = f", {self.texels} texels" if self.texels >= 0 else ""
        text = (
            f"'{self.name}' has {self.faces} faces whose normals point inwards{texels} "
            f"(its lightmap would be black there): {FIX}"
        )
        return text if mode is None else f"{text}; {ACTIONS[mode][0 if done else 1]}"

    def note(self, mode: str) -> dict:
        """The sidecar's record of it."""
        return {
            "object": self.name,
            "inward_faces": self.faces,
            "inward_texels": self.texels,
            "action": mode.lower(),
            "message": self.message(mode),
        }


def light_points(scene) -> np.ndarray:
    """(N, 3) points that light a closed shell from inside when they lie in it: the point, spot
    and area lights' positions and, for each emissive triangle of `scene` (a BakeScene; it emits
    on both sides), its centroid moved a little off it to either side (a room's own glowing
    panel lights the room)."""
    points = [np.asarray(light.position, np.float64) for light in scene.lights if hasattr(light, "position")]
    out = np.array(points, np.float64).reshape(-1, 3)
    if scene.emission is not None:
        tris = np.asarray(scene.triangles, np.float64)[np.asarray(scene.emission).any(axis=1)]
        normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        step = normal * (START_OFFSETS * ray_offset(np.asarray(scene.triangles)))
        centre = tris.mean(axis=1)
        out = np.concatenate([out, centre + step, centre - step])
    return out


def find(
    surface: SurfaceTriangles, objects: list[str], lights: np.ndarray | None = None, check=None, threads: int = 0
) -> list[InwardObject]:
    """The objects of one atlas (`surface.object_index` indexes `objects`) with faces that point
    in, in object order; `lights` (N, 3): `light_points` of the scene (a closed shell holding
    one is a room seen from inside: not flagged). The objects are checked on `threads` workers
    (0 = every core; Embree and numpy's large operations release the GIL), the largest first;
    `check()` between objects (a `core.progress.Tick` is told the share of triangles done)."""
    lights = np.zeros((0, 3)) if lights is None else np.asarray(lights, np.float64).reshape(-1, 3)
    positions = np.asarray(surface.positions, np.float64)
    object_index = np.asarray(surface.object_index)
    polygon = getattr(surface, "polygon", None)
    normals = np.asarray(surface.normals)
    order = np.argsort(object_index, kind="stable")
    keys, starts = np.unique(object_index[order], return_index=True)
    parts = np.split(order, starts[1:]) if len(order) else []
    tick = progress.ticker(check)
    flagged: dict[int, np.ndarray] = {}
    with ThreadPoolExecutor(max_workers=parallel.resolve_threads(threads)) as pool:
        futures = {
            pool.submit(lambda rows: rows[inward_triangles(positions[rows], normals[rows], lights)], parts[j]): j
            for j in sorted(range(len(parts)), key=lambda j: -len(parts[j]))
        }
        try:
            done = 0
            for future in as_completed(futures):
                j = futures[future]
                flagged[j] = future.result()
                done += len(parts[j])
                tick.at(done / max(len(order), 1))
        finally:
            for future in futures:
                future.cancel()
    found = []
    for j, k in enumerate(keys):
        if len(flagged[j]):
            rows = flagged[j]
            faces = len(np.unique(np.asarray(polygon)[rows])) if polygon is not None else len(rows)
            found.append(InwardObject(str(objects[int(k)]), faces, rows))
    return found


def inward_triangles(positions: np.ndarray, normals: np.ndarray, lights: np.ndarray | None = None) -> np.ndarray:
    """(T,) bool: the triangles `positions (T, 3, 3)` of one object whose side its corner normals
    `normals (T, 3, 3)` point to is enclosed by the object's closed shells (the module's rule)."""
    positions = np.asarray(positions, np.float64)
    t = len(positions)
    out = np.zeros(t, bool)
    if t < 4:
        return out
    cross = np.cross(positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0])
    length = np.linalg.norm(cross, axis=1)
    vertex = weld(positions)
    good = (
        (length > 0) & (vertex[:, 0] != vertex[:, 1]) & (vertex[:, 1] != vertex[:, 2]) & (vertex[:, 0] != vertex[:, 2])
    )
    component, closed = closed_shells(vertex, good)
    rows = np.flatnonzero(closed)
    if len(rows) == 0:
        return out
    # the side each triangle's normals point to: its face normal turned to their mean
    face = cross[rows] / length[rows, None]
    mean = np.asarray(normals, np.float64)[rows].sum(axis=1)
    turned = np.einsum("ij,ij->i", face, mean) < 0.0
    face *= np.where(turned, -1.0, 1.0)[:, None]
    # faces facing alike across every shared edge form a patch: judged by a few of its faces
    patch = facing_patches(vertex[rows], turned)
    sample = _samples(patch)
    shells = RayScene(positions[rows])
    offset = ray_offset(positions[rows])
    start = positions[rows[sample]].mean(axis=1) + face[sample] * (START_OFFSETS * offset)
    shell = np.unique(component[rows], return_inverse=True)[1].reshape(-1)
    odd = _odd(shells, start, offset, shell, shell[sample], _boxes(positions[rows], shell))
    inside_sample = odd.sum(axis=1) >= PARITY_RAYS - 1
    votes = np.bincount(patch[sample], weights=inside_sample, minlength=patch.max() + 1)
    count = np.bincount(patch[sample], minlength=patch.max() + 1)
    inside = (2 * votes > count)[patch]
    lights = np.zeros((0, 3)) if lights is None else lights
    if inside.any() and len(lights):  # a shell holding a light or an emitter is a room seen from inside
        lit = _lit(shells, lights, component[rows], offset)
        inside &= ~np.isin(component[rows], lit)
    out[rows[inside]] = True
    return out


def facing_patches(vertex: np.ndarray, turned: np.ndarray) -> np.ndarray:
    """(T,) patch labels of closed-shell triangles with welded corners `vertex (T, 3)`: triangles
    sharing an edge are in one patch when they face alike, i.e. their windings, each reversed
    where `turned` (its normals point against its winding), run the shared edge in opposite
    directions. A patch faces one way throughout, so a few of its faces decide it."""
    v = np.where(turned[:, None], vertex[:, ::-1], vertex)
    a = np.concatenate([v[:, 0], v[:, 1], v[:, 2]])
    b = np.concatenate([v[:, 1], v[:, 2], v[:, 0]])
    owner = np.tile(np.arange(len(v)), 3)
    span = int(v.max()) + 1
    directed = a * span + b
    reverse = b * span + a
    order = np.argsort(directed, kind="stable")
    at = np.searchsorted(directed[order], reverse)
    found = (at < len(order)) & (directed[order][np.minimum(at, len(order) - 1)] == reverse)
    left, right = owner[found], owner[order[at[found]]]
    return _components(len(v), left, right)


def _components(n: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """(n,) labels of the connected components of n nodes joined by the pairs (left, right):
    each node's label is the smallest node of its component (`raster_kernels.components`)."""
    return raster_kernels.get().components(
        n, np.ascontiguousarray(left, np.int64), np.ascontiguousarray(right, np.int64)
    )


def _samples(patch: np.ndarray, per_patch: int = PATCH_SAMPLES) -> np.ndarray:
    """Indices of up to `per_patch` triangles of each patch, spread over its triangles' order."""
    order = np.argsort(patch, kind="stable")
    labels, start, size = np.unique(patch[order], return_index=True, return_counts=True)
    k = np.minimum(size, per_patch)
    which = np.repeat(np.arange(len(labels)), k)
    rank = np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)
    return order[start[which] + (rank * size[which]) // k[which]]


def _boxes(positions: np.ndarray, shell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low (K, 3), high (K, 3)): the bounding box of each shell 0..K-1 (`shell (T,)`) of the
    triangles `positions (T, 3, 3)`."""
    k = int(shell.max()) + 1
    low = np.full((k, 3), np.inf)
    high = np.full((k, 3), -np.inf)
    np.minimum.at(low, shell, positions.min(axis=1))
    np.maximum.at(high, shell, positions.max(axis=1))
    return low, high


def closed_shells(vertex: np.ndarray, good: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connected shells of triangles with welded corner ids `vertex (T, 3)` (only `good` ones:
    not degenerate): (component (T,) int, -1 for bad triangles; closed (T,) bool: the
    triangle's shell has every edge shared by exactly two triangles)."""
    t = len(vertex)
    tri = np.flatnonzero(good)
    component = np.full(t, -1, np.int64)
    closed = np.zeros(t, bool)
    if len(tri) == 0:
        return component, closed
    v = vertex[tri]
    a = np.concatenate([v[:, 0], v[:, 1], v[:, 2]])
    b = np.concatenate([v[:, 1], v[:, 2], v[:, 0]])
    owner = np.tile(np.arange(len(tri)), 3)
    edge = np.minimum(a, b) * (int(v.max()) + 1) + np.maximum(a, b)  # one int64 key per edge
    _, edge_id, counts = np.unique(edge, return_inverse=True, return_counts=True)
    edge_id = edge_id.reshape(-1)
    # union of triangles sharing an edge
    order = np.argsort(edge_id, kind="stable")
    e_sorted, o_sorted = edge_id[order], owner[order]
    pair = e_sorted[1:] == e_sorted[:-1]
    label = _components(len(tri), o_sorted[:-1][pair], o_sorted[1:][pair])
    open_edge = counts[edge_id] != 2  # per (triangle, edge) entry
    open_label = np.unique(label[owner[open_edge]])
    component[tri] = label
    closed[tri] = ~np.isin(label, open_label)
    return component, closed


def _directions(n: int) -> np.ndarray:
    """n fixed unit directions (n even) in opposite pairs, spread over the sphere (Fibonacci),
    tilted off the axes so parity rays do not run along a box's faces or through its edges."""
    half = _spread(n // 2)
    return np.concatenate([half, -half])


def _spread(n: int) -> np.ndarray:
    """n fixed unit directions spread over the sphere (Fibonacci), tilted off the axes."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    phi = k * np.pi * (3.0 - np.sqrt(5.0)) + 0.3719
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    tilt = np.array([[0.9553, 0.1737, 0.2391], [-0.1411, 0.9780, -0.1538], [-0.2606, 0.1156, 0.9585]])
    d = d @ tilt.T
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _odd(
    shells: RayScene,
    start: np.ndarray,
    offset: float,
    shell: np.ndarray,
    own: np.ndarray,
    boxes: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """(S, PARITY_RAYS) bool: the parity rays from `start (S, 3)` cross an odd number of times
    the shell `own (S,)` and the shells whose bounding box (`boxes`, `_boxes`) holds its box:
    e.g. the outer skin of a thick wall around its inner one, but not a shell it merely pokes
    into (a handle sunk into a drawer of the same object). `shell`: the shell of each of
    `shells`' primitives."""
    ray, prim = _count(shells, start, offset)
    mine, theirs = own[ray // PARITY_RAYS], shell[prim]
    low, high = boxes
    holds = (low[theirs] <= low[mine]).all(axis=1) & (high[theirs] >= high[mine]).all(axis=1)
    hits = np.bincount(ray[(theirs == mine) | holds], minlength=len(start) * PARITY_RAYS)
    return (hits % 2 == 1).reshape(len(start), PARITY_RAYS)


def _lit(shells: RayScene, points: np.ndarray, component: np.ndarray, offset: float) -> np.ndarray:
    """The shells (labels of `component`, indexed by `shells`' primitives) that hold one of
    `points (N, 3)`: most of its parity rays cross that shell alone an odd number of times."""
    ray, prim = _count(shells, points, offset)
    if len(ray) == 0:
        return np.zeros(0, np.int64)
    key = np.stack([ray, component[prim]], axis=1)
    pairs, counts = np.unique(key, axis=0, return_counts=True)
    odd = pairs[counts % 2 == 1]  # (ray, shell) crossed an odd number of times
    point_shell, votes = np.unique(np.stack([odd[:, 0] // PARITY_RAYS, odd[:, 1]], axis=1), axis=0, return_counts=True)
    return np.unique(point_shell[votes * 2 > PARITY_RAYS, 1])


def _count(shells: RayScene, start: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Every crossing of PARITY_RAYS rays from each of `start (S, 3)` with `shells`: (ray (H,),
    prim (H,)), ray = start index · PARITY_RAYS + direction index."""
    dirs = _directions(PARITY_RAYS)
    origin = np.repeat(start, PARITY_RAYS, axis=0)
    direction = np.tile(dirs, (len(start), 1))
    alive = np.arange(len(origin))
    rays, prims = [], []
    for _ in range(MAX_CROSSINGS):
        if len(alive) == 0:
            break
        t, prim, _ng = shells.intersect(origin[alive], direction[alive])
        hit = prim >= 0
        alive, t, prim = alive[hit], t[hit].astype(np.float64), prim[hit]
        rays.append(alive)
        prims.append(prim)
        origin[alive] += direction[alive] * (t + 0.5 * offset)[:, None]
    ray = np.concatenate(rays) if rays else np.zeros(0, np.int64)
    prim = np.concatenate(prims) if prims else np.zeros(0, np.int64)
    return ray, prim


def flip(surface: SurfaceTriangles, triangles: np.ndarray) -> SurfaceTriangles:
    """`surface` with the corner normals of `triangles` turned round (a copy of the normals; the
    rest shared): their texels bake the other side's hemisphere ("bake from the open side")."""
    if len(triangles) == 0:
        return surface
    normals = np.array(surface.normals, copy=True)
    normals[triangles] *= -1.0
    return replace(surface, normals=normals)


def flip_scene(scene, positions: np.ndarray):
    """`scene` (a BakeScene) with the winding of its triangles that are `positions (F, 3, 3)` (the
    flipped faces, corners in any order) turned round (corners 1 and 2 swapped, with their texture
    UVs), so every back-face test (buried texels, `settle`, probe validity) sees those faces as the
    open side does; `scene` itself when none matches. Matched by exact corner positions (the bake
    reads receivers and occluders from the same evaluated meshes)."""
    positions = np.asarray(positions, np.float64).reshape(-1, 3, 3)
    triangles = np.asarray(scene.triangles, np.float64)
    if len(positions) == 0 or len(triangles) == 0:
        return scene
    rows = _same_triangles(positions, triangles)
    if len(rows) == 0:
        return scene
    triangles = triangles.copy()
    triangles[rows] = triangles[rows][:, [0, 2, 1]]
    changes = {"triangles": triangles}
    if scene.texture_uv is not None:
        texture_uv = np.array(scene.texture_uv, copy=True)
        texture_uv[rows] = texture_uv[rows][:, [0, 2, 1]]
        changes["texture_uv"] = texture_uv
    return replace(scene, **changes)


def _same_triangles(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Indices of the `triangles (T, 3, 3)` whose corners are exactly those of one of `positions
    (F, 3, 3)` (in any order; 0.0 and -0.0 alike). The whole scene is narrowed first to the
    triangles whose per-axis corner bounds are bit for bit some face's (bounds do not depend on
    the corners' order, and equal corners give equal bounds); only those are welded and matched."""
    candidates = np.flatnonzero(np.isin(_bounds_key(triangles), _bounds_key(positions)))
    if len(candidates) == 0:
        return candidates
    ids = weld(np.concatenate([positions, triangles[candidates]]))
    ids.sort(axis=1)
    _, key = np.unique(ids, axis=0, return_inverse=True)
    key = key.reshape(-1)
    return candidates[np.isin(key[len(positions) :], key[: len(positions)])]


def _bounds_key(triangles: np.ndarray) -> np.ndarray:
    """A 64-bit hash (T,) of each triangle's per-axis min and max corner coordinates (-0.0 as 0.0)."""
    t = np.asarray(triangles)
    # the corners' minimum and maximum pairwise (a reduction over the middle axis is slow in numpy)
    lo = np.minimum(np.minimum(t[:, 0], t[:, 1]), t[:, 2]) + 0.0
    hi = np.maximum(np.maximum(t[:, 0], t[:, 1]), t[:, 2]) + 0.0
    bits = np.concatenate([lo, hi], axis=1).view(np.uint64)
    key = np.zeros(len(t), np.uint64)
    for k in range(bits.shape[1]):
        key = (key ^ bits[:, k]) * np.uint64(0x100000001B3)
    return key


def count_texels(found: list[InwardObject], triangle: np.ndarray) -> None:
    """Sets each object's `texels`: the bake points whose triangle (`BakePoints.triangle`) is one
    of its flagged triangles."""
    for item in found:
        item.texels = int(np.isin(triangle, item.triangles).sum())
