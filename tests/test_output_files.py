"""The files a bake writes (no Blender): EXR round trips, half vs float, atomic replacement,
dilation, the sidecar, and re-encoding from the SH EXR."""

import json

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, dilate, encoding, hhd, octahedral, unwrap
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.scene import BakeScene, SunLight
from hhd_lightmapper.core.tracer import BakeSettings
from scenekit import meshes


def test_float_channels_round_trip_bit_exact_and_rows_are_top_down(tmp_path):
    rng = np.random.default_rng(1)
    a = (rng.standard_normal((7, 5)) * 10.0 ** rng.integers(-30, 30, (7, 5))).astype(np.float32)
    a[0, 0], a[1, 1] = np.float32(3.4e38), np.float32(1e-45)  # extremes of float32
    h = rng.random((7, 5)).astype(np.float16)
    exr.write(tmp_path / "x.exr", {"A.V": a, "B.V": h}, {"note": "hi"})
    channels, header = exr.read(tmp_path / "x.exr")
    assert channels["A.V"].dtype == np.float32 and channels["B.V"].dtype == np.float16
    assert channels["A.V"].tobytes() == a.tobytes()
    assert channels["B.V"].tobytes() == h.tobytes()
    assert header["note"] == "hi"
    bottom_up = np.arange(6, dtype=np.float32).reshape(3, 2)
    assert np.array_equal(exr.from_exr_rows(exr.to_exr_rows(bottom_up)), bottom_up)
    assert exr.to_exr_rows(bottom_up)[0, 0] == 4.0  # the top row of the image comes first


def test_atomic_write_keeps_the_previous_file_when_writing_fails(tmp_path):
    target = tmp_path / "l.exr"
    exr.write(target, {"V.V": np.ones((4, 4), np.float32)})
    before = target.read_bytes()
    with pytest.raises(TypeError):  # the second channel cannot be stored: fails mid-write
        exr.write(target, {"V.V": np.zeros((4, 4), np.float32), "W.V": np.zeros((4, 4), np.float64)})
    assert target.read_bytes() == before
    with pytest.raises(RuntimeError):
        with exr.Staging() as staging:
            exr.write_file(staging.stage(target), {"V.V": np.zeros((4, 4), np.float32)})
            staging.write_text(tmp_path / "side.json", "{}")
            raise RuntimeError("interrupted before commit")
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.exr"]  # no temporaries left


def test_dilation_fills_from_the_nearest_source_and_reaches_everything():
    valid = np.zeros((9, 12), bool)
    valid[2:4, 2:5] = True
    valid[7, 10] = True
    image = np.zeros((9, 12, 2))
    image[valid] = np.arange(valid.sum() * 2).reshape(-1, 2) + 1.0
    out = dilate.dilate(image, valid, rings=3)
    assert np.array_equal(out[valid], image[valid])
    assert np.array_equal(out[2, 1], image[2, 2]) and np.array_equal(out[8, 11], image[7, 10])
    index = dilate.nearest_source(valid, 3)
    ys, xs = np.nonzero(index >= 0)
    sy, sx = np.divmod(index[index >= 0], 12)
    assert (np.maximum(abs(ys - sy), abs(xs - sx)) <= 3).all()  # within `rings`, chessboard
    far = index < 0
    assert far.any() and np.allclose(out[far], image[valid].mean(axis=0))
    assert np.isfinite(dilate.dilate(np.zeros((4, 4, 1)), np.zeros((4, 4), bool))).all()


def nearest_source_by_loops(valid, rings, through=None):
    """`dilate.nearest_source` spelled out texel by texel: ring by ring, a texel without a source
    takes that of its first neighbour (edges before diagonals, `dilate._NEIGHBOURS`) that had one
    after the previous ring, entering only `through` texels."""
    h, w = valid.shape
    index = [[y * w + x if valid[y, x] else -1 for x in range(w)] for y in range(h)]
    for _ in range(rings):
        grown = [row[:] for row in index]
        for y in range(h):
            for x in range(w):
                if grown[y][x] >= 0 or (through is not None and not through[y, x]):
                    continue
                for dy, dx in dilate._NEIGHBOURS:
                    if 0 <= y + dy < h and 0 <= x + dx < w and index[y + dy][x + dx] >= 0:
                        grown[y][x] = index[y + dy][x + dx]
                        break
        index = grown
    return np.array(index, np.int64).reshape(h, w)


@pytest.mark.parametrize("seed", range(6))
def test_nearest_source_is_the_ring_by_ring_rule(seed):
    rng = np.random.default_rng(seed)
    h, w = (int(n) for n in rng.integers(1, 40, 2))
    valid = rng.random((h, w)) < rng.uniform(0.005, 0.3)
    through = rng.random((h, w)) < 0.7 if seed % 2 else None
    rings = int(rng.integers(0, 25))
    found = dilate.nearest_source(valid, rings, through)
    assert found.dtype == np.int64
    np.testing.assert_array_equal(found, nearest_source_by_loops(valid, rings, through))


def plane_bake(tmp_path, sun=(3.0, 2.0, 1.0), resolution=256, encoder=encoding.EncoderSettings()):
    v, f = meshes.plane(2.0)
    res = unwrap.unwrap([unwrap.UnwrapMesh("floor", v, f)], unwrap.UnwrapSettings(resolution=resolution))
    surface = bakepoints.SurfaceTriangles(
        v[f], np.tile([0, 0, 1.0], (2, 3, 1)), res.objects[0].uv.astype(float), np.zeros(2, int), np.full((2, 3), 0.5)
    )
    scene = BakeScene(
        v[f],
        np.full((2, 3), 0.5),
        lights=[SunLight(np.array([0.6, 0.0, 0.8]), np.array(sun))],
        world=np.array([0.1, 0.2, 0.3]),
    )
    settings = bake.PipelineSettings(trace=BakeSettings(samples=16, bounces=1), encoder=encoder)
    bake.run([bake.AtlasInput("Lightmap", resolution, resolution, surface, ["floor"])], scene, settings, tmp_path)
    return lightmap_files.AtlasFiles(tmp_path, "Lightmap")


def test_written_files_decode_to_the_encoder_output_and_sidecar_describes_them(tmp_path):
    files = plane_bake(tmp_path)
    doc = json.loads(files.sidecar.read_text())
    assert doc["format"] == "hhd-lightmap" and doc["format_version"] == lightmap_files.FORMAT_VERSION
    assert set(doc["channels"]["sh"]) == set(lightmap_files.SH_CHANNELS) and len(doc["channels"]["sh"]) == 27
    assert doc["channels"]["hhd"]["Iz.R"]["type"] == "half"
    assert doc["objects"][0]["name"] == "floor" and doc["objects"][0]["texels"] == doc["stats"]["texels_baked"]
    assert {"sh_basis", "hhd", "direction", "uv"} <= set(doc["conventions"])
    assert doc["bake"]["samples"] == 16 and doc["timings_seconds"]["trace"] > 0
    data = lightmap_files.read_texel_data(files)
    params = hhd.encode(data.sh[data.baked], data.normal[data.baked])
    channels, header = exr.read(files.hhd)
    assert header["hhdFormat"] == "hhd-lightmap"
    iz = np.stack([exr.from_exr_rows(channels[f"Iz.{c}"]) for c in "RGB"], -1)[data.baked].astype(float)
    np.testing.assert_allclose(iz, params.irradz, rtol=1e-3, atol=1e-6)  # half precision
    oct_uv = np.stack([exr.from_exr_rows(channels[f"Direction.{a}"]) for a in "XY"], -1)[data.baked].astype(float)
    cos = np.einsum("pi,pi->p", octahedral.decode(oct_uv), params.direction)
    assert cos.min() > np.cos(np.radians(0.1))
    x0, y0, x1, y1 = doc["objects"][0]["rect"]
    assert data.baked[y0:y1, x0:x1].sum() == data.baked.sum()
    everywhere = np.stack([channels[f"Iz.{c}"] for c in "RGB"], -1).astype(float)
    assert everywhere.min() > 0.1  # dilated: no black texel for bilinear filtering to pull in


def test_hdr_values_beyond_half_are_stored_as_float_not_clipped(tmp_path):
    files = plane_bake(tmp_path, sun=(3e5, 2e5, 1e5))
    channels, _ = exr.read(files.hhd)
    assert channels["Iz.R"].dtype == np.float32 and np.isfinite(channels["Iz.R"]).all()
    assert channels["Iz.R"].max() > 65504
    assert json.loads(files.sidecar.read_text())["channels"]["hhd"]["Iz.R"]["type"] == "float"


@pytest.mark.slow
def test_reencode_reads_the_sh_exr_and_changes_only_the_encoded_file(tmp_path):
    files = plane_bake(tmp_path)
    sh_before, texels_before = files.sh.read_bytes(), files.texels.read_bytes()
    bake.reencode(files, encoding.EncoderSettings(model="ahd", ambient="rgb"))
    assert files.sh.read_bytes() == sh_before and files.texels.read_bytes() == texels_before
    channels, _ = exr.read(files.hhd)
    assert {"Wa.R", "Wa.G", "Wa.B"} <= set(channels) and "Wa.V" not in channels
    doc = json.loads(files.sidecar.read_text())
    assert doc["encoder"]["model"] == "ahd" and doc["reencoded_from_sh"]
    other = tmp_path / "direct"
    direct = plane_bake(other, encoder=encoding.EncoderSettings(model="ahd", ambient="rgb"))
    assert exr.read(direct.hhd)[0]["Iz.G"].tobytes() == channels["Iz.G"].tobytes()


def test_a_cancelled_bake_replaces_no_file(tmp_path):
    files = plane_bake(tmp_path)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    v, f = meshes.plane(2.0)
    res = unwrap.unwrap([unwrap.UnwrapMesh("floor", v, f)], unwrap.UnwrapSettings(resolution=256))
    surface = bakepoints.SurfaceTriangles(
        v[f], np.tile([0, 0, 1.0], (2, 3, 1)), res.objects[0].uv.astype(float), np.zeros(2, int), np.full((2, 3), 0.9)
    )
    calls = []
    with pytest.raises(bake.tracer.BakeCancelled):
        bake.run(
            [bake.AtlasInput("Lightmap", 256, 256, surface, ["floor"])],
            BakeScene(v[f], np.full((2, 3), 0.9), world=np.ones(3)),
            bake.PipelineSettings(),
            files.folder,
            cancel=lambda: calls.append(1) or len(calls) > 3,
        )
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_the_direction_preview_holds_the_unit_vector_and_old_previews_are_upgraded(tmp_path):
    """The preview's `dir` image holds each texel's direction decoded (x, y, z: a bilinear filter
    may blend it), not the octahedral pair of the HHD file (filtering that across the map's folds
    blends unrelated directions); Show Preview rewrites one a bake made before holds as the pair
    (`files.preview.upgrade_direction`), once."""
    from hhd_lightmapper.core.files.preview import upgrade_direction

    files = plane_bake(tmp_path)
    channels, _ = exr.read(files.hhd)
    oct_xy = np.stack([channels["Direction.X"], channels["Direction.Y"]], -1).reshape(-1, 2).astype(float)
    preview, header = exr.read(files.preview_image("dir"))
    assert header["hhdPreviewValue"] == "unpacked" and preview["R"].dtype == np.float16
    vector = np.stack([preview[c] for c in "RGB"], -1).reshape(-1, 3).astype(float)
    np.testing.assert_allclose(vector, octahedral.decode(oct_xy), atol=1e-3)  # half precision
    assert not upgrade_direction(files)
    old = {"R": channels["Direction.X"].astype(np.float32), "G": channels["Direction.Y"].astype(np.float32)}
    exr.write(files.preview_image("dir"), {**old, "B": np.zeros_like(old["R"])})  # as written before
    assert upgrade_direction(files) and not upgrade_direction(files)
    assert exr.read(files.preview_image("dir"))[0]["B"].tobytes() == preview["B"].tobytes()


def test_a_fills_index_lists_are_found_in_blocks_as_whole(monkeypatch):
    """`dilate.Fill`'s flat index lists (sources, invalid, empty texels and their sources), made
    INDEX_BLOCK texels at a time (memory), are those of the whole mask at once."""
    rng = np.random.default_rng(5)
    valid = rng.random((37, 53)) < 0.3
    black = ~valid & (rng.random((37, 53)) < 0.1)
    chart = valid | black | (rng.random((37, 53)) < 0.2)
    whole = dilate.Fill(valid, 4, black=black, chart=chart)
    monkeypatch.setattr(dilate, "INDEX_BLOCK", 64)  # 31 blocks, the last one partial
    blocks = dilate.Fill(valid, 4, black=black, chart=chart)
    for name in ("valid", "invalid", "black", "empty", "source"):
        np.testing.assert_array_equal(getattr(blocks, name), getattr(whole, name))
        assert getattr(blocks, name).dtype == np.int32, name
    np.testing.assert_array_equal(blocks.valid, np.flatnonzero(valid))
    np.testing.assert_array_equal(blocks.empty, np.flatnonzero(~valid))
