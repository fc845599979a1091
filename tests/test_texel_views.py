"""The views before a bake (issue 57, part 3): texel density, texel checker, problems.

Core (no bpy): the density of a plane of known world and UV area is sqrt(texels / m²) (exact up
to float32 UVs); the objects' densities agree with the unwrap's reported texels per object ÷
area within 1% (and equal the Texel Density setting on flat charts); the problems math flags
exactly the texels two charts overlap (rectangles whose expected texels are known in closed
form, and a real unwrap with one object's charts moved onto another's, against the texels each
object covers alone), nothing on a good unwrap, and flipped / degenerate faces and objects with
too few texels where they were made.

Blender: View Show in each mode and Hide Preview leave every material, mesh, image and object
as they were (tests/test_workflow_blender.py's scene hash plus the node trees' layout and the
objects' and meshes' keys); an object without the lightmap UV layer is reported by name and left
alone; the density view's face colours are the heat colours of core's densities, which agree
with the unwrap's report; the Problems view's mask image holds exactly the overlapped texels.
EEVEE: an orthographic render of the checker on a plane facing the camera, 8 pixels per texel:
every cell edge within 1 pixel of where the texel edges project, cells 8 ± 1 pixels wide.
"""

import re

import numpy as np
import pytest

from hhd_lightmapper.core import raster, unwrap
from hhd_lightmapper.core.unwrap import texel_density, uv_problems
from scenekit import meshes

# ---- core ------------------------------------------------------------------------------------


def quad_mesh(name, corners_world, uv_rect, width, height, polygon_base=0):
    """A quad (two triangles, one polygon) with world corners (4, 3) and the UV rectangle
    (x0, y0, x1, y1) in texels of a width × height atlas."""
    x0, y0, x1, y1 = uv_rect
    uv = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64) / [width, height]
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    return texel_density.ViewMesh.of(name, corners_world, tri, uv[tri], np.zeros(2, np.int64) + polygon_base)


def test_density_of_a_plane_is_texels_over_area():
    w = h = 128
    # a 2 m × 3 m plane, tilted and moved: 6 m²; its UVs a 40 × 30 texel rectangle: 1200 texels
    rotation = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    corners = np.array([[0, 0, 0], [2, 0, 0], [2, 3, 0], [0, 3, 0]], float) @ rotation.T + [5, -2, 1]
    mesh = quad_mesh("Plane", corners, (10.25, 20.5, 50.25, 50.5), w, h)
    d = texel_density.density(mesh, w, h)
    assert d.total_area == pytest.approx(6.0, rel=1e-12)
    assert d.total_texels == pytest.approx(1200.0, rel=1e-6)
    assert d.density[0] == pytest.approx(np.sqrt(1200.0 / 6.0), rel=1e-2)
    assert d.mean_density == pytest.approx(np.sqrt(200.0), rel=1e-6)
    # the heat colours: half blue, on target green, double red, clamped beyond
    colours = texel_density.heat([0.25, 0.5, 1.0, 2.0, 4.0])
    legend = {name: rgb for _, name, rgb in texel_density.LEGEND}
    np.testing.assert_allclose(colours, [legend["blue"], legend["blue"], legend["green"], legend["red"], legend["red"]])


def unwrap_meshes():
    out = []
    v, f = meshes.cube(1.0)
    out.append(unwrap.UnwrapMesh("Cube", v, f))
    v, f = meshes.uv_sphere()
    out.append(unwrap.UnwrapMesh("Sphere", v + [3.0, 0.0, 0.0], f))
    v, f = meshes.plane(4.0)
    out.append(unwrap.UnwrapMesh("Floor", v + [-2.0, -2.0, -1.0], f))
    return out


@pytest.fixture(scope="module", params=[None, 20.0], ids=["resolution", "density"])
def unwrapped(request):
    ms = unwrap_meshes()
    result = unwrap.unwrap(ms, unwrap.UnwrapSettings(resolution=256, texel_density=request.param, padding=4))
    views = [texel_density.ViewMesh.of(m.name, m.positions, m.triangles, o.uv) for m, o in zip(ms, result.objects)]
    return request.param, result, views


def test_density_agrees_with_the_unwraps_texels_per_object(unwrapped):
    setting, result, views = unwrapped
    ((w, h),) = result.atlas_sizes
    densities = [texel_density.density(v, w, h) for v in views]
    for obj, view, d in zip(result.objects, views, densities):
        area = texel_density.world_areas(view.corners).sum()
        assert d.mean_density**2 == pytest.approx(obj.texels / area, rel=0.01), obj.name
    target = texel_density.target_density(densities, setting)
    if setting:  # flat charts are packed at exactly the setting
        assert target == setting
        for name in ("Cube", "Floor"):
            d = densities[[v.name for v in views].index(name)]
            np.testing.assert_allclose(d.density, setting, rtol=0.01)
    else:  # the resolution's density: what xatlas scaled the charts to
        assert target == pytest.approx(
            np.sqrt(sum(o.texels for o in result.objects) / sum(d.total_area for d in densities))
        )


def test_a_good_unwrap_has_no_problems(unwrapped):
    _, result, views = unwrapped
    ((w, h),) = result.atlas_sizes
    found = uv_problems.find(views, w, h)
    assert len(found.shared) == 0 and not found.mask().any()
    for p in found.objects:
        assert p.count == 0, p.line()
        assert "0 shared texels, 0 flipped, 0 degenerate faces" in p.line()


def texel_set(uv, w, h):
    return set(np.unique(raster.rasterise(uv, w, h).texel).tolist())


def test_overlapping_rectangles_flag_exactly_their_common_texels():
    w, h = 64, 48
    world = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    a = quad_mesh("A", world, (10.3, 5.2, 30.6, 20.9), w, h)
    b = quad_mesh("B", world + [2, 0, 0], (25.5, 15.7, 40.1, 33.0), w, h)
    c = quad_mesh("C", world + [4, 0, 0], (45.0, 30.0, 50.0, 34.0), w, h)  # touches nobody
    found = uv_problems.find([a, b, c], w, h)
    # the intersection [25.5, 30.6] × [15.7, 20.9] overlaps texels i = 25 … 30, j = 15 … 20
    expected = sorted(j * w + i for i in range(25, 31) for j in range(15, 21))
    assert found.shared.tolist() == expected
    assert [p.shared for p in found.objects] == [36, 36, 0]
    assert found.mask().sum() == 36 and found.mask()[15:21, 25:31].all()
    # two charts of one object overlapping count the same; a chart's own triangles never do
    both = texel_density.ViewMesh(
        "AB", np.concatenate([a.corners, b.corners]), np.concatenate([a.uv, b.uv]), np.array([0, 0, 1, 1]), 2
    )
    assert uv_problems.find([both, c], w, h).shared.tolist() == expected


def test_a_chart_moved_onto_another_flags_exactly_the_texels_they_share(unwrapped):
    _, result, views = unwrapped
    ((w, h),) = result.atlas_sizes
    cube, sphere, floor = views
    # move the cube's charts so that its first triangle lands on the middle of the floor's chart
    shift = floor.uv.reshape(-1, 2).mean(0) - cube.uv[0].mean(0)
    moved = texel_density.ViewMesh(cube.name, cube.corners, cube.uv + shift, cube.polygon, cube.polygons)
    found = uv_problems.find([moved, sphere, floor], w, h)
    expected = texel_set(moved.uv, w, h) & (texel_set(floor.uv, w, h) | texel_set(sphere.uv, w, h))
    assert len(expected) > 50
    assert set(found.shared.tolist()) == expected
    for view, problems in zip((moved, sphere, floor), found.objects):
        assert problems.shared == len(texel_set(view.uv, w, h) & expected), view.name
    assert found.objects[0].shared == len(expected)


def strip(name, uv_x, y=4.0, width=64, height=64):
    """Three quads in a row (world x 0 … 3, y 0 … 1, 1 m each), one chart; UVs: texel x of the
    four vertex columns `uv_x`, y … y + 10 texels."""
    xs = np.arange(4, dtype=float)
    positions = np.array([[x, y, 0.0] for y in (0.0, 1.0) for x in xs])
    uvs = np.array([[u, v] for v in (y, y + 10.0) for u in uv_x]) / [width, height]
    quads = [(k, k + 1, k + 5, k + 4) for k in range(3)]
    tri = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return texel_density.ViewMesh.of(name, positions, tri, uvs[tri], np.repeat(np.arange(3), 2), 3)


def test_flipped_degenerate_and_too_few_texels():
    w = h = 64
    good = strip("Good", [4.0, 14.0, 24.0, 34.0])
    folded = strip("Folded", [40.0, 50.0, 45.0, 60.0])  # the middle quad runs backwards
    collapsed = strip("Collapsed", [4.0, 14.0, 24.0, 24.0], y=20.0)  # the last quad has no UV width
    tiny = quad_mesh("Tiny", np.array([[0, 5, 0], [1, 5, 0], [1, 6, 0], [0, 6, 0]], float), (4, 40, 8, 44), w, h)
    found = uv_problems.find([good, folded, collapsed, tiny], w, h, target=10.0)
    g, f, c, t = found.objects
    assert g.count == 0
    assert f.flipped.tolist() == [False, False, True, True, False, False] and not f.degenerate.any()
    assert f.shared == 0  # the fold overlaps its own chart: shown as flipped, not as shared
    assert (f.flipped_faces, c.degenerate_faces, c.flipped_faces) == (1, 1, 0)
    assert "'Folded': 0 shared texels, 1 flipped, 0 degenerate faces (" in f.line() and f.count == 1
    assert t.line().endswith("(16 texels, too few texels)") and t.count == 1
    assert c.degenerate.tolist() == [False, False, False, False, True, True] and not c.flipped.any()
    assert t.few and not g.few and t.texels == pytest.approx(16.0)
    flipped, degenerate = uv_problems.polygon_flags(folded, f)
    assert flipped.tolist() == [False, True, False] and not degenerate.any()
    colours = uv_problems.face_colours(collapsed, c)
    np.testing.assert_array_equal(colours, [[1, 1, 1], [1, 1, 1], uv_problems.DEGENERATE_COLOUR])
    np.testing.assert_array_equal(uv_problems.face_colours(tiny, t), [uv_problems.FEW_COLOUR])


# ---- Blender ---------------------------------------------------------------------------------


def objects_state():
    """What a view must leave as it found: every mesh's attributes, every object's and
    material's keys, the node trees' layout, the images."""
    import bpy

    from test_preview_eevee import tree_state

    return (
        {m.name: sorted((a.name, a.domain, a.data_type) for a in m.attributes) for m in bpy.data.meshes},
        {
            m.name: (m.color_attributes.active_color_name, m.color_attributes.default_color_name)
            for m in bpy.data.meshes
        },
        {o.name: sorted(o.keys()) for o in bpy.data.objects},
        {m.name: tree_state(m) for m in bpy.data.materials},
        sorted(i.name for i in bpy.data.images),
    )


@pytest.fixture
def unwrapped_scene(extension, restore_hhd_settings):
    import bpy

    from scenekit import blender as kit

    kit.clear_scene()
    grey = kit.material("Grey", (0.6, 0.6, 0.6))
    floor = kit.plane("Floor", (0, 0, 0), 4, grey)
    cube = kit.box("Cube", (0.6, 0.5, 0.5), (1, 1, 1), kit.material("Red", (0.8, 0.2, 0.1)))
    other = kit.plane("Other", (6, 0, 0), 1, grey)  # shares Floor's material, never unwrapped
    kit.unwrap([floor, cube])
    return bpy.context.scene, floor, cube, other


def unwrap_texels(summary: str) -> dict:
    """{object: texels} from the unwrap's summary line ("texels per object: Floor: 1234, …")."""
    return {name: float(t) for name, t in re.findall(r"(\w+): (\d+)", summary.split("texels per object:")[1])}


@pytest.mark.bpy
def test_views_show_and_hide_restore_everything_exactly(unwrapped_scene):
    import bpy

    from hhd_lightmapper.bridge import view_data
    from scenekit.blender import scene_hash

    scene, floor, cube, other = unwrapped_scene
    texels = unwrap_texels(scene.hhd.unwrap_summary)
    before, state = scene_hash(), objects_state()
    from scenekit import blender as kit

    kit.select([floor, cube, other])
    for mode in ('DENSITY', 'CHECKER', 'PROBLEMS', 'DENSITY'):
        assert bpy.ops.hhd.view_show(mode=mode) == {'FINISHED'}
        summary = scene.hhd.view_summary
        assert "'Other' has no lightmap UV layer" in summary
        assert "hhd_preview" not in other and "hhd_view_size" not in other
        assert view_data.COLOUR not in other.data.attributes
        assert tuple(floor["hhd_view_size"]) == (256.0, 256.0, 0.0)
        groups = [n.node_tree.name for n in floor.material_slots[0].material.node_tree.nodes if n.type == 'GROUP']
        assert groups == ["HHD Texel Checker"]
        assert (view_data.COLOUR in floor.data.attributes) == (mode != 'CHECKER')
        if mode == 'PROBLEMS':
            assert "'Floor': 0 shared texels, 0 flipped, 0 degenerate faces" in summary
            assert "'Cube': 0 shared texels, 0 flipped, 0 degenerate faces" in summary
            assert "0 texels shared by two charts" in summary
    # the density view: each face's heat colour of core's density, which agrees with the unwrap
    densities = {}
    for obj in (floor, cube):
        mesh = view_data.read_view_mesh(obj, scene.hhd.uv_layer)
        densities[obj.name] = d = texel_density.density(mesh, 256, 256)
        assert d.total_texels == pytest.approx(texels[obj.name], rel=0.01, abs=1.0)
    target = texel_density.target_density(list(densities.values()))
    assert f"target {target:.3g} texels/m" in scene.hhd.view_summary
    for obj in (floor, cube):
        written = np.zeros(len(obj.data.polygons) * 3, np.float32)
        obj.data.attributes[view_data.COLOUR].data.foreach_get("vector", written)
        expected = texel_density.heat(densities[obj.name].density / target)
        np.testing.assert_allclose(written.reshape(-1, 3), expected, atol=1e-6)
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert scene_hash() == before
    assert objects_state() == state


@pytest.mark.bpy
def test_problems_view_marks_exactly_the_overlapped_texels(unwrapped_scene, tmp_path):
    import bpy

    from hhd_lightmapper.bridge import view_data
    from hhd_lightmapper.core.files import exr
    from scenekit import blender as kit

    scene, floor, cube, other = unwrapped_scene
    layer = scene.hhd.uv_layer
    views = {o.name: view_data.read_view_mesh(o, layer) for o in (floor, cube)}
    # move the cube's charts so that its first triangle lands on the middle of the floor's chart
    uv = np.zeros(len(cube.data.loops) * 2, np.float32)
    cube.data.uv_layers[layer].data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2) + (views["Floor"].uv.reshape(-1, 2).mean(0) - views["Cube"].uv[0].mean(0)).astype(np.float32)
    cube.data.uv_layers[layer].data.foreach_set("uv", uv.ravel())
    moved = view_data.read_view_mesh(cube, layer)
    expected = texel_set(moved.uv, 256, 256) & texel_set(views["Floor"].uv, 256, 256)
    assert len(expected) > 100
    kit.select([floor, cube])
    assert bpy.ops.hhd.view_show(mode='PROBLEMS') == {'FINISHED'}
    assert f"'Cube': {len(expected)} shared texels" in scene.hhd.view_summary
    assert f"{len(expected)} texels shared by two charts" in scene.hhd.view_summary
    (image,) = [i for i in bpy.data.images if "hhd_view" in i]
    channels, _ = exr.read(bpy.path.abspath(image.filepath))
    mask = exr.from_exr_rows(channels["R"]) > 0.5  # rows bottom-up: row j = texel row j
    assert set(np.flatnonzero(mask.ravel()).tolist()) == expected
    nodes = floor.material_slots[0].material.node_tree.nodes
    assert {n.interpolation for n in nodes if n.type == 'TEX_IMAGE'} == {'Closest'}
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    assert not [i for i in bpy.data.images if "hhd_view" in i]


@pytest.mark.eevee
def test_checker_cells_are_one_texel_in_an_orthographic_render(extension, restore_hhd_settings, tmp_path):
    """A 2 m plane facing the camera, its lightmap UVs 16 texels of a 64² atlas across (offset by
    0.3 texel, so cell edges fall between pixels), one texel = 0.125 m; ortho scale 2.5 m over
    160 pixels: 8 pixels per texel."""
    import bpy

    from hhd_lightmapper import blender_compat
    from hhd_lightmapper.core.files import exr
    from scenekit import blender as kit

    scene = kit.clear_scene()
    plane = kit.plane("Plane", (0, 0, 0), 2.0, kit.material("Grey", (0.6, 0.6, 0.6)))
    mesh = plane.data
    co = np.zeros(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    loops = np.zeros(len(mesh.loops), np.int64)
    mesh.loops.foreach_get("vertex_index", loops)
    xy = co.reshape(-1, 3)[loops, :2]
    atlas, offset, span = 64, np.array([20.3, 30.3]), 16.0  # texels
    uv = (offset + (xy + 1.0) / 2.0 * span) / atlas
    mesh.uv_layers.new(name=scene.hhd.uv_layer).data.foreach_set("uv", uv.astype(np.float32).ravel())
    plane.hhd.atlas, plane.hhd.atlas_width, plane.hhd.atlas_height = "Lightmap", atlas, atlas
    kit.select([plane])
    assert bpy.ops.hhd.view_show(mode='CHECKER') == {'FINISHED'}

    pixels, ortho = 160, 2.5
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.data.type, cam.data.ortho_scale = 'ORTHO', ortho
    cam.location = (0.0, 0.0, 5.0)
    scene.camera = cam
    scene.render.engine = blender_compat.eevee_engine()
    scene.render.resolution_x = scene.render.resolution_y = pixels
    scene.render.resolution_percentage = 100
    scene.render.filter_size = 0.0
    scene.eevee.taa_render_samples = 1
    scene.view_settings.view_transform = 'Standard'
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth = 'OPEN_EXR', '32'
    scene.render.filepath = str(tmp_path / "checker.exr")
    bpy.ops.render.render(write_still=True)
    channels, _ = exr.read(tmp_path / "checker.exr")
    light = exr.from_exr_rows(channels["G"]) > 0.5  # rows bottom-up: row r is world y increasing
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}

    per_texel = pixels / ortho * (2.0 / span)
    assert per_texel == 8.0
    # where the texel edges project: world x = (k − offset)/span · 2 − 1 for texel edges k
    to_pixel = lambda world: (world + ortho / 2) / ortho * pixels
    inside = slice(int(to_pixel(-1.0)) + 2, int(to_pixel(1.0)) - 2)
    for axis in (0, 1):
        lines = light[pixels // 2 + 3, inside] if axis == 0 else light[inside, pixels // 2 + 3]
        edges = np.flatnonzero(lines[1:] != lines[:-1]) + 1 + inside.start  # first pixel after a change
        k = np.arange(np.ceil(offset[axis]), offset[axis] + span)
        expected = to_pixel((k - offset[axis]) / span * 2.0 - 1.0)
        expected = expected[(expected > inside.start + 1) & (expected < inside.stop - 1)]
        assert len(edges) == len(expected) >= 14, (edges, expected)
        assert np.abs(edges - expected).max() <= 1.0, (edges, expected)
        widths = np.diff(edges)
        assert widths.min() >= per_texel - 1 and widths.max() <= per_texel + 1, widths
        assert widths.mean() == pytest.approx(per_texel, abs=0.1)
    # the parity: texel (i, j) with i + j even is light (the pixel at the plane's centre)
    centre = offset + span / 2 + np.array([0.5 / per_texel, 0.5 / per_texel])
    assert light[pixels // 2, pixels // 2] == (int(np.floor(centre[0]) + np.floor(centre[1])) % 2 == 0)


@pytest.mark.bpy
def test_instances_are_viewed_through_their_own_rectangles(extension, restore_hhd_settings):
    """Three linked duplicates of one cube (one scaled 2×), unwrapped as instances: `uv-report`'s
    figures (`texel_views.report`, the views' computation) give each instance the unwrap's texels
    over its own world area (the scaled one half the density) and no shared texel, though all
    three share one UV layer; moving one instance's rectangle onto another's (a real overlap)
    flags their common texels. The checker (and the Problems mask) read the layer's UVs through
    each object's rectangle, and the density view names the mesh whose instances differ in density."""
    import bpy

    from hhd_lightmapper.shaders import texel_views
    from scenekit import blender as kit

    scene = kit.clear_scene()
    cube = kit.box("Cube", (0.0, 0.0, 0.5), (1, 1, 1), kit.material("Red", (0.8, 0.2, 0.1)))
    objs = [cube]
    for k in (1, 2):
        obj = bpy.data.objects.new(f"Cube_{k}", cube.data)
        scene.collection.objects.link(obj)
        obj.location, obj.scale = (3.0 * k, 0.0, 0.5), cube.scale * (1 + (k == 2))
        objs.append(obj)
    meshes = len(bpy.data.meshes)
    kit.unwrap(objs)
    assert len(bpy.data.meshes) == meshes
    texels = unwrap_texels(scene.hhd.unwrap_summary)
    rects = [tuple(o.hhd.lightmap_rect) for o in objs]
    assert len(set(rects)) == 3 and len({r[:2] for r in rects}) == 1
    doc, _ = texel_views.report(objs, scene.hhd)
    (atlas,) = doc["atlases"]
    assert atlas["shared_texels"] == 0
    entries = {e["name"]: e for e in atlas["objects"]}
    for obj in objs:
        area = sum(p.area for p in obj.data.polygons) * obj.scale[0] ** 2  # m², uniform scale
        e = entries[obj.name]
        assert e["texels"] == pytest.approx(texels[obj.name], rel=0.01, abs=1.0)
        assert e["area_m2"] == pytest.approx(area, rel=1e-4)
        assert e["texels_per_metre"] == pytest.approx(np.sqrt(texels[obj.name] / area), rel=0.01)
        assert e["shared_texels"] == 0
    assert entries["Cube_2"]["texels_per_metre"] == pytest.approx(0.5 * entries["Cube"]["texels_per_metre"], rel=0.01)
    lines, _ = texel_views.show(objs, 'DENSITY', scene.hhd)
    assert any("share the mesh" in line and "'Cube_2'" in line for line in lines), lines
    assert tuple(objs[1]["hhd_view_size"]) == (atlas["width"], atlas["height"], 0.0)
    # the checker reads the layer's UV through the object's rectangle (an Instancer attribute: the object's own
    # for a linked duplicate, the Empty's for a collection instance)
    nodes = cube.material_slots[0].material.node_tree.nodes
    (checker,) = [n for n in nodes if n.type == 'GROUP']
    mapped = checker.inputs["UV"].links[0].from_node
    assert mapped.type == 'VECT_MATH' and mapped.operation == 'MULTIPLY_ADD'
    rect = mapped.inputs[1].links[0].from_node.inputs[0].links[0].from_node.inputs[0].links[0].from_node
    assert (rect.attribute_type, rect.attribute_name) == ('INSTANCER', "hhd.lightmap_rect")
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}

    objs[1].hhd.lightmap_rect = rects[0]  # a real overlap: Cube_1's texels on Cube's
    doc, _ = texel_views.report(objs, scene.hhd)
    (atlas,) = doc["atlases"]
    entries = {e["name"]: e for e in atlas["objects"]}
    assert entries["Cube"]["shared_texels"] == entries["Cube_1"]["shared_texels"] > 0.5 * texels["Cube"]
    assert entries["Cube_2"]["shared_texels"] == 0
