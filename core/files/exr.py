"""OpenEXR reading and writing with atomic replacement. No bpy.

Images are `(height, width)` arrays per channel in EXR scanline order: row 0 is the top of the
image (as every viewer shows it). Blender's image rows run bottom-up, so lightmap texel (x, y)
with y = v · height lives in EXR row `height - 1 - y`; `to_exr_rows` / `from_exr_rows` convert.

Writes never leave a half-written file under the final name: the data goes to a temporary file
in the same folder, which is then renamed over the target (`os.replace` is atomic on one file
system). `Staging` extends this to a set of files that must all be replaced together: a bake
stages every file and renames them only once all were written. A temporary's name carries the
host and process id of its writer (`.<name>.<host>-<pid>.<8 hex>.tmp`), so a process killed
before it could delete its temporaries (SIGKILL, a power cut) leaves files the next `Staging`
in that folder recognises as stale and removes; a live process's are never touched.

No writer here stores a non-finite value: `write_file` refuses a channel holding NaN or
infinity and `Staging.write_json` a document holding one (`NonFiniteValue`, naming the file
and the channel or key), so no file the bake writes can hold one.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import socket
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .. import deps, parallel
from ..errors import BakeError
from . import zip_exr


def to_exr_rows(image: np.ndarray, copy: bool = True) -> np.ndarray:
    """Bottom-up texel rows (row y = v · height) to EXR's top-down scanlines: a contiguous copy,
    or without `copy` a view (rows reversed; `write_file` takes it as it is)."""
    return np.ascontiguousarray(image[::-1]) if copy else image[::-1]


def from_exr_rows(image: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(image[::-1])


class NonFiniteValue(BakeError):
    """A writer was handed NaN or infinity: refused, the file is not written (the previous one
    stays). Upstream validation should make this unreachable; the message names the file and
    the channel or key."""


def _host() -> str:
    """This machine's name as it may appear in a temporary's name (letters, digits, '-')."""
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())[:40] or "host"


#: `.<target>.<host>-<pid>.<8 hex>.tmp`; before the host was recorded `.<target>.<pid>.<8 hex>.tmp`.
_TEMPORARY = re.compile(r"^\.(?P<target>.+)\.(?:(?P<host>[A-Za-z0-9-]+)-)?(?P<pid>\d+)\.[0-9a-f]{8}\.tmp$")


def _temporary_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.{_host()}-{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")


def target_of(path) -> Path:
    """The file a temporary (`_temporary_name`) is written for; any other path as it is."""
    path = Path(path)
    match = _TEMPORARY.match(path.name)
    return path.with_name(match["target"]) if match else path


def _process_exists(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):  # another user's live process; a pid out of range
        return True
    return True


def remove_stale_temporaries(folder) -> list[Path]:
    """Delete the temporaries in `folder` (not its subfolders) left by writers on this machine
    whose process no longer exists; returns them. Another host's temporaries (a shared folder)
    and a live process's are left alone."""
    removed: list[Path] = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    host = _host()
    for name in names:
        match = _TEMPORARY.match(name)
        if match is None or (match["host"] is not None and match["host"] != host):
            continue
        if _process_exists(int(match["pid"])):
            continue
        path = Path(folder) / name
        try:
            path.unlink()
            removed.append(path)
        except OSError:
            pass
    return removed


def _check_finite(path, name: str, data: np.ndarray) -> None:
    if not np.isfinite(data).all():
        raise NonFiniteValue(
            f"refused to write {target_of(path)}: channel {name!r} holds NaN or infinity (a bug upstream: "
            "please report it; the previous file is intact)"
        )


def set_threads(threads: int) -> None:
    """Compress and decompress with `threads` workers (≥ 1; 1 = on the calling thread), in this
    process from now on: `write_file`'s ZIP blocks (its pool, when not given `threads`) and the
    OpenEXR binding's process-wide pool, which its reads use (not Blender's own OpenEXR). ZIP
    blocks are compressed independently, so the bytes written do not depend on it."""
    global _write_threads
    _write_threads = max(1, threads)
    openexr = deps.require("OpenEXR")
    count = threads if threads > 1 else 0  # 0: OpenEXR's single-threaded mode
    if openexr.global_thread_count() != count:
        openexr.set_global_thread_count(count)


#: `write_file`'s compression threads when not given any (`set_threads`; every core until then).
_write_threads = parallel.machine_threads()

#: Scanlines read per band when writing (a multiple of ZIP's 16-line blocks): the memory a write
#: adds is about two bands of rows of every channel (one read, one being compressed) and their
#: compressed blocks, whatever the image size.
WRITE_ROWS = 64


def write_file(
    path,
    channels: dict[str, np.ndarray],
    attributes: dict | None = None,
    rows_done: Callable[[int, int], None] | None = None,
    threads: int | None = None,
) -> None:
    """Write one scanline EXR (ZIP compression) directly to `path`. Channel arrays are
    `(height, width)` float16 (HALF) or float32 (FLOAT), any strides (views of larger arrays,
    rows reversed, `stages.PlacedImage`, `encoding.filled` images: nothing is copied whole),
    every value finite (else NonFiniteValue naming the file and channel, raised before that
    band is written: no file holds NaN or infinity); `attributes` are string header fields.

    Read WRITE_ROWS scanlines at a time and compressed on `threads` threads (default: the count
    `set_threads` set) by `zip_exr`, which lays the file out as OpenEXR's writer does: the same
    header, byte for byte, and blocks any reader decompresses to the same pixels
    (tests/test_exr_write.py). An almost empty atlas's images (`stages.PlacedImage`) compress
    their window's blocks only (`sparse_exr`), the same bytes. `rows_done(done, of)`, if given,
    is called after each band of rows is handed to the compressors (progress; it may raise to
    cancel: the file is then left half-written, as a staged temporary is)."""
    from . import sparse_exr

    window_rows = sparse_exr.placed_rows(channels)
    if window_rows is not None:
        return sparse_exr.write(path, channels, attributes, window_rows, write_file, rows_done)
    shapes = {np.shape(data) for data in channels.values()}
    for name, data in channels.items():
        if data.dtype not in zip_exr.PIXEL_TYPES:
            raise TypeError(f"EXR channel {name!r}: store float16 or float32, not {data.dtype}")
    if len(shapes) != 1 or len(next(iter(shapes))) != 2 or 0 in next(iter(shapes)):
        raise ValueError(f"EXR channels must be (height, width) images of one size, got {sorted(shapes)}")
    height, width = next(iter(shapes))
    names = sorted(channels, key=lambda n: n.encode("utf-8"))  # the header's order
    head = zip_exr.header(
        {n: channels[n].dtype for n in names}, width, height, {k: str(v) for k, v in (attributes or {}).items()}
    )

    def bands():
        for start in range(0, height, WRITE_ROWS):
            band = slice(start, min(start + WRITE_ROWS, height))
            lines = []
            for name in names:  # band by band: no image-sized mask
                data = channels[name]
                rows = np.ascontiguousarray(data[band], dtype=data.dtype.newbyteorder("<"))
                _check_finite(path, name, rows)
                lines.append(rows)
            yield lines
            if rows_done is not None:
                rows_done(band.stop, height)

    zip_exr.write(path, head, height, zip_exr.compressed_blocks(bands(), threads or _write_threads))


def write(path, channels: dict[str, np.ndarray], attributes: dict | None = None) -> None:
    """Write `path` atomically: a reader sees the previous file or the new one, never a part."""
    with Staging() as staging:
        write_file(staging.stage(path), channels, attributes)
        staging.commit()


def _unreadable(path, exc: Exception) -> BakeError:
    """The BakeError of a file the binding could not read (it raises plain exceptions, ValueError,
    RuntimeError, TypeError, for corrupt files)."""
    if isinstance(exc, OSError) and exc.errno in (errno.EACCES, errno.EPERM):
        return BakeError(f"cannot read {path}: permission denied (fix the file's permissions)")
    return BakeError(f"cannot read {path}: the file is damaged (truncated or corrupt): bake again")


def read(path) -> tuple[dict[str, np.ndarray], dict]:
    """Channels `{name: (height, width) array}` (float16 or float32 as stored) and the header."""
    openexr = deps.require("OpenEXR")
    if not Path(path).is_file():
        raise BakeError(f"EXR file not found: {path} (bake again)")
    try:
        f = openexr.File(str(path), separate_channels=True)
        channels = {name: ch.pixels for name, ch in f.channels().items()}
        header = dict(f.header())
    except Exception as exc:
        raise _unreadable(path, exc) from None
    if not channels or any(getattr(a, "ndim", 0) != 2 for a in channels.values()):
        raise BakeError(f"cannot read {path}: the file is damaged (no image channels): bake again")
    return channels, header


#: Scanlines decompressed per call of a windowed read (`read_window`, a multiple of ZIP's 16-line
#: blocks): the memory it adds is this many whole rows of the channels it reads.
READ_ROWS = 32


def shape_of(path) -> tuple[tuple[int, int], dict[str, np.dtype]]:
    """The (height, width) of a scanline EXR and its channels' stored dtypes, from its header
    only (no pixel is read)."""
    openexr = deps.require("OpenEXR")
    if not Path(path).is_file():
        raise BakeError(f"EXR file not found: {path} (bake again)")
    try:
        f = openexr.InputFile(str(path))
        try:
            header = f.header()
        finally:
            f.close()
        box = header["dataWindow"]
        shape = (box.max.y - box.min.y + 1, box.max.x - box.min.x + 1)
        dtypes = {name: _DTYPES[str(ch.type)] for name, ch in header["channels"].items()}
    except Exception as exc:
        raise _unreadable(path, exc) from None
    if not dtypes or min(shape) <= 0:
        raise BakeError(f"cannot read {path}: the file is damaged (no image channels): bake again")
    return shape, dtypes


_DTYPES: dict[str, np.dtype] = {
    "HALF": np.dtype(np.float16),
    "FLOAT": np.dtype(np.float32),
    "UINT": np.dtype(np.uint32),
}


def read_window(path, names: list[str], rows: tuple[int, int], cols: tuple[int, int]) -> dict[str, np.ndarray]:
    """Channels `names` of EXR rows a … b (top-down scanlines) and columns x0 … x1 only, as
    `{name: (b - a, x1 - x0) array}` of the stored dtype (the bits of `read`'s). Read
    READ_ROWS scanlines at a time through the binding's scanline reader (`OpenEXR.InputFile`:
    OpenEXR decompresses only the ZIP blocks holding those rows), so memory and time follow the
    window, not the file. BakeError as `read` for a missing or damaged file."""
    openexr = deps.require("OpenEXR")
    import Imath  # the OpenEXR wheel's own module of header types

    (a, b), (x0, x1) = rows, cols
    if not Path(path).is_file():
        raise BakeError(f"EXR file not found: {path} (bake again)")
    try:
        f = openexr.InputFile(str(path))
        try:
            header = f.header()
            ymin, width = header["dataWindow"].min.y, header["dataWindow"].max.x - header["dataWindow"].min.x + 1
            stored = {name: str(header["channels"][name].type) for name in names}
            out = {name: np.empty((b - a, x1 - x0), _DTYPES[t]) for name, t in stored.items()}
            for kind in dict.fromkeys(stored.values()):  # one call per stored type: each block decompressed once
                group = [name for name, t in stored.items() if t == kind]
                pixel = Imath.PixelType(getattr(Imath.PixelType, kind))
                for start in range(a, b, READ_ROWS):
                    stop = min(start + READ_ROWS, b)
                    band = f.channels(group, pixel, ymin + start, ymin + stop - 1)
                    for name, data in zip(group, band):
                        rows_of = np.frombuffer(data, _DTYPES[kind]).reshape(stop - start, width)
                        out[name][start - a : stop - a] = rows_of[:, x0:x1]
        finally:
            f.close()
    except BakeError:
        raise
    except Exception as exc:
        raise _unreadable(path, exc) from None
    return out


def _non_finite_key(doc, where: str = "") -> str:
    """The key path ('bake.time_budget') of the first non-finite number in `doc`, or ''."""
    if isinstance(doc, float) and not math.isfinite(doc):
        return where or "the document"
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list | tuple) else ()
    for key, value in items:
        found = _non_finite_key(value, f"{where}.{key}" if where else str(key))
        if found:
            return found
    return ""


class Staging:
    """Files written under temporary names and renamed over their targets together.

    `stage(path)` returns the temporary path to write; `commit()` renames every staged file onto
    its target; leaving the `with` block without commit (an error, a cancel) deletes the
    temporaries and leaves every existing target untouched."""

    def __init__(self):
        self._staged: list[tuple[Path, Path]] = []
        self._swept: set[Path] = set()

    def stage(self, path) -> Path:
        """The temporary to write for `path`; the first file staged in a folder first removes
        the stale temporaries there (`remove_stale_temporaries`)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.parent not in self._swept:
            self._swept.add(path.parent)
            remove_stale_temporaries(path.parent)
        tmp = _temporary_name(path)
        self._staged.append((tmp, path))
        return tmp

    def write_text(self, path, text: str) -> None:
        self.stage(path).write_text(text, encoding="utf-8")

    def write_json(self, path, doc, **options) -> None:
        """Stage `doc` as JSON (strict: NonFiniteValue naming the key instead of writing NaN or
        Infinity, which JSON does not have); `options` go to json.dumps (indent, ensure_ascii)."""
        try:
            text = json.dumps(doc, allow_nan=False, **options)
        except ValueError:
            raise NonFiniteValue(
                f"refused to write {path}: {_non_finite_key(doc) or 'a value'} is NaN or infinity (a bug upstream: "
                "please report it; the previous file is intact)"
            ) from None
        self.write_text(path, text)

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
