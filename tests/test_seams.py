"""Seams (core/post/seams/): finding them, reading the lightmap as the GPU does, the seam metric and
least-squares stitching. Deterministic and fast: a linear function of position baked into the
SH stands in for light, except in the last test (a small traced scene)."""

from dataclasses import replace

import numpy as np
import pytest

from hhd_lightmapper.core import bakepoints, encoding, hhd, memory, raster, rays, sh, tracer, unwrap
from hhd_lightmapper.core.errors import BakeCancelled
from hhd_lightmapper.core.post.seams import encoded_stitch, geometry, metrics, reads, stitching
from hhd_lightmapper.core.scene import BakeScene, SunLight
from scenekit import meshes

RES = 256


# --- meshes -------------------------------------------------------------------------------------


def cylinder(segments=24, radius=0.5, height=1.5, centre=(2.0, 0.0, 0.0)):
    """A capped cylinder: smooth side (radial normals), flat caps on their own vertices (hard
    rims). (positions (V, 3), triangles (T, 3), vertex normals (V, 3))."""
    k = np.arange(segments)
    k1 = (k + 1) % segments
    angle = 2 * np.pi * k / segments
    ring = np.stack([np.cos(angle), np.sin(angle)], 1) * radius
    low, high = (np.column_stack([ring, np.full(segments, z)]) for z in (0.0, height))
    side_n = np.column_stack([ring / radius, np.zeros(segments)])
    side = np.concatenate([np.stack([k, k1, k1 + segments], 1), np.stack([k, k1 + segments, k + segments], 1)])
    top = np.stack([np.zeros(segments, int), 1 + k, 1 + k1], 1) + 2 * segments
    bottom = np.stack([np.zeros(segments, int), 1 + k1, 1 + k], 1) + 3 * segments + 1
    v = np.vstack([low, high, [[0, 0, height]], high, [[0, 0, 0]], low]) + centre
    n = np.vstack([side_n, side_n, np.tile([0, 0, 1.0], (segments + 1, 1)), np.tile([0, 0, -1.0], (segments + 1, 1))])
    return v, np.concatenate([side, top, bottom]), n


def sphere(centre=(0.0, 0.0, 0.8), radius=0.8):
    v, f = meshes.uv_sphere(12, 24)
    return v * radius + centre, f, v / np.linalg.norm(v, axis=1, keepdims=True)


def surface_of(parts, resolution=RES):
    """SurfaceTriangles of meshes `parts` [(v, f, n)] unwrapped by xatlas into one atlas."""
    result = unwrap.unwrap(
        [unwrap.UnwrapMesh(f"m{k}", v, f) for k, (v, f, _) in enumerate(parts)],
        unwrap.UnwrapSettings(resolution=resolution, padding=4),
    )
    uv = np.concatenate([o.uv for o in result.objects]).astype(float)
    pos = np.concatenate([v[f] for v, f, _ in parts])
    nrm = np.concatenate([n[f] for _, f, n in parts])
    obj = np.concatenate([np.full(len(f), k) for k, (_, f, _) in enumerate(parts)])
    return bakepoints.SurfaceTriangles(pos, nrm, uv, obj, np.full((len(pos), 3), 0.6))


def two_quads(uv_b, fold=False, resolution=RES):
    """Two unit quads sharing the edge x = 1 (flat, or folded up 90° with split normals when
    `fold`), quad a at UV texels [20, 60]², quad b where `uv_b` (4, 2) texels puts its corners
    (x=1,y=0), (2,0), (2,1), (1,1)."""
    pa = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    pb = np.array([[1, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0]], float)
    nb = np.tile([0, 0, 1.0], (4, 1))
    if fold:
        pb = np.array([[1, 0, 0], [1, 0, 1], [1, 1, 1], [1, 1, 0]], float)
        nb = np.tile([-1.0, 0, 0], (4, 1))
    uva = np.array([[20, 20], [60, 20], [60, 60], [20, 60]], float)
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    pos = np.concatenate([pa[quad], pb[quad]])
    nrm = np.concatenate([np.tile([0, 0, 1.0], (2, 3, 1)), nb[quad]])
    uv = np.concatenate([uva[quad], np.asarray(uv_b, float)[quad]]) / resolution
    return bakepoints.SurfaceTriangles(pos, nrm, uv, np.zeros(4, int), np.full((4, 3), 0.6))


#: quad b laid out 1.3× larger, rotated 90° and offset by a fraction of a texel from quad a
ROTATED_B = [[150.3, 30.7], [150.3, 82.7], [98.3, 82.7], [98.3, 30.7]]


@pytest.fixture(scope="module")
def sphere_cylinder():
    surface = surface_of([sphere(), cylinder()])
    return bakepoints.build(surface, RES, RES)


# --- a linear function of position as "light" ------------------------------------------------------

RNG = np.random.default_rng(7)
L_CONST = np.abs(RNG.normal(size=(9, 3))) + np.array([3.0] + [0.5] * 8)[:, None]
L_GRAD = RNG.normal(size=(3, 9, 3)) * 0.2


def linear_sh(p: np.ndarray) -> np.ndarray:
    """Radiance SH `(P, 9, 3)`, every coefficient an affine function of the position p (P, 3)."""
    return L_CONST[None] + np.einsum("pi,ikc->pkc", p, L_GRAD)


#: Band 1 off: a lightmap's I_z (band 1 · n_v) is ≥ 0 at every texel, which no affine function of
#: position can give on a sphere; with band 1 zero, I_z is 0 everywhere, within stitching's bound.
PLAUSIBLE = np.array([1.0, 0, 0, 0, 1, 1, 1, 1, 1])[:, None]


def linear_data(points: bakepoints.BakePoints) -> encoding.TexelData:
    """The bake of `linear_sh` at `points`, band 1 off (PLAUSIBLE)."""
    return encoding.TexelData.from_points(points, linear_sh(points.position) * PLAUSIBLE)


def world_point(mesh: bakepoints.SurfaceMesh, xy: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """World positions `(S, 3)` of texel-space points `xy` in triangles `tri` (affine map)."""
    bary = bakepoints._barycentric_grouped(xy[:, None], mesh.texel_uv[tri])[:, 0]
    return np.einsum("sk,ski->si", bary, mesh.positions[tri])


# --- bilinear reads and registration ---------------------------------------------------------------


def test_bilinear_matches_the_gpu_convention_and_clamps_to_the_edge():
    image = np.random.default_rng(0).normal(size=(5, 7, 2))
    xy = np.array([[0.5, 0.5], [3.5, 2.5], [1.0, 1.0], [2.25, 3.75], [-3.0, 0.2], [6.9, 4.99], [7.0, 5.0]])
    expected = []
    for x, y in xy:  # slow reference: texel centres at i + ½, indices clamped
        fx, fy = x - 0.5, y - 0.5
        i, j = int(np.floor(fx)), int(np.floor(fy))
        tx, ty = fx - i, fy - j

        def at(a, b):
            return image[min(max(b, 0), 4), min(max(a, 0), 6)]

        expected.append(
            (1 - tx) * (1 - ty) * at(i, j)
            + tx * (1 - ty) * at(i + 1, j)
            + (1 - tx) * ty * at(i, j + 1)
            + tx * ty * at(i + 1, j + 1)
        )
    np.testing.assert_allclose(reads.bilinear(image, xy), expected, rtol=1e-12)
    np.testing.assert_array_equal(reads.bilinear(image, np.array([[3.5, 2.5]]))[0], image[2, 3])  # a centre: that texel


def test_interior_reads_reproduce_a_linear_bake_with_no_half_texel_offset():
    """Raster → bake point → image → bilinear read: inside a chart, where the four texels read
    are fully covered by the same triangle, the read is the function at the point exactly
    (float32), and half a texel away it is visibly not."""
    points = bakepoints.build(two_quads(ROTATED_B), RES, RES)
    data = linear_data(points)
    mesh = points.mesh
    rng = np.random.default_rng(1)
    tri = rng.integers(0, 4, 4000)
    bary = rng.dirichlet(np.ones(3), len(tri))
    xy = np.einsum("sk,ski->si", bary, mesh.texel_uv[tri])
    index, _ = reads.bilinear_taps(xy, RES, RES)
    cover = raster.rasterise(mesh.texel_uv / RES, RES, RES)
    whole = np.full(RES * RES, -1)  # the triangle covering each texel whole, if one does
    whole[cover.texel[cover.area == 1.0]] = cover.triangle[cover.area == 1.0]
    inside = (whole[index] == tri[:, None]).all(axis=1)
    assert inside.sum() > 1000
    xy, tri = xy[inside], tri[inside]
    truth = linear_sh(world_point(mesh, xy, tri)) * PLAUSIBLE
    read = reads.bilinear(data.sh, xy)
    scale = np.abs(truth).max()
    assert np.abs(read - truth).max() < 1e-6 * scale
    shifted = reads.bilinear(data.sh, xy + 0.5)
    assert np.abs(shifted - truth).max() > 100 * np.abs(read - truth).max()


# --- finding seams ----------------------------------------------------------------------------


def test_a_split_smooth_edge_is_one_seam_sampled_along_its_whole_length():
    points = bakepoints.build(two_quads(ROTATED_B), RES, RES)
    found = geometry.find_seams(points.mesh, RES, RES, samples_per_texel=3.0)
    assert found.edges == 1
    assert len(found) == int(np.ceil(52 * 3.0))  # the longer side: 52 texels
    np.testing.assert_allclose(found.weight.sum(), 1.0)  # metres of edge
    np.testing.assert_allclose(found.position[:, 0], 1.0)
    np.testing.assert_allclose(found.a[:, 0], 60.0)  # quad a's side x = 60 texels
    np.testing.assert_allclose(found.b[:, 1], 30.7)  # quad b's side, rotated
    np.testing.assert_allclose(found.normal, np.tile([0, 0, 1.0], (len(found), 1)))
    # the two sides' points are the same 3D point: y along the edge
    np.testing.assert_allclose((found.a[:, 1] - 20) / 40, found.position[:, 1], atol=1e-12)
    np.testing.assert_allclose((150.3 - found.b[:, 0]) / 52, found.position[:, 1], atol=1e-12)
    np.testing.assert_allclose(found.inward_a, np.tile([-1.0, 0], (len(found), 1)), atol=1e-12)
    np.testing.assert_allclose(found.inward_b, np.tile([0, 1.0], (len(found), 1)), atol=1e-12)


def test_hard_edges_and_edges_with_equal_uvs_are_not_seams():
    hard = bakepoints.build(two_quads(ROTATED_B, fold=True), RES, RES)
    assert len(geometry.find_seams(hard.mesh, RES, RES)) == 0
    shared = [[60, 20], [100, 20], [100, 60], [60, 60]]  # quad b continues quad a's chart
    same_uv = bakepoints.build(two_quads(shared), RES, RES)
    assert len(geometry.find_seams(same_uv.mesh, RES, RES)) == 0


def test_the_cylinders_rims_are_hard_and_only_smooth_splits_are_seams(sphere_cylinder):
    points = sphere_cylinder
    found = geometry.find_seams(points.mesh, RES, RES)
    on_cylinder = found.position[:, 0] > 1.2
    assert on_cylinder.any() and (~on_cylinder).any()  # both objects have seams
    np.testing.assert_allclose(found.normal[on_cylinder, 2], 0.0, atol=1e-9)  # on the side, never a rim
    # every seam sample lies on its 3D edge on both sides' triangles (same 3D point)
    assert np.isfinite(found.a).all() and np.isfinite(found.b).all()
    assert (np.abs(found.a - found.b).max(axis=1) > geometry.UV_TOLERANCE).all()


def test_edges_far_shorter_than_a_texel_give_one_finite_sample():
    tiny = [[x / 200 + 150, y / 200 + 150] for x, y in ROTATED_B]  # quad b's edge: 0.26 texel
    surface = two_quads(tiny)
    surface.uv[:2] = ((surface.uv[:2] * RES - 20) / 400 + 30) / RES  # quad a's edge: 0.1 texel
    points = bakepoints.build(surface, RES, RES)
    found = geometry.find_seams(points.mesh, RES, RES)
    assert len(found) == 1
    for f in ("a", "b", "weight", "normal", "position", "tangent", "inward_a", "inward_b", "span"):
        assert np.isfinite(getattr(found, f)).all(), f
    data = linear_data(points)
    metric = metrics.seam_metric(data, found)
    assert np.isfinite([metric["mean"], metric["interior"], metric["tilted"]["mean"]]).all()
    out, record = stitching.stitch(data, found)
    assert np.isfinite(out.sh[out.baked]).all() and record["seams"] == 1


def test_seams_save_and_load(tmp_path, sphere_cylinder):
    found = geometry.find_seams(sphere_cylinder.mesh, RES, RES)
    found.save(tmp_path / "seams.npz")
    back = geometry.Seams.load(tmp_path / "seams.npz")
    assert (back.width, back.height, len(back)) == (RES, RES, len(found))
    for f in ("a", "b", "weight", "normal", "edge", "position", "tangent", "inward_a", "inward_b", "span"):
        np.testing.assert_array_equal(getattr(back, f), getattr(found, f))
        assert getattr(back, f).dtype == getattr(found, f).dtype
    assert back.edge.dtype == np.int64


def test_two_saves_of_the_same_seams_are_byte_identical(tmp_path, sphere_cylinder, monkeypatch):
    """The seams file carries no time of writing (np.savez_compressed stamps its zip entries)."""
    import io
    import time

    found = geometry.find_seams(sphere_cylinder.mesh, RES, RES)
    found.save(tmp_path / "one.npz")
    later = time.time() + 3 * 3600 + 7
    monkeypatch.setattr(time, "time", lambda: later)
    monkeypatch.setattr(time, "localtime", lambda t=None: time.gmtime(later))
    found.save(tmp_path / "two")  # ".npz" appended, as numpy does
    buffer = io.BytesIO()
    found.save(buffer)
    one = (tmp_path / "one.npz").read_bytes()
    assert one == (tmp_path / "two.npz").read_bytes() == buffer.getvalue()
    back = geometry.Seams.load(tmp_path / "two.npz")
    np.testing.assert_array_equal(back.a, found.a)
    assert (back.width, back.height) == (RES, RES)


# --- the metric and stitching ------------------------------------------------------------------


def test_stitching_closes_the_seams_of_a_linear_bake_and_touches_nothing_else(sphere_cylinder):
    points = sphere_cylinder
    data = linear_data(points)
    found = geometry.find_seams(points.mesh, RES, RES)
    before = metrics.seam_metric(data, found)
    out, record = stitching.stitch(memory.keep(data), found)
    after = metrics.seam_metric(out, found)
    assert before["mean"] > 2e-4 and before["tilted"]["mean"] > 2e-4  # border texels sit off their centres
    assert after["mean"] < before["mean"] / 20 and after["tilted"]["mean"] < before["tilted"]["mean"] / 20
    assert after["interior"] < 1.01 * before["interior"]
    assert record["after"]["mean"] == pytest.approx(after["mean"], rel=1e-6)
    assert record["before"]["mean"] == pytest.approx(before["mean"], rel=1e-6)
    assert record["texels"] > 0 and record["groups"] >= 1 and record["samples_dropped"] == 0
    # only texels the seam samples read changed; coverage never; normals only on stitched gutter texels
    index = np.concatenate([reads.bilinear_taps(xy, RES, RES)[0] for xy in (found.a, found.b)], axis=1)
    read = np.zeros(RES * RES, bool)
    read[index.ravel()] = True
    changed = (out.sh != data.sh).reshape(RES * RES, -1).any(axis=1)
    assert changed.any() and not (changed & ~read).any()
    np.testing.assert_array_equal(out.coverage, data.coverage)
    gutter = out.extra_sources.reshape(-1)
    assert gutter.any() and not (gutter & (data.coverage.reshape(-1) != 0)).any() and not (gutter & ~read).any()
    normal_changed = (out.normal != data.normal).reshape(RES * RES, -1).any(axis=1)
    assert not (normal_changed & ~gutter).any()
    np.testing.assert_allclose(np.linalg.norm(out.normal.reshape(-1, 3)[gutter], axis=1), 1.0, rtol=1e-6)


def test_the_records_measure_an_even_subset_of_the_samples_past_the_limit(sphere_cylinder, monkeypatch):
    found = geometry.find_seams(sphere_cylinder.mesh, RES, RES)
    count = len(found)
    assert count > 40
    assert metrics.recorded(found, count) is found
    limit = count // 3
    subset = metrics.recorded(found, limit)
    # sample i · S // limit: the first kept, none more than ⌈S / limit⌉ apart, the same fields
    kept = np.flatnonzero(np.isin(np.arange(count), np.arange(limit) * count // limit))
    assert len(subset) == limit == len(kept) and kept[0] == 0 and np.diff(kept).max() <= -(-count // limit)
    np.testing.assert_array_equal(subset.a, found.a[kept])
    np.testing.assert_array_equal(subset.edge, found.edge[kept])
    # the stitch records that many samples, and the stitched SH does not depend on it
    data = linear_data(sphere_cylinder)
    whole, record = stitching.stitch(memory.keep(data), found)
    monkeypatch.setattr(metrics, "RECORD_SAMPLES", limit)
    part, part_record = stitching.stitch(memory.keep(data), found)
    np.testing.assert_array_equal(part.sh, whole.sh)
    assert record["before"]["samples"] == record["after"]["samples"] > limit
    assert part_record["before"]["samples"] == part_record["after"]["samples"] == limit
    assert part_record["before"]["mean"] == pytest.approx(record["before"]["mean"], rel=0.25)


def test_stitched_gutter_texels_are_encoded_not_overwritten_by_dilation(sphere_cylinder):
    points = sphere_cylinder
    found = geometry.find_seams(points.mesh, RES, RES)
    out, _ = stitching.stitch(linear_data(points), found)
    atlas = encoding.encode_atlas(replace(out), encoding.for_settings(encoding.EncoderSettings()), raw=False)
    gutter = np.flatnonzero(out.extra_sources.reshape(-1))
    iz = np.stack([reads.encoded_images(atlas)[f"Iz.{c}"].reshape(-1) for c in "RGB"], -1)[gutter]
    expected = hhd.irradz(
        out.sh.reshape(-1, 9, 3)[gutter].astype(np.float64), out.normal.reshape(-1, 3)[gutter].astype(np.float64)
    )
    np.testing.assert_allclose(iz, np.maximum(expected, 0.0), rtol=1e-5, atol=1e-6)


def test_a_nan_texel_does_not_spread(sphere_cylinder):
    points = sphere_cylinder
    data = linear_data(points)
    found = geometry.find_seams(points.mesh, RES, RES)
    index, weight = reads.bilinear_taps(found.a[len(found) // 2 : len(found) // 2 + 1], RES, RES)
    bad = index[0][np.argmax(weight[0] * (data.coverage.reshape(-1)[index[0]] > 0))]
    sh_bad = data.sh.copy()
    sh_bad.reshape(RES * RES, 9, 3)[bad, 0, 1] = np.nan
    out, record = stitching.stitch(memory.keep(replace(data, sh=sh_bad)), found)
    finite = np.isfinite(out.sh).reshape(RES * RES, -1).all(axis=1)
    assert not finite[bad] and finite.sum() == RES * RES - 1
    assert record["samples_dropped"] > 0
    metric = metrics.seam_metric(out, found)
    assert 0 < metric["invalid"] <= record["samples_dropped"] and np.isfinite(metric["mean"])
    assert metric["mean"] < metrics.seam_metric(data, found)["mean"] / 10  # the rest is still stitched


BAND_SCALE = np.array([1, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1, 0.1, 0.1])[None, :, None]


def test_the_hhd_reader_is_the_preview_formula_at_texel_centres(sphere_cylinder):
    """At a covered texel's centre the bilinear read is that texel: the reader then agrees with
    core.hhd.reconstruct of the texel's encoding at any shading normal (the encoder keeps
    d·n_v ≥ MIN_COS, so the two floors on d·n_v do not differ)."""
    points = sphere_cylinder
    data = encoding.TexelData.from_points(points, np.abs(linear_sh(points.position)) * BAND_SCALE)
    atlas = encoding.encode_atlas(replace(data), encoding.for_settings(encoding.EncoderSettings()), raw=False)
    rows = np.random.default_rng(2).choice(len(points.texel), 500, replace=False)
    texel = points.texel[rows]
    xy = np.stack([texel % RES + 0.5, texel // RES + 0.5], 1)
    n_v = data.normal.reshape(-1, 3)[texel].astype(np.float64)
    n_v /= np.linalg.norm(n_v, axis=1, keepdims=True)
    n = sh.tangent_frames(n_v) @ np.array([0.4, -0.3, 0.866])
    params = hhd.encode(data.sh.reshape(-1, 9, 3)[texel], n_v)
    images = reads.encoded_images(atlas)
    got = reads.hhd_reader(images)(xy)(n_v, n)
    np.testing.assert_allclose(got, hhd.reconstruct(params, n_v, n), rtol=2e-3, atol=1e-4)  # half-float layers


def test_no_seams_changes_nothing_and_the_solver_does_not_depend_on_its_thread_count(sphere_cylinder):
    plane = bakepoints.build(two_quads([[60, 20], [100, 20], [100, 60], [60, 60]]), RES, RES)
    data = linear_data(plane)
    none = geometry.find_seams(plane.mesh, RES, RES)
    out, record = stitching.stitch(data, none)
    np.testing.assert_array_equal(out.sh, data.sh)
    assert record["texels"] == 0 and record["groups"] == 0 and metrics.seam_metric(data, none)["mean"] == 0.0
    points = sphere_cylinder
    data = linear_data(points)
    found = geometry.find_seams(points.mesh, RES, RES)
    one, _ = stitching.stitch(memory.keep(data), found, threads=1)
    two, _ = stitching.stitch(memory.keep(data), found, threads=2)
    np.testing.assert_array_equal(one.sh, two.sh)


def test_the_stitch_in_blocks_is_the_stitch_in_one_block(sphere_cylinder, monkeypatch):
    """The metric's reads and the bound work through samples and texels in blocks (memory,
    `memory.row_blocks`): blocks of a few dozen give the bits and the record one block gives."""
    data = linear_data(sphere_cylinder)
    found = geometry.find_seams(sphere_cylinder.mesh, RES, RES)
    whole, whole_record = stitching.stitch(memory.keep(data), found)
    monkeypatch.setattr(metrics, "READ_SAMPLES", 48)
    monkeypatch.setattr(stitching, "BOUND_ROWS", 40)
    assert len(found) > 10 * metrics.READ_SAMPLES and whole_record["texels"] > 10 * stitching.BOUND_ROWS
    blocks, blocks_record = stitching.stitch(memory.keep(data), found)
    np.testing.assert_array_equal(blocks.sh, whole.sh)
    np.testing.assert_array_equal(blocks.extra_sources, whole.extra_sources)
    whole_record.pop("seconds"), blocks_record.pop("seconds")
    assert blocks_record == whole_record


def test_row_blocks_cover_the_rows_in_order_none_much_shorter_than_the_others():
    for n, size in ((0, 8), (1, 8), (7, 8), (8, 8), (9, 8), (1000, 48), (1 << 16, 1 << 14)):
        blocks = memory.row_blocks(n, size)
        assert blocks[0].start == 0 and blocks[-1].stop == n
        assert all(a.stop == b.start for a, b in zip(blocks, blocks[1:]))
        lengths = [b.stop - b.start for b in blocks]
        assert max(lengths) <= size and (n < size or min(lengths) >= size // 2)


def test_stitching_can_be_cancelled_between_solver_iterations(sphere_cylinder):
    calls = []

    def check():
        calls.append(1)
        if len(calls) > 1:
            raise BakeCancelled("cancelled")

    found = geometry.find_seams(sphere_cylinder.mesh, RES, RES)
    with pytest.raises(BakeCancelled):
        stitching.stitch(linear_data(sphere_cylinder), found, check, threads=2)


# --- a traced scene ----------------------------------------------------------------------------


def test_stitching_a_traced_sphere_and_cylinder_under_sun_and_sky():
    """The done-when of issue 22 on a small scene: seam ratio ≤ 1.5 after stitching (SH read and
    HHD preview read, straight and tilted normals) with the interior step no more than 1% worse."""
    surface = surface_of([sphere(), cylinder()])
    ground_v, ground_f = meshes.plane(8.0)
    triangles = np.concatenate([surface.positions, (ground_v - [4, 4, 0])[ground_f]])
    points = bakepoints.build(surface, RES, RES, occluders=rays.RayScene(triangles))
    sun = SunLight(np.array([0.5, 0.3, 0.81]) / np.linalg.norm([0.5, 0.3, 0.81]), np.array([3.0, 2.8, 2.5]))
    scene = BakeScene(triangles, np.full((len(triangles), 3), 0.6), lights=[sun], world=np.array([0.3, 0.4, 0.6]))
    traced = tracer.bake(points, scene, tracer.BakeSettings(samples=64, bounces=1, seed=1))
    data = encoding.TexelData.from_points(points, traced.sh)
    found = geometry.find_seams(points.mesh, RES, RES)
    out, record = stitching.stitch(memory.keep(data), found)
    before, after = record["before"], record["after"]
    assert after["ratio"] <= 1.5 and after["tilted"]["ratio"] <= 1.5
    assert after["mean"] < before["mean"] / 5
    assert after["interior"] <= 1.01 * before["interior"]
    assert after["tilted"]["interior"] <= 1.01 * before["tilted"]["interior"]
    encoder = encoding.for_settings(encoding.EncoderSettings())
    hhd_before = metrics.seam_metric(encoding.encode_atlas(data, encoder, raw=False), found)
    hhd_after = metrics.seam_metric(encoding.encode_atlas(replace(out), encoder, raw=False), found)
    assert hhd_after["ratio"] <= 1.5 and hhd_after["tilted"]["ratio"] <= 1.5
    assert hhd_after["mean"] < hhd_before["mean"] / 2
    assert hhd_after["interior"] <= 1.01 * hhd_before["interior"]
    # the encoding re-opens a little of the seam (each texel's own n_v in I_z, the fitted w_a
    # and d); stitching the encoded layers closes it for straight and tilted normals
    assert hhd_after["mean"] > 3 * after["mean"]
    atlas = encoding.encode_atlas(out, encoder, raw=False)
    closed, encoded = encoded_stitch.stitch_encoded(atlas, found, data.coverage)
    assert encoded["before"]["mean"] == pytest.approx(hhd_after["mean"])
    assert encoded["after"]["mean"] < hhd_after["mean"] / 4
    assert encoded["after"]["tilted"]["mean"] < hhd_after["tilted"]["mean"] / 2
    assert encoded["after"]["interior"] <= 1.01 * hhd_before["interior"]
    images = reads.encoded_images(closed)
    assert min(images[f"Iz.{c}"].min() for c in "RGB") >= 0.0
    assert 0.0 <= images["Wa.V"].min() and images["Wa.V"].max() <= 1.0
    assert max(np.abs(images[f"Direction.{c}"]).max() for c in "XY") <= 1.0


def contrast_data(points: bakepoints.BakePoints) -> encoding.TexelData:
    """A plausible but harsh bake: per texel L0 log-normal (σ = 3: neighbours differ up to
    thousands of times), band 1 along n_v (I_z > 0), bands 2 off. Deterministic."""
    rng = np.random.default_rng(3)
    count = len(points.position)
    l0 = np.exp(3.0 * rng.normal(size=(count, 1, 3)))
    n = points.normal / np.linalg.norm(points.normal, axis=1, keepdims=True)
    band1 = np.stack([-n[:, 1], n[:, 2], -n[:, 0]], 1)[:, :, None] * 0.5 * l0
    return encoding.TexelData.from_points(points, np.concatenate([l0, band1, np.zeros((count, 5, 3))], 1))


def l0_and_iz(data: encoding.TexelData, texels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = data.sh.reshape(-1, 9, 3)[texels].astype(np.float64)
    n = data.normal.reshape(-1, 3)[texels].astype(np.float64)
    return x[:, 0], hhd.irradz(x, n / np.linalg.norm(n, axis=1, keepdims=True))


def test_stitched_sh_stays_a_plausible_radiance(sphere_cylinder, monkeypatch):
    """Unbounded, the least squares drives gutter texels of a high-contrast bake negative (and far
    brighter than anything they are tied to); bounded, every stitched texel has L0 ≥ 0 and I_z
    ≥ 0 at its normal, within the range of the texels its samples read (plus the slack), and
    the seams still close."""
    points = sphere_cylinder
    data = contrast_data(points)
    assert l0_and_iz(data, points.texel)[1].min() > 0.0
    found = geometry.find_seams(points.mesh, RES, RES)
    out, record = stitching.stitch(memory.keep(data), found)
    with monkeypatch.context() as m:
        m.setattr(stitching, "_bounded", lambda s, prior, delta, normal, dtype: (prior[s.texels] + delta, 0))
        loose, _ = stitching.stitch(memory.keep(data), found)
    changed = np.flatnonzero((loose.sh != data.sh).reshape(RES * RES, -1).any(axis=1))
    l0, iz = l0_and_iz(loose, changed)
    assert (l0 < 0).any(axis=1).sum() > 100 and (iz < 0).any(axis=1).sum() > 100  # what the bound prevents
    changed = np.flatnonzero((out.sh != data.sh).reshape(RES * RES, -1).any(axis=1))
    l0, iz = l0_and_iz(out, changed)
    assert len(changed) > 1000 and record["texels_bounded"] > 0
    assert l0.min() >= 0.0 and iz.min() >= 0.0
    # the largest starting L0 (as the SH file shows it: gutter texels dilated) among the texels
    # each stitched texel's samples read; the bound allows BOUND_SLACK × the spread above it
    base = data.fill().apply(data.sh.copy()).reshape(-1, 9, 3)[:, 0].astype(np.float64)
    index = np.concatenate([reads.bilinear_taps(xy, RES, RES)[0] for xy in (found.a, found.b)], axis=1)
    row_max = base[index].max(axis=1)  # (S, 3)
    tied_max = np.zeros((RES * RES, 3))
    for k in range(index.shape[1]):
        np.maximum.at(tied_max, index[:, k], row_max)
    assert (l0 <= tied_max[changed] * (1.0 + stitching.BOUND_SLACK) * (1 + 1e-6)).all()
    assert record["after"]["ratio"] < 0.25 * record["before"]["ratio"]


def test_seams_into_buried_texels(monkeypatch):
    """A seam whose side b is buried along it (filled from b's own chart, as the leak fix does)
    is stitched like a gutter: the buried texels move and are encoded as they were stitched. A
    side b buried whole (left black: inside closed geometry) is hidden: not counted by the
    metric, not stitched (side a is not pulled towards black)."""
    points = bakepoints.build(two_quads(ROTATED_B), RES, RES)
    data = linear_data(points)
    found = geometry.find_seams(points.mesh, RES, RES)
    cover = data.coverage.copy()
    band = np.zeros_like(cover, bool)
    band[29:33, 97:152] = True  # quad b's rows along the seam (y = 30.7)
    assert (cover[band] > 0).sum() > 50
    cover[band & (cover != 0)] = -1.0
    edge = replace(data, coverage=cover)
    before = metrics.seam_metric(edge, found)
    out, record = stitching.stitch(memory.keep(edge), found)
    after = metrics.seam_metric(out, found)
    assert before["hidden"] == 0 and record["samples_hidden"] == 0
    assert after["mean"] < before["mean"] / 20
    buried = np.flatnonzero((cover < 0).reshape(-1))
    moved = buried[(out.sh != data.sh).reshape(RES * RES, -1)[buried].any(axis=1)]
    assert len(moved) > 10 and out.extra_sources.reshape(-1)[moved].all()
    atlas = encoding.encode_atlas(replace(out), encoding.for_settings(encoding.EncoderSettings()), raw=False)
    iz = np.stack([reads.encoded_images(atlas)[f"Iz.{c}"].reshape(-1) for c in "RGB"], -1)[moved]
    x = out.sh.reshape(-1, 9, 3)[moved].astype(np.float64)
    n = out.normal.reshape(-1, 3)[moved].astype(np.float64)
    np.testing.assert_allclose(iz, np.maximum(hhd.irradz(x, n), 0.0), rtol=1e-5, atol=1e-6)

    whole = data.coverage.copy()
    quad_b = np.zeros_like(whole, bool)
    quad_b[25:90, 90:160] = True
    whole[quad_b & (whole != 0)] = -1.0
    hidden = replace(data, coverage=whole)
    metric = metrics.seam_metric(hidden, found)
    out, record = stitching.stitch(memory.keep(hidden), found)
    assert metric["hidden"] == len(found) == record["samples_hidden"] and metric["samples"] == 0
    assert record["texels"] == 0
    np.testing.assert_array_equal(out.sh, hidden.sh)


@pytest.mark.parametrize("keep_black", [False, True])
def test_filled_rows_read_what_the_filled_copy_holds(keep_black):
    """`reads.FilledRows` (stitching's on-demand read of the filled SH, no copy of the atlas's)
    gives, bit for bit, the rows of `Fill.apply`'s copy: sources, dilated texels, texels out of
    the dilation's reach (the sources' mean), black texels; and `put` overrides rows."""
    from hhd_lightmapper.core import dilate

    rng = np.random.default_rng(7)
    h, w = 40, 70
    coverage = np.zeros((h, w), np.float32)
    coverage[5:15, 5:20] = 1.0
    coverage[25:35, 45:60] = rng.random((10, 15), dtype=np.float32) + 0.1
    coverage[8:11, 8:12] = -1.0  # buried texels: a chart of its own keeps some black
    coverage[30:32, 47:49] = -1.0
    coverage[0:2, 65:68] = -1.0  # a chart all buried: black
    image = rng.normal(size=(h, w, 5)).astype(np.float32)
    fill = dilate.Fill(coverage > 0.0, 3, black=coverage < 0.0, chart=coverage != 0.0)
    expected = fill.apply(image.copy(), keep_black=keep_black).reshape(h * w, 5)
    rows = reads.FilledRows(image.reshape(h * w, 5), fill, (h, w), keep_black=keep_black)
    index = rng.integers(0, h * w, size=(300, 4))
    np.testing.assert_array_equal(rows[index].view(np.uint32), expected[index].view(np.uint32))
    assert (fill.source < 0).any() and len(fill.black)  # some texels take the mean, some stay black
    changed = np.array([3, 700, 2000])
    rows.put(changed, np.full((3, 5), 9.0, np.float32))
    expected[changed] = 9.0
    np.testing.assert_array_equal(rows[np.arange(h * w)], expected)
