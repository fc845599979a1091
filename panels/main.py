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
        col.prop(settings, "atlas_mode")
        col.prop(settings, "resolution")
        col.prop(settings, "texel_density")
        col.prop(settings, "mip_levels")
        col.prop(settings, "padding")
        obj = context.object
        if obj is not None and obj.type == 'MESH':
            box = layout.box()
            box.label(text=f"Overrides for '{obj.name}' (own atlas)")
            box.prop(obj.hhd, "resolution")
            box.prop(obj.hhd, "texel_density")
        layout.operator("hhd.unwrap", icon='UV')
        if settings.unwrap_summary:
            layout.label(text=settings.unwrap_summary)
        col = layout.column()
        col.prop(settings, "samples")
        col.prop(settings, "bounces")
        col.prop(settings, "output_dir")
        col = layout.column(heading="Encoder")
        col.prop(settings, "model")
        col.prop(settings, "direction")
        col.prop(settings, "ambient")
        col.prop(settings, "phi_search")
        layout.operator("hhd.check_dependencies", icon='CHECKMARK')
