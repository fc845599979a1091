"""Emissive triangles picked by spatial cluster (core.tracer.lights.EmissiveTriangles): the density
`pdf` reports is the one `sample` draws from, next-event estimation stays unbiased against
Lambert's closed form, and a near lamp gets more samples than an equal far one. No bpy."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from hhd_lightmapper.core.tracer import lights


def by_solid_angle(solid_angle: np.ndarray) -> np.ndarray:
    """(R,) bool: the triangles of these solid angles (R,) are sampled by direction
    (`lights.emitters.SOLID_ANGLE_RANGE`, read at the call: tests change it)."""
    lo, hi = lights.emitters.SOLID_ANGLE_RANGE
    return (solid_angle >= lo) & (solid_angle <= hi)


def quad(centre, size, normal_axis=2, flip=False) -> np.ndarray:
    """Two triangles (2, 3, 3) of a square of side `size` centred at `centre`, facing ±axis."""
    a, b = [i for i in range(3) if i != normal_axis]
    c = np.asarray(centre, float)
    corners = []
    for da, db in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        p = c.copy()
        p[a] += 0.5 * size * da
        p[b] += 0.5 * size * db
        corners.append(p)
    v = np.array(corners)
    tris = np.array([[v[0], v[1], v[2]], [v[0], v[2], v[3]]])
    return tris[:, ::-1] if flip else tris


def lamps(centres, size=0.2, radiance=(5.0, 4.0, 3.0)):
    """Quads at `centres` 2 m up, facing down; a floor triangle that does not emit first."""
    floor = np.array([[[-9.0, -9.0, 0.0], [9.0, -9.0, 0.0], [0.0, 9.0, 0.0]]])
    tris = np.concatenate([floor] + [quad(c, size, flip=True) for c in centres])
    emission = np.zeros((len(tris), 3))
    emission[1:] = radiance
    return tris, emission


def polygon_irradiance(x, n, polygon, radiance) -> np.ndarray:
    """Lambert's formula: irradiance (3,) at x with normal n from a Lambertian polygon (V, 3) of
    constant radiance (3,), fully above x's horizon."""
    v = polygon - x
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    total = 0.0
    for i in range(len(v)):
        a, b = v[i], v[(i + 1) % len(v)]
        cross = np.cross(a, b)
        total += np.arccos(np.clip(a @ b, -1, 1)) * (n @ cross) / np.linalg.norm(cross)
    return 0.5 * abs(total) * np.asarray(radiance)


def test_clusters_split_separate_groups_and_stay_within_the_limit():
    rng = np.random.default_rng(1)
    groups = [rng.normal(c, 0.01, (40, 3)) for c in ((0, 0, 0), (5, 0, 0), (0, 5, 0), (0, 0, 5))]
    ids = lights.tree.cluster_splits(np.concatenate(groups), 4)
    assert sorted(np.unique(ids)) == [0, 1, 2, 3]
    for g in range(4):  # one cluster per group
        assert len(np.unique(ids[40 * g : 40 * (g + 1)])) == 1
    assert lights.tree.cluster_splits(np.concatenate(groups), 32).max() < 32
    assert (lights.tree.cluster_splits(np.zeros((7, 3)), 32) == 0).all()  # coincident points: one cluster


def lamp_grid(n=8, spacing=0.5, size=0.2, height=2.0):
    """n × n lamps (`lamps`) in a grid `spacing` apart around the origin: 2n² emitting
    triangles, more than `lights.emitters.CLUSTERS`, so the light tree splits its top clusters."""
    offsets = (np.arange(n) - (n - 1) / 2) * spacing
    return lamps([(x, y, height) for x in offsets for y in offsets], size=size)


SCENES = {
    "4 lamps": lambda: lamps([(0, 0, 2), (3, 0, 2), (-6, 1, 2), (0.3, 0.2, 2)]),
    "64 lamps": lambda: lamp_grid(size=0.04, height=1.0),  # the near ones by direction, the far by area
}


def nearest(points: np.ndarray, centres: np.ndarray, chunk: int = 8192) -> np.ndarray:
    """(P,) index of the centre (C, 3) nearest each point (P, 3) (Euclidean), a chunk of points
    at a time (the (P, C, 3) differences of 400k samples and 128 triangles would be 1.2 GB)."""
    out = np.empty(len(points), np.int64)
    for start in range(0, len(points), chunk):
        p = points[start : start + chunk]
        squared = sum((p[:, i, None] - centres[None, :, i]) ** 2 for i in range(3))
        out[start : start + chunk] = np.argmin(squared, axis=1)
    return out


@pytest.mark.statistical
@pytest.mark.parametrize("normal", [None, (0.6, 0.0, 0.8)])
@pytest.mark.parametrize("scene", SCENES)
def test_picked_triangles_follow_the_reported_density(normal, scene):
    tris, emission = SCENES[scene]()
    light = lights.emitters.EmissiveTriangles(tris, emission)
    assert len(light.cluster_power) > 1
    x = np.tile([[0.1, 0.0, 0.0]], (400_000, 1))
    normals = None if normal is None else np.tile(normal, (len(x), 1))
    dirs, dist, _, p = light._sample_points(np.random.default_rng(3), x, 1, normals)
    hit = tris[1:]
    # the triangle each sample lies on (the lamps do not overlap: the nearest centroid)
    pick = 1 + nearest(x + dirs * dist[:, None], hit.mean(axis=1))
    counts = np.bincount(pick, minlength=len(tris))[1:]
    row = light.cluster_probability(x[:1], None if normals is None else normals[:1])[0]
    expected = row[light.cluster_of[1:]] * light.within[1:]
    assert expected.sum() == pytest.approx(1.0)
    sigma = np.sqrt(len(x) * expected * (1 - expected))
    assert np.all(np.abs(counts - len(x) * expected) < 5 * sigma + 1)
    # and the density is that probability spread uniformly over the triangle, per steradian
    cos = np.abs(np.einsum("ri,ri->r", dirs, light.normal[pick]))
    chosen = row[light.cluster_of[pick]] * light.within[pick]
    solid_angle = lights.emitters.spherical_triangles(x, tris[pick])[-1]
    spherical = by_solid_angle(solid_angle)
    assert spherical.any() and not spherical.all()  # both ways of sampling a triangle are exercised
    want = np.where(spherical, chosen / solid_angle, chosen / light.area[pick] * dist**2 / cos)
    np.testing.assert_allclose(p, want, rtol=1e-9)


def test_next_event_estimate_is_unbiased_against_lamberts_formula():
    centres = [(0, 0, 2), (1.5, 0.5, 2), (-4, -3, 2), (0.2, 0.1, 2.5)]
    tris, emission = lamps(centres, size=0.3)
    light = lights.emitters.EmissiveTriangles(tris, emission)
    n = np.array([0.0, 0.0, 1.0])
    for x in (np.zeros(3), np.array([1.4, 0.4, 0.0]), np.array([-3.0, -2.0, 0.0])):
        exact = sum(polygon_irradiance(x, n, quad(c, 0.3).reshape(-1, 3)[[0, 1, 2, 5]], emission[1]) for c in centres)
        k = 200_000
        dirs, value, dist = light.sample(np.random.default_rng(7), np.tile(x, (k, 1)), lambda w: np.zeros(len(w)))
        estimate = (value * np.maximum(dirs @ n, 0.0)[:, None]).mean(axis=0)
        err = (value * np.maximum(dirs @ n, 0.0)[:, None]).std(axis=0) / np.sqrt(k)
        np.testing.assert_array_less(np.abs(estimate - exact), 5 * err + 1e-9)


def test_a_near_lamp_takes_more_samples_than_an_equal_far_one_and_the_far_one_keeps_some():
    tris, emission = lamps([(0, 0, 2), (8, 0, 2)])
    light = lights.emitters.EmissiveTriangles(tris, emission)
    p = light.cluster_probability(np.array([[0.0, 0.0, 0.0], [8.0, 0.0, 0.0]]))
    near, far = np.unique(light.cluster_of[1:3]), np.unique(light.cluster_of[3:5])  # each lamp's clusters
    assert not set(near) & set(far)
    assert p[0, near].sum() > 0.85 and p[1, far].sum() > 0.85
    assert p[0, far].sum() >= 0.5 * lights.emitters.POWER_SHARE  # never starved: the distance knows nothing of walls


def test_the_light_tree_splits_the_top_clusters_down_to_single_triangles(monkeypatch):
    tris, emission = lamp_grid(12)  # 288 emitting triangles
    light = lights.emitters.EmissiveTriangles(tris, emission)
    n = len(light.parent)
    first, count, parent = light.child_first, light.child_count, light.parent
    assert count[n] == len(np.unique(lights.tree.cluster_splits(tris[1:].mean(axis=1), lights.emitters.CLUSTERS)))
    for c in range(n + 1):  # each node's children: a consecutive run naming it their parent
        np.testing.assert_array_equal(parent[first[c] : first[c] + count[c]], c)
        assert count[c] != 1
    leaves = np.flatnonzero(count[:n] == 0)
    np.testing.assert_array_equal(np.sort(light.cluster_of[1:]), leaves)  # one triangle per leaf
    assert (light.lone[leaves] >= 0).all() and (light.lone[count[:n] > 0] < 0).all()
    np.testing.assert_allclose(light.within[1:], 1.0)
    inner = np.flatnonzero(count[:n] > 0)
    sums = [light.cluster_power[first[c] : first[c] + count[c]].sum() for c in inner]
    np.testing.assert_allclose(light.cluster_power[inner], sums, rtol=1e-12)
    for t in range(1, len(tris)):  # every node's bounding sphere holds the triangles below it
        c = light.cluster_of[t]
        while c != n:
            reach = np.linalg.norm(tris[t] - light.centre[c], axis=1).max()
            assert reach <= np.sqrt(light.radius2[c]) * (1 + 1e-9)
            c = parent[c]
    monkeypatch.setattr(lights.emitters, "MAX_LEAVES", 50)
    capped = lights.emitters.EmissiveTriangles(tris, emission)
    assert 32 < (capped.child_count[:-1] == 0).sum() <= 50
    np.testing.assert_allclose(np.bincount(capped.cluster_of[1:], capped.within[1:]), capped.child_count[:-1] == 0)
    monkeypatch.setattr(lights.emitters, "FANOUT", 0)  # the top clusters alone
    flat = lights.emitters.EmissiveTriangles(tris, emission)
    assert (flat.child_count[:-1] == 0).all() and flat.child_count[-1] == len(flat.parent) <= lights.emitters.CLUSTERS


def test_a_nodes_share_of_its_siblings_power_sums_them_one_at_a_time():
    """`sibling_shares`, which the kernels read instead of summing per sample: each node's power
    over its siblings' summed power, the sum taken one node at a time in index order, as the
    per-sample loop took it (numpy's pairwise sum differs in the last bits at some nodes, and
    a bake's samples would with it)."""
    tris, emission = lamp_grid(12)
    emission[1:] *= np.random.default_rng(3).uniform(0.01, 100.0, (len(tris) - 1, 1))  # unequal powers
    light = lights.emitters.EmissiveTriangles(tris, emission)
    power, first, count = light.cluster_power, light.child_first, light.child_count
    share = lights.emitters.sibling_shares(power, first, count)
    pairwise_differs = False
    for node in range(len(count)):
        siblings = slice(first[node], first[node] + count[node])
        total = 0.0
        for p in power[siblings]:
            total += float(p)
        np.testing.assert_array_equal(share[siblings], power[siblings] / total)
        pairwise_differs |= count[node] > 0 and np.sum(power[siblings]) != total
    assert pairwise_differs  # (the order matters for these powers)


def tree_inputs():
    """Emitter centroids (E, 3) that exercise the tree's splits: random sets of every size, lamps
    on a grid (equal boxes: ties broken by the first), coincident points, one point."""
    rng = np.random.default_rng(11)
    sets = [rng.random((n, 3)) * [10.0, 10.0, 3.0] for n in (1, 2, 3, 9, 40, 700, 7000)]
    grid = np.stack(np.meshgrid(np.arange(8.0), np.arange(8.0), np.arange(2.0)), -1).reshape(-1, 3) * 1.5 + 0.1
    sets.append(np.repeat(grid, 12, axis=0) + np.tile(rng.random((12, 3)) * 0.1, (len(grid), 1)))
    sets.append(np.repeat(rng.random((5, 3)), 30, axis=0) * 1e5)  # far from the origin, coincident in fives
    sets.append(np.zeros((7, 3)))
    x = np.nextafter(1.0, 2.0)  # the middle of [1, x] rounds onto 1: the lowest points split off
    sets.append(np.array([[1.0, 0.0, 0.0], [x, 0.0, 0.0], [x, 0.0, 0.0], [1.0, 0.0, 0.0], [x, 0.0, 0.0]]))
    return sets


def test_the_compiled_light_tree_is_the_numpy_one_to_the_bit():
    """`light_kernels.light_tree`, `node_sums` and `sibling_shares` (what `EmissiveTriangles`
    builds with: the numpy tree took ~0.3 s for thousands of emitters, per bake) give the very
    arrays of their numpy specifications, for the tree's own settings and small ones."""
    kernels = lights.emitters._kernels.get()
    for centroids in tree_inputs():
        for top, fanout, most in ((32, 8, 4096), (4, 2, 50), (32, 1, 4096), (32, 8, 40), (1, 8, 4096)):
            expected = lights.tree.light_tree(centroids, top, fanout, most)
            got = kernels.light_tree(np.ascontiguousarray(centroids), top, fanout, most)
            for e, g in zip(expected, got):
                np.testing.assert_array_equal(g, e)
            leaf, first, count, _ = expected
            n = len(count) - 1
            rng = np.random.default_rng(len(centroids))
            lo, power = np.zeros((n, 3)), np.zeros(n)
            lo[leaf] = centroids - rng.random(centroids.shape)
            power[leaf] = rng.uniform(0.01, 100.0, len(centroids))
            hi = lo + 1.0
            spec = [a.copy() for a in (lo, hi, power)]
            lights.tree.node_sums(*spec, first, count)
            kernels.node_sums(lo, hi, power, first, count)
            for e, g in zip(spec, (lo, hi, power)):
                np.testing.assert_array_equal(g, e)
            np.testing.assert_array_equal(
                kernels.sibling_shares(power, first, count), lights.emitters.sibling_shares(power, first, count)
            )


def test_among_many_lamps_the_tree_gives_the_one_overhead_several_times_the_samples(monkeypatch):
    """A point 20 cm under one of 144 small lamps, which brings most of its light: the flat
    clusters (about 5 lamps each, a triangle by power within) give that lamp a few percent of the
    samples, the light tree several times as many; both unbiased against Lambert's formula, the
    tree with far less variance."""
    spacing, size = 0.5, 0.2
    tris, emission = lamp_grid(12, spacing=spacing, size=size, height=0.2)
    centre = (0.5 * spacing, 0.5 * spacing, 0.2)  # a lamp of the grid
    x, n = np.array([centre[0], centre[1], 0.0]), np.array([0.0, 0.0, 1.0])
    overhead = np.flatnonzero(np.linalg.norm(tris[1:].mean(axis=1)[:, :2] - x[:2], axis=1) < size)
    assert len(overhead) == 2
    offsets = (np.arange(12) - 5.5) * spacing
    exact = sum(
        polygon_irradiance(x, n, quad((a, b, 0.2), size).reshape(-1, 3)[[0, 1, 2, 5]], emission[1])[0]
        for a in offsets
        for b in offsets
    )
    k = 100_000
    share, variance = {}, {}
    for tree in (False, True):
        monkeypatch.setattr(lights.emitters, "FANOUT", 8 if tree else 0)
        light = lights.emitters.EmissiveTriangles(tris, emission)
        p = light.cluster_probability(x[None], n[None])[0]
        share[tree] = (p[light.cluster_of[1 + overhead]] * light.within[1 + overhead]).sum()
        dirs, value, _ = light.sample(
            np.random.default_rng(12), np.tile(x, (k, 1)), lambda w: np.zeros(len(w)), 1, np.tile(n, (k, 1))
        )
        irradiance = value[:, 0] * np.maximum(dirs @ n, 0.0)
        assert abs(irradiance.mean() - exact) < 5 * irradiance.std() / np.sqrt(k)
        variance[tree] = irradiance.var()
    assert share[False] < 0.1 and share[True] > 2.5 * share[False]
    assert variance[True] < 0.4 * variance[False]


def test_the_density_needs_the_rays_origins():
    tris, emission = lamps([(0, 0, 2), (3, 0, 2)])
    light = lights.emitters.EmissiveTriangles(tris, emission)
    with pytest.raises(ValueError, match="origins"):
        light.pdf(np.array([[0.0, 0.0, 1.0]]), np.ones(1), np.array([1]))


def numpy_pdf(light, x, normals, d, t, prim):
    """The emitters' density from the numpy specs (`cluster_probability`, `spherical_triangles`)."""
    chosen = light.cluster_probability(x, normals)[np.arange(len(x)), light.cluster_of[prim]] * light.within[prim]
    solid_angle = lights.emitters.spherical_triangles(x, light.triangles[prim])[-1]
    cos = np.abs(np.einsum("ri,ri->r", d, light.normal[prim]))
    by_area = chosen / light.area[prim] * t * t / cos
    return np.where(by_solid_angle(solid_angle), chosen / solid_angle, by_area)


@pytest.mark.parametrize("with_normals", [False, True])
@pytest.mark.parametrize("many", [False, True])
def test_the_compiled_density_is_the_numpy_spec(with_normals, many):
    tris, emission = lamps([(0, 0, 2), (3, 0, 2), (-6, 1, 2), (0.3, 0.2, 2), (2, 2, 3)], size=0.6)
    if many:  # a light tree several levels deep
        tris, emission = lamp_grid(10, spacing=0.7, size=0.6)
    light = lights.emitters.EmissiveTriangles(tris, emission)
    rng = np.random.default_rng(5)
    x = rng.uniform(-8, 8, (3000, 3))
    # a third of them inside a lamp triangle's bounding sphere (weighed by solid angle there)
    x[:1000] = tris[rng.integers(1, len(tris), 1000)].mean(axis=1) + rng.uniform(-0.3, 0.3, (1000, 3))
    normals = None
    if with_normals:
        normals = rng.normal(size=x.shape)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    prim = rng.integers(1, len(tris), len(x))
    s, v = np.sqrt(rng.random(len(x))), rng.random(len(x))
    tri = tris[prim]
    point = tri[:, 0] * (1 - s)[:, None] + tri[:, 1] * (s * (1 - v))[:, None] + tri[:, 2] * (s * v)[:, None]
    t = np.linalg.norm(point - x, axis=1)
    d = (point - x) / t[:, None]
    got = light.pdf(d, t, prim, x, normals)
    np.testing.assert_allclose(got, numpy_pdf(light, x, normals, d, t, prim), rtol=1e-9)
    assert (light.pdf(d, t, np.zeros(len(x), np.int64), x, normals) == 0).all()  # the floor does not emit


def test_beside_one_triangle_of_a_quad_that_triangle_is_picked_by_its_solid_angle(monkeypatch):
    """A point 1 cm under a 1 m lamp quad, beside the diagonal's far end: power over distance²
    sees the quad's two triangles alike, their solid angles do not. Picked by solid angle
    (inside each triangle's bounding sphere, NEAR_RADII), the near one takes most samples and
    next-event estimation's variance falls, both ways unbiased against Lambert's formula."""
    tris, emission = lamps([(0.0, 0.0, 0.01)], size=1.0)
    x, n = np.array([0.45, -0.3, 0.0]), np.array([0.0, 0.0, 1.0])
    exact = polygon_irradiance(x, n, quad((0.0, 0.0, 0.01), 1.0).reshape(-1, 3)[[0, 1, 2, 5]], emission[1])
    k = 200_000
    variance = {}
    for near in (0.0, lights.emitters.NEAR_RADII):
        monkeypatch.setattr(lights.emitters, "NEAR_RADII", near)
        light = lights.emitters.EmissiveTriangles(tris, emission)
        p = light.cluster_probability(x[None], n[None])[0][light.cluster_of[1:]]
        dirs, value, _ = light.sample(np.random.default_rng(8), np.tile(x, (k, 1)), lambda w: np.zeros(len(w)))
        irradiance = value[:, 0] * np.maximum(dirs @ n, 0.0)
        assert abs(irradiance.mean() - exact[0]) < 5 * irradiance.std() / np.sqrt(k)
        variance[near] = irradiance.var()
        if near:
            assert p.max() > 0.8  # the triangle the point sits beside
        else:
            assert abs(p[0] - p[1]) < 0.05  # alike
    assert lights.emitters.NEAR_RADII > 0 and variance[lights.emitters.NEAR_RADII] < 0.5 * variance[0.0]


def test_stratified_uniforms_put_one_number_in_each_stratum_of_every_group():
    rng = np.random.default_rng(2)
    u = lights.light.uniforms(rng, 16 * 1000, 16)
    assert u.min() >= 0.0 and u.max() < 1.0
    strata = np.sort(np.floor(u * 16).reshape(1000, 16), axis=1)
    np.testing.assert_array_equal(strata, np.tile(np.arange(16), (1000, 1)))
    assert abs(u.mean() - 0.5) < 0.01  # uniform overall
    assert len(lights.light.uniforms(rng, 10, 4)) == 10  # not a multiple: plain uniforms


def test_stratified_light_samples_lower_the_noise_of_a_texel_and_stay_unbiased():
    tris, emission = lamps([(0, 0, 1.0), (1.5, 0.5, 2)], size=1.0)
    light = lights.emitters.EmissiveTriangles(tris, emission)
    n, k = np.array([0.0, 0.0, 1.0]), 16
    x = np.zeros((20_000 * k, 3))
    exact = sum(
        polygon_irradiance(x[0], n, quad(c, 1.0).reshape(-1, 3)[[0, 1, 2, 5]], emission[1])
        for c in [(0, 0, 1.0), (1.5, 0.5, 2)]
    )
    means = {}
    for strata in (1, k):
        dirs, value, _ = light.sample(np.random.default_rng(11), x, lambda w: np.zeros(len(w)), strata)
        per_texel = (value[:, 0] * np.maximum(dirs @ n, 0.0)).reshape(-1, k).mean(axis=1)
        means[strata] = per_texel
        assert abs(per_texel.mean() - exact[0]) < 5 * per_texel.std() / np.sqrt(len(per_texel))
    assert means[k].var() < 0.5 * means[1].var()


def test_clusters_below_the_horizon_keep_only_their_power_share():
    tris, emission = lamps([(0, 0, 2), (0, 0, -2), (5, 0, -1)])
    light = lights.emitters.EmissiveTriangles(tris, emission)
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    up = light.cluster_probability(x, np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]))
    above = np.unique(light.cluster_of[1:3])
    below = np.setdiff1d(np.arange(up.shape[1]), above)
    power_only = light.cluster_power / light.cluster_power.sum()
    # facing up: the lamps below get their power share only; facing down: the lamp above does
    np.testing.assert_allclose(up[0, below], lights.emitters.POWER_SHARE * power_only[below])
    np.testing.assert_allclose(up[1, above], lights.emitters.POWER_SHARE * power_only[above])
    # every cluster below the horizon: power alone
    sideways = light.cluster_probability(np.array([[0.0, 0.0, 10.0]]), np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(sideways[0], power_only)
    rng = np.random.default_rng(4)
    pts, nrm = rng.uniform(-6, 6, (2000, 3)), rng.normal(size=(2000, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    np.testing.assert_allclose(light.cluster_probability(pts, nrm).sum(axis=1), 1.0)


def test_a_texels_sequence_is_stratified_across_its_passes_and_independent_between_texels():
    texels = np.arange(500, dtype=np.int64) * 7 + 3
    k, passes = 16, 8
    for dim in range(4):
        u = np.stack(
            [lights.light.TexelStream(texels, k, p * k, 123).uniforms(dim).reshape(-1, k) for p in range(passes)],
            axis=1,
        ).reshape(len(texels), passes * k)  # (texels, all samples)
        assert u.min() >= 0.0 and u.max() < 1.0
        if dim == 0:  # base 2: 128 consecutive samples fill the 128 strata exactly once
            np.testing.assert_array_equal(np.sort(np.floor(u * 128), axis=1), np.tile(np.arange(128), (len(texels), 1)))
        # every texel covers [0, 1) evenly: no stratum of 8 is empty or crowded
        counts = np.stack([np.bincount(np.floor(row * 8).astype(int), minlength=8) for row in u])
        assert counts.min() >= 12 and counts.max() <= 20
        # the offsets make texels (and seeds) independent: first samples spread uniformly
        first = u[:, 0]
        assert abs(first.mean() - 0.5) < 0.05 and abs(first.var() - 1 / 12) < 0.02
    other_seed = lights.light.TexelStream(texels, k, 0, 124).uniforms(0)
    assert not np.allclose(other_seed, lights.light.TexelStream(texels, k, 0, 123).uniforms(0))


def test_directions_sampled_in_a_spherical_triangle_hit_it_uniformly():
    rng = np.random.default_rng(8)
    tri = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 1.5], [0.0, 1.5, 0.8]])
    x = np.zeros((200_000, 3))
    tris = np.broadcast_to(tri, (len(x), 3, 3))
    w = lights.emitters.sample_spherical_triangles(x, tris, rng.random(len(x)), rng.random(len(x)))
    _, _, _, cos_a, sin_a, solid_angle = (v[0] for v in lights.emitters.spherical_triangles(x[:1], tris[:1]))
    # Girard's theorem agrees on the solid angle (the angles' excess over π, each angle between
    # the planes of the great circles through its corner), and on the angle at a
    a, b, c = (v / np.linalg.norm(v) for v in tri)

    def corner(p, q, r):  # the angle at p between the great circles p–q and p–r
        u, v = np.cross(p, q), np.cross(p, r)
        return np.arccos(np.clip(u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1, 1))

    angles = corner(a, b, c), corner(b, c, a), corner(c, a, b)
    assert solid_angle == pytest.approx(sum(angles) - np.pi, rel=1e-12)
    assert (cos_a, sin_a) == pytest.approx((np.cos(angles[0]), np.sin(angles[0])), abs=1e-12)
    # every direction hits the triangle (barycentrics of the ray's hit in its plane are >= 0)
    e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
    p = np.cross(w, e2)
    det = p @ e1
    s = -tri[0]
    u = np.einsum("ri,i->r", p, s) / det
    q = np.cross(s, e1)
    v = (w @ q) / det
    assert (u >= -1e-9).all() and (v >= -1e-9).all() and (u + v <= 1 + 1e-9).all()
    # uniform in solid angle: the irradiance (∫cosθ dω) from the directions matches Lambert's formula
    n = np.array([0.0, 0.0, 1.0])
    estimate = solid_angle * np.mean(w @ n)
    exact_e = polygon_irradiance(np.zeros(3), n, tri, [1.0, 1.0, 1.0])[0]
    assert estimate == pytest.approx(exact_e, rel=3e-3)


def test_the_compiled_samples_are_the_numpy_spec():
    tris, emission = lamps([(0, 0, 0.5), (3, 0, 2), (-80, 0, 30)], size=0.8)  # the far one: by area
    light = lights.emitters.EmissiveTriangles(tris, emission)
    rng = np.random.default_rng(9)
    x = rng.uniform(-2, 2, (10000, 3)) * [1, 1, 0.1]
    x[0] = tris[1, 0]  # from an emitter's own corner: degenerate, no sample or a finite one
    u = rng.random((4, len(x)))
    dirs, dist, _, pdf = light._sample_points(rng, x, u=u)
    assert np.isfinite(pdf).all() and np.isfinite(dirs[pdf > 0]).all()
    point = x + dirs * dist[:, None]
    pick = 1 + np.argmin(np.linalg.norm(point[:, None] - tris[1:].mean(axis=1)[None], axis=2), axis=1)
    solid_angle = lights.emitters.spherical_triangles(x, tris[pick])[-1]
    spherical = by_solid_angle(solid_angle) & (pdf > 0)
    assert spherical.sum() > 1000 and (~spherical).sum() > 100
    want = lights.emitters.sample_spherical_triangles(
        x[spherical], tris[pick[spherical]], u[2, spherical], u[3, spherical]
    )
    np.testing.assert_allclose(dirs[spherical], want, atol=1e-9)
    ok = pdf > 0
    np.testing.assert_allclose(pdf[ok], numpy_pdf(light, x[ok], None, dirs[ok], dist[ok], pick[ok]), rtol=1e-9)


@pytest.mark.parametrize("count", [1, 3, 40])
def test_a_points_sample_does_not_depend_on_the_points_sampled_with_it(count):
    """The kernel computes the light tree's top weights for blocks of points together
    (`light_kernels._top_weights`): each point's sample is bit for bit the one it gets alone."""
    rng = np.random.default_rng(count)
    centres = rng.uniform(-3, 3, (count, 3)) * [1, 1, 0.2] + [0, 0, 2]
    tris, emission = lamps([tuple(c) for c in centres], size=0.5)
    light = lights.emitters.EmissiveTriangles(tris, emission)
    x = rng.uniform(-3, 3, (300, 3)) * [1, 1, 0.3]
    normals = rng.normal(size=(300, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    u = rng.random((4, len(x)))
    together = light._sample_points(rng, x, normals=normals, u=u)
    for i in (0, 1, 127, 128, 129, 299):
        alone = light._sample_points(rng, x[i : i + 1], normals=normals[i : i + 1], u=u[:, i : i + 1])
        for got, want in zip(alone, together):
            np.testing.assert_array_equal(got[0], want[i])


def lamp_room(res=32):
    """A 2 m floor (the receiver) with a small emissive box 3 cm above it (near: sampled by
    solid angle, sharp 1/d² falloff), a large one 1.5 m up and a dim far one beside it."""
    from hhd_lightmapper.core import bakepoints, rays
    from hhd_lightmapper.core.scene import BakeScene
    from scenekit import meshes

    v, f = meshes.plane(2.0)
    floor = v[f]
    boxes = [meshes.cube(0.1, centre=(0.3, -0.2, 0.08)), meshes.cube(0.5, centre=(-0.4, 0.3, 1.5))]
    boxes.append(meshes.cube(0.3, centre=(6.0, 0.0, 1.0)))
    tris = np.concatenate([floor] + [bv[bf] for bv, bf in boxes])
    emission = np.zeros((len(tris), 3))
    emission[2:14] = [30.0, 20.0, 10.0]
    emission[14:26] = [1.0, 1.0, 1.0]
    emission[26:] = [0.5, 0.5, 0.5]
    surface = bakepoints.SurfaceTriangles(
        floor, np.tile([0, 0, 1.0], (2, 3, 1)), floor[..., :2] / 2.0 + 0.5, np.zeros(2, int), np.full((2, 3), 0.5)
    )
    scene = BakeScene(tris, np.full((len(tris), 3), 0.5), emission=emission)
    return bakepoints.build(surface, res, res, occluders=rays.RayScene(tris)), scene


def test_the_new_emitter_sampling_bakes_what_power_and_area_sampling_bakes():
    """Every part of the emitter sampling switched off (power, area, independent numbers: the
    sampling before them; the numbers drawn pass by pass by scenekit/estimator_reference.py) and
    on: the same irradiance over the floor within the noise, and less noise with them on."""
    from hhd_lightmapper.core import tracer
    from scenekit import estimator_reference

    points, scene = lamp_room()
    settings = tracer.BakeSettings(samples=64, pass_samples=16, bounces=1, seed=3)
    results = {}
    saved = (lights.emitters.CLUSTERS, lights.emitters.FANOUT, lights.emitters.SOLID_ANGLE_RANGE)
    try:
        for on in (False, True):
            lights.emitters.CLUSTERS, lights.emitters.FANOUT = (32, 8) if on else (1, 0)
            lights.emitters.SOLID_ANGLE_RANGE = (3e-4, 6.22) if on else (np.inf, np.inf)
            with contextlib.nullcontext() if on else estimator_reference.used("lights"):
                results[on] = tracer.bake(points, scene, settings)
    finally:
        lights.emitters.CLUSTERS, lights.emitters.FANOUT, lights.emitters.SOLID_ANGLE_RANGE = saved
    total = {on: r.sh[:, 0, :].sum(axis=0) for on, r in results.items()}
    error = {on: np.sqrt(np.square(r.sh_error[:, 0, :].astype(np.float64)).sum(axis=0)) for on, r in results.items()}
    np.testing.assert_array_less(np.abs(total[True] - total[False]), 4 * np.hypot(error[True], error[False]))
    assert (error[True] < 0.8 * error[False]).all()
