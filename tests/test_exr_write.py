"""Writing EXRs a band of scanlines at a time from views (`exr.write_file`) gives the bytes of the
OpenEXR binding's whole-image writer, and the raw SH file's channels filled a band of rows at a
time (`encoding.filled`) are the filled copies' values, and a layer packed in
chunks is the layer packed whole: the encode and write stages' memory cuts
(bench/results/memory.md). No Blender."""

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
from hhd_lightmapper.core.files import exr


def whole_image_bytes(tmp_path, channels: dict, attributes: dict) -> bytes:
    """What `exr.write_file` wrote before it wrote in bands: `OpenEXR.File(...).write`."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({k: str(v) for k, v in attributes.items()})
    path = tmp_path / "whole.exr"
    OpenEXR.File(header, {k: np.ascontiguousarray(v) for k, v in channels.items()}).write(str(path))
    return path.read_bytes()


@pytest.mark.parametrize("shape", [(1, 1), (5, 3), (64, 7), (203, 131)])
def test_band_writes_of_views_are_the_whole_image_writers_bytes(tmp_path, shape):
    rng = np.random.default_rng(shape[0])
    h, w = shape
    sh = rng.normal(size=(h, w, 9, 3)).astype(np.float32) * 1e3
    sh[0, 0, 0, 0] = 1e6  # beyond half (non-finite values are refused: tests/test_bad_input_cli.py)
    channels = {f"SH{k}.{c}": sh[::-1, :, k, i] for k in (0, 4) for i, c in enumerate("RGB")}  # strided, reversed
    channels["Wa.V"] = rng.random((h, w)).astype(np.float16)
    attributes = {"hhdFormat": "hhd-lightmap", "hhdFormatVersion": 3, "hhdAtlas": "Lightmap.Sun ü"}
    path = tmp_path / "bands.exr"
    exr.write_file(path, channels, attributes)
    assert path.read_bytes() == whole_image_bytes(tmp_path, channels, attributes)
    read, header = exr.read(path)
    assert all(np.array_equal(read[k], v) for k, v in channels.items())
    assert header["hhdAtlas"] == "Lightmap.Sun ü"


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


def test_the_sh_files_channels_filled_band_by_band_are_the_filled_copies():
    """The raw SH file's channels as the writer reads them, a band of rows at a time, in atlas
    and EXR order: the bits of the filled copies; the TexelData is only read."""
    data = texel_data()
    fill = data.fill()
    assert len(fill.black) and (fill.source < 0).any() and (fill.source >= 0).any()
    assert max(data.coverage.shape) > 2 * DILATE_RINGS
    copies = raw_images(SH_FILE, data.layers(), fill)
    sh_before = data.sh.copy()
    lazy = raw_images(SH_FILE, data.layers(), fill, banded=True)
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
