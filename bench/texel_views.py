"""Pictures of the views before a bake (issue 57, part 3): texel density, texel checker, problems.

    python bench/texel_views.py [--resolution 512] [--out DIR]

The demo room (scenekit/scenes.py `demo_room`) plus three props made to show something: a rug (a
subdivided grid) one of whose UV vertices is dragged across its neighbours (flipped faces) and
whose corner face's UVs are put on a line (a degenerate face), a
book with its own low texel density (too few texels), and the panel's UVs moved onto the back
wall's chart after the unwrap (texels shared by two charts). Unwrapped with the extension at one shared
atlas; each view shown with `bpy.ops.hhd.view_show` and rendered by EEVEE from the room's camera.
Writes bench/results/texel_views_density.png, texel_views_checker.png, texel_views_problems.png
(each with the view's legend and report lines) and texel_views.md (the report lines).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
VIEWS = ('DENSITY', 'CHECKER', 'PROBLEMS')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=512, help="lightmap atlas size")
    ap.add_argument("--size", type=int, default=640, help="render width in pixels")
    ap.add_argument("--out", type=Path, default=Path(tempfile.mkdtemp(prefix="hhd-bench-views-")))
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy

    import hhd_lightmapper
    from hhd_lightmapper import blender_compat
    from hhd_lightmapper.core.files import exr
    from scenekit import blender, scenes

    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    scenes.demo_room()
    blender.externalise_images(out)
    hhd_lightmapper.register()
    scene = bpy.context.scene
    rug = add_rug(bpy, blender)
    book = blender.box_between("Book", (-1.2, 0.8, 0.0), (-0.9, 1.0, 0.05), blender.material("Book", (0.2, 0.3, 0.7)))
    book.hhd.texel_density = 10.0  # its own atlas at 10 texels/m: a handful of texels
    meshes = [o for o in scene.objects if o.type == 'MESH']
    scene.hhd.resolution = args.resolution
    blender.select(meshes)
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}
    unwrap_summary = scene.hhd.unwrap_summary
    fold(rug, scene.hhd.uv_layer)
    collapse(rug, scene.hhd.uv_layer)
    overlap(scene.objects["Normal-mapped Panel"], scene.objects["Wall -X"], scene.hhd.uv_layer)

    scene.render.engine = blender_compat.eevee_engine()
    scene.eevee.taa_render_samples = 8
    scene.render.resolution_x, scene.render.resolution_y = args.size, args.size * 2 // 3
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = 'Standard'
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth = 'OPEN_EXR', '32'
    report = [f"Unwrap: {unwrap_summary}", ""]
    RESULTS.mkdir(parents=True, exist_ok=True)
    for mode in VIEWS:
        blender.select(meshes)
        assert bpy.ops.hhd.view_show(mode=mode) == {'FINISHED'}
        lines = scene.hhd.view_summary.splitlines()
        scene.render.filepath = str(out / f"{mode.lower()}.exr")
        bpy.ops.render.render(write_still=True)
        channels, _ = exr.read(out / f"{mode.lower()}.exr")
        image = np.stack([exr.from_exr_rows(channels[c]) for c in "RGB"], -1)[::-1]  # top row first
        png = RESULTS / f"texel_views_{mode.lower()}.png"
        picture(image, mode, lines, png)
        report += [f"## {mode.title()}", "", *[f"- {line}" for line in lines], ""]
        print(f"{mode}: {png}")
    assert bpy.ops.hhd.preview_hide() == {'FINISHED'}
    (RESULTS / "texel_views.md").write_text(
        "# The views before a bake (bench/texel_views.py)\n\n" + "\n".join(report) + "\n", encoding="utf-8"
    )
    return 0


def add_rug(bpy, blender):
    """A 1.2 m × 0.8 m grid of 6 × 4 quads just above the floor."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=6, y_subdivisions=4, size=1.0, location=(0.6, -0.6, 0.01))
    rug = bpy.context.active_object
    rug.name = "Rug"
    rug.scale = (1.2, 0.8, 1.0)
    rug.data.materials.append(blender.material("Rug", (0.6, 0.5, 0.3)))
    return rug


def loop_uvs(obj, layer):
    uv = np.zeros(len(obj.data.loops) * 2, np.float32)
    obj.data.uv_layers[layer].data.foreach_get("uv", uv)
    return uv.reshape(-1, 2)


def fold(obj, layer):
    """Drag the UV of the rug's most central vertex across a neighbouring vertex: the faces
    around it fold over (flipped)."""
    uv = loop_uvs(obj, layer)
    vertex = np.zeros(len(obj.data.loops), np.int64)
    obj.data.loops.foreach_get("vertex_index", vertex)
    co = np.zeros(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", co)
    centre = int(np.argmin(np.linalg.norm(co.reshape(-1, 3)[:, :2], axis=1)))
    mine = vertex == centre
    step = np.abs(uv[~mine] - uv[mine][0]).max(axis=1)
    nearest = uv[~mine][np.argmin(np.where(step > 0, np.linalg.norm(uv[~mine] - uv[mine][0], axis=1), np.inf))]
    uv[mine] = uv[mine][0] + 1.6 * (nearest - uv[mine][0])
    obj.data.uv_layers[layer].data.foreach_set("uv", uv.ravel())


def collapse(obj, layer):
    """Put the UVs of the vertices of the rug's corner face (largest x + y) on one line: that
    face has no UV area (degenerate), its neighbours are squashed."""
    uv = loop_uvs(obj, layer)
    vertex = np.zeros(len(obj.data.loops), np.int64)
    obj.data.loops.foreach_get("vertex_index", vertex)
    polygon = max(obj.data.polygons, key=lambda p: p.center.x + p.center.y)
    corners = np.isin(vertex, list(polygon.vertices))
    uv[corners, 1] = uv[list(polygon.loop_indices), 1].mean()
    obj.data.uv_layers[layer].data.foreach_set("uv", uv.ravel())


def overlap(mover, target, layer):
    """Move `mover`'s UVs so their middle sits on the middle of `target`'s largest UV triangle."""
    uv, other = loop_uvs(mover, layer), loop_uvs(target, layer)
    mesh = target.data
    mesh.calc_loop_triangles()
    loops = np.zeros(len(mesh.loop_triangles) * 3, np.int64)
    mesh.loop_triangles.foreach_get("loops", loops)
    tri = other[loops].reshape(-1, 3, 2)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    largest = tri[np.argmax(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]))]
    uv += (largest.mean(0) - 0.5 * (uv.min(0) + uv.max(0))).astype(np.float32)
    mover.data.uv_layers[layer].data.foreach_set("uv", uv.ravel())


def picture(image, mode, lines, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    srgb = np.where(image <= 0.0031308, 12.92 * image, 1.055 * np.power(np.clip(image, 0, None), 1 / 2.4) - 0.055)
    caption = "\n".join(textwrap.fill(line, 120) for line in lines)
    width = 8.0
    image_h = width * image.shape[0] / image.shape[1]
    text_h = 0.12 * (caption.count("\n") + 1) + 0.15
    fig = plt.figure(figsize=(width, image_h + text_h + 0.3))
    total = image_h + text_h + 0.3
    ax = fig.add_axes((0, (text_h) / total, 1, image_h / total))
    ax.imshow(np.clip(srgb, 0, 1))
    ax.set_axis_off()
    fig.text(
        0.5,
        1 - 0.2 / total,
        {"DENSITY": "Texel Density", "CHECKER": "Texel Checker", "PROBLEMS": "Problems"}[mode],
        ha="center",
        va="top",
        fontsize=11,
    )
    fig.text(0.01, 0.05 / total, caption, fontsize=6, family="monospace", va="bottom")
    fig.savefig(png, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
