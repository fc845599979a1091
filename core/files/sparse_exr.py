"""Writing the EXR of an almost empty atlas at the cost of its window. No bpy.

An almost empty atlas's images are `stages.PlacedImage`s: one value outside the window of its
texels. `exr.write_file` would compress every 16-row ZIP block of the whole atlas, most of them
the same rows of that one value, over and over (minutes for an 8192² SH file and its previews).
`write` asks `exr.write_file` (so with the same header, compression and bytes per block) for
the blocks that hold the window, as a file of those rows, and for one block of the background;
then it lays out the whole file: the first file's header with the atlas's data
and display windows, the offset table, and per block of the atlas its compressed bytes, the
window's or the background's. A block's bytes depend on its pixels only (ZIP compresses each
block on its own), so the file is byte for byte the one `exr.write_file` writes from the whole
images (tests/test_sparse_atlas.py compares them).

Reading it back at the cost of its window (a re-encode, a blend): `uniform_blocks` tells from the
compressed bytes alone which blocks are the file's background (every block of that one value
has the same bytes), so a reader decompresses only the others (`lightmap_files.texel_window`).
"""

from __future__ import annotations

import mmap
import struct
from collections import Counter
from pathlib import Path

import numpy as np

from ..stages import PlacedImage
from . import exr

#: Scanlines per ZIP block (OpenEXR's ZIP_COMPRESSION, what `exr.write_file` writes: `zip_exr`).
BLOCK_ROWS = 16
_MAGIC = b"\x76\x2f\x31\x01"


class _Rows:
    """Rows a … b of a PlacedImage as an image of their own, read a band at a time."""

    def __init__(self, image: PlacedImage, a: int, b: int):
        self.image, self.a, self.b = image, a, b
        self.shape, self.dtype = (b - a, image.shape[1]), image.dtype

    def __getitem__(self, key: slice) -> np.ndarray:
        start, stop, _ = key.indices(self.shape[0])
        return np.asarray(self.image[self.a + start : self.a + stop])


def placed_rows(channels: dict) -> tuple[int, int] | None:
    """The rows (EXR order, a, b) of the window the images of `channels` share, when every one is
    a `PlacedImage` of one window (and orientation) and the window leaves whole ZIP blocks out;
    else None (write them as any image)."""
    images = list(channels.values())
    if not images or not all(isinstance(a, PlacedImage) for a in images):
        return None
    first = images[0]
    if any(a.window != first.window or a.flipped != first.flipped for a in images):
        return None
    h = first.shape[0]
    w = first.window
    a = h - w.y0 - w.h if first.flipped else w.y0
    a, b = a // BLOCK_ROWS * BLOCK_ROWS, min(-(-(a + w.h) // BLOCK_ROWS) * BLOCK_ROWS, h)
    return None if (a, b) == (0, h) else (a, b)


def write(path, channels: dict, attributes: dict | None, rows: tuple[int, int], write_file, rows_done=None) -> None:
    """Write `channels` (PlacedImages of one window, `placed_rows` gave `rows`) to `path` as
    `write_file` (`exr.write_file`) would write them, compressing only the window's blocks and
    one block of the background (and the last, shorter block of the atlas, if it has one); the
    rows it writes are checked for NaN and infinity as `write_file` checks them. `rows_done(done,
    of)`: `write_file`'s, for the window's rows (the rest is a block or two)."""
    path = Path(path)
    height, width = next(iter(channels.values())).shape
    a, b = rows
    tail = height % BLOCK_ROWS
    parts = {"window": (a, b)}
    full = range(0, height - tail, BLOCK_ROWS)  # the atlas's whole blocks; then one of `tail` rows
    background = next((r for r in full if r + BLOCK_ROWS <= a or r >= b), None)
    if background is not None:  # a block all of the background
        parts["background"] = (background, background + BLOCK_ROWS)
    if tail and height - tail >= b:
        parts["tail"] = (height - tail, height)
    chunks, header = {}, None
    for name, (r0, r1) in parts.items():
        tmp = exr._temporary_name(exr.target_of(path))  # a temporary of the same file (its messages name it)
        try:
            write_file(
                tmp,
                {n: _Rows(image, r0, r1) for n, image in channels.items()},
                attributes,
                rows_done if name == "window" else None,
            )
            data = tmp.read_bytes()
        finally:
            tmp.unlink(missing_ok=True)
        file_header, blocks = _parse(data, -(-(r1 - r0) // BLOCK_ROWS))
        chunks[name] = blocks
        if name == "window":
            header = file_header
    assert header is not None
    header = _with_windows(header, width, height)
    count = -(-height // BLOCK_ROWS)
    body = []
    for i in range(count):
        y = i * BLOCK_ROWS
        if a <= y < b:
            data = chunks["window"][(y - a) // BLOCK_ROWS]
        elif tail and y == height - tail:
            data = chunks["tail"][0]
        else:
            data = chunks["background"][0]
        body.append(struct.pack("<ii", y, len(data)) + data)
    offsets, at = [], len(header) + 8 * count
    for chunk in body:
        offsets.append(at)
        at += len(chunk)
    with open(path, "wb") as f:
        f.write(header)
        f.write(struct.pack(f"<{count}Q", *offsets))
        for chunk in body:
            f.write(chunk)


def _parse(data: bytes, count: int) -> tuple[bytes, list[bytes]]:
    """A single-part scanline EXR's magic, version and header (through its terminating null) and
    its `count` blocks' compressed bytes, in order."""
    if data[:4] != _MAGIC:
        raise ValueError("not an EXR file")
    at = 8
    while data[at] != 0:  # attributes: name\0 type\0 size value
        at = data.index(b"\0", at) + 1
        at = data.index(b"\0", at) + 1
        (size,) = struct.unpack_from("<i", data, at)
        at += 4 + size
    at += 1
    header = data[:at]
    offsets = struct.unpack_from(f"<{count}Q", data, at)
    blocks = []
    for offset in offsets:
        _, size = struct.unpack_from("<ii", data, offset)
        blocks.append(data[offset + 8 : offset + 8 + size])
    return header, blocks


def _with_windows(header: bytes, width: int, height: int) -> bytes:
    """`header` with its dataWindow and displayWindow set to the whole `width` × `height`."""
    out = bytearray(header)
    at = 8
    while out[at] != 0:
        end = out.index(b"\0", at)
        name = bytes(out[at:end])
        at = out.index(b"\0", end + 1) + 1
        (size,) = struct.unpack_from("<i", out, at)
        if name in (b"dataWindow", b"displayWindow"):
            struct.pack_into("<iiii", out, at + 4, 0, 0, width - 1, height - 1)
        at += 4 + size
    return bytes(out)


#: OpenEXR's ZIP_COMPRESSION (16 scanlines per block), the header's compression byte.
_ZIP = 3
#: Version-field flags of a file that is not one single-part scanline image (tiled, deep, multi-part).
_NOT_SCANLINE = 0x200 | 0x800 | 0x1000


def uniform_blocks(path) -> tuple[tuple[int, int], np.ndarray] | None:
    """The (height, width) of a single-part scanline ZIP EXR (what `exr.write_file` writes) and,
    per ZIP block (BLOCK_ROWS scanlines, EXR order), whether its compressed bytes are those of
    the block most blocks share (the background of an almost empty atlas's file, or a whole
    atlas's rows without a chart: the same pixels compress to the same bytes). Reads the offset
    table and the blocks' bytes, decompresses nothing (the blocks of that most common size
    only are compared). None when the file is not such a file or cannot be walked (a damaged
    one: the caller reads it whole, which says so), or no two blocks are alike."""
    try:
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return _uniform_blocks(data)
    except (OSError, ValueError, IndexError, struct.error):
        return None


def _uniform_blocks(data) -> tuple[tuple[int, int], np.ndarray] | None:
    if data[:4] != _MAGIC or data[4] != 2 or struct.unpack_from("<i", data, 4)[0] & _NOT_SCANLINE:
        return None
    at, box, compression = 8, None, None
    while data[at] != 0:  # attributes: name\0 type\0 size value
        end = data.find(b"\0", at)
        name = data[at:end]
        at = data.find(b"\0", end + 1) + 1
        (size,) = struct.unpack_from("<i", data, at)
        if name == b"dataWindow":
            box = struct.unpack_from("<iiii", data, at + 4)
        elif name == b"compression":
            compression = data[at + 4]
        at += 4 + size
    if box is None or compression != _ZIP:
        return None
    x0, y0, x1, y1 = box
    height, width = y1 - y0 + 1, x1 - x0 + 1
    count = -(-height // BLOCK_ROWS)
    offsets = struct.unpack_from(f"<{count}Q", data, at + 1)
    sizes = np.zeros(count, np.int64)
    for i, offset in enumerate(offsets):
        y, size = struct.unpack_from("<ii", data, offset)
        if y != y0 + i * BLOCK_ROWS or size <= 0 or offset + 8 + size > len(data):
            return None
        sizes[i] = size
    common = Counter(sizes.tolist()).most_common(1)[0][0]
    alike = np.flatnonzero(sizes == common)
    blocks = Counter(data[offsets[i] + 8 : offsets[i] + 8 + common] for i in alike)
    background, n = blocks.most_common(1)[0]
    if n < 2:
        return None
    same = np.zeros(count, bool)
    same[alike] = [data[offsets[i] + 8 : offsets[i] + 8 + common] == background for i in alike]
    return (height, width), same
