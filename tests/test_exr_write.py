"""Writing EXRs a band of scanlines at a time from views (`exr.write_file`) gives the bytes of the
OpenEXR binding's whole-image writer, and the raw SH file's channels filled in the TexelData
itself (`encoding.stage.fill_in_place`) are the filled copies' values, and a layer packed in
chunks is the layer packed whole: the encode and write stages' memory cuts
(bench/results/memory.md). No Blender."""

import numpy as np
import OpenEXR
import pytest

from hhd_lightmapper.core import dilate
from hhd_lightmapper.core.encoding import (
    SH_FILE,
    TEXELS_FILE,
    EncoderSettings,
    TexelData,
    encode_atlas,
    for_settings,
    raw_files,
)
from hhd_lightmapper.core.encoding.stage import DILATE_RINGS, fill_in_place, raw_images
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


def test_the_sh_files_channels_filled_in_place_are_the_filled_copies():
    data = texel_data()
    fill = data.fill()
    assert len(fill.black) and (fill.source < 0).any() and (fill.source >= 0).any()
    assert max(data.coverage.shape) > 2 * DILATE_RINGS
    copies = raw_images(SH_FILE, data.layers(), fill)
    sh_before = data.sh.copy()
    views = raw_images(SH_FILE, data.layers(), fill, in_place=True)
    assert views.keys() == copies.keys() and len(views) == 27
    for name, image in views.items():
        assert np.shares_memory(image, data.sh)  # no copy of the atlas's SH
        np.testing.assert_array_equal(image, copies[name], err_msg=name)
        assert image.tobytes() == copies[name].tobytes()
    assert not np.array_equal(data.sh, sh_before)  # filled in place
    baked = data.coverage > 0
    np.testing.assert_array_equal(data.sh[baked], sh_before[baked])  # sources untouched


def test_filling_in_place_refuses_what_is_not_one_run_of_texels():
    data = texel_data()
    image = data.sh[:, :50, 0, 0]  # part of each row: the rows are not one run of texels
    fill = dilate.Fill(data.baked[:, :50], DILATE_RINGS, black=data.coverage[:, :50] < 0)
    before = image.copy()
    assert not fill_in_place(fill, image, keep_black=True)
    np.testing.assert_array_equal(image, before)
    spaced = data.sh[:, ::2, 0, 0]  # every other column: evenly spaced, filled in place
    fill = dilate.Fill(data.baked[:, ::2], DILATE_RINGS, black=data.coverage[:, ::2] < 0)
    copy = fill.apply(spaced, keep_black=True)
    assert fill_in_place(fill, spaced, keep_black=True)
    np.testing.assert_array_equal(spaced, copy)


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
    `encode_atlas(raw=True)` gives, filled in the SH itself, and puts back every bit it filled:
    -0.0, NaN and values in buried texels, +0.0 elsewhere."""
    data = texel_data(seed=3)
    buried = np.flatnonzero((data.coverage < 0).reshape(-1))
    flat = data.sh.reshape(-1, 27)
    flat[buried[:4]] = -0.0
    flat[buried[4:8], 5] = np.nan
    outside = np.flatnonzero((data.coverage == 0).reshape(-1))
    flat[outside] = 0.0  # as `TexelData.from_points` leaves texels no point images
    flat[outside[:3]] = -0.0
    before = data.sh.copy()
    expected = encode_atlas(data, for_settings(EncoderSettings())).files
    fill = data.fill()
    with raw_files(data, fill) as files:
        assert files.keys() == {SH_FILE.key, TEXELS_FILE.key}
        for key, (spec, images) in files.items():
            assert spec == expected[key][0]
            assert images.keys() == expected[key][1].keys()
            for name, image in images.items():
                assert image.tobytes() == expected[key][1][name].tobytes(), name
                if key == SH_FILE.key:
                    assert np.shares_memory(image, data.sh)  # views: no copy of the atlas's SH
        assert data.sh.tobytes() != before.tobytes()  # filled while the block runs
    assert data.sh.view(np.uint32).tobytes() == before.view(np.uint32).tobytes()


def test_raw_files_put_the_sh_back_when_the_block_raises():
    data = texel_data(seed=4)
    before = data.sh.copy()
    with pytest.raises(RuntimeError, match="disk full"):
        with raw_files(data, data.fill()):
            raise RuntimeError("disk full")
    assert data.sh.view(np.uint32).tobytes() == before.view(np.uint32).tobytes()
