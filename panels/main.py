"""The HHD Lightmapper panel in Properties > Render."""
import bpy


class HHD_PT_main(bpy.types.Panel):
    bl_label = "HHD Lightmapper"
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"

    def draw(self, context):
        settings = context.scene.hhd
        layout = self.layout
        layout.use_property_split = True
        col = layout.column()
        col.prop(settings, "uv_layer")
        col.prop(settings, "resolution")
        col.prop(settings, "samples")
        col.prop(settings, "bounces")
        col.prop(settings, "output_dir")
        col = layout.column(heading="Encoder")
        col.prop(settings, "model")
        col.prop(settings, "direction")
        col.prop(settings, "ambient")
        col.prop(settings, "phi_search")
        layout.operator("hhd.check_dependencies", icon='CHECKMARK')
