"""Small meshes as numpy arrays, bpy-free: (positions (V, 3), triangles (T, 3)) (polygon meshes
also return a polygon index per triangle), and helpers that inspect UV layouts.

Used by the core tests (tests/test_tracer.py, test_unwrap_*.py, ...), by the bpy tests that need
raw vertex lists, and by the benches (`sphere_field`: bench/unwrap_raster.py, tracer.py,
threads.py, and the `field` scene of scenekit/scenes.py)."""

import numpy as np


def plane(size=1.0):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float) * size
    return v, np.array([[0, 1, 2], [0, 2, 3]])


#: The six outward (counter-clockwise) quads of `box_corners`' eight corners.
BOX_QUADS = ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))


def box_corners(lo, hi) -> list[tuple[float, float, float]]:
    """The eight corners of the axis-aligned box from `lo` to `hi`, bottom (z = lo) face first,
    counter-clockwise seen from above; `BOX_QUADS` index them."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    return [(x, y, z) for z in (z0, z1) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]


def cube(size=1.0, centre=(0, 0, 0)):
    v = (
        np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], float) - 0.5
    ) * size
    f = np.array(
        [
            (0, 3, 2),
            (0, 2, 1),
            (4, 5, 6),
            (4, 6, 7),
            (0, 1, 5),
            (0, 5, 4),
            (1, 2, 6),
            (1, 6, 5),
            (2, 3, 7),
            (2, 7, 6),
            (3, 0, 4),
            (3, 4, 7),
        ]
    )
    return v + np.asarray(centre, float), f


def uv_sphere(rings=12, segments=24, radius=1.0):
    theta = np.linspace(0, np.pi, rings + 1)
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta[1:-1], phi, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    v = np.vstack([[0, 0, 1], v, [0, 0, -1]]) * radius
    idx = lambda r, s: 1 + r * segments + s % segments
    faces = [(0, idx(0, s), idx(0, s + 1)) for s in range(segments)]
    for r in range(rings - 2):
        for s in range(segments):
            faces += [(idx(r, s), idx(r + 1, s), idx(r + 1, s + 1)), (idx(r, s), idx(r + 1, s + 1), idx(r, s + 1))]
    last = len(v) - 1
    faces += [(idx(rings - 2, s), last, idx(rings - 2, s + 1)) for s in range(segments)]
    return v, np.array(faces)


def slivers(n=24):
    """A fan of long thin triangles (aspect ~ 1:200) plus one degenerate (zero-area) face."""
    angles = np.linspace(0, np.pi / 2, n + 1)
    v = np.vstack([[0, 0, 0], np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], 1) * 2.0])
    f = [(0, k + 1, k + 2) for k in range(n)] + [(0, 1, 1)]
    return v, np.array(f)


def vertex_normals(v, f):
    n = np.zeros_like(v)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1), [0, 0, 1])


def bumpy_quads(n=16, amplitude=0.03, waves=0.6, seed=0, size=2.0):
    """An n × n grid of non-planar quads, each two triangles of one polygon, on a wavy surface
    (waves: height of the waves, amplitude: of random bumps; curved enough that xatlas cuts it
    into charts along quad diagonals): (positions (V, 3), triangles (T, 3), polygon index (T,))."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, size, n + 1), np.linspace(0, size, n + 1), indexing="ij")
    z = waves * np.sin(3 * x) * np.cos(3 * y) + amplitude * rng.normal(size=x.shape)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    idx = lambda i, j: i * (n + 1) + j
    f, poly = [], []
    for i in range(n):
        for j in range(n):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            f += [(a, b, c), (a, c, d)]
            poly += [i * n + j] * 2
    return v, np.array(f), np.array(poly)


def ngon(sides=12, radius=1.0, bump=0.1, centre=(0.0, 0.0, 0.0), concave=True):
    """One n-gon, a star when concave, warped out of its plane, triangulated by ear clipping
    in its plane as Blender does: (positions (V, 3), triangles (T, 3), polygon index (T,) all 0)."""
    angle = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    r = radius * (np.where(np.arange(sides) % 2 == 0, 1.0, 0.55) if concave else 1.0)
    v = np.stack([r * np.cos(angle), r * np.sin(angle), bump * np.cos(3 * angle)], -1) + centre
    return v, ear_clip(v[:, :2]), np.zeros(sides - 2, dtype=int)


def ear_clip(p):
    """Triangles (n - 2, 3) of the simple counter-clockwise polygon p (n, 2), by ear clipping."""
    left = list(range(len(p)))
    out = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    while len(left) > 3:
        for k in range(len(left)):
            i, j, l = left[k - 1], left[k], left[(k + 1) % len(left)]
            if cross(p[i], p[j], p[l]) <= 0:
                continue
            inside = any(
                cross(p[i], p[j], p[m]) > 0 and cross(p[j], p[l], p[m]) > 0 and cross(p[l], p[i], p[m]) > 0
                for m in left
                if m not in (i, j, l)
            )
            if not inside:
                out.append((i, j, l))
                left.pop(k)
                break
    out.append(tuple(left))
    return np.array(out)


def combine(*parts):
    """One mesh from (positions, triangles, polygons) parts: vertex and polygon indices offset."""
    v, f, poly, nv, npoly = [], [], [], 0, 0
    for pv, pf, pp in parts:
        v.append(pv)
        f.append(pf + nv)
        poly.append(pp + npoly)
        nv += len(pv)
        npoly += int(pp.max()) + 1
    return np.vstack(v), np.vstack(f), np.concatenate(poly)


def uv_charts(uv):
    """Chart label (T,) per triangle of UVs (T, 3, 2): triangles with a corner at the same UV
    are one chart (charts are padded apart, so different charts never share a UV point; vertex
    indices are not used, as meshes with split vertices have none in common)."""
    key = np.unique(uv.reshape(-1, 2), axis=0, return_inverse=True)[1].reshape(-1, 3)
    label = np.arange(len(uv))
    while True:
        low = np.full(key.max() + 1, len(uv))
        np.minimum.at(low, key.ravel(), np.repeat(label, 3))
        new = low[key].min(axis=1)
        if (new == label).all():
            return label
        label = new


def texel_overlaps(uvs, width, height):
    """How the bake would see UV layers, rasterised (core.raster): {"objects": texels covered by
    two objects, "charts": texels covered by two charts of one object, and per object: "area":
    covered area (overlaps counted once), "summed": summed coverage, "touched": texels touched,
    "partial": texels only partly covered}. uvs: per object (T, 3, 2) UVs."""
    from hhd_lightmapper.core import raster

    rows, out = [], {"area": [], "summed": [], "touched": [], "partial": []}
    for index, uv in enumerate(uvs):
        cov = raster.rasterise(np.asarray(uv, dtype=np.float64), width, height)
        chart = uv_charts(np.asarray(uv, dtype=np.float64))[cov.triangle]
        rows.append(np.unique(np.column_stack([cov.texel, np.full(len(cov.texel), index), chart]), axis=0))
        inverse = np.unique(cov.texel, return_inverse=True)[1].ravel()
        per_texel = np.bincount(inverse, weights=cov.area)
        out["area"].append(float(np.minimum(per_texel, 1.0).sum()))
        out["summed"].append(float(cov.area.sum()))
        out["touched"].append(len(per_texel))
        out["partial"].append(int((per_texel < 1.0 - 1e-9).sum()))
    rows = np.concatenate(rows)  # unique (texel, object, chart)
    objects, charts = np.unique(rows[:, :2], axis=0, return_counts=True)
    return dict(out, objects=int((np.bincount(objects[:, 0]) > 1).sum()), charts=len(np.unique(objects[charts > 1, 0])))


def sphere_field(n_triangles: int, seed: int = 0):
    """Displaced UV spheres of ~2000 triangles each on a grid, ≈ n_triangles in total (the
    displacement is deterministic: `seed` changes nothing, kept for the benches' calls)."""
    rings, segments = 25, 40  # 2 × 40 × 24 = 1920 triangles
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    unit = np.vstack([[0, 0, 1], unit, [0, 0, -1]])
    idx = lambda r, s: 1 + r * segments + s % segments
    faces = [(0, idx(0, s), idx(0, s + 1)) for s in range(segments)]
    for r in range(rings - 2):
        for s in range(segments):
            faces += [(idx(r, s), idx(r + 1, s), idx(r + 1, s + 1)), (idx(r, s), idx(r + 1, s + 1), idx(r, s + 1))]
    faces += [(idx(rings - 2, s), len(unit) - 1, idx(rings - 2, s + 1)) for s in range(segments)]
    faces = np.array(faces)
    count = max(1, round(n_triangles / len(faces)))
    side = int(np.ceil(np.sqrt(count)))
    verts, tris = [], []
    for k in range(count):
        bump = 1.0 + 0.15 * np.sin(3 * unit[:, 0] + k) * np.cos(4 * unit[:, 1])
        verts.append(unit * bump[:, None] + [3.0 * (k % side), 3.0 * (k // side), 0.0])
        tris.append(faces + k * len(unit))
    return np.vstack(verts), np.vstack(tris)
