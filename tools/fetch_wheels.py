"""Download the runtime wheels that blender_manifest.toml lists, unmodified, into ./wheels.

The manifest is the single list of wheel files; this script derives the package, version and
platform tag from each file name, asks pip to download exactly that file from the package
registry, and checks its SHA-256 against the pins below. Nothing is rebuilt or repacked.

    python tools/fetch_wheels.py                 # every platform the manifest declares
    python tools/fetch_wheels.py --platform linux-x64   # only what one platform needs

Plain Python 3.11+, no bpy.
"""
from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

SHA256 = {
    "embreex-4.4.0.post1-cp311-cp311-win_amd64.whl": "3df27becf6a12b59f5a469bc5271622e26387d52a15880edd29aa564246e7176",
    "embreex-4.4.0.post1-cp311-cp311-macosx_13_0_arm64.whl": "3ed370224566681071f245bbc5104feebee1354097679ab69cb3a70c94633cb3",
    "embreex-4.4.0.post1-cp311-cp311-macosx_13_0_x86_64.whl": "85d9b232805e95be845ee5d77ddea4e6b21c992b7e60fa7bdf4f578b84797a15",
    "embreex-4.4.0.post1-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl": "2cd0f7d5c6342e6247e31f700761689cae7829454d8c6de0c41e62124a023e1f",
    "xatlas-0.0.11-cp311-cp311-win_amd64.whl": "967b2c7434d2d0412d876a7cc6d852a0bd4acdb9d68971acad302c97bf883745",
    "xatlas-0.0.11-cp311-cp311-macosx_11_0_arm64.whl": "68c2e52266a0126d48ae79634f3a9d476aaebc83eda7a15b767e122241c2adbe",
    "xatlas-0.0.11-cp311-cp311-macosx_10_14_x86_64.whl": "364bb9f8a90d66490ea409c8f697400daece61cb6b2806d4365a1ed1a22d9025",
    "xatlas-0.0.11-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl": "c044ee009a427898b26c0929646bfb0e0356f6762be40a140f4af41a33026208",
    "openexr-3.5.3-cp311-cp311-win_amd64.whl": "6dd26f84df0cbd1468937bbbff8f06e598dcdc19f011139b775dab37898b9deb",
    "openexr-3.5.3-cp311-cp311-macosx_11_0_arm64.whl": "1d50c03e12baa9a469f71e33aab890c5cc897a0d4abe3eae90b32b8555ce4cd2",
    "openexr-3.5.3-cp311-cp311-macosx_10_15_x86_64.whl": "649385e6ffa310098c0d6df44f6b3afe6d38e43c3d91f89f898b73a0b36eb4d2",
    "openexr-3.5.3-cp311-cp311-manylinux_2_28_x86_64.whl": "45a35cb35b38b83635dc149d82627a618f8537f339753dc045f409b6dec0ac4c",
    "numba-0.60.0-cp311-cp311-win_amd64.whl": "cac02c041e9b5bc8cf8f2034ff6f0dbafccd1ae9590dc146b3a02a45e53af4e2",
    "numba-0.60.0-cp311-cp311-macosx_11_0_arm64.whl": "3fb02b344a2a80efa6f677aa5c40cd5dd452e1b35f8d1c2af0dfd9ada9978e4b",
    "numba-0.60.0-cp311-cp311-macosx_10_9_x86_64.whl": "a17b70fc9e380ee29c42717e8cc0bfaa5556c416d94f9aa96ba13acb41bdece8",
    "numba-0.60.0-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.whl": "4142d7ac0210cc86432b818338a2bc368dc773a2f5cf1e32ff7c5b378bd63ee8",
    "llvmlite-0.43.0-cp311-cp311-win_amd64.whl": "d5bd550001d26450bd90777736c69d68c487d17bf371438f975229b2b8241a91",
    "llvmlite-0.43.0-cp311-cp311-macosx_11_0_arm64.whl": "e0a9a1a39d4bf3517f2af9d23d479b4175ead205c592ceeb8b89af48a327ea57",
    "llvmlite-0.43.0-cp311-cp311-macosx_10_9_x86_64.whl": "3e8d0618cb9bfe40ac38a9633f2493d4d4e9fcc2f438d39a4e854f39cc0f5f98",
    "llvmlite-0.43.0-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl": "977525a1e5f4059316b183fb4fd34fa858c9eade31f165427a3977c95e3ee749",
}



def wheel_platform(filename: str) -> str:
    """Blender platform name ('linux-x64', ...) a wheel file belongs to."""
    tag = filename[: -len(".whl")].split("-")[-1]
    if "win_amd64" in tag:
        return "windows-x64"
    if tag.startswith("macosx_"):
        return "macos-arm64" if tag.endswith("arm64") else "macos-x64"
    if "linux" in tag and tag.endswith("x86_64"):
        return "linux-x64"
    raise ValueError(f"unknown platform tag in {filename}")


def manifest_wheels() -> list[str]:
    with open(ROOT / "blender_manifest.toml", "rb") as f:
        manifest = tomllib.load(f)
    return [Path(w).name for w in manifest.get("wheels", [])]


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def download(filename: str, dest: Path) -> None:
    """pip-download exactly `filename` (no dependencies, binary only) into dest."""
    name, version, py, abi, plat = filename[: -len(".whl")].split("-")
    cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
           "--python-version", "3.11", "--implementation", "cp", "--abi", abi,
           "--platform", plat.split(".")[0], "--dest", str(dest), f"{name}=={version}"]
    subprocess.run(cmd, check=True)


def fetch(platforms: set[str] | None = None, dest: Path = ROOT / "wheels") -> list[Path]:
    """Ensure every manifest wheel (for the given platforms) is in dest with the pinned hash."""
    dest.mkdir(exist_ok=True)
    got = []
    for filename in manifest_wheels():
        if platforms and wheel_platform(filename) not in platforms:
            continue
        path = dest / filename
        if not path.exists() or sha256(path) != SHA256[filename]:
            download(filename, dest)
        if not path.exists():
            raise SystemExit(f"pip did not produce {filename}: the registry's file name changed?")
        if sha256(path) != SHA256[filename]:
            raise SystemExit(f"{filename}: SHA-256 mismatch, refusing to package it")
        got.append(path)
    return got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--platform", action="append", help="Blender platform, e.g. linux-x64 (repeatable)")
    args = ap.parse_args()
    paths = fetch(set(args.platform) if args.platform else None)
    print(f"{len(paths)} wheels ready in {ROOT / 'wheels'}")


if __name__ == "__main__":
    main()
