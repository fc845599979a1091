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


def unregister():
    for module in reversed(_modules()):
        module.unregister()
