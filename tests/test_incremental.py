"""Bake what changed (core/incremental/, bridge/incremental_session.py, CLI `bake --only` /
`--changed`, `stale`): after a full bake, move one object and bake the changed: every texel of
every file outside that object's charts (and their gutters) keeps its bits; its re-traced texels
agree with a full rebake's within the noise; no earlier bake or a re-unwrap is refused (exit 6)
with nothing written. A small room with two lamps in light groups (light-set files too)."""

import hashlib

import numpy as np
import pytest

from hhd_lightmapper import cli
from hhd_lightmapper.bridge import incremental_session
from hhd_lightmapper.bridge import settings as bridge_settings
from hhd_lightmapper.core.files import exr, lightmap_files
from hhd_lightmapper.core.incremental import fingerprints
from scenekit import blender as kit

pytestmark = pytest.mark.bpy


def snapshot(folder) -> dict:
    """{relative path: {channel: array}} of every EXR under `folder`."""
    return {str(p.relative_to(folder)): exr.read(p)[0] for p in sorted(folder.rglob("*.exr"))}


def digests(folder) -> dict:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def chart_region(obj, width: int, height: int, margin: int) -> np.ndarray:
    """(H, W) bool, EXR rows (top-down): the texels within `margin` of the lightmap-UV bounding
    box of any face of `obj` (independent of the bake: read from the UV layer)."""
    mesh = obj.data
    uv = np.empty(len(mesh.loops) * 2)
    mesh.uv_layers["HHD_Lightmap"].data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2) * (width, height)
    region = np.zeros((height, width), bool)
    for poly in mesh.polygons:
        corners = uv[poly.loop_start : poly.loop_start + poly.loop_total]
        x0, y0 = np.floor(corners.min(0)).astype(int) - margin
        x1, y1 = np.ceil(corners.max(0)).astype(int) + margin
        region[max(y0, 0) : y1, max(x0, 0) : x1] = True
    return region[::-1]  # texel rows bottom-up → EXR rows


def chessboard(mask: np.ndarray, rings: int = 40) -> np.ndarray:
    """Chessboard distance (texels) of every texel to the nearest of `mask` (rings + 1 beyond)."""
    dist = np.where(mask, 0, rings + 1)
    grown = mask.copy()
    for d in range(1, rings + 1):
        padded = np.pad(grown, 1)
        grown = np.zeros_like(mask)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                grown |= padded[dy : dy + mask.shape[0], dx : dx + mask.shape[1]]
        dist[grown & (dist > d)] = d
    return dist


def luminance_l0(folder, name="Lightmap"):
    ch, _ = exr.read(folder / f"{name}_sh.exr")
    return sum(w * ch[f"SH0.{c}"].astype(np.float64) for w, c in zip((0.2126, 0.7152, 0.0722), "RGB"))


def noise(folder, name="Lightmap"):
    ch, _ = exr.read(folder / f"{name}_texels.exr")
    return ch["Noise.V"].astype(np.float64), ch["Coverage.V"].astype(np.float64)


@pytest.fixture
def room(extension, restore_hhd_settings, tmp_path):
    scene, (floor, box) = kit.two_lamp_room()
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.seed, s.denoise, s.pack_images = 64, 1, 0, False, False  # 4 passes: noise known
    kit.unwrap([floor, box], texel_density=28.0)  # a small atlas (the test's time)
    s.output_dir = str(tmp_path / "lightmaps")
    return scene, floor, box, tmp_path


def test_bake_changed_rewrites_only_the_moved_object_and_matches_a_full_rebake(room, capfd):
    import bpy

    scene, floor, box, tmp = room
    folder = tmp / "lightmaps"
    assert cli.main(["bake"]) == cli.EXIT_OK
    doc = lightmap_files.read_sidecar(folder / "Lightmap.json")
    assert set(doc["fingerprints"]["objects"]) >= {"Floor", "Box"} and set(doc["baked"]) == {"Floor", "Box"}
    before = snapshot(folder)
    capfd.readouterr()
    assert cli.main(["stale", "--out", str(folder)]) == cli.EXIT_OK
    assert "nothing changed" in capfd.readouterr().out

    box.location.x -= 0.25
    bpy.context.view_layer.update()
    assert cli.main(["stale"]) == cli.EXIT_OK
    out = capfd.readouterr().out
    assert "objects: Box" in out and "Bake Changed re-traces 1," in out, out
    # the settings value given (the command line's overridden view) chooses the folder, not scene.hhd
    elsewhere = bridge_settings.Overridden(scene.hhd, {"output_dir": str(tmp / "elsewhere")})
    assert incremental_session.stale_report(bpy.context, settings=elsewhere) == (
        None,
        [f"no earlier bake in {tmp / 'elsewhere'}: bake all first"],
    )
    assert bpy.ops.hhd.check_stale() == {'FINISHED'}  # the panel's line
    assert "objects: Box" in scene.hhd.stale_report
    assert bpy.ops.hhd.bake_changed(mode='CHANGED') == {'FINISHED'}
    after = snapshot(folder)
    assert set(after) == set(before)

    # every texel outside the box's charts (+ the unwrap's padding for gutters and seams) keeps its bits
    w, h = doc["width"], doc["height"]
    region = chart_region(box, w, h, margin=0)
    covered = before["Lightmap_texels.exr"]["Coverage.V"] != 0
    # and the texels outside every chart that are at least as near the box's charts as any other's
    # (their dilation fill may come from the box), within the fill's reach
    near_box, near_other = chessboard(region & covered), chessboard(covered & ~region)
    allowed = region | (~covered & (near_box <= near_other) & (near_box <= 16))
    changed_somewhere = 0
    for path, channels in before.items():
        for name, old in channels.items():
            new = after[path][name]
            assert new.shape == old.shape
            differs = old.astype(np.float32).view(np.uint32) != new.astype(np.float32).view(np.uint32)
            assert not (differs & ~allowed).any(), (path, name, int((differs & ~allowed).sum()))
            changed_somewhere += int(differs.sum())
    assert changed_somewhere > 0
    record = lightmap_files.read_sidecar(folder / "Lightmap.json")
    assert record["incremental"]["objects"] == ["Box"] and record["baked"]["Box"] >= record["baked"]["Floor"]
    capfd.readouterr()
    assert cli.main(["stale"]) == cli.EXIT_OK
    assert "nothing changed" in capfd.readouterr().out  # the box's move is baked

    # a full rebake of the moved scene elsewhere: the re-traced texels agree within their noise
    full = tmp / "full"
    assert cli.main(["bake", "--out", str(full)]) == cli.EXIT_OK
    sigma_inc, coverage = noise(folder)
    sigma_full, _ = noise(full)
    mine = region & (coverage > 0) & (sigma_inc >= 0) & (sigma_full >= 0)
    diff = np.abs(luminance_l0(folder) - luminance_l0(full))
    within = diff[mine] <= 3.0 * np.hypot(sigma_inc[mine], sigma_full[mine])
    print(f"re-traced texels within 3 sigma of a full rebake: {within.mean():.4f} of {mine.sum()}")
    assert mine.sum() > 400 and within.mean() >= 0.99, within.mean()


def test_a_partial_bake_without_an_earlier_bake_or_after_a_re_unwrap_is_refused_and_writes_nothing(room):
    scene, floor, box, tmp = room
    empty = tmp / "nothing"
    assert cli.main(["bake", "--only", "Box", "--out", str(empty)]) == cli.EXIT_FULL_BAKE
    assert not empty.exists() or not any(empty.iterdir())
    folder = tmp / "lightmaps"
    assert cli.main(["bake"]) == cli.EXIT_OK
    assert cli.main(["bake", "--only", "Box"]) == cli.EXIT_OK
    files = digests(folder)
    assert cli.main(["bake", "--only", "Nope"]) == cli.EXIT_FULL_BAKE
    scene.hhd.padding += 2  # another layout
    kit.unwrap([floor, box], texel_density=28.0)
    for args in (["--only", "Box"], ["--changed"], ["--changed", "--influenced"]):
        assert cli.main(["bake", *args]) == cli.EXIT_FULL_BAKE, args
    assert digests(folder) == files
    assert cli.main(["bake", "--only", "Box", "--objects", "Box"]) == cli.EXIT_USAGE


def test_fingerprints_hash_a_million_triangles_in_well_under_a_second():
    import time

    rng = np.random.default_rng(0)
    arrays = [rng.random((500_000, 3), dtype=np.float32), rng.integers(0, 500_000, 3_000_000, dtype=np.int32)]
    arrays.append(rng.random((3_000_000, 3), dtype=np.float32))  # corner normals
    t = time.perf_counter()
    first = fingerprints.digest(*arrays)
    assert time.perf_counter() - t < 0.5
    arrays[0][123, 1] += 1e-3
    assert fingerprints.digest(*arrays) != first


def test_the_influence_rule_is_conservative_by_distance_and_global_for_the_world_and_suns():
    box = {"hash": "a", "bounds": [[0, 0, 0], [1, 1, 1]]}
    near = {"hash": "n", "bounds": [[1.5, 0, 0], [2, 1, 1]]}
    far = {"hash": "f", "bounds": [[9, 0, 0], [10, 1, 1]]}
    old = fingerprints.Fingerprints(
        {"Box": box, "Near": near, "Far": far}, {"Sun": {"hash": "s", "position": None, "power": 1.0}}
    )
    moved = dict(box, hash="b", bounds=[[0.2, 0, 0], [1.2, 1, 1]])
    new = fingerprints.Fingerprints({"Box": moved, "Near": near, "Far": far}, dict(old.lights))
    stale = fingerprints.compare(old, new)
    assert stale.objects == ["Box"] and not stale.lights and not stale.world
    receivers = ["Box", "Near", "Far"]
    assert fingerprints.changed_receivers(stale, receivers) == ["Box"]
    assert fingerprints.influenced(stale, old, new, receivers) == ["Box", "Near"]
    new.lights["Sun"] = {"hash": "t", "position": None, "power": 2.0}
    assert fingerprints.influenced(fingerprints.compare(old, new), old, new, receivers) == receivers
