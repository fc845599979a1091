"""The compiled rasteriser, probe points, footprint triangles and settle spokes
(core/raster_kernels.py) against the numpy code they replaced (scenekit/raster_reference.py): the
same pairs, areas, centroids, per-texel choices and bake points, bit for bit, on random and
degenerate triangles, whatever the thread count."""

import dataclasses

import numpy as np
import pytest

from hhd_lightmapper.core import bakepoints, raster, rays
from hhd_lightmapper.core.bakepoints import data as bakepoint_data
from hhd_lightmapper.core.bakepoints import settling
from scenekit import bakepoint_reference, meshes
from scenekit import raster_reference as ref


def assert_same(a, b, fields):
    for name in fields:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name, strict=True)


def awkward_triangles(rng, n, res):
    """(n, 3, 2) lightmap UVs, a mix of what an atlas (or a bad one) holds: small triangles,
    needles, zero-area (collinear, repeated corners), corners on texel corners and edges,
    partly and wholly off the atlas, NaN corners, and big triangles over thousands of texels."""
    kind = rng.integers(0, 8, n)
    a = rng.random((n, 1, 2))
    uv = a + (rng.random((n, 3, 2)) - 0.5) * (rng.random((n, 1, 1)) * 12.0 / res)  # up to ~12 texels
    needle = kind == 1  # the third corner a hair off the line through the first two
    uv[needle, 2] = uv[needle, 0] + rng.random((needle.sum(), 1)) * (uv[needle, 1] - uv[needle, 0])
    uv[needle, 2, 1] += rng.normal(size=needle.sum()) * 1e-9
    flat = kind == 2  # collinear or repeated corners
    uv[flat, 2] = uv[flat, 0] + rng.integers(0, 3, (flat.sum(), 1)) * 0.5 * (uv[flat, 1] - uv[flat, 0])
    grid = kind == 3  # corners on texel corners, or on texel edges
    uv[grid] = np.round(uv[grid] * res) / res
    edge = kind == 4
    uv[edge, :, 0] = np.round(uv[edge, :, 0] * res) / res
    off = kind == 5  # partly or wholly off the atlas
    uv[off] += rng.choice([-1.0, 1.0], (off.sum(), 1, 2)) * rng.random((off.sum(), 1, 2)) * 0.3
    uv[kind == 6, rng.integers(0, 3), rng.integers(0, 2)] = np.nan
    big = kind == 7  # hundreds to thousands of texels
    uv[big] = a[big] * 0.5 + rng.random((big.sum(), 3, 2)) * 0.4
    return uv


@pytest.mark.parametrize("res", [(16, 16), (64, 48), (256, 256)])
@pytest.mark.parametrize("seed", [0, 1])
def test_compiled_raster_is_the_numpy_raster_bit_for_bit(res, seed):
    rng = np.random.default_rng(seed)
    uv = awkward_triangles(rng, 600, max(res))
    want = ref.rasterise(uv, *res)
    assert len(want.texel) > 1000
    for threads in (1, 2):
        got = raster.rasterise(uv, *res, threads=threads)
        assert_same(want, got, ("triangle", "texel", "area", "point"))
    chosen, total = raster.choose_per_texel(got)
    want_chosen, want_total = ref.choose_per_texel(want)
    np.testing.assert_array_equal(chosen, want_chosen, strict=True)
    np.testing.assert_array_equal(total, want_total, strict=True)


def test_edge_aligned_and_huge_triangles_and_ties():
    """Corners exactly on texel corners and edges (the fast paths' boundaries: a texel inside a
    triangle, a triangle inside a texel), a triangle over most of the atlas, and two triangles of
    equal overlap in one texel (ties go to the lower triangle index)."""
    res = 128
    tri = np.array(
        [
            [[1, 1], [9, 1], [1, 9]],  # grid corners
            [[20, 20], [21, 20], [20, 21]],  # inside one texel, on its corners
            [[30.5, 30], [31, 30.5], [30.5, 31]],  # inside one texel, on its edges
            [[40, 40], [41, 41], [40, 41]],  # a diagonal half of a texel, and its other half:
            [[40, 40], [41, 40], [41, 41]],  # a tie
            [[2, 60], [126, 60], [64, 127]],  # thousands of texels
            [[0, 0], [128, 0], [0, 1e-12]],  # a needle along the atlas's edge
        ],
        float,
    )
    uv = tri / res
    want, got = ref.rasterise(uv, res, res), raster.rasterise(uv, res, res, threads=2)
    assert_same(want, got, ("triangle", "texel", "area", "point"))
    assert (got.triangle == 5).sum() > 4000
    chosen, total = raster.choose_per_texel(got)
    want_chosen, want_total = ref.choose_per_texel(want)
    np.testing.assert_array_equal(chosen, want_chosen)
    np.testing.assert_array_equal(total, want_total)
    tie = got.texel[chosen] == 40 * res + 40
    assert got.triangle[chosen][tie] == [3] and total[tie] == [1.0]


def test_nothing_to_rasterise():
    for uv in (np.zeros((0, 3, 2)), np.full((4, 3, 2), 0.5), np.full((2, 3, 2), np.nan)):
        got = raster.rasterise(uv, 32, 32)
        assert len(got.texel) == 0 and got.point.shape == (0, 2)
        chosen, total = raster.choose_per_texel(got)
        assert len(chosen) == 0 and len(total) == 0


def scene(rng):
    """A wavy sheet (bench/memory.py's, 20 × 20 quads) with a thin wall sunk into it, a tray
    resting on it, some vertex normals zero or flipped (the face-normal fallback and the face
    normal's flip onto n_v's side), and UVs jittered a little (uneven overlaps, ties broken)."""
    n = 20
    u = np.linspace(0, 4.0, n + 1)
    x, y = np.meshgrid(u, u)
    v = np.stack([x, y, 0.05 * np.sin(3 * x) * np.cos(2 * y)], -1).reshape(-1, 3)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 2, i.ravel() + n + 1
    tris = v[np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])]
    uv = 0.02 + 0.9 * tris[..., :2] / 4.0 + rng.normal(size=tris[..., :2].shape) * 1e-4
    normals = np.repeat(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, None], 3, axis=1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    normals[::17] = 0.0
    normals[5::23] *= -1.0
    surface = bakepoints.SurfaceTriangles(tris, normals, uv, np.zeros(len(tris), int), np.full((len(tris), 3), 0.6))
    wall_v, wall_f = meshes.cube(1.0)
    wall_v = wall_v * [0.12, 1.5, 0.6] + [1.3, 2.0, 0.1]
    tray_v, tray_f = meshes.cube(1.0, centre=(2.8, 2.2, 0.55))
    occluders = np.concatenate([tris, wall_v[wall_f], tray_v[tray_f[[0, 1] + list(range(4, 12))]]])
    return surface, rays.RayScene(occluders)


def use_reference(monkeypatch):
    """The numpy path of scenekit/raster_reference.py in place of the compiled one."""
    for owner, name, f in (
        (raster, "rasterise", ref.rasterise),
        (raster, "choose_per_texel", ref.choose_per_texel),
        (bakepoints, "_fill_points", ref._fill_points),
        (bakepoints, "find_near_cover", ref.find_near_cover),
        (bakepoints, "find_buried", ref.find_buried),
        (bakepoints, "other_triangles", ref.other_triangles),
        (bakepoints, "settle", ref.settle),
        (bakepoints.BakePoints, "texel_points", ref.texel_points),
    ):
        monkeypatch.setattr(owner, name, f)


def assert_same_points(a, b):
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=field.name, strict=True)
        elif field.name != "mesh":
            assert x == y, field.name


def test_compiled_bake_points_are_the_numpy_bake_points_bit_for_bit(monkeypatch):
    """The whole build, then the probes alone on its points and on the same points not settled
    (scenekit/bakepoint_reference.py: bake points left inside the wall and the tray)."""
    surface, occluders = scene(np.random.default_rng(3))
    res = 96
    got = [bakepoints.build(surface, res, res, occluders=occluders, threads=t, chunk=1000) for t in (1, 2)]
    assert_same_points(got[0], got[1])
    assert got[0].buried.sum() > 20 and got[0].near_cover.sum() > 20  # the probes find something
    assert (got[0].normal != got[0].face_normal).any(axis=1).sum() > 1000
    with monkeypatch.context() as patch:
        use_reference(patch)
        want = bakepoints.build(surface, res, res, occluders=occluders, threads=2, chunk=1000)
    assert_same_points(want, got[0])
    # the probes alone, on these points and on unsettled ones, with every probe direction count
    unsettled = bakepoint_reference.unsettled(surface, res, res, occluders, threads=2, chunk=1000)
    assert (unsettled.position != got[0].position).any(axis=1).sum() > 100
    for points in (got[0], unsettled):
        probe = bakepoints.covers.shared_probe(occluders, points.offset, points.mesh.positions)
        np.testing.assert_array_equal(
            bakepoints.find_near_cover(points, probe, chunk=777), ref.find_near_cover(points, probe, chunk=777)
        )
        for probes in (3, 5, 12):
            np.testing.assert_array_equal(
                bakepoints.find_buried(points, occluders, probes, chunk=777),
                ref.find_buried(points, occluders, probes, chunk=777),
            )


def test_texel_points_are_numpys_matmul_to_its_last_bits():
    """Points anywhere around the texel (clamped into its triangle), one or many per texel, any
    texels in any order, and triangles whose UVs have no area (the barycentric fallback). Bit for
    bit where numpy's matmul fuses its multiply-adds; its rounding is its BLAS kernel's, which
    the CPU picks (on an AMD EPYC one point per texel goes unfused): there within 2 ulps of the
    largest coordinate summed."""
    surface, occluders = scene(np.random.default_rng(4))
    points = bakepoints.build(surface, 64, 64)
    rng = np.random.default_rng(5)
    points.mesh.texel_uv[::13, 2] = points.mesh.texel_uv[::13, 0]  # no area: the fallback's den = 1
    for k in (1, 8, 9):
        offsets = rng.random((k, 2)) * 3.0 - 1.0
        idx = rng.permutation(len(points.texel))[: len(points.texel) // 2]
        want = ref.texel_points(points, idx, offsets)
        got = points.texel_points(idx, offsets)
        assert got.shape == (len(idx), k, 3) and got.dtype == want.dtype
        scale = np.spacing(np.abs(points.mesh.positions).max())  # an ulp of the largest coordinate summed
        np.testing.assert_allclose(got, want, rtol=0.0, atol=2.0 * scale)


def test_near_cover_probes_each_distinct_ray_once():
    """Neighbouring texels on one triangle share their corners' points (and with FOOTPRINT 1 the
    footprint's corners are the texel's): each distinct ray is probed once, and the flags are
    those of probing all 9 rays of every texel."""
    surface, occluders = scene(np.random.default_rng(6))
    points = bakepoints.build(surface, 128, 128, occluders=occluders)
    probe = bakepoints.covers.shared_probe(occluders, points.offset, points.mesh.positions)
    rays_probed = []

    class Counting:
        def covered(self, origins, normals):
            rays_probed.append(len(origins))
            return probe.covered(origins, normals)

    flags = bakepoints.find_near_cover(points, Counting(), chunk=5000)
    np.testing.assert_array_equal(flags, ref.find_near_cover(points, probe, chunk=5000))
    assert flags.sum() > 20
    if bakepoint_data.FOOTPRINT == 1.0:
        assert sum(rays_probed) < 3.0 * len(points.texel)


@pytest.mark.parametrize("normals", [True, False])
def test_compiled_other_triangles_are_the_numpy_ones(normals):
    """`bakepoints.other_triangles` (`raster_kernels.other_triangles`) gives the numpy version's
    triangles in the same order, on awkward triangles and on the test scene, whatever the
    thread count."""
    rng = np.random.default_rng(7)
    surface, _ = scene(rng)
    cases = [(surface.uv, surface.positions, 96), (awkward_triangles(rng, 800, 64), None, 64)]
    for uv, positions, res in cases:
        if positions is None:  # random triangles in space too: normals anywhere
            positions = rng.normal(size=(len(uv), 3, 3))
            positions[::3] = positions[::3, :1]  # some of no area: face normal 0
        cov = raster.rasterise(uv, res, res)
        chosen, _ = raster.choose_per_texel(cov)
        fn = bakepoints._face_normals(positions) if normals else None
        want = ref.other_triangles(cov, chosen, fn)
        assert (want >= 0).sum() > 50
        for threads in (1, 2, 3):  # each worker its own range of texels
            got = bakepoints.other_triangles(cov, chosen, fn, threads=threads)
            np.testing.assert_array_equal(got, want, strict=True)
    empty = raster.rasterise(np.zeros((0, 3, 2)), 8, 8)
    chosen, _ = raster.choose_per_texel(empty)
    assert bakepoints.other_triangles(empty, chosen).shape == (0, bakepoints.FOOTPRINT_TRIANGLES - 1)


def test_compiled_spoke_targets_are_the_numpy_ones():
    """`settling._spoke_targets` (`raster_kernels.spoke_targets`: points on the texel's other
    triangles where they lie on one) is the numpy version bit for bit, for settle's spokes and
    for points anywhere around the texel, any texels in any order."""
    surface, occluders = scene(np.random.default_rng(8))
    points = bakepoints.build(surface, 96, 96, occluders=occluders)
    spokes = settling._SPOKES * bakepoint_data.FOOTPRINT + 0.5 * (1.0 - bakepoint_data.FOOTPRINT)
    rng = np.random.default_rng(9)
    moved = 0
    for offsets in (spokes, rng.random((5, 2)) * 2.0 - 0.5):
        idx = rng.permutation(len(points.texel))[: len(points.texel) // 2]
        want = ref._spoke_targets(points, idx, offsets)
        got = settling._spoke_targets(points, idx, offsets)
        np.testing.assert_array_equal(got, want, strict=True)
        moved += (got != points.texel_points(idx, offsets)).any(axis=2).sum()
    assert moved > 500  # many points lie on another triangle of their texel
    alone = dataclasses.replace(points, others=None)
    np.testing.assert_array_equal(
        settling._spoke_targets(alone, idx, offsets), ref._spoke_targets(alone, idx, offsets), strict=True
    )


def test_compiled_spoke_rays_are_numpys():
    """`raster_kernels.spoke_rays` (settle's anchors, unit directions, lengths and reach) is the
    numpy code's arithmetic bit for bit, zero-length spokes (the target at the anchor) and
    spokes shorter than a texel included."""
    from hhd_lightmapper.core import raster_kernels

    surface, occluders = scene(np.random.default_rng(10))
    points = bakepoints.build(surface, 64, 64, occluders=occluders)
    start, stop = 100, len(points.texel) - 50
    idx = np.arange(start, stop)
    target = ref._spoke_targets(points, idx, settling._SPOKES)
    target[::7, 3] = points.origins(idx[::7])  # zero length
    got = raster_kernels.get().spoke_rays(
        points.position, points.face_normal, points.texel_size, points.offset, start, target
    )
    anchor = points.origins(idx)  # scenekit/raster_reference.py `settle`'s numpy
    ray = target - anchor[:, None, :]
    length = np.linalg.norm(ray, axis=2)
    direction = ray / np.maximum(length, 1e-300)[..., None]
    reach = np.maximum(length, points.texel_size[idx][:, None])
    want = anchor, np.repeat(anchor, len(settling._SPOKES), axis=0), direction, length, reach
    for name, a, b in zip(("anchor", "origin", "direction", "length", "reach"), got, want):
        np.testing.assert_array_equal(a, b, err_msg=name, strict=True)
    assert (length == 0.0).sum() >= len(idx) // 7 and (length < reach).sum() > 1000


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_compiled_near_box_is_numpys(dtype):
    """`covers._near_box` (the cover probe's filter, compiled) keeps exactly the triangles the
    numpy per-axis reductions kept: boxes touching the receivers' box edge on, triangles
    straddling it, far ones and NaN ones (never kept)."""
    from hhd_lightmapper.core.bakepoints import covers

    rng = np.random.default_rng(11)
    tri = rng.uniform(-3.0, 3.0, (20000, 3, 3)).astype(dtype) * rng.uniform(0.01, 1.0, (20000, 1, 1)).astype(dtype)
    tri[:50] += dtype(2.5)  # edge on: a vertex exactly on the grown box's face below
    tri[:50, 0, 0] = dtype(0.5 + 0.25)
    tri[50:60, 1, 2] = np.nan
    receivers = np.array([[[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.25]]])
    margin = 0.25
    lo, hi = rays.bounds(receivers)
    lo, hi = lo - margin, hi + margin
    want = np.ones(len(tri), bool)  # the numpy code until 2026-12-03
    for i in range(3):
        c = tri[:, :, i]
        want &= np.minimum(np.minimum(c[:, 0], c[:, 1]), c[:, 2]) <= hi[i]
        want &= np.maximum(np.maximum(c[:, 0], c[:, 1]), c[:, 2]) >= lo[i]
    got = covers._near_box(tri, receivers, margin)
    np.testing.assert_array_equal(got, want, strict=True)
    assert 0 < want.sum() < len(tri) and not got[50:60].any()
