"""Build and validate the extension zips, one per platform, with Blender's own extension tool.

    python tools/build_extension.py [--output-dir dist]

Steps: download the manifest's wheels (tools/fetch_wheels.py) and extract OIDN's lightmap weights
into oidn_weights/ (tools/fetch_oidn_weights.py; both hash-checked and cached), then run Blender's
`blender_ext.py build --split-platforms` and `blender_ext.py validate` on every zip. The tool is
the script behind `blender --command extension build/validate`; it ships inside the `bpy` wheel
and runs with plain Python, so no Blender install is needed. Pass --blender to use a Blender
binary's `--command extension` instead. Prints the zip paths, one per line, last.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fetch_oidn_weights  # noqa: E402
import fetch_wheels  # noqa: E402

ROOT = fetch_wheels.ROOT


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


def build(output_dir: Path, blender: str | None = None) -> list[Path]:
    """Build one validated zip per declared platform into output_dir; return their paths."""
    fetch_wheels.fetch()
    fetch_oidn_weights.fetch()  # shipped in every zip: oidn_weights/*.tza
    output_dir.mkdir(parents=True, exist_ok=True)
    for old in output_dir.glob("hhd_lightmapper-*.zip"):
        old.unlink()
    tool = extension_tool(blender)
    subprocess.run(
        tool + ["build", "--split-platforms", "--source-dir", str(ROOT), "--output-dir", str(output_dir)], check=True
    )
    zips = sorted(output_dir.glob("hhd_lightmapper-*.zip"))
    if not zips:
        raise SystemExit("the extension tool produced no zip")
    for z in zips:
        subprocess.run(tool + ["validate", str(z)], check=True)
    return zips


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output-dir", type=Path, default=ROOT / "dist")
    ap.add_argument("--blender", help="path to a Blender binary (default: the tool inside the bpy wheel)")
    args = ap.parse_args()
    for z in build(args.output_dir.resolve(), args.blender):
        print(z)


if __name__ == "__main__":
    main()
