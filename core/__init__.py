"""Pure-Python core of HHD Lightmapper.

No module in this package imports bpy or mathutils: they use the standard library, numpy and,
lazily, the compiled dependencies (embreex, xatlas, OpenEXR) through `core.deps`.
"""
