"""OpenEXR reading and writing with atomic replacement. No bpy.

Images are `(height, width)` arrays per channel in EXR scanline order: row 0 is the top of the
image (as every viewer shows it). Blender's image rows run bottom-up, so lightmap texel (x, y)
with y = v · height lives in EXR row `height - 1 - y`; `to_exr_rows` / `from_exr_rows` convert.

Writes never leave a half-written file under the final name: the data goes to a temporary file
in the same folder, which is then renamed over the target (`os.replace` is atomic on one file
system). `Staging` extends this to a set of files that must all be replaced together: a bake
stages every file and renames them only once all were written.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import numpy as np

from . import deps
from .errors import BakeError

#: Largest finite half-float value.
HALF_MAX = 65504.0


def fits_half(values: np.ndarray) -> bool:
    """True when every finite value is within the half-float range (so nothing would clip to
    infinity). Values below half's precision lose bits but not range: that is not clipping."""
    finite = np.asarray(values)[np.isfinite(values)]
    return finite.size == 0 or float(np.abs(finite).max()) <= HALF_MAX


def to_exr_rows(image: np.ndarray, copy: bool = True) -> np.ndarray:
    """Bottom-up texel rows (row y = v · height) to EXR's top-down scanlines: a contiguous copy,
    or without `copy` a view (rows reversed; `write_file` takes it as it is)."""
    return np.ascontiguousarray(image[::-1]) if copy else image[::-1]


def from_exr_rows(image: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(image[::-1])


def _temporary_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")


def set_threads(threads: int) -> None:
    """Compress and decompress with `threads` workers (≥ 1; 1 = on the calling thread). Sets the
    OpenEXR binding's process-wide pool, shared by every EXR read and write in this process (not
    Blender's own OpenEXR). ZIP blocks are compressed independently, so the bytes written do not
    depend on it."""
    openexr = deps.require("OpenEXR")
    count = threads if threads > 1 else 0  # 0: OpenEXR's single-threaded mode
    if openexr.global_thread_count() != count:
        openexr.set_global_thread_count(count)


#: Scanlines handed to OpenEXR per call when writing (a multiple of ZIP's 16-line blocks): the
#: memory a write adds is this many rows of every channel, whatever the image size.
WRITE_ROWS = 64


def write_file(path, channels: dict[str, np.ndarray], attributes: dict | None = None) -> None:
    """Write one scanline EXR (ZIP compression) directly to `path`. Channel arrays are
    `(height, width)` float16 (HALF) or float32 (FLOAT), any strides (views of larger arrays,
    rows reversed: nothing is copied whole); `attributes` are string header fields.

    Written WRITE_ROWS scanlines at a time through the binding's scanline writer
    (`OpenEXR.OutputFile`), so the file never exists whole in memory a second time; its bytes
    are those of the binding's whole-image writer (`OpenEXR.File(header, pixels).write`, which
    wants every channel contiguous at once): the same header attributes, the same ZIP blocks
    (tests/test_exr_write.py compares them)."""
    openexr = deps.require("OpenEXR")
    import Imath  # the OpenEXR wheel's own module of header types

    types = {np.dtype(np.float16): Imath.PixelType.HALF, np.dtype(np.float32): Imath.PixelType.FLOAT}
    shapes = {np.shape(data) for data in channels.values()}
    for name, data in channels.items():
        if data.dtype not in types:
            raise TypeError(f"EXR channel {name!r}: store float16 or float32, not {data.dtype}")
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"EXR channels must be (height, width) images of one size, got {sorted(shapes)}")
    height, width = next(iter(shapes))
    header = openexr.Header(width, height)
    header["compression"] = Imath.Compression(Imath.Compression.ZIP_COMPRESSION)
    header["channels"] = {name: Imath.Channel(Imath.PixelType(types[data.dtype])) for name, data in channels.items()}
    header["type"] = b"scanlineimage"  # as the whole-image writer records it
    header.update({k: str(v).encode("utf-8") for k, v in (attributes or {}).items()})
    out = openexr.OutputFile(str(path), header)
    try:
        for start in range(0, height, WRITE_ROWS):
            rows = slice(start, min(start + WRITE_ROWS, height))
            out.writePixels({name: data[rows].tobytes() for name, data in channels.items()}, rows.stop - start)
    finally:
        out.close()


def write(path, channels: dict[str, np.ndarray], attributes: dict | None = None) -> None:
    """Write `path` atomically: a reader sees the previous file or the new one, never a part."""
    with Staging() as staging:
        write_file(staging.stage(path), channels, attributes)
        staging.commit()


def read(path) -> tuple[dict[str, np.ndarray], dict]:
    """Channels `{name: (height, width) array}` (float16 or float32 as stored) and the header."""
    openexr = deps.require("OpenEXR")
    if not Path(path).is_file():
        raise BakeError(f"EXR file not found: {path}")
    try:
        f = openexr.File(str(path), separate_channels=True)
    except Exception as exc:  # the binding raises plain exceptions for corrupt files
        raise BakeError(f"cannot read EXR file {path}: {exc}") from exc
    channels = {name: ch.pixels for name, ch in f.channels().items()}
    return channels, dict(f.header())


class Staging:
    """Files written under temporary names and renamed over their targets together.

    `stage(path)` returns the temporary path to write; `commit()` renames every staged file onto
    its target; leaving the `with` block without commit (an error, a cancel) deletes the
    temporaries and leaves every existing target untouched."""

    def __init__(self):
        self._staged: list[tuple[Path, Path]] = []

    def stage(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _temporary_name(path)
        self._staged.append((tmp, path))
        return tmp

    def write_text(self, path, text: str) -> None:
        self.stage(path).write_text(text, encoding="utf-8")

    def staged(self, path) -> Path:
        """The temporary file staged for `path` (the latest), to read back before the commit."""
        path = Path(path)
        for tmp, target in reversed(self._staged):
            if target == path:
                return tmp
        raise KeyError(f"{path} is not staged")

    def commit(self) -> list[Path]:
        targets = []
        for tmp, path in self._staged:
            os.replace(tmp, path)
            targets.append(path)
        self._staged = []
        return targets

    def discard(self) -> None:
        for tmp, _ in self._staged:
            tmp.unlink(missing_ok=True)
        self._staged = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.discard()
        return False
