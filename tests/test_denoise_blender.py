"""Denoising in Blender: the scene's Denoise setting through the Bake and Re-encode operators and the
command line, with the OIDN library Blender ships (found by bridge/denoiser.py) and the weights of
tools/fetch_oidn_weights.py (the `oidn_weights` fixture: skipped with the reason if unavailable).

The raw SH file always keeps the SH as traced, so a Re-encode can switch denoising off and on
without tracing; a Blender without the library bakes undenoised and says so."""

import importlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from conftest import EXTENSION_MODULE
from hhd_lightmapper import cli
from hhd_lightmapper.core.colour import LUMINANCE
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.post.denoise import oidn
from scenekit import blender as kit
from test_oidn import bpy_library_dirs

pytestmark = pytest.mark.bpy
NOT_FOUND = "Open Image Denoise library not found in this Blender"


def build_scene(folder: Path):
    """Floor + cube under a sun and a sky, unwrapped at 256², 8 samples and 1 bounce (noisy, so the
    denoiser has work), receivers selected, saved as folder/scene.blend with Denoise on."""
    import bpy

    scene = kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4, kit.material("grey"))
    cube = kit.box("Cube", (0, 0, 0.5), (1, 1, 1), kit.material("red", (0.8, 0.1, 0.1)))
    kit.light('SUN', rotation=(0.5, 0.2, 0), energy=3.0)
    kit.world((0.1, 0.2, 0.3))
    kit.unwrap([floor, cube])
    s = scene.hhd
    s.preset = 'PRODUCTION'
    s.samples, s.bounces, s.seed, s.output_dir, s.pack_images = 8, 1, 0, str(folder / "lightmaps"), False
    assert s.preset == 'CUSTOM' and s.denoise
    kit.select([floor, cube])
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "scene.blend"))
    return scene


@pytest.fixture
def scene(extension, oidn_weights, restore_hhd_settings, tmp_path):
    """`build_scene` in tmp_path: (scene, tmp_path)."""
    return build_scene(tmp_path), tmp_path


@pytest.fixture(scope="module")
def on_and_off(extension, oidn_weights, tmp_path_factory):
    """`build_scene` baked once with Denoise on into on/ and once off into off/: {'on': files,
    'off': files, 'summary': {'on': …, 'off': …}} (the panel's bake summaries). Shared by the
    tests of this module: copy a folder (`copied`) before changing it."""
    from conftest import hhd_settings_restored

    folder = tmp_path_factory.mktemp("denoise")
    with hhd_settings_restored():
        scene = build_scene(folder)
        baked = {"summary": {}}
        for name, denoise in (("on", True), ("off", False)):
            baked[name] = bake(scene, folder / name, denoise)
            baked["summary"][name] = scene.hhd.bake_summary
    return baked


def copied(files: lightmap_files.AtlasFiles, folder: Path) -> lightmap_files.AtlasFiles:
    """A copy of the bake `files` in `folder`."""
    shutil.copytree(files.folder, folder)
    return lightmap_files.AtlasFiles(folder, files.name)


def bake(scene, folder: Path, denoise: bool) -> lightmap_files.AtlasFiles:
    """Bake with the Bake operator into `folder` with Denoise set to `denoise`."""
    import bpy

    scene.hhd.output_dir, scene.hhd.denoise = str(folder), denoise
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    return lightmap_files.AtlasFiles(folder, "Lightmap")


def reencode(scene, files: lightmap_files.AtlasFiles, denoise: bool) -> None:
    import bpy

    scene.hhd.output_dir, scene.hhd.denoise = str(files.folder), denoise
    assert bpy.ops.hhd.encode() == {'FINISHED'}


def pixels(path: Path) -> dict:
    """An EXR's channels as bytes."""
    return {k: v.tobytes() for k, v in exr.read(path)[0].items()}


def record(files: lightmap_files.AtlasFiles) -> dict:
    return lightmap_files.read_sidecar(files.sidecar)["post"]["denoise"]


def irradz(files: lightmap_files.AtlasFiles) -> np.ndarray:
    """The HHD file's I_z luminance (H, W), rows bottom-up as `TexelData`."""
    channels, _ = exr.read(files.hhd)
    iz = np.stack([exr.from_exr_rows(channels[f"Iz.{c}"]) for c in "RGB"], -1).astype(np.float64)
    return iz @ LUMINANCE


def without_library(monkeypatch) -> None:
    """Simulate a Blender without OIDN: the library lookup of the installed extension (the
    operators) and of the package (the in-process command line) finds nothing."""
    for package in (EXTENSION_MODULE, "hhd_lightmapper"):
        monkeypatch.setattr(importlib.import_module(f"{package}.bridge.denoiser"), "oidn_library", lambda: "")


def test_denoised_bake_filters_the_encoding_and_keeps_the_raw_sh(on_and_off):
    """Denoise on: the sidecar records OIDN's run, the HHD file is of the filtered SH (less
    texel-to-texel noise, the same mean light), the raw SH and texel files are the traced ones."""
    on, off = on_and_off["on"], on_and_off["off"]
    assert ", denoised (" in on_and_off["summary"]["on"]
    assert ", not denoised (" in on_and_off["summary"]["off"]

    r = record(on)
    assert r["enabled"] and r["applied"] and "warning" not in r
    assert r["oidn_version"].startswith("2.") and r["charts"] >= 1 and r["pages"] >= 1
    assert r["page_texels"] > 0 and r["seconds"] >= 0.0
    assert record(off) == {"enabled": False}
    assert on.sh.read_bytes() == off.sh.read_bytes()
    assert on.texels.read_bytes() == off.texels.read_bytes()
    assert pixels(on.hhd) != pixels(off.hhd)

    baked = lightmap_files.read_texel_data(off).baked
    noisy, clean = irradz(off), irradz(on)
    pairs = baked[:, 1:] & baked[:, :-1]  # horizontally adjacent baked texels (mostly in one chart)
    roughness = [np.median(np.abs(np.diff(iz, axis=1))[pairs]) for iz in (noisy, clean)]
    assert roughness[1] < 0.25 * roughness[0], roughness  # measured 0.04 (bpy 5.3)
    assert abs(clean[baked].mean() / noisy[baked].mean() - 1.0) < 0.02  # measured 0.0002


def test_reencode_switches_denoising_off_and_on_without_tracing(scene, on_and_off):
    """Re-encode with Denoise off gives the undenoised bake's HHD file, with it on the denoised
    one (the raw SH file and the sidecar's bake record untouched)."""
    scene, folder = scene
    off, on = copied(on_and_off["off"], folder / "off"), copied(on_and_off["on"], folder / "on")
    denoised, undenoised, sh = on.hhd.read_bytes(), off.hhd.read_bytes(), on.sh.read_bytes()
    bake_record = lightmap_files.read_sidecar(on.sidecar)["bake"]
    reencode(scene, on, False)
    assert on.hhd.read_bytes() == undenoised  # the undenoised bake's file, bit for bit
    doc = lightmap_files.read_sidecar(on.sidecar)
    assert doc["post"]["denoise"] == {"enabled": False} and doc["reencoded_from_sh"]
    assert doc["bake"] == bake_record and on.sh.read_bytes() == sh  # no tracing, raw SH untouched
    reencode(scene, on, True)
    assert on.hhd.read_bytes() == denoised
    assert record(on)["applied"] and on.sh.read_bytes() == sh
    reencode(scene, off, True)  # a bake made undenoised can be denoised later, the same way
    assert off.hhd.read_bytes() == denoised


def test_without_the_library_the_bake_finishes_undenoised_and_says_why(scene, monkeypatch, capfd):
    scene, folder = scene
    off = bake(scene, folder / "off", False)
    without_library(monkeypatch)
    capfd.readouterr()
    missing = bake(scene, folder / "missing", True)
    out = capfd.readouterr()
    warning = f"atlas 'Lightmap', denoise: not denoised: {NOT_FOUND}"
    assert f"Warning: {warning}" in out.out + out.err  # the operator's report
    assert "not denoised (see the warnings)" in scene.hhd.bake_summary
    assert missing.hhd.read_bytes() == off.hhd.read_bytes()
    r = record(missing)
    assert r["enabled"] and not r["applied"] and NOT_FOUND in r["warning"]

    reencode(scene, missing, True)  # Re-encode reports it the same way
    out = capfd.readouterr()
    assert f"Warning: {warning}" in out.out + out.err
    assert missing.hhd.read_bytes() == off.hhd.read_bytes()

    # the command line prints it, and the bake still succeeds
    assert cli.main(["bake", "--out", str(folder / "cli"), "--objects", "Floor", "Cube"]) == cli.EXIT_OK
    out = capfd.readouterr().out
    assert f"warning: {warning}" in out and "not denoised (see the warnings)" in out
    assert (folder / "cli" / "Lightmap_hhd.exr").read_bytes() == off.hhd.read_bytes()
    assert cli.main(["encode", "--out", str(folder / "cli"), "--objects", "Floor", "Cube"]) == cli.EXIT_OK
    assert f"warning: {warning}" in capfd.readouterr().out


def test_command_line_denoise_flags_override_the_scene_and_the_preset(scene, capsys):
    scene, folder = scene
    s = scene.hhd

    def run(action, name, *args, scene_denoise):
        """`action` into folder/name with the scene's Denoise at `scene_denoise`: the sidecar's
        denoise record and the summary line."""
        s.preset, s.samples, s.bounces, s.denoise = 'CUSTOM', 8, 1, scene_denoise
        capsys.readouterr()
        code = cli.main([action, "--out", str(folder / name), "--objects", "Floor", "Cube", *args])
        out = capsys.readouterr().out
        assert code == cli.EXIT_OK, out
        summary = [line for line in out.splitlines() if line.startswith(f"{action}: ")][-1]  # the last line
        return json.loads((folder / name / "Lightmap.json").read_text())["post"]["denoise"], summary

    on, summary = run("bake", "a", scene_denoise=True)
    assert on["applied"] and ", denoised (" in summary
    off, summary = run("bake", "b", "--no-denoise", scene_denoise=True)
    assert off == {"enabled": False} and ", not denoised (" in summary
    on, _ = run("bake", "c", "--denoise", scene_denoise=False)
    assert on["applied"]
    # a preset sets Denoise like its other knobs (reference: off), unless the flag is given too
    reference = ("--preset", "reference", "--samples", "8", "--bounces", "1")
    off, _ = run("bake", "d", *reference, scene_denoise=True)
    assert off == {"enabled": False}
    assert s.preset == 'CUSTOM' and s.denoise  # the scene's own settings: the options hold for this run only
    on, _ = run("bake", "e", *reference, "--denoise", scene_denoise=False)
    assert on["applied"]
    off, _ = run("bake", "f", "--preset", "draft", "--samples", "8", "--no-denoise", scene_denoise=True)
    assert off == {"enabled": False}
    # Re-encode: the flag, else the scene's setting
    off, summary = run("encode", "a", "--no-denoise", scene_denoise=True)
    assert off == {"enabled": False} and "not denoised)" in summary
    on, summary = run("encode", "b", "--denoise", scene_denoise=False)
    assert on["applied"] and ", denoised)" in summary
    off, _ = run("encode", "c", scene_denoise=False)
    assert off == {"enabled": False}


def test_a_preset_sets_denoise_and_unticking_it_makes_the_preset_custom(restore_hhd_settings):
    import bpy

    from hhd_lightmapper.core import presets

    s = bpy.context.scene.hhd
    for name, preset in presets.PRESETS.items():
        s.preset = name
        assert s.preset == name and s.denoise == preset.denoise
    s.preset = 'PRODUCTION'
    s.denoise = not presets.get("PRODUCTION").denoise
    assert s.preset == 'CUSTOM'
    s.preset = 'PRODUCTION'
    assert s.preset == 'PRODUCTION' and s.denoise == presets.get("PRODUCTION").denoise


def test_the_library_found_is_the_one_the_bpy_module_ships(extension):
    expected = oidn.find_library(bpy_library_dirs())
    if expected is None:
        pytest.skip(f"this bpy build has no Open Image Denoise library ({bpy_library_dirs()})")
    for package in (EXTENSION_MODULE, "hhd_lightmapper"):
        found = importlib.import_module(f"{package}.bridge.denoiser").oidn_library()
        assert Path(found) == expected, package


def test_the_folders_searched_cover_each_platforms_blender(extension):
    """Where Blender keeps its OIDN library, from the paths bpy reports on each platform."""
    from hhd_lightmapper.bridge.denoiser import install_dirs

    linux = install_dirs("", "/opt/blender-4.2/4.2", "/opt/blender-4.2/blender")
    assert Path("/opt/blender-4.2/lib") in linux
    windows = install_dirs("", "C:/Blender/4.2", "C:/Blender/blender.exe")
    assert Path("C:/Blender/blender.shared") in windows
    app = "/Applications/Blender.app/Contents"
    macos = install_dirs("", f"{app}/Resources/4.2", f"{app}/MacOS/Blender")
    assert Path(f"{app}/Resources/lib") in macos
    module = install_dirs("/venv/site-packages/bpy/__init__.so", "/venv/site-packages/bpy/5.3", "")
    assert module[:2] == [Path("/venv/site-packages/bpy/lib"), Path("/venv/site-packages/bpy")]
    assert len(module) == len(set(module))
