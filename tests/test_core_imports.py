"""Every core module imports with bpy and mathutils unavailable (core never imports Blender)."""

import subprocess
import sys
import textwrap


def test_every_core_module_imports_without_bpy():
    script = textwrap.dedent("""
        import importlib, pkgutil, sys
        for name in ("bpy", "mathutils", "bmesh", "gpu"):
            sys.modules[name] = None          # any import of these now raises ImportError
        import hhd_lightmapper.core as core
        names = [m.name for m in pkgutil.walk_packages(core.__path__, core.__name__ + ".")]
        for name in names:
            importlib.import_module(name)
        assert "bpy" not in [m for m in sys.modules if sys.modules[m] is not None]
        print(len(names))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) >= 3  # errors, deps and the math modules at least
