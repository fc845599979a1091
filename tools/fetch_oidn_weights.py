"""Extract Open Image Denoise's lightmap weights into ./oidn_weights, hash-checked.

Blender's OIDN library lacks the RTLightmap filter's trained weights (core/post/denoise/oidn.py passes them at
run time). The official OIDN 2.5.1 binaries hold them verbatim; we take them from the `pyoidn`
2.5.1.0 wheel (manylinux x86_64) on the package registry, downloaded with pip into a cache:

    python tools/fetch_oidn_weights.py [--cache build/oidn-cache]

The two blobs (`rtlightmap_hdr.tza`, `rtlightmap_dir.tza`, TZA tensor archives starting with the
bytes D7 41 02) are found in `libOpenImageDenoise_core.so.2.5.1` by scanning for the magic, taking
WEIGHTS_BYTES bytes and keeping what matches the SHA-256 pins (`core/post/denoise/oidn.py` `WEIGHTS`, their one
definition). Nothing else of the wheel is kept. A no-op when both files are present and intact.
Needs numpy (core/post/denoise/oidn.py imports it), as every tool run from the project's venvs has.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WHEEL = "pyoidn-2.5.1.0-py3-none-manylinux2014_x86_64.whl"
WHEEL_SHA256 = "32ad13368f8de1ef63001942ad05b02a00cd732d1206d97f352d3a3f606d823e"
CORE_LIBRARY = "libOpenImageDenoise_core.so.2.5.1"  # inside the wheel, under pyoidn/oidn/lib/
TZA_MAGIC = b"\xd7\x41\x02"


def _core_oidn():
    """core/post/denoise/oidn.py, loaded from its file (tools run without the package installed)."""
    spec = importlib.util.spec_from_file_location("_hhd_core_oidn", ROOT / "core" / "post" / "denoise" / "oidn.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


OIDN = _core_oidn()
DEST = OIDN.WEIGHTS_DIR


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def ready(dest: Path = DEST) -> bool:
    """Both blobs in dest with their pinned hashes."""
    for name, digest in OIDN.WEIGHTS.values():
        path = dest / name
        if not path.is_file() or sha256(path.read_bytes()) != digest:
            return False
    return True


def download_wheel(cache: Path) -> Path:
    """The pinned pyoidn wheel in cache (pip downloads it once; reruns find it there)."""
    path = cache / WHEEL
    if not path.is_file() or sha256(path.read_bytes()) != WHEEL_SHA256:
        cache.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:"]
        cmd += ["--platform", "manylinux2014_x86_64", "--dest", str(cache), "pyoidn==2.5.1.0"]
        subprocess.run(cmd, check=True)
    if not path.is_file():
        raise SystemExit(f"pip did not produce {WHEEL}: the registry's file name changed?")
    if sha256(path.read_bytes()) != WHEEL_SHA256:
        raise SystemExit(f"{WHEEL}: SHA-256 mismatch, refusing to use it")
    return path


def extract(library: bytes) -> dict[str, bytes]:
    """{file name: blob} of every pinned weight blob found in the library's bytes."""
    wanted = {digest: name for name, digest in OIDN.WEIGHTS.values()}
    found: dict[str, bytes] = {}
    at = library.find(TZA_MAGIC)
    while at >= 0 and len(found) < len(wanted):
        blob = library[at : at + OIDN.WEIGHTS_BYTES]
        name = wanted.get(sha256(blob))
        if name:
            found[name] = blob
        at = library.find(TZA_MAGIC, at + 1)
    return found


def fetch(cache: Path = ROOT / "build" / "oidn-cache", dest: Path = DEST) -> list[Path]:
    """Ensure both weight blobs are in dest (hash-checked); return their paths."""
    paths = [dest / name for name, _ in OIDN.WEIGHTS.values()]
    if ready(dest):
        return paths
    with zipfile.ZipFile(download_wheel(cache)) as z:
        member = next((n for n in z.namelist() if n.endswith("/" + CORE_LIBRARY)), None)
        if member is None:
            raise SystemExit(f"{WHEEL} holds no {CORE_LIBRARY}")
        found = extract(z.read(member))
    missing = [p.name for p in paths if p.name not in found]
    if missing:
        raise SystemExit(f"{CORE_LIBRARY}: no blob with the pinned SHA-256 for {', '.join(missing)}")
    dest.mkdir(exist_ok=True)
    for path in paths:
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(found[path.name])
        tmp.replace(path)
    if not ready(dest):
        raise SystemExit(f"the weights written to {dest} do not match their SHA-256")
    return paths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=ROOT / "build" / "oidn-cache", help="where pip keeps the wheel")
    args = ap.parse_args()
    for path in fetch(args.cache):
        print(path)


if __name__ == "__main__":
    main()
