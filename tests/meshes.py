"""Small test meshes as numpy arrays: (positions (V, 3), triangles (T, 3))."""
import numpy as np


def plane(size=1.0):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float) * size
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def cube(size=1.0, centre=(0, 0, 0)):
    v = (np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], float) - 0.5) * size
    f = np.array([(0, 3, 2), (0, 2, 1), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5),
                  (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)])
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
