"""Download the runtime wheels that blender_manifest.toml lists, unmodified, into ./wheels.

The manifest is the single list of wheel files; this script derives the package, version and
platform tag from each file name, asks pip to download exactly that file from the package
registry, and checks its SHA-256 against the pins below. Nothing is rebuilt or repacked.

    python tools/fetch_wheels.py                 # every platform the manifest declares
    python tools/fetch_wheels.py --platform linux-x64   # only what one platform needs

Plain Python 3.11+, no bpy. A compiled package has one file per (CPython version, platform):
Blender picks the wheels of its own Python at install time (cp311 for Blender 4.2-5.0, cp313 for
5.1+; bl_pkg's `_extensions_wheel_filter_for_this_system`). A pure-Python wheel (`py3-none-any`)
is one file for every platform and Python, and a stable-ABI wheel (`cp36-abi3`, `cp311-abi3`) one
file per platform for every Python from its tag on; `macosx_*_universal2` serves both Macs.
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
    "isal-1.9.1-cp311-cp311-macosx_10_9_x86_64.whl": "ff2418b001c73e6822bc287232d1fd2b9134fa29778b176edfaef36732147b3d",
    "isal-1.9.1-cp311-cp311-macosx_11_0_arm64.whl": "f6b22c7ccdd88102394948d59603b07038dd67eecabcf72004b10956a861c205",
    "isal-1.9.1-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "a5b2f93fc39b8be92c6547965143094ee4d6a5543ef2d762a0edb6f06201feb5",
    "isal-1.9.1-cp311-cp311-win_amd64.whl": "85456c25150cb3608901641d355ee1f7b34f16c24db268e5b54a529b7a8e3c2d",
    "isal-1.9.1-cp313-cp313-macosx_10_13_x86_64.whl": "a89b29c2c2994b01d47b6332ae7c0c30cf2e23a0cf7957a21cda7ee87f943955",
    "isal-1.9.1-cp313-cp313-macosx_11_0_arm64.whl": "a2059238d509c871d181c13dd3e027936b2cec0275838aa2b12fd8deddbb2af8",
    "isal-1.9.1-cp313-cp313-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "5ba6b5c13fb97e7c3c04677725177c40283fbd6c620c169070b231c4cb0cf4b3",
    "isal-1.9.1-cp313-cp313-win_amd64.whl": "2ddd321a6b61745220fa0371fe99ec6a0e397e3520994add5ef0755b363a01ce",
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
    # Dask (the farm client: `bake --scheduler`) and every package it needs at run time
    "click-8.5.1-py3-none-any.whl": "8bb5376d2006950386f8c6427613334a2acadc5f559cb80e638d00b4df957e37",
    "cloudpickle-3.1.3-py3-none-any.whl": "1654f4f18e416447210a63c5c25a135d65a292156aa5fa519dfa4baf7726dddb",
    "dask-2026.8.0-py3-none-any.whl": "ccc0c83a189b0398602435189771d28dad7b5773b6089bb8dce14ae732dd782c",
    "distributed-2026.8.0-py3-none-any.whl": "3bd8882861a2cf497453f28c6b61135fa8ef2bb1d6885ad3b9f27e887e9c0e01",
    "fsspec-2026.9.0-py3-none-any.whl": "8dd6e646e99ea382bd85f97a45e6b526a442d79423a7dc673f1e2756d05fcb5f",
    "importlib_metadata-10.2.0-py3-none-any.whl": "c7a4bf1c7479601f6b8e437cfc14f4f77028ba62a8f34ae95cd93d9774dfba51",
    "jinja2-3.1.6-py3-none-any.whl": "85ece4451f492d0c13c5dd7c13a64681a86afae63a5f347908daf103ce6d2f67",
    "lazy_importer-0.1.0-py3-none-any.whl": "bd93fab7bef18e842eea02b839410954d37889140dc64ca4d9680aec6880c739",
    "locket-1.0.0-py2.py3-none-any.whl": "b6c819a722f7b6bd955b80781788e4a66a55628b858d347536b7e81325a3a5e3",
    "markupsafe-3.0.4-cp311-cp311-macosx_10_9_x86_64.whl": "9e25feb9e330b63edb0278a0acdf85e50d0cb0fbf49c3084abbe4e24ae195346",
    "markupsafe-3.0.4-cp311-cp311-macosx_11_0_arm64.whl": "7d3391b2188d18737cb2fa147028b1096236eaa7e156446c650a489fa2cadc91",
    "markupsafe-3.0.4-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "6da83a088f8ef93b2d483a8232a4dbf4d69d3d8496b568a03c56becac43e1808",
    "markupsafe-3.0.4-cp311-cp311-win_amd64.whl": "fdb4ca07ab75ffadab4a8b135ad59cdbb3156b99310f3d565370da74a15d6bd3",
    "markupsafe-3.0.4-cp313-cp313-macosx_10_13_x86_64.whl": "2d1b7d9308288661f56672b1b157d75fc536714d3638487bbea17b6318a78248",
    "markupsafe-3.0.4-cp313-cp313-macosx_11_0_arm64.whl": "73e77980c7207854f00fc4e71fb1626868d5740ab4012623d55c7a99ad122a72",
    "markupsafe-3.0.4-cp313-cp313-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "434139499bb20b502ed3baa1f169e618f924a97e7a777fea1a49446d80106cf6",
    "markupsafe-3.0.4-cp313-cp313-win_amd64.whl": "1f1f9477e174582b0a1b583d60b66e1f2cf5d3fe12cee985e4aedf44766600e5",
    "msgpack-1.2.4-cp311-cp311-macosx_10_9_x86_64.whl": "1095b1ebcc8c9d3e70c51240b7160d8e9da66044e0a45c3ef8403d3a9ef0c5ad",
    "msgpack-1.2.4-cp311-cp311-macosx_11_0_arm64.whl": "a4b47ec7422bef149223786a87df80067ac65bfc7c0565e5cf1dfbdc40acee50",
    "msgpack-1.2.4-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "a45ceb5f199d5e388f28b550ba881096a3740d4bda10e661d77f59d9a2e8187a",
    "msgpack-1.2.4-cp311-cp311-win_amd64.whl": "9db832747bd05834530189e564a3fe31e2617547dc1f3a005f835eafc2b8e048",
    "msgpack-1.2.4-cp313-cp313-macosx_10_13_x86_64.whl": "fb811ac3d463a75013b234d2aae56b9f0bdb0105caf4dd2ee65305b6a8a6078d",
    "msgpack-1.2.4-cp313-cp313-macosx_11_0_arm64.whl": "36258fd0909e1bf26e94604439108846432abe4ffa9a23c9dc2f6f1c60f94b60",
    "msgpack-1.2.4-cp313-cp313-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "7fabd415c41e62006c6641fcdf5b3e866f581c4e11c58328c0d0f69584b9577d",
    "msgpack-1.2.4-cp313-cp313-win_amd64.whl": "318d4e634d2b320be10decd9968ad1ae0be1d80cba23b5528c37b429eeb0e3e0",
    "packaging-26.4-py3-none-any.whl": "81383611a09c1bc0b08b76e0fd5829d7c6824c65b27a6aee339da133f4233ea2",
    "partd-1.4.2-py3-none-any.whl": "978e4ac767ec4ba5b86c6eaa52e5a2a3bc748a2ca839e8cc798f1cc6ce6efb0f",
    "psutil-7.2.2-cp36-abi3-macosx_10_9_x86_64.whl": "ed0cace939114f62738d808fdcecd4c869222507e266e574799e9c0faa17d486",
    "psutil-7.2.2-cp36-abi3-macosx_11_0_arm64.whl": "1a7b04c10f32cc88ab39cbf606e117fd74721c831c98a27dc04578deb0c16979",
    "psutil-7.2.2-cp36-abi3-manylinux2010_x86_64.manylinux_2_12_x86_64.manylinux_2_28_x86_64.whl": "076a2d2f923fd4821644f5ba89f059523da90dc9014e85f8e45a5774ca5bc6f9",
    "psutil-7.2.2-cp37-abi3-win_amd64.whl": "eb7e81434c8d223ec4a219b5fc1c47d0417b12be7ea866e24fb5ad6e84b3d988",
    "pyyaml-6.0.4-cp311-cp311-macosx_10_15_x86_64.whl": "180ac792c958c2173f6e4467c55ae5f73ab1a9a624ee29fc7095c56d5e3a4055",
    "pyyaml-6.0.4-cp311-cp311-macosx_11_0_arm64.whl": "730788375056c43d3ac15bd894c9cd2fb7a931a38b302f408620c64b3ef176ed",
    "pyyaml-6.0.4-cp311-cp311-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "622aa875fa6533f25fedcffe23079357d65a690d462200afed5d8e9d0e01ebee",
    "pyyaml-6.0.4-cp311-cp311-win_amd64.whl": "0db75f402e99c25239003a499c214a61947b4ef5312af34711d4c63e5c179318",
    "pyyaml-6.0.4-cp313-cp313-macosx_10_15_x86_64.whl": "61eef2f08e977b725f37a8d1663f5a222c6f09207ac0794030d5fca062e7c96e",
    "pyyaml-6.0.4-cp313-cp313-macosx_11_0_arm64.whl": "9d4211f080920629a90c9e31c51e326fb70cfae38f18d4128b9913c23642bace",
    "pyyaml-6.0.4-cp313-cp313-manylinux2014_x86_64.manylinux_2_17_x86_64.manylinux_2_28_x86_64.whl": "50588147ab2c6a59b5f990a4905db80899a6c2bd197e046a6201f1e67587e794",
    "pyyaml-6.0.4-cp313-cp313-win_amd64.whl": "0a3a351f04dc124f9357512bdb80ac37cd1750cf1371da33e7cbb96d80ac865f",
    "sortedcontainers-2.4.0-py2.py3-none-any.whl": "a163dcaede0f1c021485e957a39245190e74249897e2ae4b2aa38595db237ee0",
    "tblib-3.2.2-py3-none-any.whl": "26bdccf339bcce6a88b2b5432c988b266ebbe63a4e593f6b578b1d2e723d2b76",
    "toolz-1.2.0-py3-none-any.whl": "890f820b1cb8152785aaf9386d8707770110809035800985ca65cb24ce1120ef",
    "tornado-6.6.1-cp311-abi3-macosx_10_9_universal2.whl": "a8d3e6acde5a80d13b13b5e4c7c226ca682f31d0a62b6c33cea038714bc2de1b",
    "tornado-6.6.1-cp311-abi3-manylinux1_x86_64.manylinux_2_28_x86_64.manylinux_2_5_x86_64.whl": "1b6ff57cc69b339f8feb9e7b567b0e0eacb16bfaf234159496623ef7a67ba640",
    "tornado-6.6.1-cp311-abi3-win_amd64.whl": "5cb82ca38596e1350fceaf994f287847f82f7b8436380d36ba0937a03107d0ee",
    "zict-3.0.0-py2.py3-none-any.whl": "5796e36bd0e0cc8cf0fbc1ace6a68912611c1dbd74750a3f3026b9b9d6a327ae",
    "zipp-4.1.2-py3-none-any.whl": "b30cb6cd253122169c47de245ca24a86bac2a5d3802ba15bf7ba6414eb9e144d",
}


#: Every platform the manifest may declare (a pure-Python wheel belongs to each).
PLATFORMS = ("windows-x64", "macos-arm64", "macos-x64", "linux-x64")
#: The Python of the oldest supported Blender (4.2): what pip checks a pure-Python or stable-ABI
#: wheel's Requires-Python against (the same file serves Python 3.13 too).
OLDEST_PYTHON = "3.11"


def _tags(filename: str) -> tuple[str, str, str, str, str]:
    """(name, version, python tag, abi tag, platform tag) of a wheel file name (no build tag)."""
    parts = filename[: -len(".whl")].split("-")
    if len(parts) != 5:
        raise ValueError(f"unexpected wheel file name: {filename}")
    name, version, py, abi, plat = parts
    return name, version, py, abi, plat


def wheel_platforms(filename: str) -> set[str]:
    """Blender platform names ('linux-x64', ...) a wheel file serves: every one for a pure-Python
    wheel ('any'), both Macs for 'universal2'."""
    tag = _tags(filename)[4]
    if tag == "any":
        return set(PLATFORMS)
    if "win_amd64" in tag:
        return {"windows-x64"}
    if tag.startswith("macosx_"):
        if tag.endswith("_universal2"):
            return {"macos-arm64", "macos-x64"}
        return {"macos-arm64"} if tag.endswith("arm64") else {"macos-x64"}
    if "linux" in tag and tag.endswith("x86_64"):
        return {"linux-x64"}
    raise ValueError(f"unknown platform tag in {filename}")


def python_version(filename: str) -> str:
    """The CPython version 'X.Y' pip is asked for: the wheel's own for a version-specific
    compiled wheel ('cp313-cp313' -> '3.13'), else the oldest Blender's (OLDEST_PYTHON)."""
    _, _, py, abi, _ = _tags(filename)
    if abi == "none" or abi.startswith("abi3"):
        return OLDEST_PYTHON
    if not py.startswith("cp3") or not py[3:].isdigit():
        raise ValueError(f"not a CPython 3 wheel: {filename}")
    return f"3.{py[3:]}"


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
    name, version, _, abi, plat = _tags(filename)
    pure = plat == "any"
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
        "py" if pure else "cp",
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
        if platforms and not wheel_platforms(filename) & platforms:
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
