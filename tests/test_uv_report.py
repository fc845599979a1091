"""`uv-report` (issue 57, part 3 headless): the views' figures from the command line, the .blend
unchanged.

A floor and a cube unwrapped into one atlas, the cube's charts then moved onto the floor's (a
deliberately overlapped layer), and a plane never unwrapped. The command's JSON equals what the
views compute (`bridge.view_data` reading, `core.unwrap.texel_density` and `core.unwrap.uv_problems`) and what
the Problems and Texel Density views report; exit 0 with problems, 1 naming a receiver without
the UV layer (the others still reported), 1 when none has it; the .blend's bytes unchanged.
"""

import hashlib
import json
import re

import numpy as np
import pytest

from hhd_lightmapper.core import raster
from hhd_lightmapper.core.unwrap import texel_density, uv_problems

pytestmark = pytest.mark.bpy


def texel_set(uv, w, h):
    return set(np.unique(raster.rasterise(uv, w, h).texel).tolist())


@pytest.fixture
def overlapped_blend(extension, restore_hhd_settings, tmp_path):
    """The scene saved as tmp_path/scene.blend; returns (path, texels the floor and cube share)."""
    import bpy

    from hhd_lightmapper.bridge import view_data
    from scenekit import blender as kit

    scene = kit.clear_scene()
    grey = kit.material("Grey", (0.6, 0.6, 0.6))
    floor = kit.plane("Floor", (0, 0, 0), 4, grey)
    cube = kit.box("Cube", (0.6, 0.5, 0.5), (1, 1, 1), kit.material("Red", (0.8, 0.2, 0.1)))
    kit.plane("Other", (6, 0, 0), 1, grey)  # never unwrapped
    kit.unwrap([floor, cube])
    layer = scene.hhd.uv_layer
    floor_uv = view_data.read_view_mesh(floor, layer).uv
    cube_view = view_data.read_view_mesh(cube, layer)
    uv = np.zeros(len(cube.data.loops) * 2, np.float32)
    cube.data.uv_layers[layer].data.foreach_get("uv", uv)
    shift = (floor_uv.reshape(-1, 2).mean(0) - cube_view.uv[0].mean(0)).astype(np.float32)
    cube.data.uv_layers[layer].data.foreach_set("uv", (uv.reshape(-1, 2) + shift).ravel())
    moved = view_data.read_view_mesh(cube, layer)
    shared = texel_set(moved.uv, 256, 256) & texel_set(floor_uv, 256, 256)
    assert len(shared) > 100
    kit.select([floor, cube])
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path, shared


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def data_state():
    """What the report must not change in memory: every mesh's UV layers and attributes, every
    object's custom properties, every material's nodes, the images."""
    import bpy

    meshes = {}
    for mesh in bpy.data.meshes:
        layers = []
        for layer in mesh.uv_layers:
            uv = np.zeros(len(mesh.loops) * 2, np.float32)
            layer.data.foreach_get("uv", uv)
            layers.append((layer.name, hashlib.sha256(uv.tobytes()).hexdigest()))
        meshes[mesh.name] = (layers, sorted(a.name for a in mesh.attributes))
    return (
        meshes,
        {o.name: sorted(o.keys()) for o in bpy.data.objects},
        {m.name: sorted(n.name for n in m.node_tree.nodes) for m in bpy.data.materials if m.node_tree},
        sorted(i.name for i in bpy.data.images),
    )


def test_uv_report_json_equals_the_views_figures(overlapped_blend, cli_run, tmp_path):
    import bpy

    from hhd_lightmapper.bridge import view_data

    blend, shared = overlapped_blend
    before = digest(blend)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    state = data_state()
    out = tmp_path / "report.json"
    result = cli_run(blend, "uv-report", "--objects", "Floor", "Cube", "--json", out)
    assert result.returncode == 0, result.stderr
    assert digest(blend) == before
    assert data_state() == state  # nothing changed in memory either
    doc = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    (atlas,) = doc["atlases"]
    assert (atlas["name"], atlas["width"], atlas["height"]) == ("Lightmap", 256, 256)
    assert atlas["shared_texels"] == len(shared)
    by_name = {o["name"]: o for o in atlas["objects"]}
    assert sorted(by_name) == ["Cube", "Floor"] and doc["missing_uv_layer"] == []
    # core on the same reading: densities, target, problems
    layer = bpy.context.scene.hhd.uv_layer
    views = [view_data.read_view_mesh(bpy.data.objects[n], layer) for n in ("Floor", "Cube")]
    densities = [texel_density.density(v, 256, 256) for v in views]
    target = texel_density.target_density(densities)
    assert atlas["target_texels_per_metre"] == pytest.approx(target, rel=1e-12)
    found = uv_problems.find(views, 256, 256, target)
    assert set(found.shared.tolist()) == shared
    for view, d, p in zip(views, densities, found.objects):
        entry = by_name[view.name]
        assert entry["texels_per_metre"] == pytest.approx(d.mean_density, rel=1e-12)
        assert entry["ratio"] == pytest.approx(d.mean_density / target, rel=1e-12)
        assert entry["texels"] == pytest.approx(d.total_texels, rel=1e-12)
        assert (entry["shared_texels"], entry["flipped_faces"], entry["degenerate_faces"]) == (
            p.shared,
            p.flipped_faces,
            p.degenerate_faces,
        )
        assert entry["too_few_texels"] == p.few and entry["problems"] == p.count
    assert by_name["Cube"]["shared_texels"] == len(shared)
    assert doc["totals"]["shared_texels"] == len(shared)
    # the printed report and summary
    assert f"atlas 'Lightmap' 256×256: target {target:.3g} texels/m" in result.stdout
    assert f"'Cube': {len(shared)} shared texels, 0 flipped, 0 degenerate faces" in result.stdout
    assert re.search(rf"uv-report: 2 object\(s\) in 1 atlas\(es\): {len(shared)} problem\(s\)", result.stdout)
    # the views report the same figures
    assert bpy.ops.hhd.view_show(mode='PROBLEMS') == {'FINISHED'}
    summary = bpy.context.scene.hhd.view_summary
    assert f"'Cube': {by_name['Cube']['shared_texels']} shared texels" in summary
    assert f"'Floor': {by_name['Floor']['shared_texels']} shared texels" in summary
    assert f"{atlas['shared_texels']} texels shared by two charts" in summary
    assert bpy.ops.hhd.view_show(mode='DENSITY') == {'FINISHED'}
    summary = bpy.context.scene.hhd.view_summary
    for name, entry in by_name.items():
        assert f"'{name}' {entry['texels_per_metre']:.3g} ({entry['ratio']:.2f}×)" in summary
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}


def test_uv_report_exit_codes_without_the_uv_layer(overlapped_blend, cli_run, tmp_path):
    blend, shared = overlapped_blend
    before = digest(blend)
    out = tmp_path / "partial.json"
    partial = cli_run(blend, "uv-report", "--objects", "Floor", "Cube", "Other", "--json", out)
    assert partial.returncode == 1
    assert "'Other' has no lightmap UV layer" in partial.stderr and "unwrap it first" in partial.stderr
    assert f"'Cube': {len(shared)} shared texels" in partial.stdout  # the others are still reported
    assert json.loads(out.read_text())["missing_uv_layer"] == ["Other"]
    alone = cli_run(blend, "uv-report", "--objects", "Other")
    assert alone.returncode == 1 and "no receiver has the lightmap UV layer" in alone.stderr
    assert "'Other'" in alone.stderr
    assert cli_run(blend, "uv-report", "--collection", "Nowhere").returncode == 1
    selected = cli_run(blend, "uv-report")  # the saved selection: Floor and Cube
    assert selected.returncode == 0, selected.stderr
    unwritable = cli_run(blend, "uv-report", "--json", blend / "report.json")  # a file stands there
    assert unwritable.returncode == 4 and "cannot write" in unwritable.stderr
    assert digest(blend) == before
