"""Intel Open Image Denoise's lightmap filter ("RTLightmap") through its C API (ctypes). No bpy.

We use the OIDN library Blender itself ships (no binary of our own per platform): the bpy module
has `bpy/lib/libOpenImageDenoise.so.2` (OIDN 2.5.0 in bpy 5.3, 2.3.0 in bpy 4.2), a Blender
install has it in its lib folder (Windows `blender.shared/OpenImageDenoise.dll`, macOS
`Contents/Resources/lib/`). The caller finds it (`find_library(candidate_dirs)`): core does not
know where Blender lives.

Blender builds OIDN without the RTLightmap weights: `oidnNewFilter(device, "RTLightmap")`
succeeds but `oidnCommitFilter` fails with "unsupported combination of input features". We pass
the upstream weights ourselves (`oidnSetSharedFilterData(filter, "weights", ...)`): the two
Apache-2.0 blobs in `oidn_weights/` at the extension's root, extracted hash-checked from the
official OIDN 2.5.1 binaries by `tools/fetch_oidn_weights.py` (`WEIGHTS` below is their one
definition).

    denoiser = Denoiser(find_library(dirs), threads=0)
    clean = denoiser.denoise(noisy_rgb)                 # (H, W, C) float32, HDR radiance
    clean_l1 = denoiser.denoise(l1_over_l0, directional=True)   # values in [-1, 1]

Every failure (library or weights missing, OIDN reporting an error) raises `DenoiserError`
(`DenoiserUnavailable` when nothing could be denoised at all), so a caller can report it and keep
the undenoised result.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import sys
import threading
from collections.abc import Iterable
from pathlib import Path

import numpy as np

#: The RTLightmap weight blobs (OIDN's TZA tensor archives, oidn-weights at OIDN v2.5.1,
#: Apache-2.0): mode -> (file name, SHA-256). `tools/fetch_oidn_weights.py` writes and checks them.
WEIGHTS = {
    "hdr": ("rtlightmap_hdr.tza", "5f9757cb6a3d6c966cbd50dcd0cbffef88fe78f80cb7bf45ca99bcbd4ff1292d"),
    "dir": ("rtlightmap_dir.tza", "3fa8be25ea8ef4db87d2db5b85df63cfb251ca736d1075b787c56a6cc9c8541c"),
}
#: Size in bytes of each blob.
WEIGHTS_BYTES = 1_830_792
#: Where the extension ships them: `oidn_weights/` beside `core/`.
WEIGHTS_DIR = Path(__file__).resolve().parents[3] / "oidn_weights"

#: OIDN's shared-library file name on each platform (the C API's major version is 2).
LIBRARY_NAMES = {
    "linux": ("libOpenImageDenoise.so.2", "libOpenImageDenoise.so"),
    "darwin": ("libOpenImageDenoise.2.dylib", "libOpenImageDenoise.dylib"),
    "win32": ("OpenImageDenoise.dll",),
}

# oidn.h enums
#: OIDN's scratch-memory cap per filter (its `maxMemoryMB`): beyond it OIDN tiles the image
#: itself, output bit-identical to the untiled one (its default, -1, takes memory in proportion
#: to the page at once; the trade in memory and CPU is measured in bench/results/memory.md).
MAX_MEMORY_MB = 256
_DEVICE_TYPE_CPU = 1
_FORMAT_FLOAT = 1  # FLOAT2 = 2, FLOAT3 = 3: _FORMAT_FLOAT - 1 + channels
_ERRORS = {
    1: "unknown error",
    2: "invalid argument",
    3: "invalid operation",
    4: "out of memory",
    5: "unsupported hardware",
    6: "cancelled",
}


class DenoiserError(RuntimeError):
    """OIDN failed (its own message included); the bake keeps the undenoised result."""


class DenoiserUnavailable(DenoiserError):
    """No denoising possible here: the library or the weights are missing or do not load."""


def find_library(candidate_dirs: Iterable[str | Path]) -> Path | None:
    """The first OIDN library file in `candidate_dirs` (in order; missing dirs skipped), or None."""
    names = LIBRARY_NAMES.get(sys.platform, LIBRARY_NAMES["linux"])
    for d in candidate_dirs:
        for name in names:
            path = Path(d) / name
            if path.is_file():
                return path
    return None


def load_weights(mode: str, weights_dir: Path = WEIGHTS_DIR) -> bytes:
    """The weight blob of `mode` ("hdr" or "dir"), hash-checked; DenoiserUnavailable if missing or wrong."""
    name, digest = WEIGHTS[mode]
    path = Path(weights_dir) / name
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DenoiserUnavailable(f"OIDN lightmap weights missing: {path} ({e.strerror})") from None
    if len(data) != WEIGHTS_BYTES or hashlib.sha256(data).hexdigest() != digest:
        raise DenoiserUnavailable(f"OIDN lightmap weights corrupt: {path} (SHA-256 mismatch)")
    return data


def _bind(lib: ctypes.CDLL) -> None:
    """Declare the signatures (oidn.h, OIDN 2.x) of the functions we call."""
    p, s, c = ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p
    sigs = {
        "oidnNewDevice": (p, [ctypes.c_int]),
        "oidnSetDeviceInt": (None, [p, c, ctypes.c_int]),
        "oidnCommitDevice": (None, [p]),
        "oidnReleaseDevice": (None, [p]),
        "oidnGetDeviceError": (ctypes.c_int, [p, ctypes.POINTER(c)]),
        "oidnGetDeviceInt": (ctypes.c_int, [p, c]),
        "oidnNewFilter": (p, [p, c]),
        "oidnSetSharedFilterImage": (None, [p, c, p, ctypes.c_int, s, s, s, s, s]),
        "oidnSetSharedFilterData": (None, [p, c, p, s]),
        "oidnSetFilterBool": (None, [p, c, ctypes.c_bool]),
        "oidnSetFilterFloat": (None, [p, c, ctypes.c_float]),
        "oidnSetFilterInt": (None, [p, c, ctypes.c_int]),
        "oidnCommitFilter": (None, [p]),
        "oidnExecuteFilter": (None, [p]),
        "oidnReleaseFilter": (None, [p]),
    }
    for name, (restype, argtypes) in sigs.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = restype, argtypes


class Denoiser:
    """One OIDN CPU device (created once) running RTLightmap on float32 images.

    library: path of OIDN's shared library (`find_library`); threads: OIDN's `numThreads`
    (0 = OIDN's default, every core); weights_dir: where the two weight blobs are. Raises
    DenoiserUnavailable if any of them is missing or the device does not start. Calls are
    serialised (one lock): OIDN's error state is per device and thread.
    """

    def __init__(self, library: str | Path, threads: int = 0, weights_dir: Path = WEIGHTS_DIR):
        # the blobs stay alive (and unmoved) as long as any filter may read them
        self._weights = {m: ctypes.create_string_buffer(load_weights(m, weights_dir), WEIGHTS_BYTES) for m in WEIGHTS}
        try:
            self._lib = ctypes.CDLL(str(library))
            _bind(self._lib)
        except (OSError, AttributeError) as e:
            raise DenoiserUnavailable(f"Open Image Denoise did not load from {library}: {e}") from None
        self._lock = threading.Lock()
        self._device = self._lib.oidnNewDevice(_DEVICE_TYPE_CPU)
        if not self._device:
            self._check("oidnNewDevice", unavailable=True)
            raise DenoiserUnavailable("Open Image Denoise: no CPU device")
        if threads > 0:
            self._lib.oidnSetDeviceInt(self._device, b"numThreads", int(threads))
        self._lib.oidnCommitDevice(self._device)
        self._check("device commit", unavailable=True)
        major, minor, patch = (
            self._lib.oidnGetDeviceInt(self._device, k) for k in (b"versionMajor", b"versionMinor", b"versionPatch")
        )
        self.version = f"{major}.{minor}.{patch}"
        self.library = Path(library)

    def _check(self, what: str, unavailable: bool = False) -> None:
        """Raise OIDN's first pending error (and clear it); device may be NULL (global errors)."""
        msg = ctypes.c_char_p()
        code = self._lib.oidnGetDeviceError(self._device, ctypes.byref(msg))
        if code:
            text = msg.value.decode(errors="replace") if msg.value else _ERRORS.get(code, f"error {code}")
            raise (DenoiserUnavailable if unavailable else DenoiserError)(f"Open Image Denoise, {what}: {text}")

    def close(self) -> None:
        if getattr(self, "_device", None):
            self._lib.oidnReleaseDevice(self._device)
            self._device = None

    def __del__(self) -> None:
        self.close()

    def denoise(self, image: np.ndarray, directional: bool = False, input_scale: float | None = None) -> np.ndarray:
        """RTLightmap on `image` (H, W, C), C in 1..3, float32 (other floats converted).

        HDR mode (default): linear radiance >= 0, any unit (`input_scale` maps it to OIDN's
        units, 1 = 100 cd/m^2; None = OIDN's auto-exposure, which differs per image: set it once
        per atlas when denoising crops). Directional mode: SH coefficients with L0 divided out,
        in [-1, 1] (`input_scale` maps another range there; the output is not rescaled).
        Non-finite inputs are taken as 0; an all-zero image comes back as zeros without running OIDN
        (which would leave ~3% of 1/`input_scale` in its corner pixels). A strided view (e.g. `rgba[..., :3]`, 16-byte pixels)
        is read in place when already finite. Returns a new (H, W, C) float32 array, all finite.
        A 4-channel image is refused: pass its RGB view. Pixels are independent of row order.
        """
        if image.ndim != 3 or not 1 <= image.shape[2] <= 3:
            raise ValueError(f"RTLightmap takes an (H, W, C) image with 1-3 channels, not shape {image.shape}")
        h, w, c = image.shape
        if h == 0 or w == 0:
            return np.zeros((h, w, c), np.float32)
        src = image
        if (
            src.dtype != np.float32
            or src.strides[2] != 4
            or src.strides[1] < 4 * c
            or src.strides[0] < src.strides[1] * w
            or not np.isfinite(src).all()
        ):
            src = np.nan_to_num(np.ascontiguousarray(image, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        if not src.any():  # all black: nothing to denoise (the network would add a faint floor at the corners)
            return np.zeros((h, w, c), np.float32)
        out = np.empty((h, w, c), np.float32)
        fmt = _FORMAT_FLOAT - 1 + c
        lib = self._lib
        with self._lock:
            if not self._device:
                raise DenoiserError("Open Image Denoise: the denoiser was closed")
            filt = lib.oidnNewFilter(self._device, b"RTLightmap")
            if not filt:
                self._check("new RTLightmap filter", unavailable=True)
                raise DenoiserUnavailable("Open Image Denoise has no RTLightmap filter")
            try:
                weights = self._weights["dir" if directional else "hdr"]
                lib.oidnSetSharedFilterData(filt, b"weights", ctypes.addressof(weights), WEIGHTS_BYTES)
                lib.oidnSetSharedFilterImage(
                    filt, b"color", src.ctypes.data, fmt, w, h, 0, src.strides[1], src.strides[0]
                )
                lib.oidnSetSharedFilterImage(filt, b"output", out.ctypes.data, fmt, w, h, 0, 4 * c, 4 * c * w)
                lib.oidnSetFilterBool(filt, b"directional", bool(directional))
                scale = math.nan if input_scale is None else float(input_scale)
                lib.oidnSetFilterFloat(filt, b"inputScale", scale)
                lib.oidnSetFilterInt(filt, b"maxMemoryMB", MAX_MEMORY_MB)
                self._check("filter parameters")
                lib.oidnCommitFilter(filt)
                self._check("filter commit")
                lib.oidnExecuteFilter(filt)
                self._check("filter execute")
            finally:
                lib.oidnReleaseFilter(filt)
        return np.nan_to_num(out, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
