"""Lightmap UVs of quads and n-gons: one UV per polygon corner, no texel shared between charts,
charts cached by mesh content and re-packed (never re-charted) while fitting the atlas."""

import numpy as np
import pytest

from hhd_lightmapper.core import unwrap
from hhd_lightmapper.core.errors import BakeError
from hhd_lightmapper.core.unwrap import charting, data, packing, worker_runs, xatlas_packing, xatlas_worker
from scenekit import meshes


@pytest.fixture(autouse=True)
def fresh_cache():
    unwrap.clear_chart_cache()
    yield
    unwrap.clear_chart_cache()


def quads_and_ngons():
    """Bumpy (non-planar) quads, a warped concave 12-gon, a quad with a zero-area triangle (three
    corners in a row) and a quad with no area at all, as one mesh with polygon indices."""
    in_a_row = (
        np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 0.3]], float) + [0, 4, 0],
        np.array([[0, 1, 2], [0, 2, 3]]),
        np.array([0, 0]),
    )
    flat = (
        np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float) + [0, 6, 0],
        np.array([[0, 1, 2], [0, 2, 3]]),
        np.array([0, 0]),
    )
    return meshes.combine(
        meshes.bumpy_quads(),
        meshes.ngon(centre=(4.0, 1.0, 0.0)),
        meshes.ngon(sides=7, concave=False, bump=0.4, centre=(4.0, 4.0, 0.0)),
        in_a_row,
        flat,
    )


def corner_uv_spread(uv, triangles, polygons):
    """Largest difference between the UVs given to one (polygon, vertex) pair: the loop a
    Blender polygon has there can hold one UV only."""
    key = np.repeat(polygons, 3) * (triangles.max() + 1) + triangles.ravel()
    flat = uv.reshape(-1, 2).astype(np.float64)
    order = np.argsort(key, kind="stable")
    same = key[order][1:] == key[order][:-1]
    return float(np.abs(flat[order][1:] - flat[order][:-1])[same].max(initial=0.0))


@pytest.mark.parametrize("build", [meshes.bumpy_quads, meshes.ngon, quads_and_ngons])
def test_every_loop_of_a_polygon_gets_one_uv(build):
    v, f, poly = build()
    res = unwrap.unwrap(
        [unwrap.UnwrapMesh("polygons", v, f, polygons=poly)], unwrap.UnwrapSettings(resolution=512, padding=4)
    )
    assert corner_uv_spread(res.objects[0].uv, f, poly) == 0.0
    assert not res.warnings


def test_charts_of_quads_and_ngons_share_no_texel_and_cover_what_is_reported():
    """Rasterised as the bake covers texels: no texel in two charts or two objects, no texel
    covered twice within a chart, and the covered area is the texel count reported."""
    v, f, poly = quads_and_ngons()
    sv, sf = meshes.uv_sphere()
    res = unwrap.unwrap(
        [unwrap.UnwrapMesh("polygons", v, f, polygons=poly), unwrap.UnwrapMesh("sphere", sv, sf)],
        unwrap.UnwrapSettings(resolution=512, padding=2),
    )
    report = meshes.texel_overlaps([o.uv for o in res.objects], 512, 512)
    assert report["objects"] == 0 and report["charts"] == 0
    for o, area, summed in zip(res.objects, report["area"], report["summed"]):
        assert summed == pytest.approx(area, rel=1e-9)
        assert area == pytest.approx(o.texels, rel=1e-6)
    flat = poly == poly.max()  # the quad without area: no texels
    assert (res.objects[0].uv[f[:, 0] < 0] == 0).all() and (res.objects[0].uv[flat] == 0).all()


def test_charts_are_scaled_to_their_true_area():
    """Every chart gets the same texels per m², so texel counts follow surface areas."""
    v, f, poly = quads_and_ngons()
    res = unwrap.unwrap([unwrap.UnwrapMesh("p", v, f, polygons=poly)], unwrap.UnwrapSettings(texel_density=64.0))
    uv = res.objects[0].uv.astype(np.float64) * res.atlas_sizes[0]
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    texels = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    area = data.triangle_areas(v, f)
    live = area > 1e-3
    # per triangle within the charts' own distortion; in total within xatlas's rounding of chart sizes
    assert np.median(texels[live] / area[live]) == pytest.approx(64.0**2, rel=0.05)
    assert texels.sum() == pytest.approx(64.0**2 * area.sum(), rel=0.1)


def _chart(triangles_uv, key):
    uv = np.asarray(triangles_uv, dtype=np.float64)
    return xatlas_worker._invalid_charts(uv, np.zeros(len(uv), dtype=np.int64), np.asarray(key), 1)[0]


@pytest.mark.parametrize("max_pairs", [xatlas_worker.MAX_PAIRS, 2])
def test_charts_that_overlap_themselves_are_found(monkeypatch, max_pairs):
    monkeypatch.setattr(xatlas_worker, "MAX_PAIRS", max_pairs)  # tested in small chunks too
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    ring_outer = np.array([[0, 0], [3, 0], [3, 3], [0, 3]], float)
    ring_inner = np.array([[1, 1], [2, 1], [2, 2], [1, 2]], float)
    pts = np.vstack([ring_outer, ring_inner])
    ring = [(0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    assert not _chart(pts[ring], ring)  # a ring with its hole
    assert not _chart([np.array(square)[[0, 1, 2]], np.array(square)[[0, 2, 3]]], [(0, 1, 2), (0, 2, 3)])
    assert _chart([[[0, 0], [1, 0], [0, 1]], [[0, 0], [0, 1], [1, 0]]], [(0, 1, 2), (0, 3, 4)])  # flipped
    crossing = [[[0, 0], [2, 0], [0, 2]], [[0.5, 0.5], [2.5, 0.5], [0.5, 2.5]]]  # two triangles cross
    assert _chart(crossing, [(0, 1, 2), (3, 4, 5)])
    # no edge crosses, but the boundary winds twice round the middle: a patch on its own vertices
    # lying over the whole square (Suzanne's eye ring: a hole loop laid inside the chart's own part)
    patch = np.array([[0.5, 0.5], [2.5, 0.5], [2.5, 2.5], [0.5, 2.5]])
    layered = [np.array(square)[[0, 1, 2]] * 3, np.array(square)[[0, 2, 3]] * 3, patch[[0, 1, 2]], patch[[0, 2, 3]]]
    assert _chart(layered, [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)])
    apart = [np.array(square)[[0, 1, 2]], np.array(square)[[0, 2, 3]], patch[[0, 1, 2]] + 3, patch[[0, 2, 3]] + 3]
    assert not _chart(apart, [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)])  # two pieces side by side


def test_charts_are_cached_by_mesh_content(monkeypatch):
    v, f, poly = quads_and_ngons()
    settings = unwrap.UnwrapSettings(resolution=512)
    first = unwrap.unwrap([unwrap.UnwrapMesh("a", v, f, polygons=poly)], settings)
    assert first.stats["charted"] == 1
    tasks = []
    real = worker_runs._run_worker
    for module in (charting, packing):
        monkeypatch.setattr(module, "_run_worker", lambda job, *a: tasks.append(job["task"]) or real(job, *a))
    moved = unwrap.unwrap([unwrap.UnwrapMesh("a", v + [5.0, 0.0, 1.0], f, polygons=poly)], settings)
    assert moved.stats == dict(moved.stats, charted=0, cached=1) and tasks == []  # nothing charted or packed
    np.testing.assert_array_equal(moved.objects[0].uv, first.objects[0].uv)
    other = unwrap.unwrap([unwrap.UnwrapMesh("a", v, f, polygons=poly)], unwrap.UnwrapSettings(resolution=256))
    assert other.stats["charted"] == 0 and tasks and "chart" not in tasks  # re-packed only
    bent = v.copy()
    bent[0, 2] += 0.5
    assert unwrap.unwrap([unwrap.UnwrapMesh("a", bent, f, polygons=poly)], settings).stats["charted"] == 1
    monkeypatch.setattr(charting, "CHART_CACHE_BYTES", 1)  # bounded: only the newest stays
    sv, sf = meshes.uv_sphere()
    unwrap.unwrap([unwrap.UnwrapMesh("s", sv, sf)], settings)
    assert len(charting._CACHE) == 1


def test_a_mesh_of_many_parts_is_charted_in_parallel_pieces(monkeypatch):
    """A mesh larger than one process's share is split between its connected parts; the pieces'
    charts join into one valid set."""
    monkeypatch.setattr(charting, "_cores", lambda: 2)
    monkeypatch.setattr(charting, "TRIANGLES_PER_PROCESS", 100)
    parts = [meshes.bumpy_quads(n=6, seed=k) for k in range(5)]
    v, f, poly = meshes.combine(*[(pv + [3.0 * k, 0, 0], pf, pp) for k, (pv, pf, pp) in enumerate(parts)])
    mesh = unwrap.UnwrapMesh("parts", v, f, polygons=poly)
    jobs = charting._chart_jobs([mesh])
    assert len(jobs) == 2 and abs(sum(len(p[3]) for p in jobs[0]) - sum(len(p[3]) for p in jobs[1])) <= 72
    res = unwrap.unwrap([mesh], unwrap.UnwrapSettings(resolution=512, padding=2))
    assert res.stats["chart_processes"] == 2
    assert corner_uv_spread(res.objects[0].uv, f, poly) == 0.0
    report = meshes.texel_overlaps([res.objects[0].uv], 512, 512)
    assert report["charts"] == 0 and report["summed"][0] == pytest.approx(report["area"][0], rel=1e-9)
    labels = charting.connected_parts(f, len(v))
    assert len(np.unique(labels)) == 5


@pytest.mark.parametrize("side_by_side", [False, True])
def test_fitting_packs_the_same_charts_again_at_a_smaller_density(monkeypatch, side_by_side):
    """Charts that spill out of the atlas are packed again (xatlas charts once) at a density
    shrunk by the share that spilled; then between the best that fitted and the smallest that
    spilled. Two densities a round, in one child or in two parallel ones."""
    for module in (charting, packing):
        monkeypatch.setattr(module, "_cores", lambda: 2 if side_by_side else 1)
    monkeypatch.setattr(packing, "ONE_CHILD_TRIANGLES", 0)
    monkeypatch.setattr(xatlas_packing, "FIRST_FILL", (1.6, 1.5))  # first densities far too high
    tasks = []
    real = worker_runs._run_worker
    for module in (charting, packing):
        monkeypatch.setattr(module, "_run_worker", lambda job, *a: tasks.append(job["task"]) or real(job, *a))
    sv, sf = meshes.uv_sphere()
    res = unwrap.unwrap([unwrap.UnwrapMesh("s", sv, sf)], unwrap.UnwrapSettings(resolution=256, padding=2))
    tries = res.stats["tries"][0]
    assert tasks.count("chart") == 1 and len(tries) == res.stats["packs"]
    assert tasks[1:] == (["pack"] * len(tries) if side_by_side else ["fit"])
    first_fit = [fits for _, fits in tries].index(True)
    assert first_fit >= 1 and all(b[0] < a[0] for a, b in zip(tries[:first_fit], tries[1 : first_fit + 1]))
    smallest_spilled = min(t for t, fits in tries if not fits)
    assert all(t < smallest_spilled for t, fits in tries if fits)
    uv = res.objects[0].uv.astype(np.float64) * 256
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    best = max(t for t, fits in tries if fits)
    assert 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum() == pytest.approx(
        best**2 * data.triangle_areas(sv, sf).sum(), rel=0.1
    )
    assert res.atlas_sizes == [(256, 256)]


def test_padding_that_cannot_fit_names_charts_padding_and_texels():
    v, f, poly = meshes.bumpy_quads(n=16, amplitude=0.6)
    with pytest.raises(BakeError, match=r"'bumpy'.*charts with padding 64 need at least \d+ texels.*256²"):
        unwrap.unwrap(
            [unwrap.UnwrapMesh("bumpy", v, f, polygons=poly)], unwrap.UnwrapSettings(resolution=256, padding=64)
        )


def test_polygon_indices_are_checked():
    v, f, _ = meshes.bumpy_quads(n=2)
    with pytest.raises(BakeError, match="'q': polygons must give one polygon index"):
        unwrap.unwrap([unwrap.UnwrapMesh("q", v, f, polygons=np.zeros(3, int))], unwrap.UnwrapSettings())


def test_millimetre_triangles_and_needles_keep_their_charts():
    """xatlas's zero-area test is absolute (in its input units), so meshes are charted at a
    scale of their own: a 1 mm sphere is cut into the same charts as a 1 m one (not one chart
    per triangle); a needle (a triangle of almost no area) gets finite UVs."""
    counts = []
    for radius in (1.0, 0.001):
        v, f = meshes.uv_sphere(radius=radius)
        needle = np.array([[0.0, 0.0, 2.0], [0.5, 0.0, 2.0], [1.0, 1e-17, 2.0]]) * radius
        mesh = unwrap.UnwrapMesh("small", np.vstack([v, needle]), np.vstack([f, [len(v), len(v) + 1, len(v) + 2]]))
        res = unwrap.unwrap([mesh], unwrap.UnwrapSettings(resolution=256))
        uv = res.objects[0].uv.astype(np.float64)
        assert np.isfinite(uv).all() and (uv >= 0).all() and (uv <= 1).all()
        counts.append(res.charts)
    assert counts[0] == counts[1]
