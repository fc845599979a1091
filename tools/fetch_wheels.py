"""Download the runtime wheels that blender_manifest.toml lists, unmodified, into ./wheels.

The manifest is the single list of wheel files; this script derives the package, version and
platform tag from each file name, asks pip to download exactly that file from the package
registry, and checks its SHA-256 against the pins below. Nothing is rebuilt or repacked.

    python tools/fetch_wheels.py                 # every platform the manifest declares
    python tools/fetch_wheels.py --platform linux-x64   # only what one platform needs

Plain Python 3.11+, no bpy. One file per (package, CPython version, platform): Blender picks the
wheels of its own Python at install time (cp311 for Blender 4.2-5.0, cp313 for 5.1+).
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
    "embreex-4.4.0.post1-cp311-cp311-macosx_13_0_arm64.whl": "3ed370224566681071f245bbc5104feebee1354097679ab69cb3a70c94633cb3",
    "embreex-4.4.0.post1-cp311-cp311-macosx_13_0_x86_64.whl": "85d9b232805e95be845ee5d77ddea4e6b21c992b7e60fa7bdf4f578b84797a15",
    "embreex-4.4.0.post1-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl": "2cd0f7d5c6342e6247e31f700761689cae7829454d8c6de0c41e62124a023e1f",
    "embreex-4.4.0.post1-cp311-cp311-win_amd64.whl": "3df27becf6a12b59f5a469bc5271622e26387d52a15880edd29aa564246e7176",
    "embreex-4.4.0.post1-cp313-cp313-macosx_13_0_arm64.whl": "8e0ec6325caab812cb428da4cecb8905b40c6d5bda386ffb73d44bbf2aa7af56",
    "embreex-4.4.0.post1-cp313-cp313-macosx_13_0_x86_64.whl": "b8bd326b36151373adaad23268b60b39d20ec8a371eb1bae309a31e4ab78ac71",
    "embreex-4.4.0.post1-cp313-cp313-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl": "83165d2bb0436ab9b07d8e7236a0f2509c7868b3a85f2fbd8c41b4d023e88e38",
    "embreex-4.4.0.post1-cp313-cp313-win_amd64.whl": "506009885b72923661f2b5cd3decd593b9340e3ef06ddb70763303fc5982253e",
    "llvmlite-0.45.1-cp311-cp311-macosx_10_15_x86_64.whl": "60f92868d5d3af30b4239b50e1717cb4e4e54f6ac1c361a27903b318d0f07f42",
    "llvmlite-0.49.0-cp311-cp311-macosx_12_0_arm64.whl": "4b0e710880b7cc910392bd6b9f1bbf468fed99b182e4420d51598f36114b3dce",
    "llvmlite-0.49.0-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.whl": "a8c0fc9d624bdc30a3d2db11eb2fb98f80fb209d20b37604eda516cd9b699cf4",
    "llvmlite-0.49.0-cp311-cp311-win_amd64.whl": "6a5b06c1b5fc4ae4c9b169b065f42b719448ef1f873687ef224ef69969b75ec3",
    "llvmlite-0.45.1-cp313-cp313-macosx_10_15_x86_64.whl": "d9ea9e6f17569a4253515cc01dade70aba536476e3d750b2e18d81d7e670eb15",
    "llvmlite-0.49.0-cp313-cp313-macosx_12_0_arm64.whl": "039fa4054a06f537fb39248d4472284ca96be311a142ec09e69f95630ab469cc",
    "llvmlite-0.49.0-cp313-cp313-manylinux2014_x86_64.manylinux_2_17_x86_64.whl": "ddc7aecd4f56397ed6e8f120ec5dcd5a1a8f0e6032ca4af413462792d4dca2e3",
    "llvmlite-0.49.0-cp313-cp313-win_amd64.whl": "a1b414dc6b164738ec39dd8987cea73829057b7dd92fc6d91b52838385fc1dd2",
    "numba-0.62.1-cp311-cp311-macosx_10_15_x86_64.whl": "f43e24b057714e480fe44bc6031de499e7cf8150c63eb461192caa6cc8530bc8",
    "numba-0.67.0-cp311-cp311-macosx_12_0_arm64.whl": "3fa3d1b27f96f2c0d54513d953d7197886aa1eaa7d2439a0eedc44d993fb181a",
    "numba-0.67.0-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.whl": "8c80c847301dc33dc8f84a97a952004023d9a05578ae4512b087176264cc1960",
    "numba-0.67.0-cp311-cp311-win_amd64.whl": "cfba1ac34f0363fb1a250a10e97240780d11e05227892f7286b26fbfd0ad58ce",
    "numba-0.62.1-cp313-cp313-macosx_10_15_x86_64.whl": "b72489ba8411cc9fdcaa2458d8f7677751e94f0109eeb53e5becfdc818c64afb",
    "numba-0.67.0-cp313-cp313-macosx_12_0_arm64.whl": "77e1c7173fee57a0d84e006c7e70346689d6cb3e7db503489bae58646b4eff7b",
    "numba-0.67.0-cp313-cp313-manylinux2014_x86_64.manylinux_2_17_x86_64.whl": "9c4953387c77864b596d8296e2cfbdef82b0eea4166ab4864b05d226c51143e0",
    "numba-0.67.0-cp313-cp313-win_amd64.whl": "b68ad5125fe245339cc8dcc036081fc1ea482c5063387b9612a76ccd83dc91cd",
    "openexr-3.5.3-cp311-cp311-macosx_10_15_x86_64.whl": "649385e6ffa310098c0d6df44f6b3afe6d38e43c3d91f89f898b73a0b36eb4d2",
    "openexr-3.5.3-cp311-cp311-macosx_11_0_arm64.whl": "1d50c03e12baa9a469f71e33aab890c5cc897a0d4abe3eae90b32b8555ce4cd2",
    "openexr-3.5.3-cp311-cp311-manylinux_2_28_x86_64.whl": "45a35cb35b38b83635dc149d82627a618f8537f339753dc045f409b6dec0ac4c",
    "openexr-3.5.3-cp311-cp311-win_amd64.whl": "6dd26f84df0cbd1468937bbbff8f06e598dcdc19f011139b775dab37898b9deb",
    "openexr-3.5.3-cp313-cp313-macosx_10_15_x86_64.whl": "ce52f9ab9f0a9503cc329ecfc2d1e348e393d9410d07145229b5514f6b06a621",
    "openexr-3.5.3-cp313-cp313-macosx_11_0_arm64.whl": "2dde224419817fc7b8ca58fbff8b89cadb63ef0782b59a828730e8fa64d08d6a",
    "openexr-3.5.3-cp313-cp313-manylinux_2_28_x86_64.whl": "0f1c9790e2b57dbbcde9f74d1788e18cb627333066101d63bbfc6be091ff24fa",
    "openexr-3.5.3-cp313-cp313-win_amd64.whl": "885609f0329669336b24a22d9124d3cd3659dfdcafdc36d79a5ed8239c5f447c",
    "xatlas-0.0.11-cp311-cp311-macosx_10_14_x86_64.whl": "364bb9f8a90d66490ea409c8f697400daece61cb6b2806d4365a1ed1a22d9025",
    "xatlas-0.0.11-cp311-cp311-macosx_11_0_arm64.whl": "68c2e52266a0126d48ae79634f3a9d476aaebc83eda7a15b767e122241c2adbe",
    "xatlas-0.0.11-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl": "c044ee009a427898b26c0929646bfb0e0356f6762be40a140f4af41a33026208",
    "xatlas-0.0.11-cp311-cp311-win_amd64.whl": "967b2c7434d2d0412d876a7cc6d852a0bd4acdb9d68971acad302c97bf883745",
    "xatlas-0.0.11-cp313-cp313-macosx_10_14_x86_64.whl": "7d41023193a433ea783df563ccde2bb8bb039dca0896469a3cb32e58db9763da",
    "xatlas-0.0.11-cp313-cp313-macosx_11_0_arm64.whl": "70a459492c0ffcf7e37a77ac37f8a4483acd87aee07de9600e4f056e56c326dd",
    "xatlas-0.0.11-cp313-cp313-manylinux_2_17_x86_64.manylinux2014_x86_64.whl": "1c2ba5ca5e26dba5e9a04aab98ee5de0e5a0e8c87a1feae83da11052b83d86dd",
    "xatlas-0.0.11-cp313-cp313-win_amd64.whl": "81431d19c3a11dc3fbae95460cd6b16239636b21fa7c30bd5796976a03844ede",
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


def python_version(filename: str) -> str:
    """CPython version 'X.Y' of a wheel from its python tag ('cp313' -> '3.13')."""
    tag = filename[: -len(".whl")].split("-")[-3]
    if not tag.startswith("cp3") or not tag[3:].isdigit():
        raise ValueError(f"not a CPython 3 wheel: {filename}")
    return f"3.{tag[3:]}"


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
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--quiet",
        "--no-deps",
        "--only-binary=:all:",
        "--python-version",
        python_version(filename),
        "--implementation",
        "cp",
        "--abi",
        abi,
        "--platform",
        plat.split(".")[0],
        "--dest",
        str(dest),
        f"{name}=={version}",
    ]
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
    _remove_unlisted(dest)
    return got


def _remove_unlisted(dest: Path) -> None:
    """Delete wheels in dest that the manifest no longer lists: Blender's build tool packs every
    file under wheels/, listed or not, so a stale wheel would ship in every zip."""
    listed = set(manifest_wheels())
    for path in dest.glob("*.whl"):
        if path.name not in listed:
            path.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--platform", action="append", help="Blender platform, e.g. linux-x64 (repeatable)")
    args = ap.parse_args()
    paths = fetch(set(args.platform) if args.platform else None)
    print(f"{len(paths)} wheels ready in {ROOT / 'wheels'}")


if __name__ == "__main__":
    main()
