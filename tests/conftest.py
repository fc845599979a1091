"""Test session set-up.

Blender's user configuration is redirected to a fresh temporary directory *before* bpy is
imported (BLENDER_USER_RESOURCES), so the tests never read or write the developer's real
Blender config. The `extension` fixture builds the package with Blender's own tool and installs
and enables it through Blender's extension machinery, exactly as a user's Blender would.
"""

import contextlib
import os
import sys
import tempfile
import time
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
USER_RESOURCES = Path(tempfile.mkdtemp(prefix="hhd-blender-user-"))
os.environ["BLENDER_USER_RESOURCES"] = str(USER_RESOURCES)
assert "bpy" not in sys.modules, "bpy was imported before the user config could be isolated"

sys.path.insert(0, str(ROOT / "tools"))  # build_extension, fetch_oidn_weights

EXTENSION_MODULE = "bl_ext.user_default.hhd_lightmapper"


IMPLY_BPY = ("cycles", "eevee", "install")


def pytest_collection_modifyitems(config, items):
    """A test that uses the installed extension runs inside Blender: it is marked `bpy` whether
    or not its module says so. `cycles`, `eevee` and `install` without `bpy` are refused: the
    LTS suite selects Blender's tests by `bpy` alone (Makefile)."""
    for item in items:
        if "extension" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.bpy)
        marks = {m.name for m in item.iter_markers()}
        wrong = [m for m in IMPLY_BPY if m in marks and "bpy" not in marks]
        if wrong:
            raise pytest.UsageError(f"{item.nodeid}: marked {wrong} but not bpy")


_EXIT_STATUS = pytest.StashKey[int]()


class SuiteClock:
    """Each test's time (setup + call + teardown, seconds) and outcome, written at the end of
    the session to out/test-times/<label>.json (label: bpy's version, or `core` without bpy):
    `make test` prints the suites' totals from these files."""

    def __init__(self):
        self.start = time.time()
        self.tests: dict[str, dict] = {}

    def pytest_runtest_logreport(self, report):
        entry = self.tests.setdefault(report.nodeid, {"seconds": 0.0, "outcome": "passed"})
        entry["seconds"] += report.duration
        if report.failed:
            entry["outcome"] = "failed"
        elif report.skipped and entry["outcome"] == "passed":
            entry["outcome"] = "skipped"

    def pytest_sessionfinish(self, session, exitstatus):
        import json

        if not self.tests or hasattr(session.config, "workerinput"):
            return
        label = "bpy-" + ".".join(map(str, sys.modules["bpy"].app.version)) if "bpy" in sys.modules else "core"
        outcomes = [t["outcome"] for t in self.tests.values()]
        slowest = sorted(self.tests.items(), key=lambda kv: -kv[1]["seconds"])
        record = {
            "suite": label,
            "python": ".".join(map(str, sys.version_info[:3])),
            "markers": session.config.option.markexpr or "",
            "wall_seconds": round(time.time() - self.start, 1),
            "tests": len(self.tests),
            **{k: outcomes.count(k) for k in ("passed", "failed", "skipped")},
            "slowest": [{"test": k, "seconds": round(v["seconds"], 2)} for k, v in slowest[:25]],
            "all": {k: round(v["seconds"], 3) for k, v in sorted(self.tests.items())},
        }
        folder = ROOT / "out" / "test-times"
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{label}.json").write_text(json.dumps(record, indent=1) + "\n")


def pytest_configure(config):
    config.pluginmanager.register(SuiteClock(), "hhd_suite_clock")


def pytest_sessionfinish(session, exitstatus):
    session.config.stash[_EXIT_STATUS] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """The isolated user configuration goes with the session (the installed extension in it is
    hundreds of megabytes; a machine running the suite often would fill its disk). On Blender
    4.x the `bpy` module can crash in its destructors at interpreter exit (e.g. after any glTF
    export: exit 139 though every test passed), so, as `blender_compat.exit_process` does for the
    CLI, the session leaves directly with its own status once everything is reported."""
    import shutil

    shutil.rmtree(USER_RESOURCES, ignore_errors=True)
    bpy = sys.modules.get("bpy")
    if bpy is not None and bpy.app.version < (5, 0, 0) and _EXIT_STATUS in config.stash:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(config.stash[_EXIT_STATUS])


@pytest.fixture(scope="session")
def extension_zip(tmp_path_factory) -> Path:
    """The running platform's extension zip, built and validated by Blender's extension tool
    (tools/build_extension.py; `make package` builds and checks every platform's)."""
    import build_extension

    (zip_path,) = build_extension.build(tmp_path_factory.mktemp("dist"), platform=build_extension.this_platform())
    return zip_path


@pytest.fixture(scope="session")
def extension(extension_zip):
    """The extension installed from its zip into the isolated user repo and enabled."""
    import bpy

    result = bpy.ops.extensions.package_install_files(
        filepath=str(extension_zip), repo="user_default", enable_on_install=True
    )
    assert result == {"FINISHED"}
    assert EXTENSION_MODULE in bpy.context.preferences.addons
    load_kernels_compiled_by_the_package_as_developed(Path(sys.modules[EXTENSION_MODULE].__file__).parent)
    return EXTENSION_MODULE


def load_kernels_compiled_by_the_package_as_developed(installed: Path) -> None:
    """In this process, a numba kernel of the installed extension (under `installed`) whose
    source file is byte for byte the repository's loads what the package as developed
    (`hhd_lightmapper`, the same file in ROOT) compiled for the same signature, from that
    file's own numba cache, instead of compiling it a second time (~10-30 s of JIT per suite;
    numba's cache key includes the function's bytecode). Only when its own cache misses; what
    it compiles itself goes to its own cache as before; a load that fails compiles. Only one
    way: an entry compiled by the installed copy would name its module (bl_ext...), which the
    package's other processes (command lines, farm workers) cannot import. The installed
    extension's processes (tools/try_install.py in tests/test_install.py) still compile from
    cold with the zip's own numba."""
    try:
        from numba.core import caching
    except ImportError:
        return
    load = caching.FunctionCache.load_overload
    if getattr(load, "developed_twin", False):
        return
    twins: dict[str, Path | None] = {}

    def twin_of(filename: str) -> Path | None:
        if filename not in twins:
            path, twins[filename] = Path(filename), None
            if path.is_relative_to(installed):
                other = ROOT / path.relative_to(installed)
                if other.is_file() and other.read_bytes() == path.read_bytes():
                    twins[filename] = other
        return twins[filename]

    def load_overload(self, sig, target_context):
        cres = load(self, sig, target_context)
        twin = None if cres is not None else twin_of(self._py_func.__code__.co_filename)
        if twin is None:
            return cres
        f = self._py_func
        try:  # the same function as if defined in the twin file: that file's cache and stamp
            clone = types.FunctionType(
                f.__code__.replace(co_filename=str(twin)), f.__globals__, f.__name__, f.__defaults__, f.__closure__
            )
            clone.__qualname__ = f.__qualname__
            return load(caching.FunctionCache(clone), sig, target_context)
        except Exception:
            return None

    load_overload.developed_twin = True
    caching.FunctionCache.load_overload = load_overload


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
def cli_run(extension, capfd):
    """The command line run in this process: `run(BLEND, *ARGS)` opens BLEND and calls
    `cli.main(ARGS)`, as `python -m hhd_lightmapper.cli BLEND ARGS` does in a process of its own,
    and returns (returncode, stdout, stderr) like subprocess.run. For the tests where the process
    boundary is not what is tested (signals and import isolation keep their subprocesses)."""
    import types

    import bpy

    from hhd_lightmapper import cli

    def run(blend, *args):
        capfd.readouterr()
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        code = cli.main([str(a) for a in args])
        out, err = capfd.readouterr()
        return types.SimpleNamespace(returncode=code, stdout=out, stderr=err)

    return run


@contextlib.contextmanager
def hhd_settings_restored():
    """The scene's HHD settings as they were before the block, after it."""
    import bpy

    settings = bpy.context.scene.hhd
    keys = [
        p.identifier
        for p in settings.bl_rna.properties
        if p.identifier != "rna_type" and not p.is_readonly and p.type in {'BOOLEAN', 'INT', 'FLOAT', 'STRING', 'ENUM'}
    ]
    keys.sort(key=lambda k: k == "preset")  # the preset last: it may set the knobs again, the same
    before = {k: getattr(settings, k) for k in keys}
    try:
        yield
    finally:
        settings = bpy.context.scene.hhd
        for key in keys:
            setattr(settings, key, before[key])


@pytest.fixture
def restore_hhd_settings(extension):
    """Puts the scene's HHD settings back after the test: the bpy scene outlives a test, and a
    later test may rely on the defaults (e.g. the Output Folder `//lightmaps`)."""
    with hhd_settings_restored():
        yield
