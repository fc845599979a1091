"""A single-part scanline EXR with ZIP compression, laid out and compressed here on several
threads. No bpy.

OpenEXR's own writer (the Python binding's `OutputFile.writePixels`) compresses on one core
whatever its thread pool, and holds the GIL while it does. Here each 16-line block is packed and
predicted with numpy and deflated (`deflate`: ISA-L's deflate from the bundled `isal` wheel, or
Python's zlib where it is missing) on a pool of threads, and the file is laid out as OpenEXR
lays it out (openexr.com, "OpenEXR File Layout"):

* the magic number and version (2; the long-names flag when a name has 32 bytes or more),
* the header: attributes `name\\0 type\\0 int32 size, value`, sorted by name as OpenEXR sorts
  them (byte order), ended by a null byte; the attributes and their values are those the
  binding's writer records (tests/test_exr_write.py compares the headers byte for byte),
* the offset table: one uint64 file offset per block,
* per block `int32 y, int32 size`, then its bytes.

A ZIP block holds BLOCK_ROWS scanlines (fewer in the last): for each scanline, for each channel
in the header's (sorted) order, that line's pixels little-endian. OpenEXR then reorders the
bytes (the even-indexed ones, then the odd-indexed ones), replaces each byte but the first by
its difference from the previous one plus 128 (mod 256), and deflates the result with a zlib
header (OpenEXRCore's internal_zip.c, `internal_zip_deconstruct_bytes` / `apply_zip_impl`). A
block whose deflated bytes are not fewer than its raw bytes is stored raw; every reader
(OpenEXR, tinyexr, FFmpeg) takes a block whose size is the raw size as stored raw. Deflating
with ISA-L or zlib instead of OpenEXR's libdeflate gives other bytes that inflate to the same
data (a zlib stream either way: any inflater reads it).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

#: Scanlines per ZIP block (OpenEXR's ZIP_COMPRESSION).
BLOCK_ROWS = 16


def _deflater() -> tuple[Callable[[Any, int], bytes], int, str]:
    """The block compressor, its level and its name: ISA-L's zlib stream (`isal.isal_zlib`, level 2
    of its 0-3) where the wheel is installed, else Python's zlib at level 3 (OpenEXR's default is
    libdeflate's 4). The choices, their sizes and seconds: bench/results/exr_write.md."""
    try:
        from isal import isal_zlib
    except ImportError:
        return zlib.compress, 3, "zlib"
    return isal_zlib.compress, 2, "isal"


#: `compress_block`'s deflate, its level, and which it is ("isal" or "zlib").
deflate, ZIP_LEVEL, DEFLATER = _deflater()
MAGIC = b"\x76\x2f\x31\x01"
_VERSION = 2
_LONG_NAMES = 0x400
#: The longest name OpenEXR reads (attribute, type or channel name, bytes).
_MAX_NAME = 255
#: OpenEXR's pixel type of each stored dtype (its `PixelType` numbers).
PIXEL_TYPES = {np.dtype(np.float16): 1, np.dtype(np.float32): 2}
#: The attributes the writer sets itself in every scanline file's header (OpenEXR's `standard_attributes`):
#: `header` refuses them as extra attributes.
STANDARD = (
    "channels",
    "compression",
    "dataWindow",
    "displayWindow",
    "lineOrder",
    "pixelAspectRatio",
    "screenWindowCenter",
    "screenWindowWidth",
    "type",
)


def _name(name: str, what: str) -> bytes:
    data = name.encode("utf-8")
    if not data or b"\0" in data or len(data) > _MAX_NAME:
        raise ValueError(f"EXR {what} name {name!r}: 1 to {_MAX_NAME} bytes of UTF-8 without a null byte")
    return data


def header(channels: dict[str, np.dtype], width: int, height: int, attributes: dict[str, str]) -> bytes:
    """The magic number, version and header of a `width` × `height` scanline ZIP file of
    `channels` (name → float16 or float32) with the string `attributes`, as OpenEXR writes them
    (data and display window (0, 0) … (width - 1, height - 1), increasing y, square pixels)."""
    chlist = b"".join(
        name + b"\0" + struct.pack("<iB3xii", PIXEL_TYPES[np.dtype(dtype)], 0, 1, 1)
        for name, dtype in sorted((_name(n, "channel"), d) for n, d in channels.items())
    )
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    attrs = {
        b"channels": (b"chlist", chlist + b"\0"),
        b"compression": (b"compression", b"\x03"),
        b"dataWindow": (b"box2i", box),
        b"displayWindow": (b"box2i", box),
        b"lineOrder": (b"lineOrder", b"\0"),
        b"pixelAspectRatio": (b"float", struct.pack("<f", 1.0)),
        b"screenWindowCenter": (b"v2f", struct.pack("<ff", 0.0, 0.0)),
        b"screenWindowWidth": (b"float", struct.pack("<f", 1.0)),
        b"type": (b"string", b"scanlineimage"),
    }
    for key, value in attributes.items():
        if key in STANDARD:
            raise ValueError(f"EXR attribute {key!r} is one the writer sets itself")
        attrs[_name(key, "attribute")] = (b"string", value.encode("utf-8"))
    names = list(attrs) + [_name(n, "channel") for n in channels]
    version = _VERSION | (_LONG_NAMES if any(len(n) >= 32 for n in names) else 0)
    fields = b"".join(
        name + b"\0" + kind + b"\0" + struct.pack("<i", len(value)) + value
        for name, (kind, value) in sorted(attrs.items())
    )
    return MAGIC + struct.pack("<i", version) + fields + b"\0"


def predicted(lines: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """One ZIP block's raw bytes from its channels' rows (`(rows, width)` little-endian
    float16/float32, contiguous, in the header's channel order), interleaved line by line, and
    those bytes reordered and predicted (module doc): what is deflated."""
    rows = lines[0].shape[0]
    raw = np.concatenate([a.view(np.uint8).reshape(rows, -1) for a in lines], axis=1).reshape(-1)
    half = (raw.size + 1) // 2
    t = np.empty_like(raw)
    t[:half] = raw[0::2]
    t[half:] = raw[1::2]
    d = np.empty_like(t)
    d[0] = t[0]
    np.subtract(t[1:], t[:-1], out=d[1:])
    d[1:] += np.uint8(128)  # mod 256
    return raw, d


def compress_block(lines: list[np.ndarray], level: int) -> bytes:
    """One ZIP block's stored bytes (`predicted`'s, deflated by `deflate` at `level`), or its raw
    bytes if deflating does not shrink them."""
    raw, d = predicted(lines)
    packed = deflate(d, level)
    return packed if len(packed) < raw.size else raw.tobytes()


def compressed_blocks(bands: Iterable[list[np.ndarray]], threads: int) -> Iterator[bytes]:
    """The stored bytes of every block of `bands` (each a list of `(rows, width)` arrays as
    `compress_block` takes them, rows a multiple of BLOCK_ROWS but for the last band), in file
    order, at zlib level ZIP_LEVEL. `threads` > 1 compresses on that many threads while the next
    band is read: at most about two bands' blocks are in flight (the band being compressed and
    the one before it)."""
    level = ZIP_LEVEL
    if threads <= 1:
        for lines in bands:
            for r in range(0, lines[0].shape[0], BLOCK_ROWS):
                yield compress_block([a[r : r + BLOCK_ROWS] for a in lines], level)
        return
    pending: list[Future[bytes]] = []
    with ThreadPoolExecutor(threads, thread_name_prefix="exr-zip") as pool:
        try:
            for lines in bands:
                for r in range(0, lines[0].shape[0], BLOCK_ROWS):
                    pending.append(pool.submit(compress_block, [a[r : r + BLOCK_ROWS] for a in lines], level))
                limit = max(2 * threads, -(-lines[0].shape[0] // BLOCK_ROWS))
                while len(pending) > limit:
                    yield pending.pop(0).result()
            while pending:
                yield pending.pop(0).result()
        finally:
            for future in pending:  # an error or a cancel: what is not started is dropped
                future.cancel()


def write(path, head: bytes, height: int, blocks: Iterable[bytes]) -> None:
    """Write the file: `head` (`header`), the offset table, then each of the height / BLOCK_ROWS
    (rounded up) blocks of `blocks` as it comes. The table is filled in once every block is
    written; if `blocks` raises (a cancel) the file is left with a table of zeros."""
    count = -(-height // BLOCK_ROWS)
    offsets = np.zeros(count, "<u8")
    with open(path, "wb") as f:
        f.write(head)
        f.write(offsets.tobytes())
        at = len(head) + offsets.nbytes
        i = -1
        for i, data in enumerate(blocks):
            offsets[i] = at
            f.write(struct.pack("<ii", i * BLOCK_ROWS, len(data)))
            f.write(data)
            at += 8 + len(data)
        if i != count - 1:
            raise ValueError(f"EXR {path}: {i + 1} blocks written for {count}")
        f.seek(len(head))
        f.write(offsets.tobytes())
