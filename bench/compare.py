"""Every encoding against Cycles on the demo room, the bedroom and staircase2 (issue 59): the
product's own comparison (`bridge.compare`, `bpy.ops.hhd.compare`) run as an artist would.

    python bench/compare.py [--scenes demo bedroom staircase2] [--resolution 512] [--samples 64]
                            [--cycles-samples 256] [--percentage 25]

Per scene: unwrap and bake the receivers (the demo room: every mesh; the external scenes: the
receivers bench/denoise.py picks), then compare every encoding from the scene camera (the
external scenes have none: one in a corner of the room, `corner_camera`) at three roughness
values. Writes bench/results/compare.md (the tables), compare_<scene>.json and
compare_<scene>_contact_sheet.png.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"


def load(name: str) -> list:
    """Open or build the scene; its receivers."""
    import bpy

    from scenekit import scenes

    if name == "demo":
        scenes.demo_room()
        return [o for o in bpy.context.scene.objects if o.type == 'MESH']
    import denoise

    return denoise.load_scene(name)


def corner_camera(bpy, scene) -> None:
    """A camera for a scene without one (the external scenes): in a corner of the meshes' bounds
    (10% in from each side, at 55% of the height), 16 mm, looking at the opposite lower corner."""
    import numpy as np
    from mathutils import Vector

    corners = [o.matrix_world @ Vector(c) for o in scene.objects if o.type == 'MESH' for c in o.bound_box]
    p = np.array([tuple(c) for c in corners])
    lo, hi = p.min(axis=0), p.max(axis=0)
    size = hi - lo
    eye = Vector(lo + size * np.array([0.1, 0.1, 0.55]))
    target = Vector(lo + size * np.array([0.9, 0.9, 0.25]))
    cam = bpy.data.objects.new("Compare camera", bpy.data.cameras.new("Compare camera"))
    scene.collection.objects.link(cam)
    cam.data.lens = 16.0
    cam.location = eye
    cam.rotation_euler = (target - eye).to_track_quat('-Z', 'Y').to_euler()
    scene.camera = cam


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["demo", "bedroom", "staircase2"])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--samples", type=int, default=256, help="bake samples per texel")
    ap.add_argument("--no-denoise", action="store_true", help="bake without the denoiser (default: denoised)")
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--cycles-samples", type=int, default=256)
    ap.add_argument("--percentage", type=int, default=25, help="share of each scene's render size")
    ap.add_argument("--out", type=Path, default=Path(tempfile.mkdtemp(prefix="hhd-bench-compare-")))
    args = ap.parse_args()
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy

    import hhd_lightmapper
    from hhd_lightmapper.bridge import compare
    from scenekit import blender as kit

    hhd_lightmapper.register()
    summary = ["# Encodings against Cycles on three scenes (bench/compare.py)", ""]
    for name in args.scenes:
        receivers = load(name)
        scene = bpy.context.scene
        if scene.camera is None:
            corner_camera(bpy, scene)
        s = scene.hhd
        s.preset = 'CUSTOM'
        s.resolution, s.samples, s.bounces = args.resolution, args.samples, args.bounces
        s.denoise = not args.no_denoise
        s.output_dir = str(args.out / name / "lightmaps")
        t = time.perf_counter()
        kit.unwrap(receivers)
        kit.select(receivers)
        assert bpy.ops.hhd.bake() == {'FINISHED'}
        bake_s = time.perf_counter() - t
        report = args.out / name / "compare"
        t = time.perf_counter()
        line, warnings = compare.run(
            bpy.context, folder=str(report), samples=args.cycles_samples, percentage=args.percentage
        )
        compare_s = time.perf_counter() - t
        print(line, *warnings, sep="\n")
        summary += [
            f"## {name}",
            "",
            f"{len(receivers)} receivers, atlas {args.resolution}², {args.samples} samples, {args.bounces} bounces, "
            f"{'no denoise' if args.no_denoise else 'denoised'}; bake {bake_s:.0f} s, comparison {compare_s:.0f} s (Cycles {args.cycles_samples} samples, "
            f"{args.percentage}% of the render size). Contact sheet: compare_{name}_contact_sheet.png.",
            "",
            *(report / "compare.md").read_text().splitlines()[4:],
            "",
        ]
        shutil.copyfile(report / "contact_sheet.png", RESULTS / f"compare_{name}_contact_sheet.png")
        doc = json.loads((report / "compare.json").read_text())
        doc["settings"] = {k: str(v) for k, v in vars(args).items()}
        (RESULTS / f"compare_{name}.json").write_text(json.dumps(doc, indent=1) + "\n")
    (RESULTS / "compare.md").write_text("\n".join(summary) + "\n")
    print((RESULTS / "compare.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
