"""Scene settings of HHD Lightmapper: `bpy.context.scene.hhd`."""
import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty, BoolProperty


class HHDSettings(bpy.types.PropertyGroup):
    uv_layer: StringProperty(
        name="Lightmap UV Layer", default="HHD_Lightmap",
        description="UV layer the unwrap writes and the bake reads; no other UV layer is touched")
    resolution: IntProperty(
        name="Resolution", default=1024, min=256, max=8192,
        description="Atlas width and height in texels")
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


classes = (HHDSettings,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.hhd = bpy.props.PointerProperty(type=HHDSettings)


def unregister():
    del bpy.types.Scene.hhd
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
