"""Lazy access to the compiled dependencies, so a missing wheel is a clear message. No bpy.

The extension enables even when a wheel is missing (for example on a platform without wheels);
the feature that needs it then reports which package is missing instead of failing at enable.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import DependencyMissing

#: import name -> (distribution name on the package registry, what it is used for)
COMPILED = {
    "embreex": ("embreex", "ray tracing the bake"),
    "xatlas": ("xatlas", "unwrapping lightmap UVs"),
    "OpenEXR": ("OpenEXR", "writing and reading EXR files"),
    "numba": ("numba", "the compiled per-sample kernels of the bake"),
}


def require(name: str) -> ModuleType:
    """Import a compiled dependency or raise DependencyMissing naming the package and its use."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        dist, use = COMPILED[name]
        raise DependencyMissing(
            f"The Python package '{dist}' (needed for {use}) is not available: {exc}. "
            "Install the HHD Lightmapper build for your platform (it bundles the wheel), "
            f"or run Blender's Python with `pip install {dist}`."
        ) from exc


def status() -> dict[str, str | None]:
    """For each compiled dependency: its version string if importable, else None."""
    out: dict[str, str | None] = {}
    for name in COMPILED:
        try:
            module = importlib.import_module(name)
        except ImportError:
            out[name] = None
        else:
            out[name] = str(getattr(module, "__version__", "installed"))
    return out
