"""Thin bpy operators: one per module, registered in `classes` order."""

import bpy

from ..shaders import probe_preview
from .bake import HHD_OT_bake
from .bake_changed import HHD_OT_bake_changed, HHD_OT_check_stale
from .check_dependencies import HHD_OT_check_dependencies
from .check_normals import HHD_OT_check_normals
from .compare import HHD_OT_compare
from .encode import HHD_OT_encode, HHD_OT_open_output
from .light_sets import HHD_OT_blend_light_sets, HHD_OT_refresh_light_sets
from .preview import HHD_OT_preview_hide, HHD_OT_preview_show
from .probes import HHD_OT_probe_preview_hide, HHD_OT_probe_preview_show
from .texel_views import HHD_OT_view_show
from .unwrap import HHD_OT_unwrap

classes = (
    HHD_OT_check_dependencies,
    HHD_OT_check_normals,
    HHD_OT_unwrap,
    HHD_OT_bake,
    HHD_OT_check_stale,
    HHD_OT_bake_changed,
    HHD_OT_encode,
    HHD_OT_compare,
    HHD_OT_open_output,
    HHD_OT_preview_show,
    HHD_OT_preview_hide,
    HHD_OT_view_show,
    HHD_OT_refresh_light_sets,
    HHD_OT_blend_light_sets,
    HHD_OT_probe_preview_show,
    HHD_OT_probe_preview_hide,
)

_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    probe_preview.register_handlers()


def unregister():
    probe_preview.unregister_handlers()
    _unregister()
