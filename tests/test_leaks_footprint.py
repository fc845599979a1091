"""A texel straddling a triangle edge averages its whole footprint, not only its own triangle's
part (`bakepoints.FOOTPRINT_TRIANGLES`). The cause of most of the classroom's leaking texels
against Cycles (bench/results/leaks.md): a wall split into triangles along a line through texel
centres, a cabinet 8 mm in front of it whose edge runs through those texels; each texel took
the lit half (its largest triangle's, lowest index on a tie), 0.38 where the whole footprint
holds ~0.15. Here the same geometry made exact: a floor of two rectangles meeting at x = 0,
which the lightmap maps onto the centres of one texel column, and a roof over x > 0 under a
zero-angle sun straight down: that column is exactly half lit, its neighbours fully lit or dark."""

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, colour, hhd, tracer
from hhd_lightmapper.core.scene import BakeScene, SunLight

RES = 64
STRENGTH = 3.0


def rectangle(x0, x1, y0, y1, z):
    """Two triangles (2, 3, 3) of the upward-facing rectangle, counter-clockwise from above."""
    a, b, c, d = (x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)
    return np.array([[a, b, c], [a, c, d]], float)


def texel_space(p):
    """Lightmap coordinates in texels of floor points: x = 0 on the centres of column 32."""
    return np.stack([32.5 + 30.0 * p[..., 0], 32.0 + 30.0 * p[..., 1]], axis=-1)


def straddling_bake(samples=16):
    """Points, luminance I_z (P,), each texel's lit fraction of its footprint (P,)."""
    floor = np.concatenate([rectangle(-1.0, 0.0, -1.0, 1.0, 0.0), rectangle(0.0, 1.0, -1.0, 1.0, 0.0)])
    roof = rectangle(0.0, 3.0, -3.0, 3.0, 0.5)
    surface = bakepoints.SurfaceTriangles(
        positions=floor,
        normals=np.tile([0.0, 0.0, 1.0], (len(floor), 3, 1)),
        uv=texel_space(floor) / RES,
        object_index=np.zeros(len(floor), int),
        albedo=np.full((len(floor), 3), 0.8),
    )
    tris = np.concatenate([floor, roof])
    scene = BakeScene(
        tris, np.full((len(tris), 3), 0.8), lights=[SunLight(np.array([0.0, 0.0, 1.0]), np.full(3, STRENGTH))]
    )
    settings = tracer.BakeSettings(samples=samples, pass_samples=16, bounces=0, seed=3)
    traced = bake.trace_surface(surface, RES, RES, scene, settings)
    points = traced.points
    iz = hhd.irradz(traced.sh, points.normal) @ colour.LUMINANCE
    column = points.texel % RES
    lit = np.clip(32.5 - column, 0.0, 1.0)  # the part of [column, column + 1] left of 32.5
    return points, iz, lit


def test_a_texel_on_a_triangle_edge_averages_its_whole_footprint():
    """The column whose centres lie on the edge between the lit and the shadowed rectangle is
    half lit, within one stratum of the stratified first tries (1/16); its neighbours are
    exactly fully lit and exactly dark: no light from the lit half reaches the dark column."""
    points, iz, lit = straddling_bake()
    full = STRENGTH / np.pi
    inside = (points.coverage >= 1.0 - 1e-9) & (np.abs(points.texel // RES - 32) < 25)
    column = points.texel % RES
    edge = inside & (column == 32)
    assert edge.sum() > 40 and (points.others[edge] >= 0).any(axis=1).all()
    np.testing.assert_allclose(iz[edge] / full, 0.5, atol=1.0 / 16 + 1e-9)
    np.testing.assert_allclose(iz[inside & (lit == 1.0)] / full, 1.0, rtol=1e-9)
    assert (iz[inside & (lit == 0.0)] == 0.0).all()


def test_with_only_the_texels_own_triangle_the_edge_column_takes_one_side(monkeypatch):
    """The defect the footprint over every triangle fixes: sampling the own triangle only, the
    edge column takes the lit rectangle's value (it owns the texel: equal overlaps, lowest
    index) where half its footprint lies in shadow."""
    monkeypatch.setattr(bakepoints, "FOOTPRINT_TRIANGLES", 1)
    points, iz, lit = straddling_bake()
    assert points.others is None
    full = STRENGTH / np.pi
    edge = (points.coverage >= 1.0 - 1e-9) & (np.abs(points.texel // RES - 32) < 25) & (points.texel % RES == 32)
    assert edge.sum() > 40
    np.testing.assert_allclose(iz[edge] / full, 1.0, rtol=1e-9)


@pytest.mark.parametrize("m", [2, 4])
def test_other_triangles_list_every_overlap_of_a_texel_largest_first(m, monkeypatch):
    """`other_triangles`: every triangle overlapping a texel besides its own, largest overlap
    first, up to FOOTPRINT_TRIANGLES - 1, checked against the raster's own pairs."""
    from hhd_lightmapper.core import raster

    monkeypatch.setattr(bakepoints, "FOOTPRINT_TRIANGLES", m)
    rng = np.random.default_rng(5)
    uv = rng.random((40, 3, 2))
    cov = raster.rasterise(uv, 16, 16)
    chosen, _ = raster.choose_per_texel(cov)
    others = bakepoints.other_triangles(cov, chosen)
    for row, pair in enumerate(chosen):
        mine = np.flatnonzero(cov.texel == cov.texel[pair])
        mine = mine[np.lexsort((cov.triangle[mine], -cov.area[mine]))]
        assert cov.triangle[mine[0]] == cov.triangle[pair]
        expect = list(cov.triangle[mine[1:m]]) + [-1] * (m - len(mine[:m]))
        assert list(others[row]) == expect


@pytest.mark.statistical
def test_samples_cover_the_whole_footprint_over_the_texels_triangles():
    """On an unwrapped UV sphere (many texels straddle triangle edges), every sample origin lies
    in one of its texel's triangles and inside the texel, and over the fully covered texels that
    straddle an edge the samples are centred on the texel centre (the own triangle's part alone
    is centred up to half a texel away)."""
    from hhd_lightmapper.core import unwrap
    from scenekit import meshes

    v, f = meshes.uv_sphere()
    result = unwrap.unwrap([unwrap.UnwrapMesh("m", v, f)], unwrap.UnwrapSettings(resolution=256, padding=4))
    uv = result.objects[0].uv.astype(np.float64)
    surface = bakepoints.SurfaceTriangles(
        v[f], meshes.vertex_normals(v, f)[f], uv, np.zeros(len(f), int), np.full((len(f), 3), 0.5)
    )
    pts = bakepoints.build(surface, 256, 256)
    k = 64
    multi = np.flatnonzero((pts.others >= 0).any(axis=1))
    assert len(multi) > 200
    origins = pts.sample_origins(np.random.default_rng(0), multi, k)
    p = origins - np.repeat(pts.face_normal[multi], k, axis=0) * pts.offset
    corner = np.repeat(np.stack([pts.texel[multi] % 256, pts.texel[multi] // 256], 1), k, axis=0)
    tris = np.repeat(np.concatenate([pts.triangle[multi, None], pts.others[multi]], axis=1), k, axis=0)
    local = np.full((len(p), 2), np.nan)
    for m in range(tris.shape[1]):
        t = np.maximum(tris[:, m], 0)
        corners = v[f][t]
        e1, e2, d = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], p - corners[:, 0]
        normal = np.cross(e1, e2)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        g00, g01, g11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        r1, r2 = (d * e1).sum(1), (d * e2).sum(1)
        det = g00 * g11 - g01**2
        b1, b2 = (g11 * r1 - g01 * r2) / det, (g00 * r2 - g01 * r1) / det
        scale = np.sqrt(det)
        on = (tris[:, m] >= 0) & (np.abs((d * normal).sum(1)) < 1e-9 * scale + 1e-12)
        on &= (np.minimum(np.minimum(b1, b2), 1 - b1 - b2) > -1e-9) & np.isnan(local[:, 0])
        t_uv = uv[t] * 256
        at = t_uv[:, 0] + b1[:, None] * (t_uv[:, 1] - t_uv[:, 0]) + b2[:, None] * (t_uv[:, 2] - t_uv[:, 0])
        local[on] = (at - corner)[on]
    assert np.isfinite(local).all()  # on one of the texel's triangles
    assert ((local >= -1e-6) & (local <= 1 + 1e-6)).all()  # inside the texel
    full = np.repeat(pts.coverage[multi] >= 1.0 - 1e-9, k)
    centre = local[full].reshape(-1, k, 2).mean(axis=1)
    off = np.abs(centre - 0.5).max(axis=1)  # (where more than 4 triangles meet, at the poles, less)
    assert np.abs(centre.mean(axis=0) - 0.5).max() < 0.01 and np.quantile(off, 0.99) < 0.05


def test_a_duplicated_surface_is_baked_as_lit_as_the_surface_one_sees():
    """Duplicated geometry (a second floor in the same plane, facing the same way: z-fighting,
    as staircase2's wall has): each copy is baked as the lit surface it shows, exactly fully lit
    under the sun, not black as Cycles bakes it (its rays start on the surface and hit the twin at
    distance 0: bench/results/leaks.md, 'coincident twin')."""
    floor = rectangle(-1.0, 1.0, -1.0, 1.0, 0.0)
    twin = rectangle(-0.5, 0.5, -0.5, 0.5, 0.0)  # a smaller copy in the same plane, split differently
    receivers = np.concatenate([floor, twin])
    uv = np.concatenate([(floor[..., :2] + 1.0) / 4.0 + 0.02, (twin[..., :2] + 0.5) / 2.0 * 0.45 + 0.53])
    surface = bakepoints.SurfaceTriangles(
        positions=receivers,
        normals=np.tile([0.0, 0.0, 1.0], (len(receivers), 3, 1)),
        uv=uv,
        object_index=np.repeat([0, 1], 2),
        albedo=np.full((len(receivers), 3), 0.8),
    )
    sun = SunLight(np.array([0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0), np.full(3, STRENGTH))
    scene = BakeScene(receivers, np.full((len(receivers), 3), 0.8), lights=[sun])
    settings = tracer.BakeSettings(samples=16, pass_samples=16, bounces=0, seed=3)
    traced = bake.trace_surface(surface, RES, RES, scene, settings)
    points = traced.points
    iz = hhd.irradz(traced.sh, points.normal) @ colour.LUMINANCE
    full = STRENGTH * sun.direction[2] / np.pi
    both = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    assert both[points.object_index == 1].sum() > 100 and both[points.object_index == 0].sum() > 500
    np.testing.assert_allclose(iz[both] / full, 1.0, rtol=1e-9)


@pytest.mark.parametrize("folded", [False, True])
def test_a_fold_inside_a_texel_keeps_the_other_side_out_of_its_footprint(folded):
    """A square of two triangles split along its diagonal, unwrapped onto a 4 × 4 atlas: the
    diagonal texels straddle both. Flat, each takes the other triangle into its footprint;
    folded 90° along the diagonal, none does (its samples, pushed off along the texel's own
    face normal, would stay on the other face: FOOTPRINT_MIN_COS)."""
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
    positions = np.concatenate([uv, np.zeros((2, 3, 1))], axis=2)
    if folded:
        positions[1, 2] = [0.5, 0.5, np.sqrt(0.5)]
    surface = bakepoints.SurfaceTriangles(
        positions, np.tile([0, 0, 1.0], (2, 3, 1)), uv, np.zeros(2, int), np.full((2, 3), 0.5)
    )
    points = bakepoints.build(surface, 4, 4)
    x, y = points.texel % 4, points.texel // 4
    diagonal = np.flatnonzero(x == y)
    assert len(diagonal) == 4 and (points.others[x != y] == -1).all()
    if folded:
        assert (points.others[diagonal] == -1).all()
    else:
        for row in diagonal:
            assert {points.triangle[row], points.others[row, 0]} == {0, 1}
            assert (points.others[row, 1:] == -1).all()
