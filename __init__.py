"""HHD Lightmapper: bake directional IrradZ/HHD lightmaps and preview them in EEVEE.

This file only delegates. bpy is imported inside register() so that `hhd_lightmapper.core`
(pure numpy) can be imported without Blender: by tests, workers and build machines.
"""

_PACKAGES = ("properties", "operators", "panels", "cli")


def _modules():
    import importlib

    return [importlib.import_module(f".{name}", __package__) for name in _PACKAGES]


def register():
    for module in _modules():
        module.register()


def __getattr__(name):
    """`glTF2ExportUserExtension`: the hook Blender's glTF exporter looks up on every enabled add-on
    or extension module (bridge/gltf_export.py, docs/gltf.md); imported only when asked for."""
    if name == "glTF2ExportUserExtension":
        from .bridge.gltf_export import glTF2ExportUserExtension

        return glTF2ExportUserExtension
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def unregister():
    for module in reversed(_modules()):
        module.unregister()
