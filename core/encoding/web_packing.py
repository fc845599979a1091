"""HHD layers as 8-bit PNG textures a browser loads (the glTF export, docs/gltf.md).

No bpy: the exporter (`bridge/gltf_export.py`), the bench (bench/gltf_packing.py), the tests and the
browser test's reference all use this module. Images are (H, W, C) arrays in **file row order**
(row 0 = the top row = EXR scanline 0 = glTF v = 0), as `core.files.exr.read` returns them.

HDR packings of I_z (RGB, ≥ 0) into RGBA8, `range` > 0 in I units (docs/gltf.md, "Packed"):

- ``rgbm``:   I = rgb · a · range
- ``rgbd``:   I = rgb / a · range / 255   (Babylon's RGBD with a range)
- ``logluv``: I from Rec.709 luminance Y = 2^(lo + (hi − lo)·L16/65535), L16 = 256·b + a bytes,
  hi = log2(range), lo = hi − LOGLUV_STOPS, and chromaticity u' = r·U_MAX, v' = g·U_MAX (CIE 1976)
- ``rgb16``:  16-bit PNG, I = rgb · range (measured only: browsers load PNGs as 8 bits)

`decode` is the reference decode; `sample_bilinear` reads a decoded image the way docs/gltf.md
asks a runtime to (decode four texels, then interpolate).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from .. import octahedral

__all__ = [
    "LOGLUV_STOPS",
    "PACKINGS",
    "CHOSEN",
    "decode",
    "decode_direction",
    "encode",
    "encode_direction",
    "png_decode",
    "png_encode",
    "sample_bilinear",
    "srgb_encode",
]

PACKINGS = ("rgbm", "rgbd", "logluv", "rgb16")
#: the packing the glTF export writes (chosen by bench/gltf_packing.py: bench/results/gltf_packing.md)
CHOSEN = "logluv"
#: dynamic range of ``logluv`` below `range`, in stops (powers of two)
LOGLUV_STOPS = 32.0
#: u' and v' of the visible gamut lie in [0, 0.62]
U_MAX = 0.62

# linear Rec.709 RGB <-> CIE XYZ (D65)
_RGB_TO_XYZ = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)
_XYZ_TO_RGB = np.linalg.inv(_RGB_TO_XYZ)


def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)


def encode(iz: np.ndarray, packing: str, range_: float) -> np.ndarray:
    """(H, W, 3) float I -> (H, W, 4) uint8 (uint16 (H, W, 3) for rgb16)."""
    x = np.clip(np.asarray(iz, dtype=np.float64), 0.0, None) / range_
    if packing == "rgb16":
        return np.clip(np.round(x * 65535.0), 0, 65535).astype(np.uint16)
    m = x.max(axis=-1)
    if packing == "rgbm":
        a = np.clip(np.ceil(m * 255.0), 1, 255) / 255.0
        rgb = x / a[..., None]
        return np.concatenate([_u8(rgb), _u8(a)[..., None]], axis=-1)
    if packing == "rgbd":
        # I/range = rgb / a / 255 with a = k/255 -> rgb = x·k; the largest k keeping rgb ≤ 1
        k = np.clip(np.floor(1.0 / np.maximum(m, 1e-30)), 1, 255)
        rgb = x * k[..., None]
        return np.concatenate([_u8(rgb), k.astype(np.uint8)[..., None]], axis=-1)
    if packing == "logluv":
        xyz = x @ _RGB_TO_XYZ.T
        y = xyz[..., 1]
        denom = xyz[..., 0] + 15.0 * xyz[..., 1] + 3.0 * xyz[..., 2]
        ok = denom > 1e-30
        u = np.where(ok, 4.0 * xyz[..., 0] / np.where(ok, denom, 1.0), 0.1978)  # D65 white
        v = np.where(ok, 9.0 * xyz[..., 1] / np.where(ok, denom, 1.0), 0.4683)
        with np.errstate(divide="ignore"):
            log_y = np.log2(np.maximum(y, 2.0 ** (-LOGLUV_STOPS - 1)))
        t = np.clip((log_y + LOGLUV_STOPS) / LOGLUV_STOPS, 0.0, 1.0)  # y is relative to range: hi = 0
        l16 = np.round(t * 65535.0).astype(np.int64)
        l16 = np.where(y > 2.0 ** (-LOGLUV_STOPS), l16, 0)  # 0 is black
        out = np.empty(x.shape[:-1] + (4,), np.uint8)
        out[..., 0] = _u8(u / U_MAX)
        out[..., 1] = _u8(v / U_MAX)
        out[..., 2] = (l16 >> 8).astype(np.uint8)
        out[..., 3] = (l16 & 255).astype(np.uint8)
        return out
    raise ValueError(f"unknown packing {packing!r}: one of {PACKINGS}")


def decode(packed: np.ndarray, packing: str, range_: float) -> np.ndarray:
    """The inverse of `encode`, per texel: (H, W, 4) uint8 -> (H, W, 3) float64 I."""
    if packing == "rgb16":
        return packed.astype(np.float64) / 65535.0 * range_
    c = packed.astype(np.float64) / 255.0
    if packing == "rgbm":
        return c[..., :3] * c[..., 3:4] * range_
    if packing == "rgbd":
        return c[..., :3] / np.maximum(c[..., 3:4], 1.0 / 255.0) * (range_ / 255.0)
    if packing == "logluv":
        l16 = packed[..., 2].astype(np.float64) * 256.0 + packed[..., 3]
        y = np.where(l16 > 0, np.exp2(l16 / 65535.0 * LOGLUV_STOPS - LOGLUV_STOPS), 0.0) * range_
        u = c[..., 0] * U_MAX
        v = np.maximum(c[..., 1] * U_MAX, 1e-6)
        xx = y * 9.0 * u / (4.0 * v)
        zz = y * (12.0 - 3.0 * u - 20.0 * v) / (4.0 * v)
        rgb = np.stack([xx, y, zz], axis=-1) @ _XYZ_TO_RGB.T
        return np.clip(rgb, 0.0, None)
    raise ValueError(f"unknown packing {packing!r}: one of {PACKINGS}")


def encode_direction(d: np.ndarray, wa: np.ndarray | None) -> np.ndarray:
    """(H, W, 3) unit directions (+ (H, W) w_a) -> (H, W, 3) uint8: RG octahedral, B w_a."""
    h, w, _ = d.shape
    e = octahedral.encode(d.reshape(-1, 3)).reshape(h, w, 2)
    b = np.zeros((h, w)) if wa is None else np.clip(wa, 0.0, 1.0)
    return np.concatenate([_u8(e * 0.5 + 0.5), _u8(b)[..., None]], axis=-1)


def decode_direction(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of `encode_direction`: (unit directions (H, W, 3), w_a (H, W))."""
    h, w, _ = rgb.shape
    c = rgb.astype(np.float64) / 255.0
    d = octahedral.decode((c[..., :2] * 2.0 - 1.0).reshape(-1, 2)).reshape(h, w, 3)
    return d, c[..., 2]


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB-encoded uint8 (glTF's base colour / emissive textures)."""
    x = np.clip(linear, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return _u8(s)


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear read of a decoded (H, W, C) image (file rows: row 0 at glTF v = 0) at glTF UVs
    (N, 2), clamp to edge, texel centres at ((x + ½)/W, (y + ½)/H): what a runtime computes
    by decoding the four texels and interpolating."""
    h, w = image.shape[:2]
    x = np.clip(uv[:, 0] * w - 0.5, 0.0, w - 1.0)
    y = np.clip(uv[:, 1] * h - 0.5, 0.0, h - 1.0)
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


# --- PNG, numpy + zlib only ---------------------------------------------------------------


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png_encode(image: np.ndarray, srgb: bool = False) -> bytes:
    """(H, W, C) uint8 or uint16, C in 1..4 -> PNG bytes, rows as given (row 0 = top). Each row
    filtered with the PNG filter (None, Sub, Up) that leaves the smallest sum of bytes. Linear
    data carries no colour chunk... except `srgb=True`, which adds sRGB (the emissive fallback)."""
    img = np.ascontiguousarray(image)
    if img.ndim == 2:
        img = img[..., None]
    h, w, c = img.shape
    depth = 16 if img.dtype == np.uint16 else 8
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    raw = img.astype(">u2").view(np.uint8).reshape(h, -1) if depth == 16 else img.reshape(h, -1)
    bpp = c * depth // 8
    raw = raw.astype(np.int16)
    sub = raw.copy()
    sub[:, bpp:] -= raw[:, :-bpp]
    up = raw.copy()
    up[1:] -= raw[:-1]
    cands = [raw & 255, sub & 255, up & 255]
    cost = np.stack([np.minimum(cd, 256 - cd).sum(axis=1) for cd in cands])
    best = cost.argmin(axis=0)
    rows = np.stack(cands)[best, np.arange(h)].astype(np.uint8)
    data = np.concatenate([best.astype(np.uint8)[:, None], rows], axis=1).tobytes()
    out = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour_type, 0, 0, 0))
    if srgb:
        out += _chunk(b"sRGB", b"\x00")
    return out + _chunk(b"IDAT", zlib.compress(data, 9)) + _chunk(b"IEND", b"")


def png_decode(blob: bytes) -> np.ndarray:
    """PNG bytes (8 or 16 bit, grey/GA/RGB/RGBA, not interlaced) -> (H, W, C) uint8/uint16."""
    assert blob[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat = 8, b""
    while pos < len(blob):
        (n,) = struct.unpack(">I", blob[pos : pos + 4])
        kind = blob[pos + 4 : pos + 8]
        data = blob[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, colour_type, _, _, interlace = struct.unpack(">IIBBBBB", data)
            assert interlace == 0 and depth in (8, 16)
        elif kind == b"IDAT":
            idat += data
        pos += 12 + n
    c = {0: 1, 4: 2, 2: 3, 6: 4}[colour_type]
    bpp = c * depth // 8
    stride = w * bpp
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, stride + 1)
    out = np.zeros((h, stride), np.uint8)
    prev = np.zeros(stride, np.int32)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) & 255
        elif f == 1:
            cur = (np.cumsum(line.reshape(-1, bpp), axis=0) & 255).reshape(-1)
        else:
            cur = np.zeros(stride, np.int32)
            for x in range(stride):
                a = cur[x - bpp] if x >= bpp else 0
                b = prev[x]
                cc = prev[x - bpp] if x >= bpp else 0
                if f == 1:
                    pred = a
                elif f == 3:
                    pred = (a + b) // 2
                else:
                    p = a + b - cc
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - cc)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else cc)
                cur[x] = (line[x] + pred) & 255
        out[y] = cur
        prev = cur
    if depth == 16:
        return out.view(">u2").astype(np.uint16).reshape(h, w, c)
    return out.reshape(h, w, c)
