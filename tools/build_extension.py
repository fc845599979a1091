"""Build and validate the extension zips, one per platform, with Blender's own extension tool.

    python tools/build_extension.py [--output-dir dist] [--platform linux-x64]

Steps: download the manifest's wheels (tools/fetch_wheels.py) and extract OIDN's lightmap weights
into oidn_weights/ (tools/fetch_oidn_weights.py; both hash-checked and cached), then run Blender's
`blender_ext.py build --split-platforms` and `blender_ext.py validate` on every zip. The tool is
the script behind `blender --command extension build/validate`; it ships inside the `bpy` wheel
and runs with plain Python, so no Blender install is needed. Pass --blender to use a Blender
binary's `--command extension` instead. Prints the zip paths, one per line, last.

Every zip is also checked for what Blender's validator does not know about: it holds exactly the
manifest's wheels of its platform and no development file (`check_zip`). `--platform` builds one
platform's zip (the test suite's: only that platform's wheels are fetched) from a staged copy of
the package whose manifest declares that platform alone, so the zip is the one a full build makes.
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

import fetch_oidn_weights  # noqa: E402
import fetch_wheels  # noqa: E402

ROOT = fetch_wheels.ROOT


def this_platform() -> str:
    """Blender's platform name for the running machine, e.g. 'linux-x64'."""
    import platform

    system = {"Linux": "linux", "Darwin": "macos", "Windows": "windows"}[platform.system()]
    arch = {"x86_64": "x64", "AMD64": "x64", "arm64": "arm64", "aarch64": "arm64"}[platform.machine()]
    return f"{system}-{arch}"


def extension_tool(blender: str | None) -> list[str]:
    """Command prefix that runs Blender's extension CLI."""
    if blender:
        return [blender, "--factory-startup", "--command", "extension"]
    spec = importlib.util.find_spec("bpy")  # locates the wheel without importing Blender
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("No `bpy` module found: install the pinned bpy (see README) or pass --blender")
    bpy_dir = Path(list(spec.submodule_search_locations)[0])
    tools = sorted(bpy_dir.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not tools:
        raise SystemExit(f"blender_ext.py not found under {bpy_dir}")
    return [sys.executable, str(tools[-1])]


#: Files a zip must not carry (the manifest's `paths_exclude_pattern` keeps them out).
DEV_PREFIXES = ("tests/", "bench/", "tools/", ".ci/", "docs/", "scenekit/", ".venv", "web/")


def build(output_dir: Path, blender: str | None = None, platform: str | None = None) -> list[Path]:
    """Build one validated zip per declared platform (or for `platform` alone) into output_dir;
    return their paths."""
    fetch_wheels.fetch({platform} if platform else None)
    fetch_oidn_weights.fetch()  # shipped in every zip: oidn_weights/*.tza
    output_dir.mkdir(parents=True, exist_ok=True)
    for old in output_dir.glob("hhd_lightmapper-*.zip"):
        old.unlink()
    tool = extension_tool(blender)
    with tempfile.TemporaryDirectory(prefix="hhd-build-") as staging:
        source = ROOT if platform is None else _stage(Path(staging), platform)
        subprocess.run(
            tool + ["build", "--split-platforms", "--source-dir", str(source), "--output-dir", str(output_dir)],
            check=True,
        )
    zips = sorted(output_dir.glob("hhd_lightmapper-*.zip"))
    if not zips:
        raise SystemExit("the extension tool produced no zip")
    for z in zips:
        subprocess.run(tool + ["validate", str(z)], check=True)
        problems = check_zip(z)
        if problems:
            raise SystemExit(f"{z.name}: " + "; ".join(problems))
    return zips


def _stage(staging: Path, platform: str) -> Path:
    """A copy of the package (what the manifest would ship) whose manifest declares `platform`
    alone and lists only its wheels; the wheels themselves are linked, not copied."""
    manifest = (ROOT / "blender_manifest.toml").read_text()
    if platform not in tomllib.loads(manifest)["platforms"]:
        raise SystemExit(f"{platform} is not a platform of blender_manifest.toml")
    lines = []
    for line in manifest.splitlines(keepends=True):
        wheel = line.strip().strip('",')
        if wheel.startswith("./wheels/") and platform not in fetch_wheels.wheel_platforms(Path(wheel).name):
            continue
        if line.startswith("platforms = "):
            line = f'platforms = ["{platform}"]\n'
        lines.append(line)
    source = staging / "hhd_lightmapper"
    ignore = shutil.ignore_patterns(
        "__pycache__", ".*", "*.egg-info", "wheels", "tests", "bench", "tools", "scenekit", "docs", "web"
    )
    shutil.copytree(ROOT, source, ignore=_top_level(ignore, {"dist", "build", "out"}))
    (source / "blender_manifest.toml").write_text("".join(lines))
    (source / "wheels").mkdir()
    for path in fetch_wheels.fetch({platform}):
        (source / "wheels" / path.name).symlink_to(path)
    return source


def _top_level(ignore, names: set[str]):
    """shutil.copytree's ignore: `ignore` everywhere, and `names` in the repository root only."""

    def pick(folder, entries):
        skipped = set(ignore(folder, entries))
        if Path(folder) == ROOT:
            skipped |= names & set(entries)
        return skipped

    return pick


def check_zip(path: Path) -> list[str]:
    """What is wrong with a built zip beyond Blender's validation (empty when nothing): it must
    hold the package, exactly the manifest's wheels of its platform, and no development file."""
    with open(ROOT / "blender_manifest.toml", "rb") as f:
        manifest = tomllib.load(f)
    names = zipfile.ZipFile(path).namelist()
    platform = next((p for p in manifest["platforms"] if path.stem.endswith(p.replace("-", "_"))), None)
    problems = []
    if platform is None:
        return [f"names no platform of the manifest {manifest['platforms']}"]
    required = ("blender_manifest.toml", "__init__.py", "core/bake/__init__.py", "cli/__init__.py", "cli/__main__.py")
    if not all(name in names for name in required):
        problems.append("the package (blender_manifest.toml, __init__.py, core/, cli/) is incomplete")
    dev = [n for n in names if n.startswith(DEV_PREFIXES) or "__pycache__/" in n]
    if dev:
        problems.append(f"development files: {dev[:5]}")
    shipped = sorted(Path(n).name for n in names if n.endswith(".whl"))
    wanted = sorted(Path(w).name for w in manifest["wheels"] if platform in fetch_wheels.wheel_platforms(Path(w).name))
    if shipped != wanted:
        problems.append(f"wheels differ from the manifest's for {platform}: {sorted(set(shipped) ^ set(wanted))}")
    return problems


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output-dir", type=Path, default=ROOT / "dist")
    ap.add_argument("--blender", help="path to a Blender binary (default: the tool inside the bpy wheel)")
    ap.add_argument(
        "--platform", help="build this platform's zip only, e.g. linux-x64, or `this` (default: every platform)"
    )
    ap.add_argument("--print-platform", action="store_true", help="print the running platform's name and stop")
    args = ap.parse_args()
    if args.print_platform:
        print(this_platform())
        return
    platform = this_platform() if args.platform == "this" else args.platform
    for z in build(args.output_dir.resolve(), args.blender, platform):
        print(z)


if __name__ == "__main__":
    main()
