"""Writing EXRs a band of scanlines at a time from views, compressed on several threads
(`exr.write_file`, `zip_exr`), gives files the OpenEXR binding reads back to the very channel
values, with the header of the binding's whole-image writer byte for byte; and the raw SH file's
channels filled a band of rows at a time (`encoding.filled`) are the filled copies' values, and
a layer packed in chunks is the layer packed whole: the encode and write stages' memory cuts
(bench/results/memory.md). No Blender (tests/test_exr_write_blender.py: Blender's reader)."""

import struct
import zlib
from dataclasses import replace

import numpy as np
import OpenEXR
import pytest

from hhd_lightmapper.core.encoding import (
    SH_FILE,
    TEXELS_FILE,
    EncoderSettings,
    TexelData,
    encode_atlas,
    for_settings,
    raw_files,
)
from hhd_lightmapper.core.encoding.stage import DILATE_RINGS, raw_images
from hhd_lightmapper.core.files import exr, sparse_exr, zip_exr


def binding_file(tmp_path, channels: dict, attributes: dict) -> bytes:
    """The OpenEXR binding's whole-image writer's file (`OpenEXR.File(...).write`, ZIP), what
    `exr.write_file` wrote before it compressed the blocks itself."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({k: str(v) for k, v in attributes.items()})
    path = tmp_path / "binding.exr"
    OpenEXR.File(header, {k: np.ascontiguousarray(v) for k, v in channels.items()}).write(str(path))
    return path.read_bytes()


def blocks(data: bytes, height: int) -> tuple[bytes, list[tuple[int, bytes]]]:
    """A scanline ZIP file's magic, version and header, and its blocks (y, stored bytes) in the
    offset table's order."""
    head, stored = sparse_exr._parse(data, -(-height // 16))
    at = len(head)
    offsets = struct.unpack_from(f"<{len(stored)}Q", data, at)
    return head, [(struct.unpack_from("<i", data, o)[0], b) for o, b in zip(offsets, stored)]


def assert_as_the_binding_writes(tmp_path, channels: dict, attributes: dict, threads: int) -> bytes:
    """`exr.write_file`'s file: the binding reads back every channel bit for bit (dtype too),
    its header is the binding's writer's byte for byte, its blocks in order of y; returns it."""
    path = tmp_path / f"ours{threads}.exr"
    exr.write_file(path, channels, attributes, threads=threads)
    read, header = exr.read(path)
    assert read.keys() == channels.keys()
    for name, data in channels.items():
        assert read[name].dtype == data.dtype, name
        assert read[name].tobytes() == np.ascontiguousarray(data).tobytes(), name
    reference = binding_file(tmp_path, channels, attributes)
    h = next(iter(channels.values())).shape[0]
    ours, theirs = blocks(path.read_bytes(), h), blocks(reference, h)
    assert ours[0] == theirs[0]  # magic, version, every attribute and the channel list
    assert [y for y, _ in ours[1]] == [y for y, _ in theirs[1]] == list(range(0, h, 16))
    return path.read_bytes()


@pytest.mark.parametrize("shape", [(1, 1), (5, 3), (37, 1), (64, 7), (203, 131)])
def test_band_writes_of_views_read_back_as_the_binding_writes_them(tmp_path, shape):
    """Float32 and half channels (strided, rows reversed), heights that are and are not a
    multiple of the 16-line block, width 1, a 1×1 image; attributes of any text; on 1 and on 3
    threads the same bytes."""
    rng = np.random.default_rng(shape[0])
    h, w = shape
    sh = rng.normal(size=(h, w, 9, 3)).astype(np.float32) * 1e3
    sh[0, 0, 0, 0] = 1e6  # beyond half (non-finite values are refused: tests/test_bad_input_cli.py)
    channels = {f"SH{k}.{c}": sh[::-1, :, k, i] for k in (0, 4) for i, c in enumerate("RGB")}  # strided, reversed
    channels["Wa.V"] = rng.random((h, w)).astype(np.float16)
    attributes = {"hhdFormat": "hhd-lightmap", "hhdFormatVersion": 3, "hhdAtlas": "Lightmap.Sun ü"}
    one = assert_as_the_binding_writes(tmp_path, channels, attributes, threads=1)
    assert assert_as_the_binding_writes(tmp_path, channels, attributes, threads=3) == one
    _, header = exr.read(tmp_path / "ours1.exr")
    assert header["hhdAtlas"] == "Lightmap.Sun ü"


def extremes(dtype, size: int, rng) -> np.ndarray:
    """`size` values of `dtype` with its extremes: the largest, the smallest normal and
    subnormal, ±0, both signs, and ordinary values."""
    info = np.finfo(dtype)
    special = np.array(
        [info.max, -info.max, info.tiny, info.smallest_subnormal, -info.smallest_subnormal, 0.0, -0.0, 1.0], dtype
    )
    values = rng.normal(size=size).astype(dtype)
    values[: min(size, special.size)] = special[:size]
    return rng.permutation(values)


@pytest.mark.parametrize("shape", [(1, 1), (17, 1), (40, 33)])
def test_extreme_values_random_bits_and_zeros_read_back_bit_for_bit(tmp_path, shape):
    """Huge and tiny values; blocks of random bits (they do not deflate: stored raw, as OpenEXR
    stores them); an all-zero channel; long names (the version's long-names flag)."""
    rng = np.random.default_rng(7)
    h, w = shape
    bits = rng.integers(0, 2**32, size=(h, w), dtype=np.uint32)
    bits[(bits >> 23 & 0xFF) == 0xFF] &= ~np.uint32(1 << 30)  # no NaN or infinity
    half_bits = rng.integers(0, 2**16, size=(h, w), dtype=np.uint16)
    half_bits[(half_bits >> 10 & 0x1F) == 0x1F] &= ~np.uint16(1 << 14)
    channels = {
        "big.F": extremes(np.float32, h * w, rng).reshape(h, w),
        "big.H": extremes(np.float16, h * w, rng).reshape(h, w),
        "noise.F": bits.view(np.float32),
        "noise.H": half_bits.view(np.float16),
        "zero.F": np.zeros((h, w), np.float32),
        "a channel name longer than 31 bytes.V": np.zeros((h, w), np.float16),
    }
    data = assert_as_the_binding_writes(tmp_path, channels, {"note": "x" * 300}, threads=2)
    assert struct.unpack_from("<i", data, 4)[0] == 2 | 0x400
    noise = {k: channels[k] for k in ("noise.F", "noise.H")}
    data = assert_as_the_binding_writes(tmp_path, noise, {}, threads=2)
    assert all(len(b) == min(16, h - y) * w * 6 for y, b in blocks(data, h)[1])  # stored raw
    zeros = {"zero.F": channels["zero.F"]}
    data = assert_as_the_binding_writes(tmp_path, zeros, {}, threads=2)
    deflated = [len(b) < min(16, h - y) * w * 4 for y, b in blocks(data, h)[1]]
    assert all(deflated) if w * h >= 40 * 33 else deflated[-1] is False  # a few bytes do not deflate smaller


def test_a_block_is_the_reordered_predicted_deflated_lines():
    """`zip_exr.compress_block` against OpenEXR's ZIP block as its specification states it: the
    lines' bytes (channels in order, line by line), even bytes then odd ones, each byte but the
    first minus its predecessor plus 128, zlib-deflated; inflated and undone here, the lines."""
    rng = np.random.default_rng(3)
    lines = [np.ascontiguousarray(rng.integers(0, 4, size=(13, 21)).astype(t) / 4) for t in ("<f4", "<f2", "<f4")]
    stored = zip_exr.compress_block(lines, zip_exr.ZIP_LEVEL)
    raw = b"".join(a[r].tobytes() for r in range(13) for a in lines)
    assert len(stored) < len(raw)
    d = np.frombuffer(zlib.decompress(stored), np.uint8).astype(np.int64)
    t = np.cumsum(np.concatenate([d[:1], d[1:] - 128])) % 256  # undo the predictor
    half = (t.size + 1) // 2
    back = np.empty(t.size, np.uint8)
    back[0::2], back[1::2] = t[:half], t[half:]
    assert back.tobytes() == raw


@pytest.mark.parametrize("deflater", ["bundled", "zlib"])
def test_either_deflate_writes_what_the_binding_reads_back(tmp_path, monkeypatch, deflater):
    """The bundled ISA-L deflate (the `isal` wheel, installed in both test environments) and
    Python's zlib, which `zip_exr` falls back to without it: each file reads back bit for bit."""
    assert zip_exr.DEFLATER == "isal"
    if deflater == "zlib":
        monkeypatch.setattr(zip_exr, "deflate", zlib.compress)
        monkeypatch.setattr(zip_exr, "ZIP_LEVEL", 3)
    rng = np.random.default_rng(5)
    smooth = np.cumsum(rng.normal(size=(70, 33)), axis=1).astype(np.float32)
    channels = {"A.R": smooth, "A.G": smooth[::-1].astype(np.float16), "B.V": np.zeros((70, 33), np.float32)}
    exr.write_file(tmp_path / "d.exr", channels, threads=2)
    back, _ = exr.read(tmp_path / "d.exr")
    for name, image in channels.items():
        assert back[name].dtype == image.dtype and back[name].tobytes() == np.ascontiguousarray(image).tobytes()


def test_a_cancel_or_a_non_finite_band_stops_a_threaded_write(tmp_path):
    """`rows_done` raising (a cancel) and a NaN in a later band: raised from the write, on
    several threads too, after the bands before it were handed over."""
    image = np.ones((300, 20), np.float32)
    done = []

    def cancel(rows, of):
        done.append(rows)
        if rows >= 128:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        exr.write_file(tmp_path / "c.exr", {"V.V": image}, rows_done=cancel, threads=2)
    assert done == [64, 128]
    image[200, 3] = np.nan
    with pytest.raises(exr.NonFiniteValue, match="'V.V'"):
        exr.write_file(tmp_path / "n.exr", {"V.V": image}, threads=2)


def test_attribute_names_the_writer_sets_and_bad_names_are_refused(tmp_path):
    image = {"V.V": np.zeros((2, 2), np.float32)}
    with pytest.raises(ValueError, match="sets itself"):
        exr.write_file(tmp_path / "a.exr", image, {"compression": "none"})
    with pytest.raises(ValueError, match="null byte"):
        exr.write_file(tmp_path / "a.exr", {"V\0.V": image["V.V"]})
    with pytest.raises(ValueError, match="one size"):
        exr.write_file(tmp_path / "a.exr", {"V.V": np.zeros((0, 2), np.float32)})


def test_band_writes_refuse_other_dtypes_and_mixed_sizes(tmp_path):
    with pytest.raises(TypeError, match="float16 or float32"):
        exr.write_file(tmp_path / "a.exr", {"X": np.zeros((2, 2))})
    with pytest.raises(ValueError, match="one size"):
        exr.write_file(tmp_path / "a.exr", {"X": np.zeros((2, 2), np.float32), "Y": np.zeros((2, 3), np.float32)})


def texel_data(h=90, w=70, seed=0) -> TexelData:
    """A chart in a corner (its far texels beyond DILATE_RINGS: they take the mean), buried
    texels inside it, a chart buried whole (black), random SH."""
    rng = np.random.default_rng(seed)
    coverage = np.zeros((h, w), np.float32)
    coverage[5:40, 5:30] = rng.uniform(0.2, 1.0, size=(35, 25))
    coverage[10:13, 8:11] = -1.0  # buried, with chart texels around
    coverage[30:40, 5:30] = -1.0  # a buried band at the chart's edge
    coverage[70:80, 50:60] = -1.0  # a chart buried whole: black
    sh = rng.normal(size=(h, w, 9, 3)).astype(np.float32)
    return TexelData(sh=sh, normal=np.zeros((h, w, 3), np.float32), coverage=coverage)


@pytest.mark.parametrize("whole", [False, True], ids=["per layer", "whole SH"])
def test_the_sh_files_channels_filled_band_by_band_are_the_filled_copies(whole):
    """The raw SH file's channels as the writer reads them, a band of rows at a time, in atlas
    and EXR order: the bits of the filled copies; the TexelData is only read. Given the
    TexelData, the nine layers are filled from one band of the whole SH (`stage._whole_sh`)."""
    data = texel_data()
    fill = data.fill()
    assert len(fill.black) and (fill.source < 0).any() and (fill.source >= 0).any()
    assert max(data.coverage.shape) > 2 * DILATE_RINGS
    copies = raw_images(SH_FILE, data.layers(), fill)
    sh_before = data.sh.copy()
    lazy = raw_images(SH_FILE, data.layers(), fill, banded=True, data=data if whole else None)
    layers = {id(image.layer) for image in lazy.values()}
    assert len(layers) == (1 if whole else 9)
    copied = raw_images(SH_FILE, {k: v.copy() for k, v in data.layers().items()}, fill, banded=True, data=data)
    assert len({id(image.layer) for image in copied.values()}) == 9  # not views of data.sh: each its own
    assert lazy.keys() == copies.keys() and len(lazy) == 27
    h = data.coverage.shape[0]
    for name, image in lazy.items():
        assert image.shape == copies[name].shape and image.dtype == np.float32
        assert image.astype(np.float32, copy=False) is image
        assert np.asarray(image).tobytes() == copies[name].tobytes(), name
        top_down = image[::-1]
        for a in range(0, h, 7):  # bands of 7 rows, as exr.write_file reads them (in EXR order)
            b = min(a + 7, h)
            assert top_down[a:b].tobytes() == np.ascontiguousarray(copies[name][::-1][a:b]).tobytes(), (name, a)
    assert data.sh.tobytes() == sh_before.tobytes()  # nothing written into the TexelData


def test_a_windowed_atlas_s_banded_channels_are_placed_as_its_copies():
    """An almost empty atlas (a window of texels): the banded channels placed in the whole atlas
    with the copies' background, the same bytes."""
    from hhd_lightmapper.core.stages import Window

    data = texel_data()
    h, w = data.coverage.shape
    data = replace(data, window=Window(10, 6, h, w, (h + 40, w + 24)))
    fill = data.fill()
    copies = raw_images(SH_FILE, data.layers(), fill, data=data)
    lazy = raw_images(SH_FILE, data.layers(), fill, banded=True, data=data)
    for name in copies:
        assert lazy[name].shape == (h + 40, w + 24)
        assert np.asarray(lazy[name][::-1]).tobytes() == np.asarray(copies[name][::-1]).tobytes(), name


def test_packing_a_layer_in_chunks_gives_the_whole_layers_values(monkeypatch):
    """The highlight direction is packed (octahedral, float64 temporaries) ENCODE_CHUNK texels at
    a time: the values and dtype of packing the whole layer at once."""
    from hhd_lightmapper.core.encoding import HHD_FILE, stage

    [direction] = [ch for ch in HHD_FILE.channels if ch.pack is not None]
    data = texel_data()
    rng = np.random.default_rng(5)
    image = rng.normal(size=data.coverage.shape + (3,)).astype(np.float32)
    image /= np.linalg.norm(image, axis=2, keepdims=True)
    whole = stage.layer_images(direction, image.copy(), data.fill())
    monkeypatch.setattr(stage, "ENCODE_CHUNK", 97)  # 63 chunks, the last one short
    chunked = stage.layer_images(direction, image.copy(), data.fill())
    assert whole.keys() == chunked.keys() and len(whole) == 2
    for name in whole:
        assert whole[name].dtype == chunked[name].dtype
        assert whole[name].tobytes() == chunked[name].tobytes()


def test_raw_files_are_the_encoders_raw_files_and_leave_the_sh_bit_for_bit():
    """`encoding.raw_files` (a bake writes its raw files before the post stages) gives the images
    `encode_atlas(raw=True)` gives, filled a band at a time, and leaves every bit of the SH as it
    was: -0.0, NaN and values in buried texels, +0.0 elsewhere."""
    data = texel_data(seed=3)
    buried = np.flatnonzero((data.coverage < 0).reshape(-1))
    flat = data.sh.reshape(-1, 27)
    flat[buried[:4]] = -0.0
    flat[buried[4:8], 5] = np.nan
    outside = np.flatnonzero((data.coverage == 0).reshape(-1))
    flat[outside] = 0.0  # as `TexelData.from_points` leaves texels no point images
    flat[outside[:3]] = -0.0
    before = data.sh.copy()
    expected = encode_atlas(replace(data), for_settings(EncoderSettings())).files  # it takes the SH out of its own
    fill = data.fill()
    with raw_files(data, fill) as files:
        assert files.keys() == {SH_FILE.key, TEXELS_FILE.key}
        for key, (spec, images) in files.items():
            assert spec == expected[key][0]
            assert images.keys() == expected[key][1].keys()
            for name, image in images.items():
                assert np.asarray(image).tobytes() == expected[key][1][name].tobytes(), name
        assert data.sh.view(np.uint32).tobytes() == before.view(np.uint32).tobytes()  # only read
    assert data.sh.view(np.uint32).tobytes() == before.view(np.uint32).tobytes()


def test_raw_files_leave_the_sh_as_it_was_when_the_block_raises():
    data = texel_data(seed=4)
    before = data.sh.copy()
    with pytest.raises(RuntimeError, match="disk full"):
        with raw_files(data, data.fill()):
            raise RuntimeError("disk full")
    assert data.sh.view(np.uint32).tobytes() == before.view(np.uint32).tobytes()
