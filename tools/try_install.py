"""Install a built extension zip as a user would, enable it and bake a small scene with it.

    python tools/try_install.py dist/hhd_lightmapper-0.1.0-linux_x64.zip --out DIR

Run it with the Python of an environment that has the `bpy` module and nothing of ours: the
compiled dependencies (embreex, xatlas, OpenEXR, numba, llvmlite) must come from the zip's own
wheels, so an environment that can already import one of them is refused. Blender's user
configuration goes to a fresh temporary directory (BLENDER_USER_RESOURCES), so the real one is
never touched. Steps: `bpy.ops.extensions.package_install_files(enable_on_install=True)`, build
`scene()` (floor + cube, sun + sky), select all, `bpy.ops.hhd.unwrap()`, `bpy.ops.hhd.bake()`.
Prints one JSON line last: Blender and numpy versions, covered texels, mean I_z (linear RGB
luminance over covered texels) and the bake's thread count. Exit 0 on success.

    python tools/try_install.py dist/hhd_lightmapper-0.1.0-linux_x64.zip --out DIR --scheduler tcp://HOST:PORT

installs the zip and bakes the same way, then bakes the same scene twice more through the installed
extension's command line (`cli.main`, what `blender -b FILE --command hhd_lightmapper bake` calls)
into DIR/local and DIR/farm, the second with `--scheduler`: Dask must come from the zip's own wheels
(an environment that can already import dask or distributed is refused too), and the bakes before
it must not import it. The JSON line then has both exit codes, whether Dask was imported before the
farm bake, the files `dask` and `distributed` were imported from and the site-packages folder
Blender installed the extension's wheels into, besides what the operators' bake reports.

    python tools/try_install.py --scene-only FILE.blend

only builds and saves the scene (no extension needed), for a headless CLI bake of the same
scene in any Blender version.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COMPILED = ("embreex", "xatlas", "OpenEXR", "numba", "llvmlite")
#: The farm client's packages (`bake --scheduler`), also bundled as wheels.
FARM = ("dask", "distributed")
MODULE = "bl_ext.user_default.hhd_lightmapper"
RESOLUTION, SAMPLES, BOUNCES = 256, 8, 1


def scene():
    """A 4 m floor and a 1 m red cube on it, a sun and a blue-grey sky; returns the receivers.
    Built from raw vertex lists, so every Blender version makes the same meshes."""
    import bpy

    compat = _blender_compat()
    for coll in (bpy.data.objects, bpy.data.meshes, bpy.data.lights, bpy.data.materials):
        for block in list(coll):
            coll.remove(block)
    s = bpy.context.scene

    def mesh(name, verts, faces, colour):
        me = bpy.data.meshes.new(name)
        me.from_pydata(verts, [], faces)
        mat = bpy.data.materials.new(name)
        bsdf = compat.ensure_node_tree(mat).nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
        bsdf.inputs["Roughness"].default_value = 1.0
        me.materials.append(mat)
        ob = bpy.data.objects.new(name, me)
        s.collection.objects.link(ob)
        return ob

    floor = mesh("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], (0.8, 0.8, 0.8))
    c = [(x, y, z) for z in (0, 1) for y in (-0.5, 0.5) for x in (-0.5, 0.5)]
    cube = mesh(
        "Cube", c, [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)], (0.8, 0.1, 0.1)
    )
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.5, 0.2, 0.0)
    s.collection.objects.link(sun)
    world = bpy.data.worlds.new("Sky")
    compat.ensure_node_tree(world).nodes["Background"].inputs["Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    s.world = world
    return [floor, cube]


def _blender_compat():
    """The repository's blender_compat module, loaded by path (this script also runs where the
    package is not importable: a bpy-only environment)."""
    spec = importlib.util.spec_from_file_location("_hhd_blender_compat", ROOT / "blender_compat.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def refuse_preinstalled() -> None:
    found = [name for name in (*COMPILED, *FARM) if importlib.util.find_spec(name) is not None]
    if found:
        raise SystemExit(
            f"this environment already has {', '.join(found)}: use one with only `bpy`, "
            "so the zip's own wheels are what gets tested"
        )


def install(zip_path: Path) -> None:
    """Install the zip into the user repository and enable it, as a user's Blender does."""
    import bpy

    result = bpy.ops.extensions.package_install_files(
        filepath=str(zip_path), repo="user_default", enable_on_install=True
    )
    if result != {"FINISHED"} or MODULE not in bpy.context.preferences.addons:
        raise SystemExit(f"installing {zip_path.name} did not enable {MODULE}")


def prepare(out: Path, denoise: bool = True):
    """scene() with the bake settings, the receivers selected; returns the receivers."""
    import bpy

    receivers = scene()
    s = bpy.context.scene
    s.hhd.resolution, s.hhd.samples, s.hhd.bounces = RESOLUTION, SAMPLES, BOUNCES
    s.hhd.denoise = denoise
    s.hhd.output_dir = str(out)
    for ob in s.objects:
        ob.select_set(ob in receivers)
    bpy.context.view_layer.objects.active = receivers[0]
    return receivers


def install_and_bake(zip_path: Path, out: Path, denoise: bool = True, scheduler: str | None = None) -> dict:
    """Install, unwrap and bake with the operators into `out`; with a `scheduler`, then `bake`
    through the installed extension's command line twice (`farm_bakes`). Returns the report."""
    import bpy

    install(zip_path)
    receivers = prepare(out, denoise)
    if bpy.ops.hhd.unwrap() != {"FINISHED"} or bpy.ops.hhd.bake() != {"FINISHED"}:
        raise SystemExit("unwrap or bake did not finish")
    report = summary(out)
    if scheduler:
        report |= farm_bakes(receivers, out, scheduler)
    return report


def farm_bakes(receivers, out: Path, scheduler: str) -> dict:
    """`bake` the unwrapped `receivers` through the installed extension's command line (what
    `blender -b FILE --command hhd_lightmapper` calls) into out/local without a scheduler and
    into out/farm with `--scheduler`: their exit codes, whether Dask was imported before the
    farm bake, and where Dask was imported from."""
    import bpy

    cli = importlib.import_module(MODULE + ".cli")
    args = ["bake", "--objects", *(ob.name for ob in receivers), "--seed", "0"]
    local = cli.main([*args, "--out", str(out / "local")])
    dask_before = sorted(name for name in FARM if name in sys.modules)
    farm = cli.main([*args, "--out", str(out / "farm"), "--scheduler", scheduler])
    import dask
    import distributed

    major_minor = "python{:d}.{:d}".format(*sys.version_info[:2])
    wheels = Path(bpy.utils.user_resource('EXTENSIONS'), ".local", "lib", major_minor, "site-packages")
    return {
        "exit_codes": [local, farm],
        "farm_imported_by_local_bake": dask_before,
        "dask": str(Path(dask.__file__).resolve()),
        "distributed": str(Path(distributed.__file__).resolve()),
        "distributed_version": distributed.__version__,
        "wheels_site_packages": str(wheels.resolve()),
    }


def summary(out: Path) -> dict:
    """Mean I_z luminance over the covered texels of the bake in `out`, read with the installed
    extension's own modules (its OpenEXR comes from the zip)."""
    import bpy
    import numpy as np

    exr = importlib.import_module(MODULE + ".core.files.exr")
    hhd_ch, _ = exr.read(out / "Lightmap_hhd.exr")
    tx_ch, _ = exr.read(out / "Lightmap_texels.exr")
    covered = tx_ch["Coverage.V"] > 0
    iz = np.stack([hhd_ch[f"Iz.{c}"] for c in "RGB"], -1).astype(np.float64)
    lum = iz @ importlib.import_module(MODULE + ".core.colour").LUMINANCE
    doc = json.loads((out / "Lightmap.json").read_text())
    return {
        "blender": bpy.app.version_string,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "texels": int(covered.sum()),
        "mean_iz": float(lum[covered].mean()),
        "threads": doc["bake"].get("threads"),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("zip", nargs="?", type=Path)
    ap.add_argument("--out", type=Path, help="bake output folder (default: a temporary one)")
    ap.add_argument("--scene-only", type=Path, metavar="FILE.blend", help="only build and save the scene")
    ap.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="bake through the installed extension's CLI without and with this Dask scheduler",
    )
    ap.add_argument("--no-denoise", dest="denoise", action="store_false", help="bake without denoising")
    args = ap.parse_args()
    user_dir = tempfile.mkdtemp(prefix="hhd-try-install-")
    os.environ["BLENDER_USER_RESOURCES"] = user_dir
    try:
        if args.scene_only:
            import bpy

            scene()
            bpy.ops.wm.save_as_mainfile(filepath=str(args.scene_only.resolve()))
            report = {"scene": str(args.scene_only)}
        else:
            if args.zip is None:
                ap.error("give the zip to install (or --scene-only FILE.blend)")
            refuse_preinstalled()
            out = (args.out or Path(tempfile.mkdtemp(prefix="hhd-try-bake-"))).resolve()
            report = install_and_bake(args.zip.resolve(), out, args.denoise, args.scheduler)
    finally:
        shutil.rmtree(user_dir, ignore_errors=True)  # the installed extension: hundreds of MB
    print(json.dumps(report), flush=True)
    _blender_compat().exit_process(0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
