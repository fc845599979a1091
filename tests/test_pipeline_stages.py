"""The pipeline's stages in core/bake/ (no Blender): a post stage plugs in at core/post/ and
receives the atlas's texel images; `trace_surface` is stages 1–2 of `run`."""

from dataclasses import replace

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, encoding, post, unwrap
from hhd_lightmapper.core.bake import finishing
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.post.denoise import filtering, oidn, pages
from hhd_lightmapper.core.post.seams import geometry, stitching
from hhd_lightmapper.core.scene import BakeScene, SunLight
from hhd_lightmapper.core.tracer import BakeSettings
from scenekit import meshes
from test_oidn import bpy_library_dirs, denoiser, library  # noqa: F401  (fixtures)

RES = 256


def plane():
    v, f = meshes.plane(2.0)
    res = unwrap.unwrap([unwrap.UnwrapMesh("floor", v, f)], unwrap.UnwrapSettings(resolution=RES))
    surface = bakepoints.SurfaceTriangles(
        v[f], np.tile([0, 0, 1.0], (2, 3, 1)), res.objects[0].uv.astype(float), np.zeros(2, int), np.full((2, 3), 0.5)
    )
    cv, cf = meshes.cube(0.4, centre=(1.0, 1.0, 0.5))  # an occluder: shadow and bounce make the passes differ
    tris = np.concatenate([v[f], cv[cf]])
    scene = BakeScene(
        tris,
        np.full((len(tris), 3), 0.5),
        lights=[SunLight(np.array([0.6, 0.0, 0.8]), np.ones(3))],
        world=np.array([0.1, 0.2, 0.3]),
    )
    return surface, scene


def written_sh(folder) -> np.ndarray:
    channels, _ = exr.read(lightmap_files.AtlasFiles(folder, "Lightmap").sh)
    return np.stack([channels[n] for n in lightmap_files.SH_CHANNELS], -1)


def test_a_post_stage_receives_the_texel_images_and_its_output_is_what_gets_encoded(tmp_path, monkeypatch):
    surface, scene = plane()
    settings = bake.PipelineSettings(trace=BakeSettings(samples=8, pass_samples=4, bounces=1, seed=3))
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"])
    bake.run([atlas], scene, settings, tmp_path / "plain")
    seen = []

    def double(data: encoding.TexelData, check) -> tuple[encoding.TexelData, dict]:
        check()
        seen.append(data)
        return replace(data, sh=2.0 * data.sh), {"enabled": True, "factor": 2}

    monkeypatch.setattr(post, "stages_for", lambda s, seams=None, raw_sh=None: [("double", double)])
    bake.run([atlas], scene, settings, tmp_path / "doubled")
    (data,) = seen
    assert data.sh.shape == (RES, RES, 9, 3) and data.baked.sum() > 0.9 * RES * RES
    # the raw SH file keeps the SH as traced; the encoding is of the stage's output
    np.testing.assert_array_equal(written_sh(tmp_path / "doubled"), written_sh(tmp_path / "plain"))
    plain, doubled = (lightmap_files.AtlasFiles(tmp_path / k, "Lightmap") for k in ("plain", "doubled"))
    irradiance = [exr.read(f.hhd)[0]["Iz.R"] for f in (plain, doubled)]
    np.testing.assert_allclose(irradiance[1], 2.0 * irradiance[0], rtol=1e-5)
    assert lightmap_files.read_sidecar(doubled.sidecar)["post"]["double"] == {"enabled": True, "factor": 2}
    records = lightmap_files.read_sidecar(plain.sidecar)["post"]
    assert records["denoise"] == {"enabled": False} and records["stitch"]["applied"]  # the defaults


def test_stitching_runs_after_denoising_on_the_seams_of_the_atlas_and_is_off_when_switched_off(tmp_path, monkeypatch):
    """The stitch stage follows the denoise stage and receives the seams found on the bake
    points' mesh (the seams file keeps the same); switched off, it does not run, and the sidecar
    says so."""
    settings = bake.PipelineSettings(denoise=True)
    assert [name for name, _ in post.stages_for(settings)] == ["denoise", "stitch"]
    assert [name for name, _ in post.stages_for(replace(settings, stitch_seams=False))] == ["denoise"]

    surface, scene = plane()
    trace = BakeSettings(samples=4, pass_samples=4, bounces=0, seed=3)
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"])
    seen = []

    def stitch(data, pairs, check=None, threads=0):
        seen.append(pairs)
        return data, {"seams": len(pairs)}

    monkeypatch.setattr(stitching, "stitch", stitch)
    (on,) = bake.run([atlas], scene, bake.PipelineSettings(trace=trace), tmp_path / "on")
    (pairs,) = seen
    traced = bake.trace_surface(surface, RES, RES, scene, trace)
    expected = geometry.find_seams(traced.points.mesh, RES, RES)
    assert len(pairs) == len(expected) and np.array_equal(pairs.a, expected.a) and np.array_equal(pairs.b, expected.b)
    stored = geometry.Seams.load(on.files.seams)
    assert np.array_equal(stored.a, expected.a) and np.array_equal(stored.weight, expected.weight)
    record = lightmap_files.read_sidecar(on.files.sidecar)["post"]["stitch"]
    assert record["encoded"]["enabled"]  # the second half, on the encoded layers
    assert {k: v for k, v in record.items() if k != "encoded"} == {
        "enabled": True,
        "applied": True,
        "seams": len(expected),
    }
    (off,) = bake.run([atlas], scene, bake.PipelineSettings(trace=trace, stitch_seams=False), tmp_path / "off")
    assert len(seen) == 1 and off.files.seams.is_file()
    assert lightmap_files.read_sidecar(off.files.sidecar)["post"]["stitch"] == {"enabled": False}


def test_trace_surface_is_the_first_two_stages_of_a_bake(tmp_path):
    surface, scene = plane()
    trace = BakeSettings(samples=8, pass_samples=4, bounces=1, seed=3)
    traced = bake.trace_surface(surface, RES, RES, scene, trace)
    bake.run(
        [bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"])], scene, bake.PipelineSettings(trace=trace), tmp_path
    )
    image = traced.points.image(traced.sh, dtype=np.float32).reshape(RES, RES, 27)
    written = exr.from_exr_rows(written_sh(tmp_path))
    mask = traced.points.image(np.ones(len(traced.points.texel)), dtype=bool)
    np.testing.assert_array_equal(written[mask], image[mask])


def sphere():
    """A smooth UV sphere (vertex normals) cut into charts by xatlas, above a floor, under a sun
    and a sky: an atlas with smooth seams."""
    v, f = meshes.uv_sphere(rings=8, segments=16, radius=0.8)
    v = v + [0.0, 0.0, 1.0]
    res = unwrap.unwrap([unwrap.UnwrapMesh("sphere", v, f)], unwrap.UnwrapSettings(resolution=RES))
    normals = meshes.vertex_normals(v, f)[f]
    surface = bakepoints.SurfaceTriangles(
        v[f], normals, res.objects[0].uv.astype(float), np.zeros(len(f), int), np.full((len(f), 3), 0.6)
    )
    fv, ff = meshes.plane(6.0)
    tris = np.concatenate([v[f], fv[ff]])
    scene = BakeScene(
        tris,
        np.full((len(tris), 3), 0.5),
        lights=[SunLight(np.array([0.5, 0.3, 0.8]), np.full(3, 3.0))],
        world=np.array([0.2, 0.3, 0.5]),
    )
    return surface, scene


@pytest.mark.slow
def test_a_stitched_bake_keeps_the_traced_files_and_reencodes_to_the_same_bytes(tmp_path):
    """Stitching changes only the encoding: the raw SH and texel files are those of the
    unstitched bake, and a re-encode of either bake with stitching on gives the stitched bake's
    encoding bit for bit (from the seams file, without the mesh); with it off, the unstitched one."""
    surface, scene = sphere()
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["sphere"])
    trace = BakeSettings(samples=4, pass_samples=4, bounces=1, seed=1)
    (on,) = bake.run([atlas], scene, bake.PipelineSettings(trace=trace), tmp_path / "on")
    (off,) = bake.run([atlas], scene, bake.PipelineSettings(trace=trace, stitch_seams=False), tmp_path / "off")
    record = lightmap_files.read_sidecar(on.files.sidecar)["post"]["stitch"]
    assert record["applied"] and record["seams"] > 0 and record["texels"] > 0
    assert record["after"]["mean"] < 0.5 * record["before"]["mean"], record
    for f in ("sh", "texels"):
        assert getattr(on.files, f).read_bytes() == getattr(off.files, f).read_bytes(), f
    stitched, unstitched = on.files.hhd.read_bytes(), off.files.hhd.read_bytes()
    assert stitched != unstitched
    bake.reencode(off.files, encoding.EncoderSettings(), threads=1)
    assert off.files.hhd.read_bytes() == stitched
    bake.reencode(on.files, encoding.EncoderSettings(), threads=1, stitch_seams=False)
    assert on.files.hhd.read_bytes() == unstitched
    on.files.seams.unlink()  # a bake from before seams files: encoded unstitched, with a warning
    _, warnings = bake.reencode(on.files, encoding.EncoderSettings(), threads=1)
    assert warnings == [f"atlas 'Lightmap', stitch: {post.NO_SEAMS}"] and on.files.hhd.read_bytes() == unstitched


@pytest.mark.parametrize("model", ["sh_l2", "sg9", "hbasis_l2"])
def test_a_stitched_bake_in_a_coefficient_encoding_encodes_the_stitched_sh(tmp_path, model):
    """A bake (and a re-encode) in one of Baking Lab's encodings with stitching on: the SH stitch
    runs, the encoded layers are the stitched SH's projection (no second, HHD-only stitch: it
    used to fail on layers it did not know), and the sidecar says so."""
    surface, scene = sphere()
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["sphere"])
    trace = BakeSettings(samples=4, pass_samples=4, bounces=1, seed=1)
    settings = bake.PipelineSettings(trace=trace, encoder=encoding.EncoderSettings(model=model))
    (done,) = bake.run([atlas], scene, settings, tmp_path / "on")
    record = lightmap_files.read_sidecar(done.files.sidecar)["post"]["stitch"]
    assert record["applied"] and record["seams"] > 0
    assert record["encoded"] == {"enabled": False, "why": post.ENCODED_STITCH_SKIPPED}
    path = done.files.path(encoding.for_settings(settings.encoder).file)
    first = path.read_bytes()
    bake.reencode(done.files, settings.encoder, threads=1)
    assert path.read_bytes() == first


class FailingDenoiser:
    """Blender's OIDN, raising DenoiserError at its `fail_at`-th directional call (the pass that
    writes a banded page into the SH), noting whether the SH had been written by then."""

    def __init__(self, real, fail_at: int):
        self.real, self.fail_at, self.calls = real, fail_at, 0

    def __getattr__(self, name):
        return getattr(self.real, name)

    def denoise(self, image, directional=False, input_scale=None):
        if directional:
            self.calls += 1
            if self.calls == self.fail_at:
                raise oidn.DenoiserError("injected failure")
        return self.real.denoise(image, directional=directional, input_scale=input_scale)


@pytest.mark.slow
def test_a_denoiser_failing_half_way_gives_the_undenoised_bake(tmp_path, monkeypatch, library, denoiser):  # noqa: F811
    """The bake denoises in place with nothing of the traced SH kept (its raw files are written
    first); OIDN failing after part of the atlas is written puts the traced SH back from the
    raw SH file, so the atlas is encoded exactly as an undenoised bake, with a warning."""
    surface, scene = plane()
    trace = BakeSettings(samples=8, pass_samples=4, bounces=1, seed=3)
    atlas = bake.AtlasInput("Lightmap", RES, RES, surface, ["floor"])
    (plain,) = bake.run([atlas], scene, bake.PipelineSettings(trace=trace), tmp_path / "plain")
    monkeypatch.setattr(pages, "BAND_TEXELS", 32 * RES)  # 16-row bands of the 260-row page, written 114 rows behind
    restored = []
    read_back = finishing.Staged.traced_sh
    monkeypatch.setattr(finishing.Staged, "traced_sh", lambda *a: (restored.append(1), read_back(*a))[1])
    real_for = filtering.denoiser_for
    monkeypatch.setattr(filtering, "denoiser_for", lambda lib, threads: FailingDenoiser(real_for(lib, threads), 37))
    settings = bake.PipelineSettings(trace=trace, denoise=True, denoiser_library=str(library))
    (failed,) = bake.run([atlas], scene, settings, tmp_path / "failed")
    assert restored == [1], "the failure came before any texel was written: no restore to test"
    assert any("not denoised: injected failure" in w for w in failed.warnings)
    for path in ("hhd", "sh", "texels"):
        assert getattr(failed.files, path).read_bytes() == getattr(plain.files, path).read_bytes(), path
    # a re-encode denoises the SH it read: it reads it back from the raw SH file (once to denoise, once back)
    read = []
    real_read = lightmap_files.read_sh
    monkeypatch.setattr(lightmap_files, "read_sh", lambda path: (read.append(path), real_read(path))[1])
    _, warnings = bake.reencode(
        failed.files, encoding.EncoderSettings(), threads=2, denoise=True, denoiser_library=str(library)
    )
    assert read == [failed.files.sh] * 2 and any("not denoised: injected failure" in w for w in warnings)
    assert exr.read(failed.files.hhd)[0].keys() == exr.read(plain.files.hhd)[0].keys()
    for name, channel in exr.read(failed.files.hhd)[0].items():
        assert channel.tobytes() == exr.read(plain.files.hhd)[0][name].tobytes(), name
