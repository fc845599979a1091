"""The Open Image Denoise library of the running Blender, for the denoise post stage (`core.post`).

The extension ships no OIDN binary: it uses the one Blender itself ships (and the RTLightmap
weights of `oidn_weights/`, `core.post.denoise.oidn`). Where that library lives:

- bpy as a Python module (pip `bpy`): Linux and macOS `bpy/lib/` (`libOpenImageDenoise.so.2`,
  `libOpenImageDenoise.2.dylib`), Windows the `bpy/` folder itself (`OpenImageDenoise.dll`: the
  Python module's DLLs are installed beside `__init__.pyd`, not into `blender.shared`).
- Linux, portable or installed Blender: `lib/` beside the `blender` binary.
- Windows: `blender.shared/` beside `blender.exe`.
- macOS: `Blender.app/Contents/Resources/lib/` (the binary is `Contents/MacOS/Blender`).

The folders are found from the bpy module's own file, from Blender's version folder
(`bpy.utils.resource_path('LOCAL')`: `bpy/5.3`, `<install>/4.2`, `Contents/Resources/4.2`, whose
parent holds `lib`/`blender.shared`) and from `bpy.app.binary_path` (empty under the bpy module).
"""

from __future__ import annotations

from pathlib import Path

import bpy

from ..core.post.denoise import oidn


def candidate_dirs() -> list[Path]:
    """Folders that may hold the running Blender's OIDN library (`install_dirs` of its paths)."""
    spec = getattr(bpy, "__spec__", None)
    origin = getattr(spec, "origin", None)
    module = origin if origin and origin not in ("built-in", "frozen") else ""
    return install_dirs(module, bpy.utils.resource_path('LOCAL'), bpy.app.binary_path)


def install_dirs(module_file: str, version_dir: str, binary: str) -> list[Path]:
    """Folders that may hold Blender's OIDN library, most specific first, duplicates dropped
    (missing ones are kept: `oidn.find_library` skips them), from the bpy module's compiled file
    (`bpy.__spec__.origin`, bpy/__init__.so or .pyd; not `bpy.__file__`, which is the package in
    the scripts folder), Blender's version folder (`bpy.utils.resource_path('LOCAL')`) and its
    binary (`bpy.app.binary_path`); "" for each that is unknown."""
    dirs: list[Path] = []
    if module_file:
        module = Path(module_file).parent  # bpy/
        dirs += [module / "lib", module]
    if version_dir:
        root = Path(version_dir).parent  # bpy/, <install>/ or Blender.app/Contents/Resources/
        dirs += [root / "lib", root / "blender.shared"]
    if binary:
        folder = Path(binary).parent
        dirs += [folder / "lib", folder / "blender.shared", folder.parent / "Resources" / "lib", folder]
    return list(dict.fromkeys(dirs))


def oidn_library() -> str:
    """Path of the OIDN shared library this Blender ships (module doc), or "" if none is found
    (a denoised bake then comes out undenoised, with a warning)."""
    path = oidn.find_library(candidate_dirs())
    return "" if path is None else str(path)


def failed(warnings: list[str]) -> bool:
    """Whether an atlas's post-stage `warnings` (`AtlasResult.warnings`, `core.bake.reencode`)
    say its denoise stage did not run: its SH was encoded undenoised."""
    return any("denoise: " in w for w in warnings)


def outcome(enabled: bool, atlas_warnings: list[list[str]]) -> str:
    """Summary words for a bake or re-encode: denoise setting `enabled`, each atlas's warnings."""
    if not enabled:
        return "not denoised"
    undone = sum(failed(w) for w in atlas_warnings)
    if undone == 0:
        return "denoised"
    if undone == len(atlas_warnings):
        return "not denoised (see the warnings)"
    return f"denoised {len(atlas_warnings) - undone} of {len(atlas_warnings)} atlases (see the warnings)"
