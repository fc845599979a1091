"""Capture every file of a set of small bakes, to prove a refactor or a speed-up changed nothing.

    .venv/bin/python tools/capture_bake.py capture OUT.json [--keep DIR] [--only CASE ...]
    .venv/bin/python tools/capture_bake.py compare BEFORE.json AFTER.json

`capture` builds the capture scenes with bpy, saves each as a .blend and bakes it with the
command line (`python -m hhd_lightmapper.cli FILE.blend bake ...`, a process per bake, as a build
machine runs it), then records the SHA-256 of every file the bake wrote: the EXRs byte for byte,
the JSON sidecars after removing what differs between two runs of one bake (timings, seconds,
dates, absolute paths). `compare` lists every file whose digest differs (exit 1) or says that
all are identical (exit 0).

The cases cover each light type, the HDRI world, emissive meshes, a textured albedo, a box resting
on the floor (covered and buried texels), the denoiser, seam stitching (a smooth sphere, whose
seams move texels, with and without the denoiser), a noise target, one thread, two atlases with
light sets and an irradiance volume, and a bake on a Dask cluster (`dask scheduler` and two
`dask worker` processes on 127.0.0.1; skipped when `distributed` is not installed). They are
small (256 texels square, a few samples) so a capture takes a few minutes.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: sidecar keys whose values differ between two runs of one bake
RUN_DETAILS = {"timings_seconds", "seconds", "time", "baked", "date", "created", "blend_file", "output_dir", "host"}

#: case → (scene builder name, CLI options after `bake`)
BASE = ["--unwrap", "--seed", "3", "--bounces", "1", "--no-denoise"]
CASES: dict[str, tuple[str, list[str]]] = {
    "sun": ("sun", [*BASE, "--resolution", "256", "--samples", "8"]),
    "point": ("point", [*BASE, "--resolution", "256", "--samples", "8"]),
    "spot": ("spot", [*BASE, "--resolution", "256", "--samples", "8"]),
    "area": ("area", [*BASE, "--resolution", "256", "--samples", "8"]),
    "hdri": ("hdri", [*BASE, "--resolution", "256", "--samples", "8"]),
    "emissive": ("emissive", [*BASE, "--resolution", "256", "--samples", "8"]),
    "textured": ("textured", [*BASE, "--resolution", "256", "--samples", "8"]),
    "denoised-ahd": (
        "sun",
        [
            "--unwrap",
            "--seed",
            "3",
            "--resolution",
            "256",
            "--samples",
            "8",
            "--bounces",
            "2",
            "--denoise",
            "--model",
            "ahd",
        ],
    ),
    "noise-target": ("point", [*BASE, "--resolution", "256", "--samples", "64", "--noise-target", "5"]),
    "one-thread": ("point", [*BASE, "--resolution", "256", "--samples", "8", "--threads", "1"]),
    "light-sets": ("light_sets", ["--seed", "3", "--bounces", "1", "--samples", "8", "--stitch"]),
    "stitched": ("sphere", [*BASE, "--resolution", "256", "--samples", "8", "--stitch"]),
    "stitched-denoised-ahd": (
        "sphere",
        ["--unwrap", "--seed", "3", "--resolution", "256", "--samples", "8", "--bounces", "1"]
        + ["--denoise", "--stitch", "--model", "ahd"],
    ),
    "farm": ("sun", [*BASE, "--resolution", "256", "--samples", "8"]),
}


# ---- scenes (run inside this process's bpy) ---------------------------------------------------


def _room(kit):
    """A 4 m floor, a back wall and a box resting on the floor (covered texels); returns receivers."""
    kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4, kit.material("grey"))
    wall = kit.plane("Wall", (0, 2, 1), 4, kit.material("wall", (0.7, 0.6, 0.5)), rotation=(1.5708, 0, 0))
    cube = kit.box("Box", (0.5, 0.3, 0.4), (0.8, 0.8, 0.8), kit.material("white"))
    return [floor, wall, cube]


def build(name: str):
    """Build the named capture scene; returns its receiver objects."""
    import bpy

    from scenekit import blender as kit

    receivers = _room(kit)
    if name == "sun":
        kit.light('SUN', rotation=(0.6, 0.2, 0.4), energy=3.0, name="Sun", angle=0.1)
        kit.world((0.2, 0.3, 0.5))
    elif name == "point":
        kit.light('POINT', (-1.0, -0.5, 1.5), energy=150.0, name="Lamp", shadow_soft_size=0.2)
    elif name == "spot":
        kit.light('SPOT', (0.0, -1.0, 2.0), rotation=(0.4, 0, 0), energy=300.0, name="Spot", spot_size=0.9)
    elif name == "area":
        kit.light('AREA', (0.0, 0.0, 2.2), energy=200.0, name="Rect", shape='RECTANGLE', size=0.8, size_y=0.4)
        kit.light('AREA', (1.2, -1.0, 1.8), energy=80.0, name="Disk", shape='DISK', size=0.5)
    elif name == "hdri":
        kit.hdri_world(kit.sky_pixels())
    elif name == "emissive":
        kit.box("Glow", (-1.2, 1.0, 1.6), (0.6, 0.1, 0.3), kit.material("glow", emission=(1.0, 0.8, 0.6, 8.0)))
        kit.world((0.02, 0.02, 0.03))
    elif name == "textured":
        receivers[0].data.materials[0] = kit.textured_material("checks", (0.8, 0.2, 0.1), (0.1, 0.3, 0.8))
        kit.light('SUN', rotation=(0.5, 0.1, 0.3), energy=3.0, name="Sun")
        kit.world((0.2, 0.3, 0.5))
    elif name == "sphere":  # smooth seams: the stitch moves texels (the room's flat faces have none)
        from scenekit import meshes

        # from numpy, not Blender's primitive: two builds of the primitive differ in their last bits
        v, f = meshes.uv_sphere(rings=8, segments=16, radius=0.5)
        mesh = bpy.data.meshes.new("Sphere")
        mesh.from_pydata((v + (-0.8, -0.6, 0.5)).tolist(), [], f.tolist())
        mesh.polygons.foreach_set("use_smooth", [True] * len(mesh.polygons))
        mesh.materials.append(kit.material("red", (0.8, 0.2, 0.1)))
        sphere = bpy.data.objects.new("Sphere", mesh)
        bpy.context.scene.collection.objects.link(sphere)
        receivers.append(sphere)
        kit.light('POINT', (-1.0, -0.5, 1.5), energy=150.0, name="Lamp", shadow_soft_size=0.2)
        kit.world((0.2, 0.3, 0.5))
    elif name == "light_sets":
        red = kit.light('POINT', (-1.0, -1.0, 1.5), energy=150.0, name="RedLamp", color=(1.0, 0.2, 0.1))
        blue = kit.light('POINT', (1.2, 1.0, 1.2), energy=100.0, name="BlueLamp", color=(0.1, 0.3, 1.0))
        kit.world((0.05, 0.05, 0.08))
        red.lightgroup, blue.lightgroup = "Red", "Blue"
        bpy.ops.object.lightprobe_add(type='VOLUME', location=(0.0, 0.0, 0.75))
        volume = bpy.context.active_object
        volume.name = "Volume"
        volume.scale = (1.5, 1.5, 0.5)
        volume.data.resolution_x, volume.data.resolution_y, volume.data.resolution_z = 3, 3, 2
        scene = bpy.context.scene
        scene.hhd.atlas_mode = 'PER_OBJECT'  # three atlases
        scene.hhd.resolution = 128
        kit.unwrap(receivers)
    else:
        raise KeyError(name)
    kit.select(receivers)
    return receivers


def save_scenes(folder: Path, names: set[str]) -> dict[str, Path]:
    """Each named scene saved as folder/NAME.blend (the add-on registered for its settings)."""
    import bpy

    import hhd_lightmapper

    hhd_lightmapper.register()
    paths = {}
    for name in sorted(names):
        build(name)
        bpy.context.scene.hhd.pack_images = False
        paths[name] = folder / f"{name}.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(paths[name]))
    return paths


# ---- digests ---------------------------------------------------------------------------------


def _scrub(value):
    """A sidecar's JSON without the run's details (RUN_DETAILS keys, at any depth)."""
    if isinstance(value, dict):
        return {k: _scrub(v) for k, v in value.items() if k not in RUN_DETAILS}
    if isinstance(value, list):
        return [_scrub(v) for v in value]
    return value


def digests(folder: Path) -> dict[str, str]:
    """relative path → SHA-256 of every file under `folder` (JSON scrubbed of run details)."""
    out = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        data = path.read_bytes()
        if path.suffix == ".json":
            data = json.dumps(_scrub(json.loads(data)), sort_keys=True).encode()
        out[path.relative_to(folder).as_posix()] = hashlib.sha256(data).hexdigest()
    return out


# ---- the bakes -------------------------------------------------------------------------------


@contextlib.contextmanager
def dask_cluster(folder: Path):
    """A `dask scheduler` and two single-thread `dask worker`s on 127.0.0.1; yields the address."""
    info, common = folder / "scheduler.json", ["--no-dashboard", "--host", "127.0.0.1"]
    log = open(folder / "dask.log", "w")
    start = dict(stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    scheduler = [sys.executable, "-m", "dask", "scheduler", "--port", "0", "--scheduler-file", str(info), *common]
    procs = [subprocess.Popen(scheduler, **start)]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        worker = [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", *common]
        procs += [subprocess.Popen(worker, **start) for _ in range(2)]
        import distributed

        with distributed.Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            p.wait(timeout=30)
        log.close()


def bake(blend: Path, out: Path, options: list[str]) -> None:
    """One CLI bake of `blend` into `out`; raises with its stderr when it fails."""
    cmd = [sys.executable, "-m", "hhd_lightmapper.cli", str(blend), "bake", "--out", str(out), *options]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}\nexit {run.returncode}\n{run.stderr[-3000:]}")


def capture(manifest: Path, keep: Path | None, only: list[str] | None) -> None:
    names = only or list(CASES)
    with tempfile.TemporaryDirectory(prefix="hhd-capture-") as tmp:
        work = keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        blends = save_scenes(work, {CASES[n][0] for n in names})
        result = {}
        for name in names:
            scene, options = CASES[name]
            out = work / "bakes" / name
            started = time.monotonic()
            if name == "farm":
                try:
                    import distributed  # noqa: F401
                except ImportError:
                    print("farm: skipped (dask.distributed is not installed)")
                    continue
                with dask_cluster(work) as address:
                    bake(blends[scene], out, [*options, "--scheduler", address])
            else:
                bake(blends[scene], out, options)
            result[name] = digests(out)
            print(f"{name}: {len(result[name])} files, {time.monotonic() - started:.1f} s", flush=True)
    manifest.write_text(json.dumps({"cases": {n: CASES[n][1] for n in result}, "digests": result}, indent=1))
    print(f"wrote {manifest}")


def compare(before: Path, after: Path) -> int:
    a, b = (json.loads(p.read_text())["digests"] for p in (before, after))
    differ = []
    for case in sorted(set(a) | set(b)):
        files_a, files_b = a.get(case, {}), b.get(case, {})
        for f in sorted(set(files_a) | set(files_b)):
            if files_a.get(f) != files_b.get(f):
                differ.append(f"{case}/{f}: {files_a.get(f, 'missing')[:12]} → {files_b.get(f, 'missing')[:12]}")
    total = sum(len(v) for v in a.values())
    if differ:
        print(f"{len(differ)} of {total} files differ:\n  " + "\n  ".join(differ))
        return 1
    print(f"all {total} files of {len(a)} cases identical")
    return 0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    cap = sub.add_parser("capture", help="bake the capture scenes and write their files' digests")
    cap.add_argument("manifest", type=Path)
    cap.add_argument("--keep", type=Path, help="bake here and keep the files (default: a temporary folder)")
    cap.add_argument("--only", nargs="+", choices=list(CASES), help="these cases only")
    cmp_ = sub.add_parser("compare", help="list the files whose digests differ")
    cmp_.add_argument("before", type=Path)
    cmp_.add_argument("after", type=Path)
    args = parser.parse_args(argv)
    if args.command == "capture":
        capture(args.manifest, args.keep, args.only)
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
