"""Embree 4 through its C API: the library the embreex wheel ships, without embreex's Python layer. No bpy.

Why not embreex's own classes: its `TriangleMesh` copies a mesh into Embree one Python-indexed
float at a time with the GIL held and its `run()` copies every ray batch into a fresh float32
layout. Embree itself can share our arrays (about a hundred times faster for a large mesh; the
README has the figures) and be called per ray from compiled code. So:
- the scene is built through ctypes (`Scene`), sharing a padded float32 vertex array and a
  uint32 index array with Embree; ctypes releases the GIL, so Embree's own threads build the
  BVH while Python does other work;
- queries are numba kernels (`nogil`, cached like `core.compiled`'s sets) calling `rtcIntersect8` /
  `rtcOccluded8` once per 8 consecutive rays (a packet, `PACKET`) on an `RTCRayHit8` in a small
  aligned scratch buffer: callers put rays that start near each other next to each other (a
  texel's samples, a bake point's spokes), and Embree traverses the BVH once for the packet.
  The answers are one ray at a time's, bit for bit, but for rays that start on or graze a
  triangle within float rounding, where the packet's arithmetic may decide otherwise
  (tests/test_embree.py; bench/tracer.py measures the gain). Where the library was built
  without ray packets, `rtcIntersect1` / `rtcOccluded1` once per ray.
The library is found among embreex's installed files (`find_library`: `libembree4*.so*` on
Linux, `libembree4*.dylib` on macOS, `embree4*.dll` on Windows), after importing embreex so
that the platform's loader has already placed Embree and TBB in the process.

Ray layout (Embree 4 `RTCRayHit`, 32-bit words, 16-byte aligned): org 0–2, tnear 3, dir 4–6,
time 7, tfar 8, mask 9, id 10, flags 11; hit: Ng 12–14 (unnormalised, CCW winding), u 15, v 16,
primID 17, geomID 18, instID 19. `rtcOccluded1` reads the first 12 words and sets tfar to -inf
on a hit. A packet (`RTCRayHit8`, 32-byte aligned) holds the same fields as arrays of 8 (word
8·f + j is field f of ray j), with an int32 mask (-1: lane valid, 0: not) beside it.
"""

from __future__ import annotations

import ctypes
import importlib
import importlib.metadata
import math
import os
import re
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from . import deps
from .errors import BakeError, DependencyMissing

_LIBRARY_NAME = re.compile(r"^(lib)?embree4([-.][^/\\]*)?\.(so(\.\d+)*|dylib|dll)$")
_INVALID = 0xFFFFFFFF
_GEOMETRY_TRIANGLE = 0
_BUFFER_INDEX, _BUFFER_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_RAY_WORDS = 32  # RTCRayHit is 80–96 bytes by build options; 128 is enough
_UNBOUNDED = float(np.float32(3e38))
_CHUNK = 1 << 18  # triangles moved into a scene's frame at a time  # the length of a shadow ray towards a direction
#: Rays per packet query of the compiled kernels (`rtcIntersect8` / `rtcOccluded8`), used where
#: the library answers them (`library().packets`; else one ray per query: bench/tracer.py
#: compares the two).
PACKET = 8

_HANDLE = ctypes.c_size_t  # Embree handles and pointers, passed as integers
_ERRORS = {
    1: "unknown error",
    2: "invalid argument",
    3: "invalid operation",
    4: "out of memory",
    5: "unsupported CPU",
    6: "cancelled",
}


def find_library(paths) -> str | None:
    """The Embree 4 shared library among `paths` (a package's installed files), or None."""
    found = sorted(str(p) for p in paths if _LIBRARY_NAME.match(Path(str(p)).name))
    return found[0] if found else None


def _embreex_files() -> list[Path]:
    """embreex's installed files, absolute: from its distribution record, else its folders."""
    try:
        files = importlib.metadata.files("embreex") or []
        paths = [Path(f.locate()) for f in files]
    except importlib.metadata.PackageNotFoundError:
        paths = []
    if not paths:  # no record (copied install): look where wheels put it
        package = Path(str(deps.require("embreex").__file__)).parent
        for folder in (package, package / ".dylibs", package.parent / "embreex.libs"):
            paths += list(folder.glob("*")) if folder.is_dir() else []
    return paths


# ---- the library (loaded once per process) -----------------------------------------------------
_library: SimpleNamespace | None = None
_library_lock = threading.Lock()


def library() -> SimpleNamespace:
    """The loaded Embree library: its C functions (ctypes), one device, and the query kernels
    (compiled on first use, cached on disk). Raises DependencyMissing if embreex or numba is
    missing, or if embreex ships no Embree 4 library."""
    global _library
    with _library_lock:
        if _library is None:
            _library = _load()
    return _library


def _load() -> SimpleNamespace:
    deps.require("embreex")
    importlib.import_module("embreex.rtcore_scene")  # the platform loads Embree and TBB its way
    path = find_library(_embreex_files())
    if path is None:
        raise DependencyMissing(
            "The installed 'embreex' package ships no Embree 4 library (looked for libembree4 / "
            "embree4 among its files). Install the HHD Lightmapper build for your platform."
        )
    lib = ctypes.CDLL(path)
    c = SimpleNamespace()
    for name, restype, argtypes in (
        ("rtcNewDevice", _HANDLE, [ctypes.c_char_p]),
        ("rtcGetDeviceError", ctypes.c_int, [_HANDLE]),
        ("rtcNewScene", _HANDLE, [_HANDLE]),
        ("rtcReleaseScene", None, [_HANDLE]),
        ("rtcCommitScene", None, [_HANDLE]),
        ("rtcNewGeometry", _HANDLE, [_HANDLE, ctypes.c_int]),
        (
            "rtcSetSharedGeometryBuffer",
            None,
            [
                _HANDLE,
                ctypes.c_int,
                ctypes.c_uint,
                ctypes.c_int,
                _HANDLE,
                ctypes.c_size_t,
                ctypes.c_size_t,
                ctypes.c_size_t,
            ],
        ),
        ("rtcCommitGeometry", None, [_HANDLE]),
        ("rtcAttachGeometry", ctypes.c_uint, [_HANDLE, _HANDLE]),
        ("rtcReleaseGeometry", None, [_HANDLE]),
    ):
        function = getattr(lib, name)
        function.restype, function.argtypes = restype, argtypes
        setattr(c, name, function)
    # HHD_EMBREE_CONFIG: Embree's device configuration, e.g. "isa=avx2" pins the ISA (docs/farm.md)
    device = c.rtcNewDevice(os.environ.get("HHD_EMBREE_CONFIG", "").encode() or None)
    if not device:
        _check(c, 0, "start")
        raise BakeError("Embree could not start.")
    kernels = _compile(lib)
    return SimpleNamespace(c=c, device=device, kernels=kernels, packets=_answers_packets(c, device, kernels))


# ---- query kernels (numba) ----------------------------------------------------------------------
# Bound to numba ExternalFunctions by `_compile`: the compiled code calls Embree by symbol name,
# which keeps the kernels cacheable on disk (a raw ctypes pointer would not be).
rtc_intersect1: Any = None
rtc_occluded1: Any = None


def _ray_scratch():
    """An RTCRayHit-sized uint32 buffer, its float32 view, the word offset that makes it 16-byte
    aligned and the aligned address."""
    words = np.zeros(_RAY_WORDS + 4, np.uint32)
    base = ((16 - words.ctypes.data % 16) % 16) // 4
    return words, words.view(np.float32), base, words.ctypes.data + 4 * base


def _set_ray(f, w, b, s, origins, directions, i, tmax):
    """Ray i of origins / directions (R, 3), reaching tmax, into the scratch at word b, field k
    at word b + k·s (f, w: the scratch's float32 and uint32 views): s = 1 for an RTCRay,
    s = PACKET for lane j of a packet at b + j."""
    f[b] = origins[i, 0]
    f[b + s] = origins[i, 1]
    f[b + 2 * s] = origins[i, 2]
    f[b + 3 * s] = 0.0  # tnear: callers offset origins themselves
    f[b + 4 * s] = directions[i, 0]
    f[b + 5 * s] = directions[i, 1]
    f[b + 6 * s] = directions[i, 2]
    f[b + 7 * s] = 0.0
    f[b + 8 * s] = tmax
    w[b + 9 * s] = _INVALID  # mask: every geometry
    w[b + 10 * s] = 0
    w[b + 11 * s] = 0
    w[b + 17 * s] = _INVALID  # primID, geomID (a closest-hit query's "no hit")
    w[b + 18 * s] = _INVALID


def _store_hit(f, w, b, s, i, t, prim, ng, u, v):
    """Row i of the closest-hit outputs from the hit at word b (fields at b + k·s, `_set_ray`):
    t (inf on a miss), prim (-1), ng (zeros), u, v."""
    if w[b + 18 * s] != _INVALID:
        t[i] = f[b + 8 * s]
        prim[i] = w[b + 17 * s]
        ng[i, 0] = f[b + 12 * s]
        ng[i, 1] = f[b + 13 * s]
        ng[i, 2] = f[b + 14 * s]
        u[i] = f[b + 15 * s]
        v[i] = f[b + 16 * s]
    else:
        t[i] = np.inf
        prim[i] = -1
        ng[i, 0] = 0.0
        ng[i, 1] = 0.0
        ng[i, 2] = 0.0
        u[i] = 0.0
        v[i] = 0.0


def intersect_rays(scene, origins, directions, tmax, t, prim, ng, u, v):
    """Closest hit of each ray (R,) within [0, tmax]: writes t (inf on a miss), prim (-1), ng
    (zeros), u, v (hit = (1-u-v)·p0 + u·p1 + v·p2)."""
    w, f, b, address = _ray_scratch()
    for i in range(origins.shape[0]):
        _set_ray(f, w, b, 1, origins, directions, i, tmax[i])
        rtc_intersect1(scene, address, 0)
        _store_hit(f, w, b, 1, i, t, prim, ng, u, v)


def occluded_rays(scene, origins, directions, tmax, out):
    """Whether anything lies within [0, tmax] along each ray (Embree's any-hit query)."""
    w, f, b, address = _ray_scratch()
    for i in range(origins.shape[0]):
        _set_ray(f, w, b, 1, origins, directions, i, tmax[i])
        rtc_occluded1(scene, address, 0)
        out[i] = f[b + 8] == -np.inf


def shadow_rays(scene, origins, directions, dist, normals, offset, allowed, scale, cosine, out):
    """Next-event estimation's shadow rays, one per row i of origins (R, 3) towards a light
    along directions[i] at distance dist[i] (inf: a direction): a row whose direction lies
    above its normal (c = directions[i]·normals[i] > 0) and that `allowed` (R,) bool permits
    (no rows: every row) is traced up to dist·(1 − 1e-4) − offset (at least 0; unbounded for
    inf) with Embree's any-hit query; out[i] = scale·(c if cosine else 1) where nothing is hit,
    else 0. Returns how many rows were traced."""
    w, f, b, address = _ray_scratch()
    traced = 0
    for i in range(origins.shape[0]):
        c = directions[i, 0] * normals[i, 0] + directions[i, 1] * normals[i, 1] + directions[i, 2] * normals[i, 2]
        out[i] = 0.0
        if not c > 0.0 or (allowed.shape[0] > 0 and not allowed[i]):
            continue
        reach = dist[i] * (1.0 - 1e-4) - offset if math.isfinite(dist[i]) else _UNBOUNDED
        _set_ray(f, w, b, 1, origins, directions, i, 0.0 if reach < 0.0 else reach)
        rtc_occluded1(scene, address, 0)
        traced += 1
        if f[b + 8] != -np.inf:
            out[i] = scale * c if cosine else scale
    return traced


# A packet: RTCRayHit8's 20 fields of 8 words (instance ids and what a build may add after them
# fit in 24), then the int32 valid mask; 24·8 words keep the mask 64-byte aligned as well.
rtc_intersect8: Any = None
rtc_occluded8: Any = None
_PACKET_WORDS = 24 * PACKET


def _packet_scratch():
    """An RTCRayHit8 and its valid mask: the uint32 words, their float32 and int32 views, the
    word offsets of the (64-byte aligned) packet and of its mask, and their addresses."""
    words = np.zeros(_PACKET_WORDS + PACKET + 16, np.uint32)
    b = ((64 - words.ctypes.data % 64) % 64) // 4
    m = b + _PACKET_WORDS
    return (
        words,
        words.view(np.float32),
        words.view(np.int32),
        b,
        m,
        words.ctypes.data + 4 * b,
        words.ctypes.data + 4 * m,
    )


def _set_valid(mask, m, lanes):
    """The first `lanes` lanes of the packet valid, the others not."""
    for j in range(PACKET):
        mask[m + j] = -1 if j < lanes else 0


def intersect_packets(scene, origins, directions, tmax, t, prim, ng, u, v):
    """`intersect_rays`, 8 consecutive rays per query."""
    w, f, mask, b, m, address, valid = _packet_scratch()
    n = origins.shape[0]
    for s in range(0, n, PACKET):
        lanes = min(PACKET, n - s)
        for j in range(lanes):
            _set_ray(f, w, b + j, PACKET, origins, directions, s + j, tmax[s + j])
        _set_valid(mask, m, lanes)
        rtc_intersect8(valid, scene, address, 0)
        for j in range(lanes):
            _store_hit(f, w, b + j, PACKET, s + j, t, prim, ng, u, v)


def occluded_packets(scene, origins, directions, tmax, out):
    """`occluded_rays`, 8 consecutive rays per query."""
    w, f, mask, b, m, address, valid = _packet_scratch()
    n = origins.shape[0]
    for s in range(0, n, PACKET):
        lanes = min(PACKET, n - s)
        for j in range(lanes):
            _set_ray(f, w, b + j, PACKET, origins, directions, s + j, tmax[s + j])
        _set_valid(mask, m, lanes)
        rtc_occluded8(valid, scene, address, 0)
        for j in range(lanes):
            out[s + j] = f[b + 8 * PACKET + j] == -np.inf


def shadow_packets(scene, origins, directions, dist, normals, offset, allowed, scale, cosine, out):
    """`shadow_rays`, the traced rows gathered 8 per query (in order)."""
    w, f, mask, b, m, address, valid = _packet_scratch()
    rows = np.empty(PACKET, np.int64)
    cosines = np.empty(PACKET)
    lanes = 0
    traced = 0
    n = origins.shape[0]
    for i in range(n):
        c = directions[i, 0] * normals[i, 0] + directions[i, 1] * normals[i, 1] + directions[i, 2] * normals[i, 2]
        out[i] = 0.0
        if not c > 0.0 or (allowed.shape[0] > 0 and not allowed[i]):
            continue
        reach = dist[i] * (1.0 - 1e-4) - offset if math.isfinite(dist[i]) else _UNBOUNDED
        _set_ray(f, w, b + lanes, PACKET, origins, directions, i, 0.0 if reach < 0.0 else reach)
        rows[lanes] = i
        cosines[lanes] = c
        lanes += 1
        if lanes == PACKET:
            _shadow_packet(f, mask, b, m, address, valid, scene, lanes, rows, cosines, scale, cosine, out)
            traced += lanes
            lanes = 0
    if lanes:
        _shadow_packet(f, mask, b, m, address, valid, scene, lanes, rows, cosines, scale, cosine, out)
        traced += lanes
    return traced


def _shadow_packet(f, mask, b, m, address, valid, scene, lanes, rows, cosines, scale, cosine, out):
    """Traces the packet's first `lanes` shadow rays; out[rows[j]] = scale·(cosines[j] or 1)
    for those that reach their light."""
    _set_valid(mask, m, lanes)
    rtc_occluded8(valid, scene, address, 0)
    for j in range(lanes):
        if f[b + 8 * PACKET + j] != -np.inf:
            out[rows[j]] = scale * cosines[j] if cosine else scale


def _compile(lib) -> SimpleNamespace:
    numba = deps.require("numba")
    from llvmlite import binding as llvm
    from numba import types

    module = globals()
    for symbol, name, arguments in (
        ("rtcIntersect1", "rtc_intersect1", 3),
        ("rtcOccluded1", "rtc_occluded1", 3),
        ("rtcIntersect8", "rtc_intersect8", 4),
        ("rtcOccluded8", "rtc_occluded8", 4),
    ):
        llvm.add_symbol(symbol, ctypes.cast(getattr(lib, symbol), ctypes.c_void_p).value)
        module[name] = types.ExternalFunction(symbol, types.void(*[types.uintp] * arguments))
    jit = numba.njit(nogil=True, cache=True)
    module["_ray_scratch"] = jit(_ray_scratch)
    module["_packet_scratch"] = jit(_packet_scratch)
    # called per ray or packet: compiled without reference counting (they make no array), else
    # each call counts the arrays it is passed up and down atomically (`core.compiled`)
    for helper in (_set_ray, _store_hit, _set_valid, _shadow_packet):
        module[helper.__name__] = numba.njit(nogil=True, cache=True, _nrt=False)(helper)
    return SimpleNamespace(
        intersect_rays=jit(intersect_rays),
        occluded_rays=jit(occluded_rays),
        shadow_rays=jit(shadow_rays),
        intersect_packets=jit(intersect_packets),
        occluded_packets=jit(occluded_packets),
        shadow_packets=jit(shadow_packets),
    )


def _answers_packets(c, device, kernels) -> bool:
    """Whether the library answers packet queries (Embree built with ray packets): a ray traced
    as a packet at a one-triangle scene hits it, with no error reported."""
    _check(c, device, "start")  # clear
    vertices = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0, 0], np.float32)  # + Embree's padding float
    indices = np.arange(3, dtype=np.uint32)
    scene = c.rtcNewScene(device)
    geometry = c.rtcNewGeometry(device, _GEOMETRY_TRIANGLE)
    c.rtcSetSharedGeometryBuffer(geometry, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3, vertices.ctypes.data, 0, 12, 3)
    c.rtcSetSharedGeometryBuffer(geometry, _BUFFER_INDEX, 0, _FORMAT_UINT3, indices.ctypes.data, 0, 12, 1)
    c.rtcCommitGeometry(geometry)
    c.rtcAttachGeometry(scene, geometry)
    c.rtcReleaseGeometry(geometry)
    c.rtcCommitScene(scene)
    try:
        out = np.zeros(1, np.bool_)
        origin, direction = np.array([[0.2, 0.2, 1.0]]), np.array([[0.0, 0.0, -1.0]])
        kernels.occluded_packets(scene, origin, direction, np.array([2.0]), out)
        return bool(out[0]) and c.rtcGetDeviceError(device) == 0
    finally:
        c.rtcReleaseScene(scene)


# ---- scenes -----------------------------------------------------------------------------------
class Scene:
    """An Embree scene of one triangle geometry sharing `triangles` (T, 3, 3) float32 corners
    (triangle i is primitive i), held relative to `origin` (3,) (world space minus origin, in
    float64 before rounding to float32); queries take world-space origins and subtract it. The
    BVH build starts at construction on Embree's threads; queries wait for it."""

    def __init__(self, triangles: np.ndarray, origin: np.ndarray | None = None):
        self._lib = library()
        c = self._lib.c
        tri = np.asarray(triangles).reshape(-1, 3, 3)
        n = len(tri)
        self.origin = np.zeros(3) if origin is None else np.asarray(origin, np.float64).reshape(3)
        self._moved = bool(self.origin.any())
        # Embree reads vertices with 16-byte loads: one float of padding after the last
        self._vertices = np.zeros(9 * n + 1, np.float32)
        self.triangles = self._vertices[: 9 * n].reshape(n, 3, 3)  # (T, 3, 3) float32, Embree's
        if self._moved:
            for s in range(0, n, _CHUNK):  # in float64, a chunk at a time
                self.triangles[s : s + _CHUNK] = np.asarray(tri[s : s + _CHUNK], np.float64) - self.origin
        else:
            self.triangles[:] = tri
        self.triangles.flags.writeable = False
        self._indices = np.arange(3 * n, dtype=np.uint32)
        self.handle = c.rtcNewScene(self._lib.device)
        geometry = c.rtcNewGeometry(self._lib.device, _GEOMETRY_TRIANGLE)
        c.rtcSetSharedGeometryBuffer(
            geometry, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3, self._vertices.ctypes.data, 0, 12, 3 * n
        )
        c.rtcSetSharedGeometryBuffer(geometry, _BUFFER_INDEX, 0, _FORMAT_UINT3, self._indices.ctypes.data, 0, 12, n)
        c.rtcCommitGeometry(geometry)
        c.rtcAttachGeometry(self.handle, geometry)
        c.rtcReleaseGeometry(geometry)
        _check(c, self._lib.device, "set up the ray-tracing scene")
        self._error: BakeError | None = None
        self._built = threading.Thread(target=self._commit, name="embree-build", daemon=True)
        self._built.start()

    def _commit(self) -> None:
        try:
            self._lib.c.rtcCommitScene(self.handle)
            _check(self._lib.c, self._lib.device, "build the ray-tracing scene")
        except BakeError as exc:  # Embree's error codes are per thread: read here
            self._error = exc

    def wait(self) -> None:
        """Block until the BVH is built; raises BakeError if Embree reported an error."""
        self._built.join()
        if self._error is not None:
            raise self._error

    def intersect(self, origins, directions, tmax):
        """Closest hits: (t, prim, ng, u, v) as `intersect_rays` writes them, float32/int32."""
        self.wait()
        r = len(origins)
        t = np.empty(r, np.float32)
        prim = np.empty(r, np.int32)
        ng = np.empty((r, 3), np.float32)
        u = np.empty(r, np.float32)
        v = np.empty(r, np.float32)
        self._kernel("intersect")(self.handle, self._local(origins), directions, tmax, t, prim, ng, u, v)
        return t, prim, ng, u, v

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        """(R,) bool: anything within tmax along each ray."""
        self.wait()
        out = np.empty(len(origins), np.bool_)
        self._kernel("occluded")(self.handle, self._local(origins), directions, tmax, out)
        return out

    def shadow(self, origins, directions, dist, normals, offset, allowed, scale, cosine) -> tuple[np.ndarray, int]:
        """Next-event estimation's shadow weights (R,) float64 and how many rays were traced
        (`shadow_rays`; float64 rows, `allowed` bool (R,) or no rows)."""
        self.wait()
        out = np.empty(len(origins))
        traced = self._kernel("shadow")(
            self.handle,
            self._local(origins),
            directions,
            dist,
            normals,
            float(offset),
            allowed,
            float(scale),
            bool(cosine),
            out,
        )
        return out, int(traced)

    def _local(self, origins: np.ndarray) -> np.ndarray:
        """Ray origins (R, 3) in the scene's frame (float64; as given when it is the world's)."""
        if not self._moved:
            return origins
        return np.asarray(origins, np.float64) - self.origin

    def _kernel(self, query: str):
        """The compiled kernel of `query`: packets where the library answers them."""
        return getattr(self._lib.kernels, f"{query}_packets" if self._lib.packets else f"{query}_rays")

    def __del__(self):
        handle, self.handle = getattr(self, "handle", 0), 0
        if handle:
            # the last reference can die on the build thread itself (its frame holds `self`)
            if hasattr(self, "_built") and self._built is not threading.current_thread():
                self._built.join()
            self._lib.c.rtcReleaseScene(handle)


def _check(c, device, doing: str) -> None:
    """Raise BakeError if Embree reported an error on this thread since the last check."""
    code = c.rtcGetDeviceError(device)
    if code:
        raise BakeError(f"Embree could not {doing}: {_ERRORS.get(code, f'error {code}')}.")
