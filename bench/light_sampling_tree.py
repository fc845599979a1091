"""What building the emitters' light tree costs a bake, compiled against its numpy specification.

    .venv/bin/python bench/light_sampling_tree.py [--emitters 16 700 7000 30000] [--triangles 450000]

A bake builds one `lights.emitters.EmissiveTriangles` per light group and atlas it traces: the
light tree over the emitting triangles (`light_kernels.light_tree`), each node's box and power
(`node_sums`) and its share of its siblings' power (`sibling_shares`). Per count of emitting
triangles: a scene of `--triangles` triangles of which that many emit, laid out as lamps (small
quads of two triangles on a ceiling grid, as a level's bulbs and panels are); the construction
timed with the compiled kernels and with their numpy specifications (the code before them, the
peer, in the same run, the two interleaved; the median of `--repeats`), and whether both give the same arrays.

With `--bedroom` (bpy), also in a bake: the shared bedroom with its lamp bulbs emitting (the
`LampEmitter` material given an emission: 7,012 emitting triangles, as a level lit by emissive
meshes) and its receivers unwrapped at `--resolution`², traced on one thread (`--samples` spp,
8 bounces, the bake points built before) with each build, interleaved: the whole trace's seconds.

Writes bench/results/light_sampling_tree.md.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from hhd_lightmapper.core.tracer import light_kernels
from hhd_lightmapper.core.tracer.lights import emitters, tree

OUT = Path(__file__).resolve().parent / "results" / "light_sampling_tree.md"
ARRAYS = ("cluster_of", "within", "child_first", "child_count", "parent", "cluster_power", "centre", "radius2")


def lamp_scene(emitting: int, triangles: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(triangles (T, 3, 3), emission (T, 3)): `emitting` triangles as 20 cm lamps (quads) on a
    grid under a 3 m ceiling, spread among `triangles` random non-emitting ones."""
    rng = np.random.default_rng(seed)
    lamps = emitting // 2
    side = int(np.ceil(np.sqrt(lamps)))
    xy = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:lamps] * 0.8
    corners = np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.2], [0.0, 0.2]])
    quad = xy[:, None, :] + corners[None]
    v = np.concatenate([quad, np.full(quad.shape[:2] + (1,), 3.0)], axis=2)  # (L, 4, 3)
    lamp_tris = np.concatenate([v[:, [0, 2, 1]], v[:, [0, 3, 2]]])  # facing down
    tris = rng.random((triangles, 3, 3)) * [side * 0.8, side * 0.8, 3.0]
    at = rng.choice(triangles, len(lamp_tris), replace=False)
    tris[at] = lamp_tris
    emission = np.zeros((triangles, 3))
    emission[at] = rng.uniform(1.0, 20.0, (len(at), 1))
    return tris, emission


def build(tris: np.ndarray, emission: np.ndarray) -> emitters.EmissiveTriangles:
    light = emitters.EmissiveTriangles(tris, emission)
    light._emitters()  # the kernels' arrays, shares included: made once per bake
    return light


def timed(tris, emission) -> tuple[float, emitters.EmissiveTriangles]:
    t = time.perf_counter()
    light = build(tris, emission)
    return time.perf_counter() - t, light


def with_numpy_specs():
    """The compiled kernels' namespace with the three swapped for their numpy specifications
    (the code before them); returns the function that puts them back."""
    kernels = light_kernels.get()
    saved = kernels.light_tree, kernels.node_sums, kernels.sibling_shares
    kernels.light_tree, kernels.node_sums, kernels.sibling_shares = (
        tree.light_tree,
        tree.node_sums,
        emitters.sibling_shares,
    )

    def restore():
        kernels.light_tree, kernels.node_sums, kernels.sibling_shares = saved

    return restore


def bedroom_traces(resolution: int, samples: int, repeats: int) -> dict:
    """One-thread traces of the bedroom lit by its lamp bulbs, with the compiled build and with
    the numpy specifications (interleaved): their medians, the emitting triangles and the texels."""
    import tempfile

    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="hhd-bench-blender-"))
    import bpy  # noqa: F401

    import hhd_lightmapper
    import trace_profile  # bench/, the script's folder
    from hhd_lightmapper.core import bake, rays, tracer

    hhd_lightmapper.register()
    surface, scene = trace_profile.read_scene("bedroom", resolution, edit=_lamps_emit)
    ray_scene = rays.RayScene(scene.triangles)
    settings = tracer.BakeSettings.from_samples(samples, bounces=8, threads=1)
    objects = [str(k) for k in range(int(surface.object_index.max(initial=-1)) + 1)]
    points = bake.points_of(bake.AtlasInput("atlas", resolution, resolution, surface, objects), ray_scene)
    tracer.bake(points, scene, settings, ray_scene=ray_scene)  # untimed: warm
    runs = []
    for _ in range(repeats):
        compiled_s = tracer.bake(points, scene, settings, ray_scene=ray_scene).seconds
        restore = with_numpy_specs()
        try:
            runs.append((compiled_s, tracer.bake(points, scene, settings, ray_scene=ray_scene).seconds))
        finally:
            restore()
    return {
        "emitting": int((scene.emission.max(axis=1) > 0.0).sum()),
        "texels": int(len(points.texel)),
        "compiled": statistics.median(c for c, _ in runs),
        "numpy": statistics.median(n for _, n in runs),
    }


def _lamps_emit() -> None:
    """The bedroom's lamp bulbs (`LampEmitter`) emit a warm white at strength 10."""
    import bpy

    node = next(n for n in bpy.data.materials["LampEmitter"].node_tree.nodes if n.type == 'BSDF_PRINCIPLED')
    node.inputs["Emission Color"].default_value = (1.0, 0.9, 0.8, 1.0)
    node.inputs["Emission Strength"].default_value = 10.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--emitters", type=int, nargs="+", default=[16, 700, 7000, 30000])
    ap.add_argument("--triangles", type=int, default=450_000, help="the scene's triangles (the bedroom has 449,389)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--bedroom", action="store_true", help="also time traces of the bedroom lit by its lamp bulbs")
    ap.add_argument("--resolution", type=int, default=256, help="--bedroom's atlas")
    ap.add_argument("--samples", type=int, default=16, help="--bedroom's samples per texel")
    args = ap.parse_args()
    build(*lamp_scene(16, args.triangles))  # compiled (or loaded from numba's cache), memory touched, before any timing
    rows = []
    for n in args.emitters:
        tris, emission = lamp_scene(n, max(args.triangles, n))
        runs = []  # interleaved: both see the same machine
        for _ in range(args.repeats):
            compiled_run = timed(tris, emission)
            restore = with_numpy_specs()
            try:
                runs.append((compiled_run, timed(tris, emission)))
            finally:
                restore()
        compiled_s = statistics.median(c[0] for c, _ in runs)
        numpy_s = statistics.median(n[0] for _, n in runs)
        fast, spec = runs[-1][0][1], runs[-1][1][1]
        same = all(np.array_equal(getattr(fast, a), getattr(spec, a)) for a in ARRAYS)
        same &= all(np.array_equal(x, y) for x, y in zip(fast._emitters(), spec._emitters()))
        rows.append((n, len(fast.parent), numpy_s, compiled_s, same))
        print(f"{n} emitters: numpy {numpy_s:.3f} s, compiled {compiled_s:.3f} s, same {same}", flush=True)
    lines = [
        "# Building the emitters' light tree: compiled against its numpy specification",
        "",
        f"`bench/light_sampling_tree.py`: one `EmissiveTriangles` (light tree, node sums, sibling shares) per row, "
        f"in a scene of {args.triangles:,} triangles of which the given number emit (20 cm lamps of two "
        f"triangles on a ceiling grid); median of {args.repeats} builds; the same run, load "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}. "
        "A bake builds one per light group and atlas it traces. *Same*: every array of the two equal to the bit.",
        "",
        "| emitting triangles | tree nodes | numpy s | compiled s | numpy / compiled | same |",
        "|---|---|---|---|---|---|",
    ]
    for n, nodes, numpy_s, compiled_s, same in rows:
        ratio = numpy_s / compiled_s
        lines.append(
            f"| {n:,} | {nodes:,} | {numpy_s:.3f} | {compiled_s:.3f} | {ratio:.1f}× | {'yes' if same else 'NO'} |"
        )
    lines += [
        "",
        "The compiled build still reads and writes per-triangle arrays of the whole scene (primitive ids index "
        "them): that part is the same in both columns and is most of the compiled one's time.",
    ]
    if args.bedroom:
        b = bedroom_traces(args.resolution, args.samples, args.repeats)
        print(f"bedroom: numpy {b['numpy']:.2f} s, compiled {b['compiled']:.2f} s", flush=True)
        lines += [
            "",
            f"In a bake: the bedroom lit by its lamp bulbs ({b['emitting']:,} emitting triangles), {b['texels']:,} "
            f"texels at {args.resolution}², {args.samples} spp, 8 bounces, one thread, the whole trace (the light "
            f"tree built in it), median of {args.repeats}, interleaved:",
            "",
            "| build | trace s |",
            "|---|---|",
            f"| numpy specifications | {b['numpy']:.2f} |",
            f"| compiled | {b['compiled']:.2f} |",
            f"| numpy / compiled | {b['numpy'] / b['compiled']:.2f}× |",
        ]
    OUT.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
