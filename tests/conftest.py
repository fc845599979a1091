"""Test session set-up.

Blender's user configuration is redirected to a fresh temporary directory *before* bpy is
imported (BLENDER_USER_RESOURCES), so the tests never read or write the developer's real
Blender config. The `extension` fixture builds the package with Blender's own tool and installs
and enables it through Blender's extension machinery, exactly as a user's Blender would.
"""

import os
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
USER_RESOURCES = Path(tempfile.mkdtemp(prefix="hhd-blender-user-"))
os.environ["BLENDER_USER_RESOURCES"] = str(USER_RESOURCES)
assert "bpy" not in sys.modules, "bpy was imported before the user config could be isolated"

sys.path.insert(0, str(ROOT / "tools"))  # build_extension, fetch_oidn_weights
sys.path.insert(0, str(ROOT))  # scenekit, the shared test/bench scenes

EXTENSION_MODULE = "bl_ext.user_default.hhd_lightmapper"


def pytest_unconfigure(config):
    """The isolated user configuration goes with the session (the installed extension in it is
    hundreds of megabytes; a machine running the suite often would fill its disk)."""
    import shutil

    shutil.rmtree(USER_RESOURCES, ignore_errors=True)


def this_platform() -> str:
    """Blender's platform name for the running machine, e.g. 'linux-x64'."""
    import platform

    system = {"Linux": "linux", "Darwin": "macos", "Windows": "windows"}[platform.system()]
    arch = {"x86_64": "x64", "AMD64": "x64", "arm64": "arm64", "aarch64": "arm64"}[platform.machine()]
    return f"{system}-{arch}"


@pytest.fixture(scope="session")
def built_zips(tmp_path_factory):
    """Every platform's validated extension zip, built by Blender's extension tool."""
    import build_extension

    return build_extension.build(tmp_path_factory.mktemp("dist"))


@pytest.fixture(scope="session")
def extension(built_zips):
    """The extension installed from its zip into the isolated user repo and enabled."""
    import bpy

    tag = this_platform().replace("-", "_")
    zip_path = next(z for z in built_zips if z.stem.endswith(tag))
    result = bpy.ops.extensions.package_install_files(
        filepath=str(zip_path), repo="user_default", enable_on_install=True
    )
    assert result == {"FINISHED"}
    assert EXTENSION_MODULE in bpy.context.preferences.addons
    return EXTENSION_MODULE


@pytest.fixture(scope="session")
def oidn_weights() -> list[Path]:
    """OIDN's lightmap weights in oidn_weights/ (tools/fetch_oidn_weights.py: hash-checked, the
    wheel they come from cached under build/), for every test that bakes with denoising, which
    the scene's Denoise setting (on by default) asks for. Skips with the reason if unavailable.
    The extension's zip ships them too (the build fetches them): this covers the bakes of the
    package itself (`python -m hhd_lightmapper.cli`, `hhd_lightmapper.bridge`)."""
    import subprocess

    import fetch_oidn_weights

    try:
        return fetch_oidn_weights.fetch()
    except (SystemExit, subprocess.CalledProcessError, OSError) as e:
        pytest.skip(f"OIDN lightmap weights unavailable (tools/fetch_oidn_weights.py: {e})")


@pytest.fixture
def restore_hhd_settings(extension):
    """Puts the scene's HHD settings back after the test: the bpy scene outlives a test, and a
    later test may rely on the defaults (e.g. the Output Folder `//lightmaps`)."""
    import bpy

    settings = bpy.context.scene.hhd
    keys = [
        p.identifier
        for p in settings.bl_rna.properties
        if p.identifier != "rna_type" and not p.is_readonly and p.type in {'BOOLEAN', 'INT', 'FLOAT', 'STRING', 'ENUM'}
    ]
    keys.sort(key=lambda k: k == "preset")  # the preset last: it may set the knobs again, the same
    before = {k: getattr(settings, k) for k in keys}
    yield
    settings = bpy.context.scene.hhd
    for key in keys:
        setattr(settings, key, before[key])
