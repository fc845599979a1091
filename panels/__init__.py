"""UI panels: Properties editor > Render > HHD Lightmapper.

The Render tab holds scene-wide bake settings already (Cycles' Bake panel lives there), and the
settings here are per scene, not per view, so they sit beside it rather than in a 3D View tab.
"""

import bpy

from .main import HHD_PT_main, HHD_UL_light_sets

classes = (HHD_UL_light_sets, HHD_PT_main)

register, unregister = bpy.utils.register_classes_factory(classes)
