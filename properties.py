"""Scene settings of HHD Lightmapper: `bpy.context.scene.hhd`."""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty


class HHDSettings(bpy.types.PropertyGroup):
    uv_layer: StringProperty(
        name="Lightmap UV Layer", default="HHD_Lightmap",
        description="UV layer the unwrap writes and the bake reads; no other UV layer is touched")
    resolution: IntProperty(
        name="Resolution", default=1024, min=256, max=8192,
        description="Atlas width and height in texels")
    texel_density: FloatProperty(
        name="Texel Density", default=0.0, min=0.0, soft_max=200.0, unit='NONE',
        description="Texels per metre; 0 uses the fixed Resolution instead")
    atlas_mode: EnumProperty(
        name="Atlas", default='SHARED',
        items=[('SHARED', "Shared", "All target objects in one atlas"),
               ('PER_OBJECT', "Per Object", "One atlas per object")])
    mip_levels: IntProperty(
        name="Mip Levels", default=2, min=0, max=6,
        description="Mip levels the padding must survive (padding = 2 × 2^levels texels)")
    padding: IntProperty(
        name="Padding", default=0, min=0, max=64,
        description="Texels between charts; 0 derives it from Mip Levels")
    unwrap_summary: StringProperty(name="Last Unwrap", default="", options={'SKIP_SAVE'})
    samples: IntProperty(
        name="Samples", default=256, min=1, max=65536,
        description="Hemisphere samples per lightmap texel")
    bounces: IntProperty(
        name="Bounces", default=3, min=0, max=16,
        description="Diffuse interreflection bounces after the first hit")
    output_dir: StringProperty(
        name="Output Folder", default="//lightmaps", subtype='DIR_PATH',
        description="Where the EXR files and JSON sidecar are written (relative to the .blend)")
    model: EnumProperty(
        name="Model", default='HHD',
        items=[('HHD', "HHD", "Hemisphere light + highlight direction (IrradZ)"),
               ('AHD', "AHD", "Constant ambient + highlight direction (IrradZ)")])
    direction: EnumProperty(
        name="Direction", default='SEARCHED',
        items=[('SEARCHED', "Searched", "Golden-section search for the least-error direction"),
               ('OPTIMAL_LINEAR', "Optimal Linear", "Direction of the SH linear band (baseline)")])
    ambient: EnumProperty(
        name="Ambient Weight", default='LUMINANCE',
        items=[('LUMINANCE', "Luminance", "One ambient weight per texel"),
               ('RGB', "RGB", "One ambient weight per colour channel")])
    phi_search: BoolProperty(
        name="Search Azimuth", default=False,
        description="Also search the highlight direction's azimuth (slower, slightly lower error)")


class HHDObjectSettings(bpy.types.PropertyGroup):
    """Per-object overrides: `object.hhd`. An object with an override gets its own atlas."""
    resolution: IntProperty(
        name="Resolution Override", default=0, min=0, max=8192,
        description="Own atlas of this size; 0 uses the scene settings")
    texel_density: FloatProperty(
        name="Texel Density Override", default=0.0, min=0.0, soft_max=200.0,
        description="Own atlas at this many texels per metre; 0 uses the scene settings")


classes = (HHDSettings, HHDObjectSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.hhd = bpy.props.PointerProperty(type=HHDSettings)
    bpy.types.Object.hhd = bpy.props.PointerProperty(type=HHDObjectSettings)


def unregister():
    del bpy.types.Object.hhd
    del bpy.types.Scene.hhd
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
