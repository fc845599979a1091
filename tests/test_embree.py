"""Our Embree binding (core.embree through core.rays) against a brute-force numpy ray-triangle
intersection, against embreex's own API, and on the library lookup of every shipped wheel."""

import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core import embree, rays


def brute_force(tri, origins, dirs, tmax):
    """Closest hit of each ray over all triangles (Möller–Trumbore, float64, both faces):
    (t or inf, prim or -1, u, v)."""
    p0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    pvec = np.cross(dirs[:, None, :], e2[None])  # (R, T, 3)
    det = np.einsum("tj,rtj->rt", e1, pvec)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origins[:, None, :] - p0[None]
        u = np.einsum("rtj,rtj->rt", s, pvec) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("rj,rtj->rt", dirs, q) * inv
        t = np.einsum("tj,rtj->rt", e2, q) * inv
    ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= tmax[:, None])
    t = np.where(ok, t, np.inf)
    prim = np.argmin(t, axis=1)
    rows = np.arange(len(origins))
    best = t[rows, prim]
    return best, np.where(np.isfinite(best), prim, -1), u[rows, prim], v[rows, prim]


@pytest.fixture
def scene():
    """Small random triangles in a unit box, rays from inside it, some of them short."""
    rng = np.random.default_rng(3)
    centres = rng.uniform(-1, 1, (300, 1, 3))
    tri = centres + 0.15 * rng.normal(size=(300, 3, 3))
    origins = rng.uniform(-1.2, 1.2, (4000, 3))
    dirs = rng.normal(size=(4000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    tmax = np.where(rng.random(4000) < 0.3, rng.uniform(0.0, 1.0, 4000), np.inf)
    return tri, origins, dirs, tmax


def test_closest_hits_match_brute_force_intersection(scene):
    tri, origins, dirs, tmax = scene
    t, prim, ng, u, v = rays.RayScene(tri).intersect(origins, dirs, tmax, barycentrics=True)
    t_ref, prim_ref, u_ref, v_ref = brute_force(tri, origins, dirs, tmax)
    assert (prim >= 0).sum() > 1000 and (prim < 0).sum() > 500  # decisive both ways
    agree = prim == prim_ref
    assert agree.mean() > 0.998  # float32 ties at shared depths may differ
    hit = agree & (prim >= 0)
    np.testing.assert_allclose(t[hit], t_ref[hit], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(u[hit], u_ref[hit], atol=1e-4)
    np.testing.assert_allclose(v[hit], v_ref[hit], atol=1e-4)
    assert np.all(np.isinf(t[prim < 0])) and np.all(ng[prim < 0] == 0)
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[prim[hit]]
    cos = np.einsum("ij,ij->i", ng[hit], face) / np.linalg.norm(ng[hit], axis=1) / np.linalg.norm(face, axis=1)
    np.testing.assert_allclose(cos, 1.0, atol=1e-5)  # counter-clockwise winding, unnormalised


def test_occlusion_agrees_with_the_closest_hit_and_dtypes_agree(scene):
    tri, origins, dirs, tmax = scene
    rs = rays.RayScene(tri)
    reach = np.where(np.isinf(tmax), 0.8, tmax)
    t, prim, _ = rs.intersect(origins, dirs, reach)
    np.testing.assert_array_equal(rs.occluded(origins, dirs, reach), prim >= 0)
    t32, prim32, _ = rs.intersect(origins.astype(np.float32), dirs.astype(np.float32), reach)
    assert np.mean(prim32 == prim) > 0.999
    assert rs.occluded(origins, dirs, 0.0).sum() == 0  # zero-length rays see nothing
    scalar = rs.occluded(origins, dirs, 0.5)
    np.testing.assert_array_equal(scalar, rs.occluded(origins, dirs, np.full(len(origins), 0.5)))


def test_shadow_rays_are_the_occlusion_query_above_the_horizon(scene):
    """`RayScene.shadow` (next-event estimation's fused query) against its spelling in numpy
    queries: rows below the normal's horizon or not allowed are not traced and weigh 0; the
    others weigh scale·cosθ (or scale) unless something lies short of the light (stopping
    offset and 1e-4 of the way before it; a light at infinity: unbounded)."""
    tri, origins, dirs, tmax = scene
    rs = rays.RayScene(tri)
    rng = np.random.default_rng(4)
    normals = rng.normal(size=origins.shape)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    dist = np.where(rng.random(len(origins)) < 0.5, rng.uniform(0.0, 2.0, len(origins)), np.inf)
    allowed = rng.random(len(origins)) < 0.8
    offset = 1e-3
    cos = (dirs * normals).sum(axis=1)
    reach = np.maximum(np.where(np.isfinite(dist), dist * (1 - 1e-4) - offset, 3e38), 0.0)
    seen = ~rs.occluded(origins, dirs, reach)
    for scale, cosine, rows in ((1.0, True, None), (0.25, False, allowed)):
        weight, traced = rs.shadow(origins, dirs, dist, normals, offset, scale, cosine, rows)
        traced_rows = (cos > 0) & (True if rows is None else rows)
        assert traced == traced_rows.sum()
        want = np.where(traced_rows & seen, scale * cos if cosine else scale, 0.0)
        np.testing.assert_array_equal(weight, want)
        assert (weight[traced_rows] == 0).sum() > 200 and (weight[traced_rows] > 0).sum() > 200  # both ways
    # a sun's directions may be one row broadcast to every point
    sun = np.broadcast_to(dirs[:1], dirs.shape)
    weight, _ = rs.shadow(origins, sun, np.full(len(origins), np.inf), normals, offset)
    want = np.where(normals @ dirs[0] > 0, ~rs.occluded(origins, np.ascontiguousarray(sun), 3e38), False)
    np.testing.assert_array_equal(weight > 0, want)


@pytest.mark.parametrize("count", [0, 1, 7, 9, 3997])
def test_packets_answer_exactly_as_single_rays(scene, count, monkeypatch):
    """Packet queries (8 consecutive rays per rtcIntersect8 / rtcOccluded8, the shadow rays'
    traced rows gathered) return bit for bit what one ray per query returns, for any number of
    rays (a partial last packet, shadow rows skipped mid-packet)."""
    tri, origins, dirs, tmax = scene
    origins, dirs, tmax = origins[:count], dirs[:count], tmax[:count]
    rs = rays.RayScene(tri)
    assert embree.library().packets  # this build of Embree answers packets
    rng = np.random.default_rng(5)
    normals = rng.normal(size=origins.shape)
    dist = np.where(rng.random(count) < 0.5, rng.uniform(0.0, 2.0, count), np.inf)
    allowed = rng.random(count) < 0.7
    reach = np.where(np.isinf(tmax), 0.8, tmax)

    def queries():
        return (
            *rs.intersect(origins, dirs, tmax, barycentrics=True),
            rs.occluded(origins, dirs, reach),
            *rs.shadow(origins, dirs, dist, normals, 1e-3, 0.5, True, allowed),
        )

    packets = queries()
    monkeypatch.setattr(embree.library(), "packets", False)  # as a library without packets
    single = queries()
    for a, b in zip(packets, single):
        np.testing.assert_array_equal(a, b)
    if count > 1000:
        assert (packets[1] >= 0).sum() > 1000 and packets[5].sum() > 100 and (packets[6] > 0).sum() > 100


def test_a_library_without_packets_is_queried_one_ray_at_a_time(scene, monkeypatch):
    tri, origins, dirs, tmax = scene
    rs = rays.RayScene(tri)
    expected = rs.intersect(origins, dirs, tmax)
    monkeypatch.setattr(embree.library(), "packets", False)
    assert rs._scene._kernel("intersect") is embree.library().kernels.intersect_rays
    for a, b in zip(rs.intersect(origins, dirs, tmax), expected):
        np.testing.assert_array_equal(a, b)


def test_agrees_with_embreex_own_api(scene):
    """The same Embree library through embreex's classes (copying) and ours (shared buffers)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    tri, origins, dirs, tmax = scene
    theirs = rtcore_scene.EmbreeScene()
    TriangleMesh(theirs, tri.astype(np.float32))
    out = theirs.run(origins.astype(np.float32), dirs.astype(np.float32), output=True)
    t, prim, ng = rays.RayScene(tri).intersect(origins, dirs)
    np.testing.assert_array_equal(prim, out["primID"])
    hit = prim >= 0
    np.testing.assert_allclose(t[hit], out["tfar"][hit], rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(ng[hit], out["Ng"][hit], rtol=1e-4, atol=1e-6)


def test_scene_owns_its_copy_and_threads_query_it_together(scene):
    tri, origins, dirs, tmax = scene
    mine = tri.copy()
    rs = rays.RayScene(mine)
    expected = rs.intersect(origins, dirs, tmax)[1]
    mine[:] = 0.0  # the caller's array is not Embree's
    del mine
    results = [None] * 4

    def work(i):
        results[i] = rs.intersect(origins, dirs, tmax)[1]

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    for r in results:
        np.testing.assert_array_equal(r, expected)


def test_degenerate_input_empty_scene_nan_triangles_and_nan_rays():
    ray_o, ray_d = np.array([[0.1, 0.1, -1.0], [np.nan, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    for tri in (np.zeros((0, 3, 3)), np.zeros((3, 3, 3))):  # nothing / zero-area only
        rs = rays.RayScene(tri)
        t, prim, ng = rs.intersect(ray_o, ray_d)
        assert np.all(prim == -1) and np.all(np.isinf(t))
        assert not rs.occluded(ray_o, ray_d, 5.0).any()
    good = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    rs = rays.RayScene(np.array([[[np.nan, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], good]))
    t, prim, _ = rs.intersect(ray_o, ray_d)
    assert prim.tolist() == [1, -1]  # the NaN triangle is skipped, ids kept
    np.testing.assert_allclose(t[0], 1.0, rtol=1e-6)
    assert rs.intersect(np.zeros((0, 3)), np.zeros((0, 3)))[1].shape == (0,)


def test_the_embree_library_is_found_in_every_shipped_embreex_wheel():
    import fetch_wheels  # downloads (hash-checked) what is missing

    wheels = [w for w in fetch_wheels.fetch() if w.name.startswith("embreex-")]
    assert len(wheels) == 8  # 4 platforms x CPython 3.11, 3.13
    for wheel in wheels:
        names = zipfile.ZipFile(wheel).namelist()
        found = embree.find_library(names)
        assert found is not None and "embree4" in Path(found).name, wheel.name
        assert "tbb" not in found and not found.endswith((".py", ".pyd", ".pxd")), wheel.name
        assert embree.find_library([n for n in names if n != found]) is None  # exactly one


def test_the_library_is_found_in_this_install():
    lib = embree.library()
    assert lib.device and lib.kernels.intersect_rays is not None
