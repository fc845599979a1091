"""The channel specification and the encode stage (no Blender): the spec drives the files, the
sidecar, the preview and docs/format.md; writing does not encode; an encoding is one module
plus a registry line."""

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hhd_lightmapper.core import bake, encoding, hhd
from hhd_lightmapper.core.encoding import doc_tables, raw, registry
from hhd_lightmapper.core.encoding import hhd as hhd_encoding
from hhd_lightmapper.core.encoding.spec import DILATE_BURIED_BLACK, FLOAT, Channel, Encoded, FileSpec
from hhd_lightmapper.core.files import exr, lightmap_files, preview
from scenekit import synthetic

ROOT = Path(__file__).resolve().parent.parent


def texel_data(h=24, w=40, seed=3) -> encoding.TexelData:
    """A small atlas: two charts, some buried texels, empty texels beyond the dilation reach."""
    rng = np.random.default_rng(seed)
    coverage = np.zeros((h, w), np.float32)
    coverage[2:10, 2:12] = 1.0
    coverage[14:20, 4:9] = 0.5
    coverage[3, 3] = coverage[15, 5] = -1.0
    baked = coverage > 0
    normals = synthetic.random_normals(rng, int(baked.sum()))
    sh = np.zeros((h, w, 9, 3), np.float32)
    sh[baked] = synthetic.hemisphere_sh(synthetic.sky(40.0), normals, n_z=8, n_phi=16)
    normal = np.zeros((h, w, 3), np.float32)
    normal[baked] = normals
    normal[coverage < 0] = (0.0, 0.0, 1.0)
    return encoding.TexelData(sh=sh, normal=normal, coverage=coverage)


def write(tmp_path, data, settings=encoding.EncoderSettings(), raw_files=True, sidecar=None):
    files = lightmap_files.AtlasFiles(tmp_path, "Lightmap")
    encoded = encoding.encode_atlas(replace(data), encoding.for_settings(settings), raw=raw_files)  # ours: data
    with exr.Staging() as staging:
        lightmap_files.write_atlas(staging, files, encoded, sidecar or {})
        staging.commit()
    return files


def test_docs_format_md_holds_the_current_channel_tables():
    text = (ROOT / "docs" / "format.md").read_text(encoding="utf-8")
    for block in doc_tables.blocks():
        assert block in text, (
            "docs/format.md is stale: run python -m hhd_lightmapper.core.encoding.doc_tables\n" + block
        )
    assert doc_tables.update(text) == text


@pytest.mark.parametrize("ambient", ["luminance", "rgb"])
def test_files_and_sidecar_follow_the_spec(tmp_path, ambient):
    settings = encoding.EncoderSettings(ambient=ambient)
    files = write(tmp_path, texel_data(), settings)
    doc = json.loads(files.sidecar.read_text())
    hhd_file = hhd_encoding.FILE.for_settings(settings)
    for spec in (hhd_file, raw.SH_FILE, raw.TEXELS_FILE):
        channels, _ = exr.read(files.path(spec))
        assert set(channels) == set(spec.exr_names)
        assert list(doc["channels"][spec.key]) == spec.exr_names  # spec order
        meanings = {n: ch.meaning for ch in spec.channels for n in ch.exr_names}
        for name, entry in doc["channels"][spec.key].items():
            assert entry["meaning"] == meanings[name]
            assert entry["type"] == {np.float16: "half", np.float32: "float"}[channels[name].dtype.type]
        assert doc["files"][spec.key] == files.path(spec).name
    assert ("Wa.V" in doc["channels"]["hhd"]) == (ambient == "luminance")
    assert doc["encoder"] == settings.kwargs()


def test_writing_does_not_encode(tmp_path, monkeypatch):
    """The writer lays out what the encode stage produced: the encoder is never called by it."""
    data = texel_data()
    encoded = encoding.encode_atlas(data, encoding.for_settings(encoding.EncoderSettings()))

    def fail(*args, **kwargs):
        raise AssertionError("the writer called the encoder")

    monkeypatch.setattr(hhd, "encode", fail)
    files = lightmap_files.AtlasFiles(tmp_path, "Lightmap")
    with exr.Staging() as staging:
        lightmap_files.write_atlas(staging, files, encoded, {})
        staging.commit()
    assert files.hhd.is_file() and files.sh.is_file() and files.texels.is_file()


def test_encode_stage_matches_the_encoder_and_fills_by_the_spec(tmp_path):
    data = texel_data()
    files = write(tmp_path, data)
    channels, _ = exr.read(files.hhd)
    baked = data.baked
    params = hhd.encode(data.sh[baked], data.normal[baked])
    iz = np.stack([exr.from_exr_rows(channels[f"Iz.{c}"]) for c in "RGB"], -1)
    np.testing.assert_allclose(iz[baked], params.irradz, rtol=1e-3, atol=1e-6)
    # buried texels (DILATE_BURIED_BLACK) take their chart's nearest baked texel, here the one to
    # their left (dilate._NEIGHBOURS' order): (3, 3) from (3, 2), (15, 5) from (15, 4)
    assert np.array_equal(iz[[3, 15], [3, 5]], iz[[3, 15], [2, 4]])
    assert (iz[data.coverage == 0] > 0).all()  # dilated everywhere else
    sh_ch, _ = exr.read(files.sh)
    sh0 = exr.from_exr_rows(sh_ch["SH0.G"])
    assert (sh0[data.coverage < 0] != 0).all() and (sh0[data.coverage == 0] != 0).all()
    tx_ch, _ = exr.read(files.texels)
    assert np.array_equal(exr.from_exr_rows(tx_ch["Coverage.V"]), data.coverage)  # NO_FILL


def test_reencoding_the_files_gives_the_fresh_encoding_bit_for_bit(tmp_path):
    data = texel_data()
    fresh = write(tmp_path / "fresh", data, encoding.EncoderSettings(model="ahd", ambient="rgb"))
    files = write(tmp_path / "re", data)
    bake.reencode(files, encoding.EncoderSettings(model="ahd", ambient="rgb"), threads=1)
    a, _ = exr.read(fresh.hhd)
    b, _ = exr.read(files.hhd)
    assert list(a) == list(b) and all(a[n].tobytes() == b[n].tobytes() for n in a)


def test_half_or_float_is_chosen_per_layer_and_never_clips(tmp_path):
    data = texel_data()
    data.sh *= np.float32(1e6)
    files = write(tmp_path, data)
    channels, _ = exr.read(files.hhd)
    assert all(channels[f"Iz.{c}"].dtype == np.float32 for c in "RGB")
    assert channels["Wa.V"].dtype == np.float16 and np.isfinite(channels["Iz.R"]).all()


@pytest.mark.parametrize("scale", [1.0, 1e6])
def test_preview_images_hold_the_files_values_in_the_files_storage_type(tmp_path, scale):
    """Each preview channel is its layer's file channel, value for value and stored as the file
    stores it: half layers as half (a float32 copy held the same values at twice the bytes), a
    layer too bright for half as float32 (scale 1e6: I_z)."""
    data = texel_data()
    data.sh *= np.float32(scale)
    files = write(tmp_path, data)
    channels, _ = exr.read(files.hhd)
    for key, names in (("iz", [f"Iz.{c}" for c in "RGB"]), ("wa", ["Wa.V"] * 3)):
        rgb, _ = exr.read(files.preview_image(key))
        for c, name in zip("RGB", names):
            assert rgb[c].dtype == channels[name].dtype, (scale, key, c)
            assert rgb[c].tobytes() == channels[name].tobytes(), (scale, key, c)
    assert channels["Iz.R"].dtype == (np.float16 if scale == 1.0 else np.float32)


def test_preview_modes_sample_layers_whose_images_the_writer_stages(tmp_path):
    files = write(tmp_path, texel_data())
    assert not any(files.preview_image(layer.preview).exists() for layer in raw.SH_LAYERS)  # on demand
    assert preview.sh_previews(files)
    for mode in ("HHD", "AHD", "L1", "L2", "SCALAR"):
        for layer in preview.sampled(mode):
            assert files.preview_image(layer.preview).is_file(), (mode, layer.name)
    assert [layer.name for layer in preview.sampled("L2")] == [f"SH{k}" for k in range(9)]
    assert [layer.name for layer in preview.sampled("HHD")] == ["Iz", "Wa", "Direction"]
    rgb, _ = exr.read(files.preview_image("wa"))
    assert np.array_equal(rgb["R"], rgb["G"]) and np.array_equal(rgb["R"], rgb["B"])  # one component, repeated


def test_sh_previews_hold_the_sh_files_values_and_follow_it(tmp_path):
    """The raw SH file's preview images, written on demand: each layer's colours exactly as the
    file holds them (float32 RGB, EXR rows), left alone while current, rewritten when the SH
    file is newer (a re-bake)."""
    import os

    files = write(tmp_path, texel_data())
    assert preview.sh_previews(files) and not preview.sh_previews(files)
    channels, _ = exr.read(files.sh)
    for k, layer in enumerate(raw.SH_LAYERS):
        rgb, _ = exr.read(files.preview_image(layer.preview))
        assert layer.preview == f"sh{k}" and all(rgb[c].dtype == np.float32 for c in "RGB")
        for c, name in zip("RGB", layer.exr_names):
            assert np.array_equal(rgb[c], channels[name].astype(np.float32)), (layer.name, c)
    stamp = files.preview_image("sh4").stat().st_mtime
    os.utime(files.sh, (stamp + 10, stamp + 10))
    assert preview.sh_previews(files)
    assert files.preview_image("sh4").stat().st_mtime > stamp
    files.preview_image("sh7").unlink()
    assert preview.sh_previews(files) and files.preview_image("sh7").is_file()


@dataclass
class _L1:
    """A toy encoding: the first 4 SH coefficients, as a new module would define it."""

    options: encoding.EncoderSettings
    file: FileSpec = field(default=None)
    settings: dict = field(default=None)

    FILE = FileSpec(
        "l1",
        "_l1.exr",
        tuple(
            Channel(f"L1_{k}", tuple("RGB"), FLOAT, "L1 radiance SH coefficient", fill=DILATE_BURIED_BLACK)
            for k in range(4)
        ),
    )

    def __post_init__(self):
        self.file, self.settings = self.FILE, {"model": self.options.model}

    def encode(self, sh, n_v):
        return Encoded({f"L1_{k}": np.asarray(sh[:, k], np.float64) for k in range(4)}, {"texels": len(sh)})

    def summary(self, stats, texels):
        return {"l1_texels": sum(s["texels"] for s in stats)}


def test_an_encoding_is_one_module_plus_a_registry_line(tmp_path, monkeypatch):
    module = SimpleNamespace(FILE=_L1.FILE, encoding=_L1)
    monkeypatch.setitem(registry.ENCODINGS, "l1", module)
    data = texel_data()
    files = write(tmp_path, data, encoding.EncoderSettings(model="l1"))
    doc = json.loads(files.sidecar.read_text())
    assert doc["files"] == {"l1": "Lightmap_l1.exr", "sh": "Lightmap_sh.exr", "texels": "Lightmap_texels.exr"}
    assert list(doc["channels"]["l1"]) == _L1.FILE.exr_names
    assert doc["stats"]["l1_texels"] == doc["stats"]["texels_baked"] == int(data.baked.sum())
    channels, _ = exr.read(files.path(_L1.FILE))
    sh_ch, _ = exr.read(files.sh)
    assert channels["L1_2.B"].tobytes() == sh_ch["SH2.B"].tobytes()  # same values, same fill
    assert any("`L1_0.R`" in block for block in doc_tables.blocks())  # docs/format.md would need it


def test_unknown_model_is_refused():
    with pytest.raises(ValueError, match="encoder model"):
        encoding.for_settings(encoding.EncoderSettings(model="nope"))


def test_the_models_and_the_sh_channels_have_one_home():
    assert set(registry.MODELS) >= {"hhd", "ahd"}
    assert lightmap_files.SH_CHANNELS == raw.SH_FILE.exr_names


def test_texel_data_carries_the_standard_error_when_asked():
    points = SimpleNamespace(
        texel=np.array([0, 5]),
        width=3,
        height=2,
        buried=np.array([False, True]),
        coverage=np.array([1.0, 1.0]),
        normal=np.tile([0.0, 0.0, 1.0], (2, 1)),
    )
    points.image = lambda values, fill=0.0, dtype=np.float64: _image(points, values, dtype)
    sh = np.ones((2, 9, 3))
    data = encoding.TexelData.from_points(points, sh, sh_error=np.full((2, 9, 3), 0.5, np.float32))
    assert data.sh_error.shape == (2, 3, 9, 3) and data.sh_error.dtype == np.float32
    assert data.sh_error[0, 0, 0, 0] == 0.5 and data.coverage[1, 2] == -1.0
    assert encoding.TexelData.from_points(points, sh).sh_error is None


def _image(points, values, dtype):
    out = np.zeros((points.height * points.width,) + values.shape[1:], dtype)
    out[points.texel] = values
    return out.reshape((points.height, points.width) + values.shape[1:])


def test_encoding_in_chunks_on_several_threads_gives_the_images_of_one_thread(monkeypatch):
    """`encode_images` encodes ENCODE_CHUNK texels per task on a thread pool and writes them in
    order: the images (bit for bit) and the statistics do not depend on the thread count."""
    from hhd_lightmapper.core.encoding import stage

    data = texel_data()
    monkeypatch.setattr(stage, "ENCODE_CHUNK", 16)  # ~8 chunks of this small atlas
    encoder = encoding.for_settings(encoding.EncoderSettings())
    one = encoding.encode_atlas(replace(data), encoder, raw=False, threads=1)  # it takes the SH out of its own
    two = encoding.encode_atlas(replace(data), encoder, raw=False, threads=2)
    assert one.stats == two.stats
    images_one, images_two = one.files[encoder.file.key][1], two.files[encoder.file.key][1]
    assert images_one.keys() == images_two.keys()
    for name in images_one:
        np.testing.assert_array_equal(images_one[name], images_two[name])


def test_a_small_atlas_is_encoded_in_several_chunks_with_the_images_of_one():
    """An atlas of fewer than ENCODE_SPLIT × ENCODE_CHUNK texels is split into ENCODE_SPLIT chunks
    (so every core encodes some): each texel's values are those of encoding it in one chunk, bit
    for bit; the statistics summed per chunk agree to rounding."""
    from hhd_lightmapper.core.encoding import stage

    data = texel_data()
    baked = int((data.coverage > 0).sum())
    assert stage.encode_chunk_texels(baked) == stage.MIN_ENCODE_CHUNK > baked  # a small atlas: one chunk
    assert stage.encode_chunk_texels(8 * stage.ENCODE_CHUNK) == stage.ENCODE_CHUNK
    assert stage.encode_chunk_texels(8 * stage.ENCODE_CHUNK - 8) == stage.ENCODE_CHUNK - 1
    encoder = encoding.for_settings(encoding.EncoderSettings())
    one = encoding.encode_atlas(replace(data), encoder, raw=False, threads=2)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(stage, "MIN_ENCODE_CHUNK", 1)
        assert stage.encode_chunk_texels(baked) < baked  # now split
        split = encoding.encode_atlas(replace(data), encoder, raw=False, threads=2)
    assert one.stats["texels_invalid"] == split.stats["texels_invalid"]
    assert one.stats["irradz_max"] == split.stats["irradz_max"]
    assert one.stats["irradz_mean_luminance"] == pytest.approx(split.stats["irradz_mean_luminance"], rel=1e-12)
    images_one, images_split = one.files[encoder.file.key][1], split.files[encoder.file.key][1]
    assert images_one.keys() == images_split.keys()
    for name in images_one:
        assert np.asarray(images_one[name]).tobytes() == np.asarray(images_split[name]).tobytes(), name
