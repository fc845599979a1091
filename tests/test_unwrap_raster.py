"""xatlas unwrap, conservative rasterisation and bake points against independent references."""

import numpy as np
import pytest

from hhd_lightmapper.core import bakepoints, raster, rays, textures, tracer, unwrap
from hhd_lightmapper.core.bakepoints import data as bakepoint_data
from hhd_lightmapper.core.bakepoints import flags
from hhd_lightmapper.core.bakepoints.covers import CoverProbe
from hhd_lightmapper.core.errors import BakeError
from hhd_lightmapper.core.scene import BakeScene
from hhd_lightmapper.core.unwrap import charting, data, instance_packing, packing, worker_runs
from scenekit import bakepoint_reference, meshes


# --- an independent, slow reference: clip one triangle against one texel in pure Python ---
def clip_area(tri, x0, y0):
    poly = [tuple(p) for p in tri]
    for inside, cut in (
        (lambda p: p[0] >= x0, lambda a, b: (x0, a[1] + (x0 - a[0]) * (b[1] - a[1]) / (b[0] - a[0]))),
        (lambda p: p[0] <= x0 + 1, lambda a, b: (x0 + 1, a[1] + (x0 + 1 - a[0]) * (b[1] - a[1]) / (b[0] - a[0]))),
        (lambda p: p[1] >= y0, lambda a, b: (a[0] + (y0 - a[1]) * (b[0] - a[0]) / (b[1] - a[1]), y0)),
        (lambda p: p[1] <= y0 + 1, lambda a, b: (a[0] + (y0 + 1 - a[1]) * (b[0] - a[0]) / (b[1] - a[1]), y0 + 1)),
    ):
        out = []
        for i, a in enumerate(poly):
            b = poly[(i + 1) % len(poly)]
            if inside(a):
                out.append(a)
            if inside(a) != inside(b):
                out.append(cut(a, b))
        poly = out
        if not poly:
            return 0.0
    return (
        abs(
            sum(
                poly[i][0] * poly[(i + 1) % len(poly)][1] - poly[(i + 1) % len(poly)][0] * poly[i][1]
                for i in range(len(poly))
            )
        )
        / 2
    )


def reference_coverage(uv, w, h):
    cov = {}
    for t, tri in enumerate(uv * [w, h]):
        for x in range(int(np.floor(tri[:, 0].min())), int(np.ceil(tri[:, 0].max()))):
            for y in range(int(np.floor(tri[:, 1].min())), int(np.ceil(tri[:, 1].max()))):
                a = clip_area(tri, x, y)
                if a > 1e-12:
                    cov[(t, y * w + x)] = a
    return cov


def unwrapped(mesh_fn, resolution=256, **kw):
    v, f = mesh_fn(**kw)
    result = unwrap.unwrap([unwrap.UnwrapMesh("m", v, f)], unwrap.UnwrapSettings(resolution=resolution, padding=4))
    return v, f, result


@pytest.mark.slow
@pytest.mark.parametrize("mesh_fn", [meshes.plane, meshes.cube, meshes.uv_sphere, meshes.slivers])
def test_raster_matches_the_slow_clipping_reference(mesh_fn):
    v, f, result = unwrapped(mesh_fn)
    uv = result.objects[0].uv.astype(np.float64)
    cov = raster.rasterise(uv, 256, 256)
    # the reference is pure Python: check 10 triangles spread over the mesh (degenerate included)
    some = np.unique(np.linspace(0, len(uv) - 1, 10).astype(int))
    ref = {(int(some[t]), x): a for (t, x), a in reference_coverage(uv[some], 256, 256).items()}
    got = {(int(t), int(x)): a for t, x, a in zip(cov.triangle, cov.texel, cov.area) if t in some}
    assert set(got) == set(ref)  # every touched texel, slivers included
    for key, a in ref.items():
        assert got[key] == pytest.approx(a, abs=1e-9)


@pytest.mark.parametrize("mesh_fn", [meshes.plane, meshes.cube, meshes.uv_sphere, meshes.slivers])
def test_bake_points_cover_every_texel_and_lie_on_the_surface(mesh_fn):
    v, f, result = unwrapped(mesh_fn)
    uv = result.objects[0].uv.astype(np.float64)
    n = meshes.vertex_normals(v, f)
    surface = bakepoints.SurfaceTriangles(v[f], n[f], uv, np.zeros(len(f), int), np.full((len(f), 3), 0.5))
    pts = bakepoints.build(surface, 256, 256)
    # summed coverage = UV area in texels (charts do not overlap)
    uv_area = np.abs(raster._signed_area(uv * 256)).sum()
    assert pts.coverage.sum() == pytest.approx(uv_area, rel=1e-9)
    assert (pts.coverage > 0).all() and (pts.coverage <= 1).all()
    assert len(np.unique(pts.texel)) == len(pts.texel)
    # positions lie in their triangle's plane and map back into their own texel
    tri = v[f][pts.triangle]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    assert np.abs(np.einsum("pi,pi->p", pts.position - tri[:, 0], fn)).max() < 1e-9
    for p_, t_, tx in list(zip(pts.position, pts.triangle, pts.texel))[::7]:
        # solve position = Σ b_k P_k (Σ b_k = 1) for b, then map b to the lightmap UV
        m = np.vstack([v[f[t_]].T, np.ones(3)])
        b = np.linalg.lstsq(m, np.append(p_, 1.0), rcond=None)[0]
        u_ = (b @ uv[t_]) * 256
        assert int(tx % 256) - 1e-6 <= u_[0] <= int(tx % 256) + 1 + 1e-6
        assert int(tx // 256) - 1e-6 <= u_[1] <= int(tx // 256) + 1 + 1e-6
    np.testing.assert_allclose(np.linalg.norm(pts.normal, axis=1), 1.0)
    assert (np.einsum("pi,pi->p", pts.normal, pts.face_normal) >= 0).all()


@pytest.mark.slow
@pytest.mark.parametrize("mesh_fn", [meshes.cube, meshes.uv_sphere])
@pytest.mark.parametrize("footprint", [0.5, 1.0])
def test_sample_origins_cover_the_footprint_of_the_texel_inside_its_triangle(mesh_fn, footprint, monkeypatch):
    """The bake footprint (the whole texel, as Cycles from 5.2.1; the central ½ × ½ before):
    uniform over the central footprint × footprint square of the texel, restricted to the
    texel's triangle (rejection sampling); texels whose triangle misses that square (partly
    covered texels at chart edges) sample the triangle's part of the whole texel instead.
    (Sampling every triangle of a texel, the default: tests/test_leaks_footprint.py.)"""
    monkeypatch.setattr(bakepoint_data, "FOOTPRINT", footprint)
    monkeypatch.setattr(bakepoints, "FOOTPRINT_TRIANGLES", 1)
    v, f, result = unwrapped(mesh_fn)
    uv = result.objects[0].uv.astype(np.float64)
    surface = bakepoints.SurfaceTriangles(
        v[f], meshes.vertex_normals(v, f)[f], uv, np.zeros(len(f), int), np.full((len(f), 3), 0.5)
    )
    pts = bakepoints.build(surface, 256, 256)
    k = 64
    origins = pts.sample_origins(np.random.default_rng(0), np.arange(len(pts.texel)), k)
    tri = np.repeat(pts.triangle, k)
    p = origins - np.repeat(pts.face_normal, k, axis=0) * pts.offset
    # barycentrics of each origin in its triangle (3D), then its lightmap UV in texels
    corners = v[f][tri]
    e1, e2, d = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], p - corners[:, 0]
    g = np.stack([np.einsum("ri,ri->r", e1, e1), np.einsum("ri,ri->r", e1, e2), np.einsum("ri,ri->r", e2, e2)], 1)
    r1, r2 = np.einsum("ri,ri->r", d, e1), np.einsum("ri,ri->r", d, e2)
    det = g[:, 0] * g[:, 2] - g[:, 1] ** 2
    b1, b2 = (g[:, 2] * r1 - g[:, 1] * r2) / det, (g[:, 0] * r2 - g[:, 1] * r1) / det
    assert min(b1.min(), b2.min(), (1 - b1 - b2).min()) > -1e-9  # inside the triangle
    t_uv = uv[tri] * 256
    at = t_uv[:, 0] + b1[:, None] * (t_uv[:, 1] - t_uv[:, 0]) + b2[:, None] * (t_uv[:, 2] - t_uv[:, 0])
    local = at - np.repeat(np.stack([pts.texel % 256, pts.texel // 256], 1), k, axis=0)
    assert ((local >= -1e-6) & (local <= 1 + 1e-6)).all()
    lo, hi = 0.5 - footprint / 2, 0.5 + footprint / 2
    central = ((local >= lo - 1e-6) & (local <= hi + 1e-6)).all(axis=1)
    assert central[np.repeat(pts.coverage >= 1.0 - 1e-9, k)].mean() > 0.999
    # uniform within the square on fully covered texels: mean offset at the centre, spread ±F/2
    full = np.repeat(pts.coverage >= 1.0 - 1e-9, k)
    assert np.abs(local[full].mean(axis=0) - 0.5).max() < 0.01
    assert np.abs(local[full].std(axis=0) - footprint / np.sqrt(12)).max() < 0.01


def test_choice_between_overlapping_triangles_is_deterministic():
    uv = np.array([[[0.1, 0.1], [0.6, 0.1], [0.1, 0.6]], [[0.1, 0.1], [0.6, 0.1], [0.1, 0.6]]])
    cov = raster.rasterise(uv, 16, 16)
    chosen, total = raster.choose_per_texel(cov)
    assert (cov.triangle[chosen] == 0).all()  # ties go to the lowest index
    again, _ = raster.choose_per_texel(raster.rasterise(uv, 16, 16))
    np.testing.assert_array_equal(chosen, again)
    assert total.max() == pytest.approx(1.0)  # overlapping coverage clips at 1


def test_shared_atlas_charts_never_share_a_texel_and_density_sets_texel_counts():
    v1, f1 = meshes.cube()
    v2, f2 = meshes.uv_sphere()
    res = unwrap.unwrap(
        [unwrap.UnwrapMesh("cube", v1, f1), unwrap.UnwrapMesh("sphere", v2, f2)],
        unwrap.UnwrapSettings(resolution=512, padding=4),
    )
    assert res.atlas_sizes == [(512, 512)] and 0.3 < res.utilisation[0] <= 1.0
    texels = [set(raster.rasterise(o.uv.astype(float), 512, 512).texel.tolist()) for o in res.objects]
    assert not texels[0] & texels[1]
    for o in res.objects:
        assert (o.uv >= 0).all() and (o.uv <= 1).all()
    dens = unwrap.unwrap([unwrap.UnwrapMesh("cube", v1 * 2.0, f1)], unwrap.UnwrapSettings(texel_density=40.0))
    # 6 faces of 2 m × 2 m at 40 texels/m: 24 m² × 1600 = 38 400 texels
    assert dens.objects[0].texels == pytest.approx(24 * 1600, rel=0.02)
    per = unwrap.unwrap(
        [unwrap.UnwrapMesh("a", v1, f1), unwrap.UnwrapMesh("b", v1, f1, resolution=256)],
        unwrap.UnwrapSettings(resolution=512),
    )
    assert per.atlas_sizes == [(512, 512), (256, 256)] and per.objects[1].atlas == 1


def test_small_objects_are_warned_about_and_bad_geometry_named():
    v, f = meshes.cube(0.01)
    big_v, big_f = meshes.cube(10.0)
    res = unwrap.unwrap(
        [unwrap.UnwrapMesh("tiny", v, f), unwrap.UnwrapMesh("big", big_v, big_f)], unwrap.UnwrapSettings(resolution=256)
    )
    assert any("'tiny'" in w for w in res.warnings)
    bad = v.copy()
    bad[0, 0] = np.nan
    with pytest.raises(BakeError, match="'broken'.*NaN"):
        unwrap.unwrap([unwrap.UnwrapMesh("broken", bad, f)], unwrap.UnwrapSettings())
    with pytest.raises(BakeError, match="'empty'.*no faces"):
        unwrap.unwrap([unwrap.UnwrapMesh("empty", v, np.zeros((0, 3), int))], unwrap.UnwrapSettings())
    with pytest.raises(BakeError, match="'flat'.*zero-area"):
        unwrap.unwrap([unwrap.UnwrapMesh("flat", v, np.array([[0, 0, 1], [2, 2, 2]]))], unwrap.UnwrapSettings())


def test_albedo_is_sampled_from_the_materials_own_uvs():
    v, f = meshes.plane()
    res = unwrap.unwrap([unwrap.UnwrapMesh("p", v, f)], unwrap.UnwrapSettings(resolution=256))
    tex_uv = v[f][:, :, :2]  # planar mapping: material UV = (x, y)
    image = np.zeros((4, 4, 3))
    image[..., 0] = np.arange(4)[None, :] / 3.0  # red ramps with x
    surface = bakepoints.SurfaceTriangles(
        v[f],
        np.tile([0, 0, 1.0], (2, 3, 1)),
        res.objects[0].uv.astype(float),
        np.zeros(2, int),
        np.full((2, 3), 0.5),
        np.zeros(2, int),
        tex_uv,
        [textures.Texture(image)],
    )
    pts = bakepoints.build(surface, 256, 256)
    expected = textures.sample_bilinear(image, pts.position[:, :2])
    np.testing.assert_allclose(pts.albedo, expected, atol=1e-9)
    centre = textures.sample_bilinear(image, np.array([[(2 + 0.5) / 4, (1 + 0.5) / 4]]))
    np.testing.assert_allclose(centre[0], [2 / 3, 0, 0])  # texel centres are exact
    edge = np.array([[0.01, 0.5]])
    assert textures.Texture(image, "Linear", "REPEAT").sample(edge)[0, 0] > 0.2  # wraps to the right edge
    assert textures.Texture(image, "Linear", "EXTEND").sample(edge)[0, 0] == 0.0
    assert textures.Texture(image, "Closest").sample(np.array([[0.74, 0.5]]))[0, 0] == pytest.approx(2 / 3)
    assert textures.Texture(image, "Linear", "CLIP").sample(np.array([[1.2, 0.5]]))[0, 0] == 0.0


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_ray_offset_scales_with_the_scene(scale):
    v, f = meshes.cube(scale)
    off = rays.ray_offset(v)
    assert 1e-6 * scale < off < 1e-4 * scale
    far = v + 1e4 * scale
    assert rays.ray_offset(far) == pytest.approx(off, rel=1e-6)  # traced about its own centre
    world = rays.ray_offset(far, origin=np.zeros(3))  # traced about the world origin: the float32 margin
    assert world > 32 * 1.19e-7 * 1e4 * scale


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_frame_origin_leaves_out_corners_that_are_not_finite(dtype):
    """A far level is traced about the centre of its finite corners' bounds; a NaN or an infinite
    corner changes nothing (the bounds are found again without it), no corner gives the origin."""
    v, _ = meshes.cube(1.0)
    far = (v + 1e5).astype(dtype)
    centre = rays.frame_origin(far)
    np.testing.assert_allclose(centre, 1e5, rtol=1e-6)
    for bad in (np.nan, np.inf, -np.inf):
        broken = np.concatenate([far, np.full((1, 3), bad, dtype), (far[:1] * [1, 1, bad]).astype(dtype)])
        assert broken.dtype == dtype
        assert np.array_equal(rays.frame_origin(broken), centre)
    assert np.array_equal(rays.frame_origin(np.zeros((0, 3, 3), dtype)), np.zeros(3))
    assert np.array_equal(rays.frame_origin(np.full((2, 3, 3), np.nan, dtype)), np.zeros(3))
    assert np.array_equal(rays.frame_origin(v), np.zeros(3))  # about the origin: coordinates unchanged


def floor_with(obstacle_v, obstacle_f, resolution=256, settled=True):
    """Bake points of a 4 m floor with an obstacle (`settled` False: not settled,
    scenekit/bakepoint_reference.py) and the RayScene of both."""
    floor_v, floor_f = meshes.plane(4.0)
    floor_v -= [2.0, 2.0, 0.0]
    res = unwrap.unwrap([unwrap.UnwrapMesh("floor", floor_v, floor_f)], unwrap.UnwrapSettings(resolution=resolution))
    surface = bakepoints.SurfaceTriangles(
        floor_v[floor_f],
        np.tile([0, 0, 1.0], (2, 3, 1)),
        res.objects[0].uv.astype(float),
        np.zeros(2, int),
        np.full((2, 3), 0.5),
    )
    scene = rays.RayScene(np.concatenate([floor_v[floor_f], obstacle_v[obstacle_f]]))
    if not settled:
        return bakepoint_reference.unsettled(surface, resolution, resolution, scene), scene
    return bakepoints.build(surface, resolution, resolution, occluders=scene), scene


def test_thin_wall_pushed_into_the_floor_buries_the_texels_under_it():
    """A 3 cm wall (≈ 2 texels) sunk 20 cm into the floor: the floor texels inside it see only
    its inner faces and are flagged; texels a few texels away on either side are not. That is
    with their bake points left where they are (not settled: scenekit/bakepoint_reference.py);
    settled, the bake points move out of the wall onto its nearer side (`bakepoints.settle`),
    and none is left inside it unflagged."""
    v, f = meshes.cube(1.0)
    v = v * [0.03, 2.0, 1.2] + [0.0, 0.0, 0.4]
    pts, _ = floor_with(v, f)
    centre = pts.texel_points(np.arange(len(pts.texel)), np.array([[0.5, 0.5]]))[:, 0]
    under = (np.abs(centre[:, 0]) < 0.015) & (np.abs(centre[:, 1]) < 0.9)
    inside = (np.abs(pts.position[:, 0]) < 0.015) & (np.abs(pts.position[:, 1]) < 1.0)
    assert under.sum() > 50 and not (inside & ~pts.buried).any()
    assert (np.abs(pts.position[under, 0]) > 0.015).mean() > 0.95
    pts, _ = floor_with(v, f, settled=False)
    x, y = np.abs(pts.position[:, 0]), np.abs(pts.position[:, 1])
    under = (x < 0.015) & (y < 0.9)
    away = (x > 0.015 + 3 * pts.texel_size) | (y > 1.0 + 3 * pts.texel_size)
    assert under.sum() > 50 and pts.buried[under].mean() > 0.95
    assert not pts.buried[away].any()


def test_buried_probes_in_two_stages_flag_exactly_what_all_probes_flag():
    """find_buried skips the last probes of texels whose first ones hit no back face: the same
    flags as every probe from every texel, over texels open (no back-face hit) and buried
    (bake points left inside the wall: not settled, scenekit/bakepoint_reference.py)."""
    v, f = meshes.cube(1.0)
    v = v * [0.03, 2.0, 1.2] + [0.0, 0.0, 0.4]
    pts, scene = floor_with(v, f, settled=False)
    local = flags._probe_directions(flags.BURIED_PROBES)
    from hhd_lightmapper.core import sh

    dirs = np.einsum("pij,kj->pki", sh.tangent_frames(pts.face_normal), local).reshape(-1, 3)
    k = len(local)
    reach = np.repeat(4.0 * pts.texel_size + 4.0 * pts.offset, k)
    t, prim, ng = scene.intersect(np.repeat(pts.origins(), k, axis=0), dirs, reach)
    hits = ((prim >= 0) & (np.einsum("ri,ri->r", dirs, ng) > 0.0)).reshape(-1, k).sum(axis=1)
    assert (hits == 0).any() and (hits >= k // 2).sum() > 50
    np.testing.assert_array_equal(pts.buried, hits >= k * flags.BURIED_FRACTION)


def test_closed_box_pushed_into_the_floor_is_dark_inside():
    """Texels under a 1 m box: every shadow ray towards the sun ends on the box, and every probe
    ray on its inner faces, so no light reaches them whatever the flagging."""
    v, f = meshes.cube(1.0, centre=(0.0, 0.0, 0.2))
    pts, scene = floor_with(v, f)
    under = np.maximum(np.abs(pts.position[:, 0]), np.abs(pts.position[:, 1])) < 0.5 - 2 * pts.texel_size
    outside = np.maximum(np.abs(pts.position[:, 0]), np.abs(pts.position[:, 1])) > 0.5 + 4 * pts.texel_size
    assert not pts.buried[outside].any()
    rng = np.random.default_rng(0)
    d = rng.normal(size=(under.sum(), 3))
    d[:, 2] = np.abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, prim, ng = scene.intersect(pts.origins()[under], d)
    assert (prim >= 0).all() and (np.einsum("ri,ri->r", d, ng) > 0).all()  # all inner (back) faces


def _patch(x0, x1, y0, y1, z, up):
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return v[[0, 1, 2, 0, 2, 3]].reshape(2, 3, 3) if up else v[[0, 2, 1, 0, 3, 2]].reshape(2, 3, 3)


@pytest.mark.parametrize("scale,shift", [(1e-3, 0.0), (1.0, 0.0), (1e3, 0.0), (1.0, 1e4)])
def test_cover_probe_finds_faces_on_or_just_above_the_surface_only(scale, shift):
    """From millimetre to kilometre scenes and far from the origin: a face in the floor's plane
    facing down (an open tray's bottom) and one thinner than the ray offset above it cover the
    floor; the tray's walls beside a point, a same-facing duplicate of the floor and a face a
    few offsets above do not."""
    v, f = meshes.cube(1.0, centre=(0.0, 0.0, 0.5))
    tray = v[f[[0, 1] + list(range(4, 12))]]  # no top: faces 2, 3 are the lid
    floor = _patch(-2, 2, -2, 2, 0.0, up=True)
    off = rays.ray_offset(np.concatenate([floor, tray]) * scale + shift)
    rel = off / scale
    extra = [
        _patch(1.0, 1.5, -0.5, 0.5, 0.0, up=True),  # duplicate of the floor
        _patch(-1.5, -1.0, -0.5, 0.5, 3.0 * rel, up=False),  # a few offsets above
        _patch(-1.5, -1.0, 1.0, 1.5, 0.5 * rel, up=False),
    ]  # within the offset
    tris = np.concatenate([floor, tray] + extra) * scale + shift
    probe = CoverProbe(tris, off)
    at = np.array([[0.0, 0.0], [0.49, 0.0], [0.51, 0.0], [1.25, 0.0], [-1.25, 0.0], [-1.25, 1.25], [1.5, 1.5]])
    p = np.column_stack([at, np.zeros(len(at))]) * scale + shift
    up = np.tile([0.0, 0.0, 1.0], (len(at), 1))
    covered = probe.covered(p + up * off, up)
    assert covered.tolist() == [True, True, False, False, False, True, False]


def test_texels_under_an_open_tray_resting_on_the_floor_are_flagged_near_cover():
    v, f = meshes.cube(1.0, centre=(0.0, 0.0, 0.5))
    pts, scene = floor_with(v, f[[0, 1] + list(range(4, 12))])
    inner = np.maximum(np.abs(pts.position[:, 0]), np.abs(pts.position[:, 1]))
    assert pts.near_cover[inner < 0.5 - pts.texel_size].all()
    assert not pts.near_cover[inner > 0.5 + pts.texel_size].any()
    # open, so the buried probes do not catch it, but a bake point left under the tray's bottom
    # (no side near enough to move it out past: `bakepoints.settle`) makes its texel invalid
    assert pts.buried[inner < 0.5 - pts.texel_size].all()
    # the probe keeps only triangles near the receivers (the floor): a box 5 m up is left out,
    # and the flags are those of a probe over every triangle
    far_v, far_f = meshes.cube(1.0, centre=(0.0, 0.0, 5.0))
    with_far = np.concatenate([scene.local_triangles, far_v[far_f].astype(np.float32)])
    near = CoverProbe(with_far, pts.offset, receivers=pts.mesh.positions)
    assert near.scene.n_triangles == scene.n_triangles
    np.testing.assert_array_equal(
        bakepoints.find_near_cover(pts, near), bakepoints.find_near_cover(pts, CoverProbe(with_far, pts.offset))
    )
    # the tracer reuses the bake points' probe when it traces the same Embree scene, else builds its own
    from hhd_lightmapper.core.bakepoints import covers

    flagged_with = covers.shared_probe(scene, pts.offset, pts.mesh.positions.copy())  # the one build() made
    corners = scene.local_triangles.astype(float) + scene.origin
    bake_scene = BakeScene(corners, np.full((len(corners), 3), 0.5))
    np.testing.assert_array_equal(bakepoints.find_near_cover(pts, flagged_with), pts.near_cover)
    assert tracer.texel_estimator(pts, bake_scene, tracer.BakeSettings(), scene).covers is flagged_with
    own = tracer.texel_estimator(pts, bake_scene, tracer.BakeSettings()).covers
    assert own is not None and own is not flagged_with


def _crashing_worker(tmp_path, crashes):
    """A worker script that dies of SIGSEGV on its first `crashes` runs, then runs the real one."""
    script = tmp_path / "worker.py"
    script.write_text(
        "import os, pathlib, runpy, signal\n"
        f"count = pathlib.Path({str(tmp_path / 'runs')!r})\n"
        "runs = int(count.read_text()) if count.exists() else 0\n"
        "count.write_text(str(runs + 1))\n"
        f"if runs < {crashes}:\n"
        "    os.kill(os.getpid(), signal.SIGSEGV)\n"
        f"runpy.run_path({worker_runs._WORKER!r}, run_name='__main__')\n"
    )
    return str(script)


def test_a_crashing_xatlas_child_is_retried_then_named(tmp_path, monkeypatch):
    v, f = meshes.cube()
    unwrap.clear_chart_cache()
    for module in (charting, packing):  # one child at a time: runs counted in order
        monkeypatch.setattr(module, "_cores", lambda: 1)
    monkeypatch.setattr(worker_runs, "_WORKER", _crashing_worker(tmp_path, crashes=1))
    res = unwrap.unwrap([unwrap.UnwrapMesh("cube", v, f)], unwrap.UnwrapSettings(resolution=256))
    # the charting child crashed, then charted; then one child fitted the charts into the atlas
    assert (tmp_path / "runs").read_text() == "3" and res.objects[0].texels > 0
    unwrap.clear_chart_cache()
    (tmp_path / "runs").unlink()
    monkeypatch.setattr(worker_runs, "_WORKER", _crashing_worker(tmp_path, crashes=99))
    with pytest.raises(BakeError, match=r"xatlas failed 3 times unwrapping 'cube'.*SIGSEGV"):
        unwrap.unwrap([unwrap.UnwrapMesh("cube", v, f)], unwrap.UnwrapSettings(resolution=256))


def spheres(count, radius=0.3):
    """`count` UV spheres (many charts each) as separate meshes, side by side."""
    v, f = meshes.uv_sphere(rings=8, segments=16, radius=radius)
    return [unwrap.UnwrapMesh(f"s{k}", v + [k * 2.0, 0.0, 0.0], f) for k in range(count)]


@pytest.mark.slow
def test_charts_that_need_more_than_one_atlas_spill_into_several_of_the_same_size():
    objs = spheres(40)
    one = unwrap.unwrap(objs[:1], unwrap.UnwrapSettings(resolution=256, padding=8))
    assert len(one.atlas_sizes) == 1 and one.part == [0] and one.shared == [True]
    # 40 spheres' padding alone (charts × (2·8 + 2)² texels) is more than one 256² atlas holds
    assert 40 * one.charts * 18**2 > 256 * 256
    res = unwrap.unwrap(objs, unwrap.UnwrapSettings(resolution=256, padding=8))
    n = len(res.atlas_sizes)
    assert n >= 2 and res.atlas_sizes == [(256, 256)] * n
    assert res.part == list(range(n)) and res.shared == [True] * n
    assert sorted({o.atlas for o in res.objects}) == list(range(n))  # every atlas used
    for a in range(n):  # objects whole, no texel shared
        members = [o for o in res.objects if o.atlas == a]
        texels = [set(raster.rasterise(o.uv.astype(float), 256, 256).texel.tolist()) for o in members]
        assert sum(map(len, texels)) == len(set().union(*texels))
        assert all((o.uv >= 0).all() and (o.uv <= 1).all() for o in members)
    # an object with its own atlas never spills; one that alone cannot fit is named with the fix
    v, f, _ = meshes.combine(*[(o.positions, o.triangles, np.arange(len(o.triangles))) for o in objs])
    big = unwrap.UnwrapMesh("big", v, f, resolution=256)
    with pytest.raises(data.AtlasFull, match="'big'.*raise the resolution"):
        unwrap.unwrap([big], unwrap.UnwrapSettings(resolution=256, padding=8))


def test_texel_density_beyond_the_largest_atlas_spills_too(monkeypatch):
    for module in (unwrap, data, packing, instance_packing):  # everywhere the limit is read
        monkeypatch.setattr(module, "MAX_RESOLUTION", 512)
    objs = spheres(6, radius=1.0)
    res = unwrap.unwrap(objs, unwrap.UnwrapSettings(texel_density=60.0, padding=4))
    assert len(res.atlas_sizes) >= 2 and all(max(s) <= 512 for s in res.atlas_sizes)
    # the density is kept: every sphere gets the texels of its area at 60 texels/m
    area = data.triangle_areas(objs[0].positions, objs[0].triangles).sum()
    assert all(o.texels == pytest.approx(area * 60**2, rel=0.1) for o in res.objects)
