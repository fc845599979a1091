"""The pipeline's stages in core/bake.py (no Blender): a post stage plugs in at core/post.py and
receives the atlas's texel images; `trace_surface` is stages 1–2 of `run`."""

from dataclasses import replace

import numpy as np

from hhd_lightmapper.core import bake, bakepoints, encoding, exr, lightmap_files, post, unwrap
from hhd_lightmapper.core.scene import BakeScene, SunLight
from hhd_lightmapper.core.tracer import BakeSettings
from scenekit import meshes

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

    monkeypatch.setattr(post, "stages_for", lambda s: [("double", double)])
    bake.run([atlas], scene, settings, tmp_path / "doubled")
    (data,) = seen
    assert data.sh.shape == (RES, RES, 9, 3) and data.baked.sum() > 0.9 * RES * RES
    # the raw SH file keeps the SH as traced; the encoding is of the stage's output
    np.testing.assert_array_equal(written_sh(tmp_path / "doubled"), written_sh(tmp_path / "plain"))
    plain, doubled = (lightmap_files.AtlasFiles(tmp_path / k, "Lightmap") for k in ("plain", "doubled"))
    irradiance = [exr.read(f.hhd)[0]["Iz.R"] for f in (plain, doubled)]
    np.testing.assert_allclose(irradiance[1], 2.0 * irradiance[0], rtol=1e-5)
    assert lightmap_files.read_sidecar(doubled.sidecar)["post"]["double"] == {"enabled": True, "factor": 2}
    assert lightmap_files.read_sidecar(plain.sidecar)["post"] == {"denoise": {"enabled": False}}


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
