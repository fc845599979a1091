"""The three.js runtime (web/: the `HHD_lightmap` GLTFLoader plugin) in a real browser: Debian's
Chromium, headless, WebGL2 on SwiftShader, driven through playwright-core by web/test/harness.mjs
(one browser for the whole module). Renders read back from a float render target are compared
with the numpy decode of the same file (scenekit/web_harness.py `reference`: core's packing decode,
`core.hhd.reconstruct`, `core.light_sets.blend`) at the lightmap UVs and normals of the browser's
own G-buffer pass, so rasterisation does not enter the comparison.

Without Chromium (or Node, or web/node_modules) the tests skip and say how to get them; under CI
(CI set) they fail instead: CI installs Chromium and the npm packages itself (.ci/run)."""

import json
import os
import time

import numpy as np
import pytest

from hhd_lightmapper.core import hhd, light_sets, octahedral, sh, textures
from hhd_lightmapper.core.encoding import web_packing
from scenekit import web_harness

# figures of the comparisons, printed at the end of the module (pytest -s) and kept in
# out/web/figures-<Blender version>.json for the reports
FIGURES: dict = {}


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    why = web_harness.unavailable()
    if why:
        if os.environ.get("CI"):
            pytest.fail(f"the browser tests cannot run under CI: {why}")
        pytest.skip(why)
    start = time.perf_counter()
    b = web_harness.Browser(tmp_path_factory.mktemp("browser"))
    FIGURES["browser"] = {"version": b.hello["version"], "webgl": b.hello["webgl"]["renderer"]}
    FIGURES["launch_seconds"] = round(time.perf_counter() - start, 2)
    yield b
    b.close()
    import bpy

    folder = web_harness.ROOT / "out" / "web"
    folder.mkdir(parents=True, exist_ok=True)
    version = ".".join(map(str, bpy.app.version))
    (folder / f"figures-{version}.json").write_text(json.dumps(FIGURES, indent=1) + "\n")
    print("\nweb runtime figures:", json.dumps(FIGURES, indent=1))


def compare(browser, glb_path, width, height, blend=False, weights=None, filter="bilinear") -> dict:
    """Lightmap-only render vs the numpy decode at the browser's G-buffer (its lightmap sampled
    as `filter` says: web_harness.sample_params): relative errors."""
    gbuf = web_harness.gbuffer(browser, width, height, blend=blend, weights=weights)
    got = browser.render("lightmap", width, height, blend=blend, weights=weights)
    want = web_harness.reference(web_harness.Glb(glb_path), gbuf, weights=weights, blend=blend, filter=filter)
    mask = gbuf["uv"][..., 3] > 0
    err = web_harness.relative_errors(got, want, mask)
    assert err.size > 0.2 * width * height, f"only {err.size} receiver pixels"
    return {
        "pixels": int(err.size),
        "median": float(np.median(err)),
        "p95": float(np.percentile(err, 95)),
        "max": float(err.max()),
    }


# --- the runtime on a synthetic file (no bake): exact up to float32 ---------------------------


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    return web_harness.synthetic_glb(tmp_path_factory.mktemp("synthetic") / "synthetic.glb")


@pytest.mark.slow
def test_lightmap_only_render_equals_the_numpy_decode_on_a_synthetic_file(browser, synthetic):
    summary = browser.load(synthetic)
    assert summary["receivers"] == 1 and summary["lightSets"] == ["Lamps", "Sky"], summary
    assert summary["probeLit"] == 1, summary
    assert summary["warnings"] == []
    # the atlas's own layers (the state the .blend had), then the live blend of the two sets
    FIGURES["synthetic"] = figures = compare(browser, synthetic, 128, 128, blend=False)
    assert figures["median"] <= 1e-4 and figures["p95"] <= 1e-3, figures
    weights = {"Lamps": [1.0, 0.5, 0.25], "Sky": [0.3, 0.3, 2.0]}
    FIGURES["synthetic_blend"] = figures = compare(browser, synthetic, 128, 128, blend=True, weights=weights)
    assert figures["median"] <= 1e-4 and figures["p95"] <= 1e-3, figures
    # the normal map moved the shading normal away from the vertex normal (the directional part
    # of the reconstruction is exercised)
    gbuf = web_harness.gbuffer(browser, 64, 64)
    mask = gbuf["uv"][..., 3] > 0
    cos = np.einsum("ij,ij->i", gbuf["n"][mask][:, :3], gbuf["nv"][mask][:, :3])
    assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) > 5.0
    assert [e for e in browser.errors() if "favicon" not in e] == []


def test_direction_is_decoded_per_texel_then_blended_across_the_octahedral_fold(browser, tmp_path):
    """d is filtered as unit vectors, not as octahedral bytes (docs/gltf.md "Filtering"): on a
    direction texture whose neighbouring texels lie on opposite edges of the octahedral map (z < 0,
    x flipping sign every few texels) the browser's d (DEBUG.DIRECTION) and its lightmap-only render
    equal the numpy decode-then-blend; blending the bytes before decoding (what the runtime did)
    turns d by tens of degrees there, which these bounds reject."""
    glb = web_harness.synthetic_glb(tmp_path / "fold.glb", seed=7, size=32, with_sets=False, probes=False, fold=True)
    summary = browser.load(glb)
    assert summary["receivers"] == 1 and summary["warnings"] == [], summary
    w, h = 128, 128
    gbuf = web_harness.gbuffer(browser, w, h)
    mask = gbuf["uv"][..., 3] > 0
    assert mask.sum() > 0.2 * w * h
    uv = gbuf["uv"][mask][:, :2].astype(np.float64)
    doc = web_harness.Glb(glb)
    atlas = doc.ext["atlases"][0]
    want = web_harness.sample_direction(doc.layers(atlas)["dir"], uv)
    got = web_harness.unit(browser.render("dir", w, h)[mask][:, :3].astype(np.float64))
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", got, want), -1.0, 1.0)))
    # the old way: the encoded bytes blended, then decoded
    raw = doc.texture_image(atlas["direction"]["index"]).astype(np.float64)[..., :2] / 255.0
    bytes_first = octahedral.decode(web_packing.sample_bilinear(raw, uv) * 2.0 - 1.0)
    old = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", bytes_first, want), -1.0, 1.0)))
    FIGURES["fold"] = figures = {
        "direction_max_deg": float(angle.max()),
        "bytes_first_p95_deg": float(np.percentile(old, 95)),
        "bytes_first_max_deg": float(old.max()),
    }
    assert np.percentile(old, 95) > 10.0, figures  # the file straddles the fold
    assert angle.max() <= 0.5, figures
    FIGURES["fold_lightmap"] = lm = compare(browser, glb, w, h)
    assert lm["median"] <= 1e-4 and lm["p95"] <= 1e-3 and lm["max"] <= 1e-2, lm
    assert [e for e in browser.errors() if "favicon" not in e] == []


@pytest.mark.slow
def test_probe_volume_lights_meshes_without_a_lightmap_as_the_numpy_trilinear_sh(browser, synthetic):
    """The box of the synthetic file has no lightmap: the plugin lights it from the probe volume
    (trilinear L2 SH, docs/format.md "Probe volumes"), compared with numpy at the browser's world
    positions and normals."""
    summary = browser.load(synthetic)
    assert summary["probeLit"] == 1, summary
    w, h = 128, 128
    got = browser.render("probes", w, h)
    pos, nrm, albedo = (browser.render(m, w, h) for m in ("probe_position", "probe_n", "probe_albedo"))
    mask = pos[..., 3] > 0
    assert mask.sum() > 200, mask.sum()
    want = np.zeros((h, w, 3))
    want[mask] = web_harness.probe_reference(
        web_harness.Glb(synthetic), pos[mask][:, :3].astype(float), nrm[mask][:, :3].astype(float), albedo[mask][:, :3]
    )
    err = web_harness.relative_errors(got, want, mask)
    FIGURES["synthetic_probes"] = figures = {
        "pixels": int(err.size),
        "median": float(np.median(err)),
        "p95": float(np.percentile(err, 95)),
        "max": float(err.max()),
    }
    assert figures["median"] <= 1e-4 and figures["p95"] <= 1e-3, figures


def test_bicubic_option_renders_as_numpy_catmull_rom_with_the_documented_clamps(browser, synthetic, tmp_path):
    """`filter: 'bicubic'` (docs/format.md "Bicubic sampling"): I_z and w_a Catmull-Rom over 4 × 4
    decoded texels, I_z clamped at 0 and w_a to [0, 1], d bilinear. On a 24² atlas with a sharp
    disc-shaped shadow (I_z down to 2 %, w_a 0 → 1: the kernel overshoots both) the lightmap-only
    render equals the numpy reference (core.textures.sample_bicubic of the decoded textures at the
    G-buffer UVs) and the I_z / w_a the shader used (DEBUG.HHD) equal the clamped reference, where
    the unclamped one leaves [0, ∞) and [0, 1]; near the edge bicubic differs from bilinear by far
    more than the tolerance (the test fails if the option is ignored), and without the option the
    same file renders bilinear. Then the light-set blend of the synthetic file with bicubic sets."""
    glb = web_harness.synthetic_glb(tmp_path / "edge.glb", seed=3, size=24, with_sets=False, probes=False, edge=True)
    w, h = 128, 128
    summary = browser.load(glb, filter="bicubic")
    assert summary["filter"] == "bicubic" and summary["warnings"] == [], summary
    FIGURES["bicubic_edge"] = figures = compare(browser, glb, w, h, filter="bicubic")
    assert figures["median"] <= 1e-4 and figures["p95"] <= 1e-3, figures
    # the clamps: the parameters the shader reconstructed from vs the reference's
    gbuf = web_harness.gbuffer(browser, w, h)
    mask = gbuf["uv"][..., 3] > 0
    uv = gbuf["uv"][mask][:, :2].astype(np.float64)
    doc = web_harness.Glb(glb)
    layers = doc.layers(doc.ext["atlases"][0])
    want = web_harness.sample_params(layers, uv, "bicubic")
    used = browser.render("hhd", w, h)[mask].astype(np.float64)
    iz_raw = textures.sample_bicubic(layers["iz"], uv, clamp=True)
    wa_raw = textures.sample_bicubic(layers["wa"], uv, clamp=True)[:, web_harness.CHANNEL["b"]]
    assert iz_raw.min() < -0.01 * iz_raw.max() and wa_raw.min() < -0.01 and wa_raw.max() > 1.01
    iz_err = float(np.abs(used[:, :3] - want.irradz).max() / want.irradz.max())
    wa_err = float(np.abs(used[:, 3] - want.ambient_weight).max())
    # the bilinear reference of the same pixels, and the bicubic render against it
    bilinear = web_harness.reference(doc, gbuf, filter="bilinear")
    got = browser.render("lightmap", w, h)
    vs_bilinear = web_harness.relative_errors(got, bilinear, mask)
    FIGURES["bicubic_edge"].update(
        {
            "iz_max_err_of_max": iz_err,
            "wa_max_err": wa_err,
            "iz_undershoot_of_max": float(-iz_raw.min() / iz_raw.max()),
            "wa_range_unclamped": [float(wa_raw.min()), float(wa_raw.max())],
            "vs_bilinear_p95": float(np.percentile(vs_bilinear, 95)),
            "vs_bilinear_over_5pct": float((vs_bilinear > 0.05).mean()),
        }
    )
    assert iz_err <= 1e-5 and wa_err <= 1e-5, figures
    assert used[:, :3].min() >= 0.0 and 0.0 <= used[:, 3].min() and used[:, 3].max() <= 1.0
    assert np.percentile(vs_bilinear, 95) > 0.05 and (vs_bilinear > 0.05).mean() > 0.02, figures
    # without the option (and no hint in the file): bilinear, as before
    summary = browser.load(glb)
    assert summary["filter"] == "bilinear", summary
    FIGURES["bicubic_edge_default"] = default = compare(browser, glb, w, h)
    assert default["median"] <= 1e-4 and default["p95"] <= 1e-3, default
    # light sets: each set's I_z and w_a bicubic, then the blend
    summary = browser.load(synthetic, filter="bicubic")
    assert summary["filter"] == "bicubic" and summary["lightSets"] == ["Lamps", "Sky"], summary
    weights = {"Lamps": [1.0, 0.5, 0.25], "Sky": [0.3, 0.3, 2.0]}
    FIGURES["bicubic_blend"] = figures = compare(
        browser, synthetic, 128, 128, blend=True, weights=weights, filter="bicubic"
    )
    assert figures["median"] <= 1e-4 and figures["p95"] <= 1e-3, figures
    assert [e for e in browser.errors() if "favicon" not in e] == []
    with pytest.raises(RuntimeError, match="unknown filter 'lanczos'"):
        browser.load(glb, filter="lanczos")
    browser.errors()


def _random_sets(rng, n, k):
    """k light sets of HHD form at n texels (luminance w_a), their vertex normals."""
    n_v = web_harness.unit(rng.normal(size=(n, 3)))
    sets = []
    for _ in range(k):
        d = web_harness.unit(rng.normal(size=(n, 3)))
        d = np.where((np.einsum("ni,ni->n", d, n_v) < 0)[:, None], -d, d)
        d = hhd.linear_sh.clamp_to_cone(d, n_v, 0.05)
        colour = rng.uniform(0.2, 1.0, (n, 3))
        ca, cd = rng.uniform(0.0, 3.0, (n, 1)) * colour, rng.uniform(0.0, 3.0, (n, 1)) * colour
        iz = ca + cd * np.einsum("ni,ni->n", d, n_v)[:, None]
        lum = iz @ np.array([0.2126, 0.7152, 0.0722])
        wa = np.divide(ca @ np.array([0.2126, 0.7152, 0.0722]), lum, out=np.ones_like(lum), where=lum > 0)
        # what the GPU receives: float32
        f32 = lambda a: a.astype(np.float32).astype(np.float64)  # noqa: E731
        sets.append(hhd.HHDParams(irradz=f32(iz), ambient_weight=f32(wa), direction=f32(d), model="hhd"))
    return web_harness.unit(n_v.astype(np.float32).astype(np.float64)), sets


def _tilted(n_v, degrees, rng):
    frames = sh.tangent_frames(n_v)
    phi = rng.uniform(0, 2 * np.pi, len(n_v))
    t = np.radians(degrees)
    local = np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.full(len(n_v), np.cos(t))], axis=1)
    return np.einsum("nij,nj->ni", frames, local)


def test_light_set_blend_in_glsl_equals_core_blend(browser):
    """The plugin's GLSL blend (the same source the receivers compile) read back from a float
    render target vs core.light_sets.blend, three weight settings (coloured ones included), three
    sets: the irradiance it reconstructs at n_v and at normals tilted 40° within 1e-3 relative."""
    rng = np.random.default_rng(56)
    n_v, sets = _random_sets(rng, 4096, 3)
    worst = {}
    for label, w in {
        "unit": [[1.0] * 3] * 3,
        "coloured": [[1.0, 0.5, 2.0], [0.25, 1.0, 0.0], [3.0, 3.0, 3.0]],
        "one_off": [[0.0] * 3, [0.7, 0.2, 0.1], [0.05, 0.5, 1.5]],
    }.items():
        w = np.asarray(w)
        iz, wa, d = browser.blend(n_v, sets, w)
        ref = light_sets.blend(sets, n_v, w)
        js = hhd.HHDParams(irradz=iz, ambient_weight=wa, direction=web_harness.unit(d), model="hhd")
        errs = []
        for n in (n_v, _tilted(n_v, 40, rng), _tilted(n_v, 80, rng)):
            got, want = hhd.reconstruct(js, n_v, n), hhd.reconstruct(ref, n_v, n)
            scale = np.maximum(np.linalg.norm(hhd.reconstruct(ref, n_v, n_v), axis=1), 1e-6)
            errs.append(np.linalg.norm(got - want, axis=1) / scale)
        err = np.concatenate(errs)
        worst[label] = {"max": float(err.max()), "p99": float(np.percentile(err, 99))}
        assert np.abs(iz - ref.irradz).max() <= 1e-5 * max(ref.irradz.max(), 1.0), label
        assert err.max() <= 1e-3, (label, worst[label])
    FIGURES["blend_vs_core"] = worst


# --- a real bake through the real exporter ---------------------------------------------------


@pytest.fixture(scope="module")
def exported(extension, tmp_path_factory):
    """A floor (normal-mapped, its material UV map first) and a box lit by two lamps in light
    groups Red and Blue, baked at 4 samples into a 128² atlas, exported by Blender's glTF
    exporter (File > Export > glTF 2.0, cameras included) with the extension's hook."""
    import bpy

    from hhd_lightmapper import cli
    from scenekit import blender as kit

    folder = tmp_path_factory.mktemp("web_bake")
    scene = kit.clear_scene()
    floor = kit.plane(
        "Floor", (0, 0, 0), 4, kit.material("ochre", (0.8, 0.55, 0.3), normal_image=kit.bumps_normal_map())
    )
    if not floor.data.uv_layers.get("UVMap"):
        floor.data.uv_layers.new(name="UVMap")
    box = kit.box("Box", (0.5, 0.3, 0.4), (0.8, 0.8, 0.8), kit.material("white", (0.8, 0.8, 0.8)))
    red = kit.light('POINT', (-1.0, -1.0, 1.5), energy=150.0, name="RedLamp", color=(1.0, 0.3, 0.2))
    blue = kit.light('POINT', (1.2, 1.0, 1.2), energy=100.0, name="BlueLamp", color=(0.3, 0.5, 1.0))
    kit.world((0.05, 0.05, 0.08))
    red.lightgroup, blue.lightgroup = "Red", "Blue"
    kit.camera((3.2, -3.6, 2.8), (-0.62, 0.62, -0.48), lens=24.0)
    # the exported camera's field of view follows the render's aspect: Blender's default 16:9, which
    # frames the receivers in the 4:3 renders here (an earlier test may have left another size)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 1920, 1080, 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    s = scene.hhd
    s.resolution, s.texel_density = 128, 0.0
    kit.unwrap([floor, box])
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.denoise, s.stitch_seams, s.pack_images = 4, 1, False, False, False
    s.output_dir = "//lightmaps"
    kit.select([floor, box])
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "scene.blend"))
    assert cli.main(["bake", "--objects", "Floor", "Box"]) == cli.EXIT_OK
    out = folder / "scene.glb"
    assert bpy.ops.export_scene.gltf(filepath=str(out), export_format='GLB', export_cameras=True) == {"FINISHED"}
    return out


def test_exported_bake_renders_in_the_browser_as_the_numpy_decode(browser, exported):
    """The issue's check: lightmap-only render (albedo × reconstructed irradiance) from the
    Blender camera, pixel by pixel over receiver pixels against the numpy decode of the same
    file: median ≤ 1 %, p95 ≤ 4 % relative; the same with the live light-set blend at three
    weight settings (coloured included)."""
    summary = browser.load(exported)
    assert summary["receivers"] >= 2 and summary["cameras"] == 1, summary
    assert {"Blue", "Red"} <= set(summary["lightSets"]), summary
    assert summary["emissiveMaps"] == 0, "the plugin keeps the exporter's emissive fallback on"
    assert summary["warnings"] == []
    FIGURES["exported"] = figures = compare(browser, exported, 192, 144, blend=False)
    assert figures["median"] <= 0.01 and figures["p95"] <= 0.04, figures
    for label, weights in {
        "as_exported": None,
        "coloured": {"Red": [1.0, 0.4, 0.1], "Blue": [0.2, 0.6, 2.0]},
        "red_off": {"Red": [0.0, 0.0, 0.0], "Blue": [1.5, 1.5, 1.5]},
    }.items():
        FIGURES[f"exported_blend_{label}"] = figures = compare(browser, exported, 192, 144, blend=True, weights=weights)
        assert figures["median"] <= 0.01 and figures["p95"] <= 0.04, (label, figures)
    assert [e for e in browser.errors() if "favicon" not in e] == []


def test_stock_gltfloader_loads_the_export_and_shows_the_fallback(browser, exported):
    """GLTFLoader without the plugin: no error, and the receivers are lit by the emissive
    fallback (non-black) although the scene has no lights."""
    browser.load(exported)
    mask = browser.render("uv", 192, 144)[..., 3] > 0
    browser.errors()
    summary = browser.load(exported, plugin=False)
    assert summary["receivers"] == 0 and summary["emissiveMaps"] >= 2, summary
    stock = browser.render("stock", 192, 144)
    assert [e for e in browser.errors() if "favicon" not in e] == []
    lum = stock[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    lit = float((lum[mask] > 1e-3).mean())
    FIGURES["stock_fallback_lit_fraction"] = lit
    assert lit >= 0.95, lit


def test_exporter_requests_the_preview_filter_and_the_plugin_honours_it(browser, exported, tmp_path):
    """The export's root `filter` is the EEVEE preview's Filter ("bilinear" in the fixture's export);
    with Filter: Bicubic the file asks for "bicubic", the plugin without options renders the real
    bake bicubic (as the numpy Catmull-Rom decode, the exported test's bounds), and the option
    `filter: 'bilinear'` overrides the hint."""
    import bpy

    assert web_harness.Glb(exported).ext["filter"] == "bilinear"
    scene = bpy.context.scene
    scene.hhd.preview_filter = 'BICUBIC'
    try:
        out = tmp_path / "bicubic.glb"
        assert bpy.ops.export_scene.gltf(filepath=str(out), export_format='GLB', export_cameras=True) == {"FINISHED"}
    finally:
        scene.hhd.preview_filter = 'BILINEAR'
    assert web_harness.Glb(out).ext["filter"] == "bicubic"
    summary = browser.load(out)
    assert summary["filter"] == "bicubic" and summary["warnings"] == [], summary
    FIGURES["exported_bicubic"] = figures = compare(browser, out, 192, 144, filter="bicubic")
    assert figures["median"] <= 0.01 and figures["p95"] <= 0.04, figures
    assert browser.load(out, filter="bilinear")["filter"] == "bilinear"
    FIGURES["exported_bicubic_overridden"] = figures = compare(browser, out, 192, 144)
    assert figures["median"] <= 0.01 and figures["p95"] <= 0.04, figures
    assert [e for e in browser.errors() if "favicon" not in e] == []
