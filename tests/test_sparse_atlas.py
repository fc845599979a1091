"""An almost empty atlas costs what its texels cost, not its area (issue 53, part 5): a bake's
stages after tracing work on the window of the atlas that holds its texels
(`encoding.stage.window_of`, `TexelData.window`) and the files are written whole from it
(`stages.PlacedImage`), byte for byte the files of the whole atlas's images. No Blender."""

import json
import shutil
import tracemalloc

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, encoding, light_sets, raster, stages, tracer, unwrap
from hhd_lightmapper.core.bake import finishing
from hhd_lightmapper.core.encoding import stage as encode_stage
from hhd_lightmapper.core.files import exr, lightmap_files, sparse_exr
from hhd_lightmapper.core.scene import BakeScene, SunLight
from hhd_lightmapper.core.tracer import BakeSettings
from scenekit import meshes
from test_oidn import bpy_library_dirs, library  # noqa: F401  (fixtures)


def sphere_in_corner(resolution: int, scale: float, corner: tuple[float, float]):
    """A smooth UV sphere cut into charts by xatlas (smooth seams) above a floor, its lightmap
    UVs squeezed into `scale` of an atlas from `corner` (u, v): most of the atlas is empty.
    (Packed for at least 256², the unwrap's smallest atlas.)"""
    v, f = meshes.uv_sphere(rings=8, segments=16, radius=0.8)
    v = v + [0.0, 0.0, 1.0]
    packed = max(int(resolution * scale), 256)
    res = unwrap.unwrap([unwrap.UnwrapMesh("sphere", v, f)], unwrap.UnwrapSettings(resolution=packed))
    uv = res.objects[0].uv.astype(float) * scale + np.asarray(corner)
    normals = meshes.vertex_normals(v, f)[f]
    surface = bakepoints.SurfaceTriangles(v[f], normals, uv, np.zeros(len(f), int), np.full((len(f), 3), 0.6))
    fv, ff = meshes.plane(6.0)
    tris = np.concatenate([v[f], fv[ff]])
    scene = BakeScene(
        tris,
        np.full((len(tris), 3), 0.5),
        lights=[SunLight(np.array([0.5, 0.3, 0.8]), np.full(3, 3.0))],
        world=np.array([0.2, 0.3, 0.5]),
    )
    return surface, scene


def untimed(doc):
    """A sidecar without its times (every "seconds" and "timings_seconds", the fingerprints' "time"
    and the receivers' "baked" times)."""
    if isinstance(doc, dict):
        return {k: untimed(v) for k, v in doc.items() if k not in ("seconds", "timings_seconds", "time", "baked")}
    return [untimed(v) for v in doc] if isinstance(doc, list) else doc


def files_of(folder) -> dict[str, bytes]:
    """Every file of a bake by its path under `folder`, the sidecar without its times."""
    out = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        data = path.read_bytes()
        if path.suffix == ".json":
            data = json.dumps(untimed(json.loads(data)), sort_keys=True).encode()
        out[str(path.relative_to(folder))] = data
    return out


def baked(tmp_path, name, monkeypatch, surface, scene, resolution, whole: bool, **settings):
    with monkeypatch.context() as m:
        if whole:  # the whole atlas's images, as before windows
            m.setattr(encode_stage, "window_of", lambda texel, h, w: None)
        else:
            seen, written = [], []
            real, write = encode_stage.window_of, sparse_exr.write
            m.setattr(encode_stage, "window_of", lambda *a: (seen.append(real(*a)), seen[-1])[1])
            m.setattr(sparse_exr, "write", lambda path, *a: (written.append(path), write(path, *a))[1])
        atlas = bake.AtlasInput("Lightmap", resolution, resolution, surface, ["sphere"])
        trace = BakeSettings(samples=4, pass_samples=4, bounces=1, seed=2, threads=2)
        bake.run([atlas], scene, bake.PipelineSettings(trace=trace, **settings), tmp_path / name)
    if not whole:
        assert seen and seen[0] is not None and seen[0].h * seen[0].w < resolution**2 / 4, seen
        assert len(written) == 6, written  # every EXR, the previews too (the HHD file's), from the window
    return files_of(tmp_path / name)


@pytest.mark.parametrize("corner", [(0.3, 0.55), (0.0, 0.75)], ids=["inside", "at-the-edge"])
def test_a_windowed_bake_writes_the_files_of_the_whole_atlas(tmp_path, monkeypatch, corner):
    """Stitched (SH and encoded), dilated, encoded and written from the window of its texels,
    the files are those of the whole atlas's images, bit for bit (previews included), with the
    window inside the atlas or against its border."""
    surface, scene = sphere_in_corner(1024, 0.25, corner)
    whole = baked(tmp_path, "whole", monkeypatch, surface, scene, 1024, whole=True)
    window = baked(tmp_path, "window", monkeypatch, surface, scene, 1024, whole=False)
    assert whole.keys() == window.keys() and len(whole) >= 8  # sidecar, seams, 3 EXRs, 3 previews
    stitched = json.loads(window["Lightmap.json"])["post"]["stitch"]
    assert stitched["applied"] and stitched["texels"] > 0 and stitched["encoded"]["texels"] > 0
    for name in whole:
        assert whole[name] == window[name], name


@pytest.mark.slow
def test_a_windowed_denoised_bake_writes_the_files_of_the_whole_atlas(tmp_path, monkeypatch, library):  # noqa: F811
    """The denoiser's pages are those of the whole atlas (as wide), so a denoised bake's files
    are the same too."""
    surface, scene = sphere_in_corner(1024, 0.25, (0.3, 0.55))
    options = {"denoise": True, "denoiser_library": str(library)}
    whole = baked(tmp_path, "whole", monkeypatch, surface, scene, 1024, whole=True, **options)
    window = baked(tmp_path, "window", monkeypatch, surface, scene, 1024, whole=False, **options)
    assert json.loads(window["Lightmap.json"])["post"]["denoise"]["applied"]
    for name in whole:
        assert whole[name] == window[name], name


class Collect:
    def __init__(self):
        self.calls = []

    def raw(self, name, parent, images_of):
        self.calls.append(("raw", {k: dict(images) for k, (_, images) in images_of.items()}))

    def atlas(self, name, parent, encoded, sidecar):
        self.calls.append(("atlas", encoded))

    def seams(self, name, atlas_seams):
        self.calls.append(("seams", atlas_seams))


def test_an_almost_empty_8192_atlas_allocates_for_its_texels_not_its_area():
    """A 100 m × 1 cm quad two texel rows tall across an 8192² atlas (~16k texels): imaging,
    the raw files' dilation, stitching, encoding and filling allocate a small fraction of one
    whole-atlas SH image (8192² × 27 float32 = 7.2 GB); the images handed to the writer are the
    whole atlas's (8192²) and read a band of rows at a time."""
    n = 8192
    v = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [100.0, 0.01, 0.0], [0.0, 0.01, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    lo, hi = (n / 2 - 0.7) / n, (n / 2 + 0.7) / n
    uv = np.array([[2 / n, lo], [1 - 2 / n, lo], [1 - 2 / n, hi], [2 / n, hi]])[f]
    surface = bakepoints.SurfaceTriangles(v[f], np.tile([0, 0, 1.0], (2, 3, 1)), uv, np.zeros(2, int), np.ones((2, 3)))
    atlas = bake.AtlasInput("Lightmap", n, n, surface, ["quad"])
    points = bake.points_of(atlas, None, 1)
    texels = len(points.texel)
    assert 10_000 < texels < 40_000
    rng = np.random.default_rng(1)
    sh = (rng.random((texels, 9, 3)) * 0.1).astype(np.float32)
    sh[:, 0] += 1.0
    traced = stages.TracedAtlas(points, sh, np.full((texels, 1, 3), 0.01, np.float32), np.full(texels, 16), 16, 4)
    out = Collect()
    dense_sh = n * n * 27 * 4
    tracemalloc.start()
    try:
        finishing.finish_atlas(atlas, traced, bake.PipelineSettings(trace=tracer.BakeSettings(threads=1)), 0.0, {}, out)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < dense_sh / 20, f"{peak / 2**20:.0f} MB traced"
    (raw,) = [c[1] for c in out.calls if c[0] == "raw"]
    (encoded,) = [c[1] for c in out.calls if c[0] == "atlas"]
    assert (encoded.width, encoded.height) == (n, n)
    images = [*encoded.files[encoded.encoding_file.key][1].values(), *raw["sh"].values(), *raw["texels"].values()]
    for image in images:
        assert isinstance(image, stages.PlacedImage) and image.shape == (n, n)
        assert image.inner.size * 100 < n * n, image.inner.shape  # the window: rows of the strip
    iz = encoded.files[encoded.encoding_file.key][1]["Iz.R"]
    band = exr.to_exr_rows(iz, copy=False)[n // 2 - 40 : n // 2 + 40]  # EXR rows around the strip
    assert band.shape == (80, n) and band.dtype == np.float32
    assert np.all(np.isfinite(band)) and (band > 0).all()  # the strip and its fill all around
    assert encoding.DILATE_RINGS < 40


def test_the_bake_points_of_an_almost_empty_atlas_are_those_of_its_scratch_images(monkeypatch):
    """The compiled kernels' scratch images index the covered texels' ranks when the atlas is
    almost empty (`raster.texel_ranks`): the bake points are those the whole-atlas scratch gives."""
    surface, _ = sphere_in_corner(1024, 0.25, (0.3, 0.55))
    atlas = bake.AtlasInput("Lightmap", 1024, 1024, surface, ["sphere"])
    ranked = bake.points_of(atlas, None, 2)
    rank, count = raster.texel_ranks(np.array([5, 5, 1 << 20]))
    assert count == 2 and rank.tolist() == [0, 0, 1]
    monkeypatch.setattr(raster, "SPARSE_TEXELS", 1 << 40)  # never ranks: a scratch image up to the last texel
    whole = bake.points_of(atlas, None, 2)
    for name in ("texel", "position", "normal", "face_normal", "coverage", "triangle", "texel_size", "others"):
        a, b = getattr(ranked, name, None), getattr(whole, name, None)
        if a is not None or b is not None:
            np.testing.assert_array_equal(a, b, err_msg=name)


def _signed_areas(uv: np.ndarray) -> np.ndarray:
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]


@pytest.mark.parametrize(
    "settings", [unwrap.UnwrapSettings(resolution=8192), unwrap.UnwrapSettings(texel_density=80.0)]
)
def test_a_long_strip_is_packed_across_rows_with_its_handedness(settings):
    """A 100 m × 1 cm strip packed upright by xatlas would touch every row of its atlas (and every
    ZIP block of its files); the unwrap turns such an atlas a quarter, so its texels lie in a
    few rows, texel centres on texel centres and the charts' winding as xatlas gave it."""
    v, f = meshes.plane(1.0)
    strip = v * [100.0, 0.01, 1.0]  # long along x: xatlas packs it upright
    res = unwrap.unwrap([unwrap.UnwrapMesh("strip", strip, f)], settings)
    w, h = res.atlas_sizes[0]
    px = res.objects[0].uv.astype(np.float64).reshape(-1, 2) * [w, h]
    span = px.max(axis=0) - px.min(axis=0)
    assert span[1] < 64 < span[0], span
    plain = unwrap.unwrap([unwrap.UnwrapMesh("square", v, f)], unwrap.UnwrapSettings(resolution=256))
    assert np.sign(_signed_areas(res.objects[0].uv)).tolist() == np.sign(_signed_areas(plain.objects[0].uv)).tolist()
    assert res.objects[0].texels == pytest.approx(float(np.abs(_signed_areas(px.reshape(-1, 3, 2))).sum() / 2))


def reencoded(folder, monkeypatch, whole: bool) -> tuple[dict[str, bytes], list]:
    """Re-encode the bake in `folder` (in place): from the window of its texels, or (`whole`) from
    the whole atlas's images as before windows; its files and the windows it read."""
    read = []
    with monkeypatch.context() as m:
        if whole:
            m.setattr(lightmap_files, "texel_window", lambda files, shape: None)
        else:
            real = lightmap_files.texel_window
            m.setattr(lightmap_files, "texel_window", lambda *a: (read.append(real(*a)), read[-1])[1])
        bake.reencode(lightmap_files.AtlasFiles(folder, "Lightmap"), encoding.EncoderSettings(), threads=2)
    files = files_of(folder)
    doc = json.loads(files["Lightmap.json"])
    assert doc.pop("reencoded_from_sh") and doc.pop("reencode_threads") == 2
    files["Lightmap.json"] = json.dumps(doc, sort_keys=True).encode()
    return files, read


def test_reencoding_an_almost_empty_atlas_reads_its_window_and_writes_the_bake_s_files(tmp_path, monkeypatch):
    """Re-encode reads only the window of the atlas its bake's stages worked on (the same
    rectangle, found from the texels file's blocks that are not its background) and writes the
    bake's files bit for bit, as a re-encode of the whole atlas's images does."""
    surface, scene = sphere_in_corner(1024, 0.25, (0.3, 0.55))
    windows = []
    real = encode_stage.window_of
    monkeypatch.setattr(encode_stage, "window_of", lambda *a: (windows.append(real(*a)), windows[-1])[1])
    bake_files = baked(tmp_path, "bake", monkeypatch, surface, scene, 1024, whole=False)
    monkeypatch.setattr(encode_stage, "window_of", real)
    for name in ("window", "whole"):
        shutil.copytree(tmp_path / "bake", tmp_path / name)
    window, read = reencoded(tmp_path / "window", monkeypatch, whole=False)
    whole, _ = reencoded(tmp_path / "whole", monkeypatch, whole=True)
    assert read == [windows[0]] and read[0] is not None
    assert bake_files.keys() == window.keys() == whole.keys()
    for name in bake_files:
        assert window[name] == whole[name], name
        if name.endswith(".json"):  # the stitch's count of texels it changed: the bake's gutters held 0
            for files in (window, bake_files):  # before it, a re-encode's their dilated SH (as before windows)
                doc = json.loads(files[name])
                doc["post"]["stitch"].pop("texels")
                files[name] = json.dumps(doc, sort_keys=True).encode()
        assert window[name] == bake_files[name], name


def test_reencoding_an_almost_empty_8192_atlas_allocates_for_its_texels_not_its_area(tmp_path):
    """A strip across an 8192² atlas (its files written from the window, as a bake writes them):
    reading, stitching, encoding and writing it again allocate a small fraction of one
    whole-atlas SH image (8192² × 27 float32 = 7.2 GB)."""
    n = 8192
    texel = (n // 2 + np.arange(2))[:, None] * n + np.arange(4, n - 4)[None, :]  # two texel rows
    window = encode_stage.window_of(texel.reshape(-1), n, n)
    assert window is not None and window.h == 2 + 2 * encode_stage.WINDOW_MARGIN
    h, w = window.h, window.w
    local = window.local(texel.reshape(-1))
    rng = np.random.default_rng(3)
    sh = np.zeros((h * w, 9, 3), np.float32)
    sh[local] = rng.random((len(local), 9, 3)) * 0.1
    sh[local, 0] += 1.0
    normal = np.zeros((h * w, 3), np.float32)
    normal[local] = [0.0, 0.0, 1.0]
    coverage = np.zeros(h * w, np.float32)
    coverage[local] = 1.0
    data = encoding.TexelData(
        sh=sh.reshape(h, w, 9, 3), normal=normal.reshape(h, w, 3), coverage=coverage.reshape(h, w), window=window
    )
    files = lightmap_files.AtlasFiles(tmp_path, "Lightmap")
    fill = data.fill()
    with exr.Staging() as staging:
        with encoding.raw_files(data, fill) as images_of:
            lightmap_files.stage_files(staging, files, images_of)
        encoded = encoding.encode_atlas(data, encoding.for_settings(encoding.EncoderSettings()), raw=False)
        lightmap_files.write_atlas(staging, files, encoded, {"objects": []})
        staging.commit()
    before = files.hhd.read_bytes()
    dense_sh = n * n * 27 * 4
    tracemalloc.start()
    try:
        bake.reencode(files, encoding.EncoderSettings(), threads=1)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < dense_sh / 20, f"{peak / 2**20:.0f} MB traced"
    assert files.hhd.read_bytes() == before


def test_blending_the_light_sets_of_an_almost_empty_atlas_reads_its_window(tmp_path, monkeypatch):
    """`blend_atlas` reads the sets' HHD files and the texels file in the window of the atlas's
    texels only (and one texel outside it) and writes the file a blend of the whole files writes,
    bit for bit; a re-encode then restores the bake's files of the sets' sum. At 512² (the whole
    files' blend, the reference, costs a quarter of 1024²'s): the window is still a 16th of it."""
    size = 512
    surface, scene = sphere_in_corner(size, 0.25, (0.3, 0.55))
    scene.lights = [SunLight(np.array([0.5, 0.3, 0.8]), np.full(3, 3.0), group="Sun")]  # + the world: Default
    atlas = bake.AtlasInput("Lightmap", size, size, surface, ["sphere"])
    trace = BakeSettings(samples=4, pass_samples=4, bounces=1, seed=2, threads=2)
    bake.run([atlas], scene, bake.PipelineSettings(trace=trace), tmp_path / "bake")
    baked_files = files_of(tmp_path / "bake")
    assert "Lightmap.Sun_hhd.exr" in baked_files
    weights = {"Sun": [0.5, 1.0, 2.0], "Default": 0.25}
    read = []
    real = lightmap_files.texel_window
    for name, window in (("window", lambda *a: (read.append(real(*a)), read[-1])[1]), ("whole", lambda *a: None)):
        shutil.copytree(tmp_path / "bake", tmp_path / name)
        with monkeypatch.context() as m:
            m.setattr(lightmap_files, "texel_window", window)
            light_sets.blend_atlas(lightmap_files.AtlasFiles(tmp_path / name, "Lightmap"), weights)
    assert read and read[0] is not None and read[0].h * read[0].w < size**2 / 4
    window, whole = files_of(tmp_path / "window"), files_of(tmp_path / "whole")
    assert window == whole and window["Lightmap_hhd.exr"] != baked_files["Lightmap_hhd.exr"]
    bake.reencode(lightmap_files.AtlasFiles(tmp_path / "window", "Lightmap"), encoding.EncoderSettings(), threads=2)
    assert (
        exr.read(tmp_path / "window" / "Lightmap_hhd.exr")[0].keys()
        == exr.read(tmp_path / "bake" / "Lightmap_hhd.exr")[0].keys()
    )
    assert files_of(tmp_path / "window")["Lightmap_hhd.exr"] == baked_files["Lightmap_hhd.exr"]
