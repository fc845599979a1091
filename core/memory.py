"""Memory: who owns a bake's large arrays, and the plumbing that gives them back. No bpy.

The convention: a stage owns what it is handed. It may write into the arrays it receives and
take them (a hand-off object's array dropped from it: `TexelData.sh` emptied), and its caller
reads none of them afterwards; a caller that still needs its input hands over a copy (`keep`).
Each stage's docstring says what it does with what it owns: `TexelData.from_traced` gives the
traced SH back as it images it, the post stages (`post.apply`) and the encoded stitch write
into the images, `encoding.encode_atlas` takes the SH out of its TexelData (writing none of its
arrays: a caller keeps them by handing over a new TexelData of the same arrays,
`dataclasses.replace(data)`), `dilate.Fill.apply` fills the image it is handed.

Two stages also give back, while they run, memory their caller would otherwise hold to their end,
when it says nothing else reads it: `tracer.bake(spend_points=True)` the bake points' tracing-only
arrays behind each traced chunk (a bake's runner, which drops them after), and
`encoding.encode_atlas(release_sh=True)` the SH image behind each encoded chunk (a bake's
finishing, whose TexelData is spent; a re-encode or a test keeps its SH and passes neither).

A bake lets go of its inputs as it goes (`bake.run`): the atlases' surfaces once the bake points
are built, the scene and its Embree scene once the last atlas is traced, before its finishing
(unless probe volumes follow); its caller hands them over keeping no reference
(`bridge.bake_session.BakeSession.run`). Within a stage, what is per texel or per sample is
worked through in blocks (`row_blocks`) where a whole-array temporary would be atlas-sized or
as large as the seams (the stitch's metric and bound).

A stage failing half-way leaves what it owned spent. Where the bake goes on without it (the
denoiser failing: the SH passes through undenoised), the caller hands the stage a way to read
its input back instead of a copy (`post.apply`'s `raw_sh`: the raw SH file written first).

The plumbing: arrays whose pages go back to the system while they are alive, a part at a time
as a stage spends them (`releasable_zeros`, `release_rows`; an image zero outside the charts
is one too, its empty pages never resident), blocks of rows (`row_blocks`), and the C heap
trimmed between stages and between a stage's steps whose threads free much (`trim_heap`).
Within a stage, plain `del` drops what it no longer needs.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import mmap
import sys
from typing import TypeVar

import numpy as np

T = TypeVar("T")


def keep(x: T) -> T:
    """A copy of `x` for a stage to own while its caller keeps `x` itself: an array's copy
    (C-contiguous, in `releasable_zeros` memory: the stage may give it back a part at a time);
    a dataclass (a hand-off type: `encoding.TexelData`, `stages.TracedAtlas`) with each of its
    array fields so copied and its other fields shared (no stage writes into them)."""
    if isinstance(x, np.ndarray):
        out = releasable_zeros(x.shape, x.dtype)
        out[...] = x
        return out  # type: ignore[return-value]
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        arrays = {f.name: keep(v) for f in dataclasses.fields(x) if isinstance(v := getattr(x, f.name), np.ndarray)}
        return dataclasses.replace(x, **arrays)
    raise TypeError(f"keep takes an array or a dataclass of arrays, not {type(x).__name__}")


def releasable_zeros(shape: tuple[int, ...], dtype) -> np.ndarray:
    """np.zeros(shape, dtype), its memory a private anonymous mapping of its own where the
    platform has one (POSIX), so that `release_rows` can give whole pages of it back to the
    system while it is alive (np.zeros elsewhere: `release_rows` then does nothing). Pages are
    resident only once written, as np.zeros'."""
    nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
    private, anonymous = getattr(mmap, "MAP_PRIVATE", None), getattr(mmap, "MAP_ANONYMOUS", None)
    if nbytes < mmap.PAGESIZE or private is None or anonymous is None or not hasattr(mmap.mmap, "madvise"):
        return np.zeros(shape, dtype)
    memory = mmap.mmap(-1, nbytes, flags=private | anonymous, prot=mmap.PROT_READ | mmap.PROT_WRITE)
    return np.frombuffer(memory, dtype, count=nbytes // np.dtype(dtype).itemsize).reshape(shape)


def release_rows(a: np.ndarray, stop: int) -> None:
    """Give the system back the pages that lie wholly within rows 0..stop of `a` (made by
    `releasable_zeros`; anything else is left alone): those rows are spent, their values read
    0 afterwards (or anything: they must not be read again). Memory only; the array keeps its shape."""
    mapping = _mapping(a)
    if mapping is None or stop <= 0 or a.size == 0:
        return
    memory, start = mapping
    end = start + min(stop, len(a)) * (a.nbytes // len(a))
    first = -(-start // mmap.PAGESIZE) * mmap.PAGESIZE
    last = end // mmap.PAGESIZE * mmap.PAGESIZE
    if last > first:
        memory.madvise(mmap.MADV_DONTNEED, first, last - first)


def row_blocks(n: int, size: int) -> list[slice]:
    """Rows 0..n as consecutive blocks of nearly equal length, at most `size` (≥ 1) each, for a
    stage to work through a block at a time where its values are each row's own (the same
    whatever the block). No block is shorter than half of `size` unless all `n` rows are: numpy
    takes other paths for very few rows (a matrix product of one row is a dot product, whose
    rounding may differ)."""
    count = max(1, -(-n // size))
    bounds = [n * k // count for k in range(count + 1)]
    return [slice(a, b) for a, b in zip(bounds, bounds[1:])]


def trim_heap() -> None:
    """Give the C heap's free memory back to the system (glibc's `malloc_trim(0)`; nothing where
    the C library has none). Called between stages: the bake points' and the tracer's worker
    threads free many arrays of a few MB into glibc's per-thread arenas, which keep them unless
    trimmed (bench/results/memory.md), as Dask's workers trim theirs."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.cache
def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):  # not glibc (musl has none)
        return None


def _mapping(a: np.ndarray) -> tuple[mmap.mmap, int] | None:
    """The mapping of a C-contiguous array made by `releasable_zeros` (or a view of one) and the
    offset of `a`'s first byte in it; None for any other array."""
    memory, root = a.base, a
    while isinstance(memory, np.ndarray):
        root, memory = memory, memory.base
    if isinstance(memory, memoryview):  # np.frombuffer's
        memory = memory.obj
    if not isinstance(memory, mmap.mmap) or not a.flags.c_contiguous:
        return None
    return memory, a.ctypes.data - root.ctypes.data
