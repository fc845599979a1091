"""The packaged extension: manifest, per-platform build, install, enable, register cycles."""

import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.bpy
#: The farm client's bundled wheels (`bake --scheduler`): dask, distributed and their run-time needs.
DASK = {
    "dask", "distributed", "click", "cloudpickle", "fsspec", "importlib_metadata", "zipp", "lazy_importer", "jinja2",
    "markupsafe", "locket", "packaging", "partd", "sortedcontainers", "tblib", "toolz", "zict", "msgpack", "pyyaml",
    "psutil", "tornado",
}  # fmt: skip


def manifest():
    with open(ROOT / "blender_manifest.toml", "rb") as f:
        return tomllib.load(f)


def test_manifest_declares_licence_permissions_and_platform_wheels():
    m = manifest()
    assert m["schema_version"] == "1.0.0" and m["id"] == "hhd_lightmapper"
    assert m["license"] == ["SPDX:GPL-3.0-or-later"]
    assert list(m["permissions"]) == ["files", "network"]  # network: --scheduler only (docs/farm.md); no clipboard, ...
    assert m["blender_version_min"] >= "4.2.0"
    import fetch_wheels

    by_platform = {}
    for w in m["wheels"]:
        for plat in fetch_wheels.wheel_platforms(Path(w).name):
            by_platform.setdefault(plat, set()).add(Path(w).name.split("-")[0])
    assert set(by_platform) == set(m["platforms"])
    for plat, packages in by_platform.items():
        assert packages == {"embreex", "xatlas", "openexr", "isal", "numba", "llvmlite", *DASK}, plat
    # every version-specific compiled package for both Pythons Blender ships: 3.11 (4.2-5.0) and
    # 3.13 (5.1+); pure-Python (none) and stable-ABI (abi3) wheels serve both (tests/test_install.py
    # runs Blender's own filter over them)
    tags = {}
    for w in m["wheels"]:
        name = Path(w).name
        if name.split("-")[-2] in ("none", "abi3"):
            continue
        for plat in fetch_wheels.wheel_platforms(name):
            tags.setdefault((plat, name.split("-")[0]), set()).add(name.split("-")[-3])
    assert all(t == {"cp311", "cp313"} for t in tags.values()), tags
    assert m["blender_version_min"] >= "4.2.13"  # older 4.2 installers ignore the cpXY tag


def test_every_manifest_wheel_is_hash_pinned_and_no_unlisted_wheel_ships():
    import fetch_wheels

    listed = fetch_wheels.manifest_wheels()
    assert len(listed) == len(set(listed)) and set(listed) == set(fetch_wheels.SHA256)
    assert all(len(h) == 64 for h in fetch_wheels.SHA256.values())
    assert {fetch_wheels.python_version(n) for n in listed} == {"3.11", "3.13"}


def test_the_zip_holds_only_its_platforms_wheels_and_no_dev_files(extension_zip, tmp_path):
    """The suite's zip passes the check every zip of `make package` passes (build_extension's
    `check_zip`), and the check names a zip that lacks a wheel, carries another platform's or a
    development file."""
    import build_extension
    import fetch_wheels

    m = manifest()
    assert build_extension.check_zip(extension_zip) == []
    names = zipfile.ZipFile(extension_zip).namelist()
    assert "core/hhd.py" in names or "core/deps.py" in names
    plat = next(p for p in m["platforms"] if extension_zip.stem.endswith(p.replace("-", "_")))
    wheels = sorted(Path(n).name for n in names if n.endswith(".whl"))
    assert wheels == sorted(
        Path(w).name for w in m["wheels"] if plat in fetch_wheels.wheel_platforms(Path(w).name)
    )  # 5 compiled packages x cp311, cp313, and Dask's 21 packages (tests/test_install.py)
    other = next(Path(w).name for w in m["wheels"] if plat not in fetch_wheels.wheel_platforms(Path(w).name))
    bad = tmp_path / extension_zip.name
    with zipfile.ZipFile(extension_zip) as src, zipfile.ZipFile(bad, "w") as dst:
        for info in src.infolist():
            if info.filename.endswith(wheels[0]):
                continue  # a wheel missing
            dst.writestr(info, src.read(info.filename))
        dst.writestr("wheels/" + other, b"")  # another platform's
        dst.writestr("tests/test_x.py", b"")  # a development file
    problems = " ".join(build_extension.check_zip(bad))
    assert wheels[0] in problems and other in problems and "tests/test_x.py" in problems, problems


def test_installed_extension_is_enabled_with_settings(extension):
    import bpy

    assert extension in bpy.context.preferences.addons
    settings = bpy.context.scene.hhd
    for name in ("uv_layer", "resolution", "samples", "bounces", "output_dir"):
        assert hasattr(settings, name), name
    assert settings.uv_layer == "HHD_Lightmap"
    assert bpy.ops.hhd.check_dependencies() == {"FINISHED"}


def test_disable_enable_twice_leaves_nothing_behind(extension):
    import bpy

    for _ in range(2):
        bpy.ops.preferences.addon_disable(module=extension)
        assert not hasattr(bpy.types.Scene, "hhd")
        assert not hasattr(bpy.types, "HHD_PT_main")
        assert "check_dependencies" not in dir(bpy.ops.hhd)  # operators unregistered too
        bpy.ops.preferences.addon_enable(module=extension)
        assert hasattr(bpy.types.Scene, "hhd")
        assert hasattr(bpy.types, "HHD_PT_main")
        assert bpy.ops.hhd.check_dependencies() == {"FINISHED"}


def test_missing_compiled_wheel_is_a_message_not_a_failed_enable(extension, monkeypatch):
    import bpy

    from hhd_lightmapper.core import deps
    from hhd_lightmapper.core.errors import DependencyMissing

    bpy.ops.preferences.addon_disable(module=extension)
    monkeypatch.setitem(sys.modules, "embreex", None)  # as if the wheel were absent
    bpy.ops.preferences.addon_enable(module=extension)  # enabling must still work
    assert hasattr(bpy.types.Scene, "hhd")
    with pytest.raises(RuntimeError, match="embreex"):  # the operator reports it as an error
        bpy.ops.hhd.check_dependencies()
    with pytest.raises(DependencyMissing, match="embreex.*ray tracing"):
        deps.require("embreex")


def test_a_preset_sets_its_knobs_and_an_edit_makes_it_custom(extension):
    import bpy

    from hhd_lightmapper.core import presets

    s = bpy.context.scene.hhd
    for name, preset in presets.PRESETS.items():
        s.preset = name
        assert s.preset == name
        assert (s.samples, s.bounces, s.noise_target) == (preset.samples, preset.bounces, 100 * preset.noise_target)
    s.samples += 1
    assert s.preset == 'CUSTOM'
    s.preset = 'PRODUCTION'
    assert s.preset == 'PRODUCTION'
