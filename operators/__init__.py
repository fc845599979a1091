"""Thin bpy operators: one per module, registered in `classes` order."""
import bpy

from .check_dependencies import HHD_OT_check_dependencies
from .unwrap import HHD_OT_unwrap

classes = (HHD_OT_check_dependencies, HHD_OT_unwrap)

register, unregister = bpy.utils.register_classes_factory(classes)
