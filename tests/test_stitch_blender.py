"""Seam stitching in Blender: the scene's Stitch Seams setting through the Bake and Re-encode
operators and the command line (`--stitch/--no-stitch`).

A bake always writes the atlas's seams file next to its EXRs, so Re-encode can switch stitching
off and on without tracing; stitching off leaves the HHD file exactly as the encoder makes it from
the traced SH (no post stage); a bake made before seams files existed re-encodes unstitched with a
warning. Denoising is off throughout (its own tests are tests/test_denoise_blender.py): these
bakes need no OIDN weights."""

import json
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper import cli
from hhd_lightmapper.core import encoding, post
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.post.seams import geometry, reads
from scenekit import blender as kit

pytestmark = pytest.mark.bpy


@pytest.fixture
def scene(extension, restore_hhd_settings, tmp_path):
    """A smooth-shaded UV sphere on a floor under a sun and a sky, unwrapped at 256² (the sphere
    splits into several charts: smooth seams), 4 samples, 1 bounce, Denoise off, receivers
    selected, saved as tmp_path/scene.blend."""
    import bpy

    scene = kit.clear_scene()
    floor = kit.plane("Floor", (0, 0, 0), 4, kit.material("grey"))
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8, radius=0.8, location=(0, 0, 0.8))
    sphere = bpy.context.active_object
    sphere.name = "Sphere"
    sphere.data.materials.append(kit.material("red", (0.8, 0.2, 0.1)))
    bpy.ops.object.shade_smooth()
    kit.light('SUN', rotation=(0.6, 0.2, 0.4), energy=3.0)
    kit.world((0.2, 0.3, 0.5))
    kit.unwrap([floor, sphere])
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.seed, s.denoise, s.pack_images = 4, 1, 0, False, False
    s.output_dir = str(tmp_path / "lightmaps")
    kit.select([floor, sphere])
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    return scene, tmp_path


def bake(scene, folder: Path, stitch: bool) -> lightmap_files.AtlasFiles:
    """Bake with the Bake operator into `folder` with Stitch Seams set to `stitch`."""
    import bpy

    scene.hhd.output_dir, scene.hhd.stitch_seams = str(folder), stitch
    assert bpy.ops.hhd.bake() == {'FINISHED'}
    return lightmap_files.AtlasFiles(folder, "Lightmap")


def reencode(scene, files: lightmap_files.AtlasFiles, stitch: bool) -> None:
    import bpy

    scene.hhd.output_dir, scene.hhd.stitch_seams = str(files.folder), stitch
    assert bpy.ops.hhd.encode() == {'FINISHED'}


def record(files: lightmap_files.AtlasFiles) -> dict:
    return lightmap_files.read_sidecar(files.sidecar)["post"]["stitch"]


def pixels(path: Path) -> dict:
    """An EXR's channels as bytes."""
    return {k: v.tobytes() for k, v in exr.read(path)[0].items()}


def test_stitch_seams_is_a_scene_setting_on_by_default(extension, restore_hhd_settings):
    import bpy

    from hhd_lightmapper.core import bake as core_bake
    from hhd_lightmapper.core import presets

    prop = bpy.context.scene.hhd.bl_rna.properties["stitch_seams"]
    assert prop.type == 'BOOLEAN' and prop.default and prop.name == "Stitch Seams"
    assert core_bake.PipelineSettings().stitch_seams
    s = bpy.context.scene.hhd
    s.stitch_seams = True
    for name in presets.PRESETS:  # every preset stitches: it is not one of a preset's knobs
        s.preset = name
        assert s.stitch_seams


def test_a_bake_writes_the_seams_file_and_records_the_stitching(scene):
    """Stitch on: the seams file is there, the sidecar says how many seams were stitched and
    the HHD file differs from the unstitched bake's; the raw SH and texel files are the traced
    ones either way (so a re-encode starts from the same data)."""
    scene, folder = scene
    on = bake(scene, folder / "on", True)
    assert ", stitched, not denoised (" in scene.hhd.bake_summary
    off = bake(scene, folder / "off", False)
    assert ", not stitched, not denoised (" in scene.hhd.bake_summary
    r = record(on)
    assert r["enabled"] and r["applied"] and "warning" not in r
    assert r["seams"] > 0 and r["texels"] > 0 and r["groups"] >= 1 and r["seconds"] >= 0.0
    assert r["encoded"]["enabled"] and r["encoded"]["texels"] > 0  # the second pass, on the HHD layers
    assert record(off) == {"enabled": False}
    assert on.seams.is_file() and off.seams.is_file()  # written either way: Re-encode may stitch
    found = [geometry.Seams.load(f.seams) for f in (on, off)]
    assert all(np.array_equal(getattr(found[0], k), getattr(found[1], k)) for k in ("a", "b", "weight", "normal"))
    assert on.sh.read_bytes() == off.sh.read_bytes() and on.texels.read_bytes() == off.texels.read_bytes()
    assert pixels(on.hhd) != pixels(off.hhd)


def test_stitch_off_leaves_the_encoding_as_without_any_post_stage(scene, tmp_path):
    """With stitching (and denoising) off the HHD file is, byte for byte, the encoder's output
    for the traced SH read back from the bake's own raw files, with no post stage in between:
    switching stitching off changes nothing the encoder writes."""
    scene, folder = scene
    off = bake(scene, folder / "off", False)
    data = lightmap_files.read_texel_data(off)
    settings = lightmap_files.read_sidecar(off.sidecar)
    encoded = encoding.encode_atlas(data, encoding.for_settings(encoding.EncoderSettings()), raw=False)
    direct = lightmap_files.AtlasFiles(tmp_path / "direct", "Lightmap")
    with exr.Staging() as staging:
        lightmap_files.write_atlas(staging, direct, encoded, settings)
        staging.commit()
    assert off.hhd.read_bytes() == direct.hhd.read_bytes()


def test_command_line_no_stitch_bakes_what_the_operator_bakes_with_stitching_off(scene, capsys):
    scene, folder = scene
    operator_off = bake(scene, folder / "operator", False)

    def run(action, name, *args) -> tuple[dict, str]:
        """`action` into folder/name with the scene's Stitch Seams on (the flag overrides it)."""
        scene.hhd.stitch_seams = True
        capsys.readouterr()
        code = cli.main([action, "--out", str(folder / name), "--objects", "Floor", "Sphere", *args])
        out = capsys.readouterr().out
        assert code == cli.EXIT_OK, out
        summary = [line for line in out.splitlines() if line.startswith(f"{action}: ")][-1]
        return json.loads((folder / name / "Lightmap.json").read_text())["post"]["stitch"], summary

    off, summary = run("bake", "cli", "--no-stitch")
    assert off == {"enabled": False} and ", not stitched, " in summary
    cli_off = lightmap_files.AtlasFiles(folder / "cli", "Lightmap")
    assert cli_off.hhd.read_bytes() == operator_off.hhd.read_bytes()
    on, summary = run("bake", "cli_on")
    assert on["applied"] and ", stitched, " in summary
    # Re-encode: the flag, else the scene's setting
    on, summary = run("encode", "cli", "--stitch")  # (its bytes: test_reencode_switches_...)
    assert on["applied"] and ", stitched, " in summary
    off, summary = run("encode", "cli", "--no-stitch")
    assert off == {"enabled": False} and ", not stitched, " in summary
    assert cli_off.hhd.read_bytes() == operator_off.hhd.read_bytes()


def test_reencode_switches_stitching_off_and_on_without_tracing(scene):
    """Re-encode with Stitch Seams off gives the unstitched bake's HHD file, with it on the
    stitched one, bit for bit (the raw files, the seams file and the bake record untouched)."""
    scene, folder = scene
    off = bake(scene, folder / "off", False)
    on = bake(scene, folder / "on", True)
    stitched, unstitched = on.hhd.read_bytes(), off.hhd.read_bytes()
    raw = [on.sh.read_bytes(), on.texels.read_bytes(), on.seams.read_bytes()]
    bake_record = lightmap_files.read_sidecar(on.sidecar)["bake"]
    reencode(scene, on, False)
    assert on.hhd.read_bytes() == unstitched
    doc = lightmap_files.read_sidecar(on.sidecar)
    assert doc["post"]["stitch"] == {"enabled": False} and doc["reencoded_from_sh"]
    assert doc["bake"] == bake_record
    reencode(scene, on, True)
    assert on.hhd.read_bytes() == stitched and record(on)["applied"]
    assert [on.sh.read_bytes(), on.texels.read_bytes(), on.seams.read_bytes()] == raw
    reencode(scene, off, True)  # a bake made unstitched can be stitched later, the same way
    assert off.hhd.read_bytes() == stitched


def test_a_bake_without_a_seams_file_reencodes_unstitched_with_a_warning(scene, capfd):
    """A bake made before seams files existed: Re-encode with Stitch Seams on still succeeds,
    encodes the SH unstitched and says why (the operator's report and the sidecar)."""
    scene, folder = scene
    off = bake(scene, folder / "off", False)
    old = bake(scene, folder / "old", True)
    old.seams.unlink()
    capfd.readouterr()
    reencode(scene, old, True)
    out = capfd.readouterr()
    assert f"Warning: atlas 'Lightmap', stitch: {post.NO_SEAMS}" in out.out + out.err
    assert old.hhd.read_bytes() == off.hhd.read_bytes()
    assert record(old) == {"enabled": True, "applied": False, "warning": post.NO_SEAMS}
    assert not old.seams.exists()  # nothing invented: only a bake writes it
    # the command line prints it too, and succeeds
    assert cli.main(["encode", "--out", str(old.folder), "--objects", "Floor", "Sphere"]) == cli.EXIT_OK
    out = capfd.readouterr().out
    assert f"warning: atlas 'Lightmap', stitch: {post.NO_SEAMS}" in out and ", not stitched (see the warnings), " in out


def test_stitching_brings_the_two_sides_of_each_seam_together(scene):
    """On the baked sphere the seam metric of the encoded I_z drops with stitching (the core
    tests measure it precisely; here: the wiring delivers the stitched SH to the encoder)."""
    scene, folder = scene
    off = bake(scene, folder / "off", False)
    on = bake(scene, folder / "on", True)
    pairs = geometry.Seams.load(on.seams)
    assert len(pairs) > 0
    gaps = []
    for files in (off, on):
        channels, _ = exr.read(files.hhd)
        iz = np.stack([exr.from_exr_rows(channels[f"Iz.{c}"]) for c in "RGB"], -1).astype(np.float64)
        a, b = reads.bilinear(iz, pairs.a), reads.bilinear(iz, pairs.b)
        gaps.append(float(np.sum(pairs.weight * np.abs(a - b).sum(-1)) / np.sum(pairs.weight)))
    assert gaps[1] < 0.5 * gaps[0], gaps
