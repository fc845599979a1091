"""The HHD Lightmapper panel in Properties > Render: receivers → unwrap → bake → preview → files."""

import bpy

#: The light sets' list (registered with the panel; the panel falls back to Blender's plain list
#: with the active set's weight below it when this class is not registered).
LIGHT_SETS_LIST = "HHD_UL_light_sets"


class HHD_UL_light_sets(bpy.types.UIList):
    """The light sets of the last bake: name and RGB weight (animatable) per row."""

    bl_idname = LIGHT_SETS_LIST

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.label(text=item.name, icon='LIGHT')
        row.prop(item, "weight", text="")


class HHD_PT_main(bpy.types.Panel):
    bl_label = "HHD Lightmapper"
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"

    def draw(self, context):
        settings = context.scene.hhd
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        self.draw_receivers(layout, settings, context)
        self.draw_unwrap(layout, settings, context)
        self.draw_bake(layout, settings, context)
        self.draw_light_sets(layout, settings)
        self.draw_output(layout, settings)

    @staticmethod
    def draw_receivers(layout, settings, context):
        col = layout.column(heading="Receivers")
        col.prop(settings, "target", text="Receivers")
        if settings.target == 'COLLECTION':
            col.prop(settings, "target_collection")
        col.label(text="Occluders: every render-visible object", icon='INFO')

    @staticmethod
    def draw_unwrap(layout, settings, context):
        box = layout.box()
        box.label(text="Lightmap UVs", icon='UV')
        col = box.column()
        col.prop(settings, "uv_layer")
        col.prop(settings, "atlas_mode")
        col.prop(settings, "resolution")
        col.prop(settings, "texel_density")
        col.prop(settings, "mip_levels")
        col.prop(settings, "padding")
        obj = context.object
        if obj is not None and obj.type == 'MESH':
            sub = box.column()
            sub.label(text=f"'{obj.name}' overrides (own atlas)")
            sub.prop(obj.hhd, "resolution")
            sub.prop(obj.hhd, "texel_density")
            if obj.hhd.atlas:
                sub.label(text=f"Atlas '{obj.hhd.atlas}' {obj.hhd.atlas_width}×{obj.hhd.atlas_height}")
        box.operator("hhd.unwrap", icon='UV')
        if settings.unwrap_summary:
            box.label(text=settings.unwrap_summary)

    @staticmethod
    def draw_bake(layout, settings, context):
        box = layout.box()
        box.label(text="Bake", icon='RENDER_STILL')
        col = box.column()
        col.prop(settings, "preset")
        col.prop(settings, "samples")
        col.prop(settings, "bounces")
        col.prop(settings, "noise_target")
        col.prop(settings, "denoise")
        col.prop(settings, "stitch_seams")
        col.prop(settings, "time_budget")
        col.prop(settings, "seed")
        col.prop(settings, "inward_faces")
        row = box.row()
        row.operator("hhd.check_normals", icon='NORMALS_FACE')
        for line in settings.inward_report.splitlines():  # faces that point into their own object
            box.label(text=line, icon='ERROR')
        col = box.column(heading="Encoder")
        col.prop(settings, "model")
        if settings.model in {'HHD', 'AHD'}:  # the highlight direction's fit
            col.prop(settings, "direction")
            col.prop(settings, "ambient")
            col.prop(settings, "phi_search")
            col.prop(settings, "golden_iterations")
        elif settings.model.startswith('SG'):
            col.prop(settings, "solve")
        wm = context.window_manager
        if wm.hhd_status:
            box.progress(factor=wm.hhd_progress, type='BAR', text=wm.hhd_status)
        box.prop(settings, "scheduler", icon='NETWORK_DRIVE')
        row = box.row(align=True)
        row.operator("hhd.bake", icon='RENDER_STILL')
        row.operator("hhd.encode", icon='FILE_REFRESH')
        row.operator("hhd.compare", icon='IMAGE_REFERENCE', text="Compare")
        if settings.bake_summary:
            box.label(text=settings.bake_summary)
        row = box.row(align=True)  # bake what changed (README: Bake what changed)
        row.operator("hhd.check_stale", icon='VIEWZOOM')
        row.operator("hhd.bake_changed", text="Bake Selected").mode = 'SELECTED'
        row.operator("hhd.bake_changed", text="Bake Changed").mode = 'CHANGED'
        row.operator("hhd.bake_changed", text="+ Influenced").mode = 'INFLUENCED'
        for line in settings.stale_report.splitlines():
            box.label(text=line, icon='TIME')
        col = box.column()
        col.prop(settings, "view_mode")
        if settings.view_mode == 'LIGHTING':
            col.prop(settings, "preview_mode")
            col.prop(settings, "preview_term")
            col.prop(settings, "preview_filter")
            col.prop(settings, "preview_self_bounce")
        row = box.row(align=True)
        if settings.view_mode == 'LIGHTING':
            row.operator("hhd.preview_show", icon='HIDE_OFF')
        else:  # the views before a bake: from the lightmap UVs alone
            row.operator("hhd.view_show", text="Show Preview", icon='HIDE_OFF').mode = settings.view_mode
        row.operator("hhd.preview_hide", icon='HIDE_ON')
        if settings.view_mode != 'LIGHTING':
            for line in settings.view_summary.splitlines():
                box.label(text=line)
        col = box.column()
        col.prop(settings, "probe_mode")
        row = box.row(align=True)
        row.operator("hhd.probe_preview_show", icon='OUTLINER_OB_LIGHTPROBE')
        row.operator("hhd.probe_preview_hide", icon='HIDE_ON')

    @staticmethod
    def draw_light_sets(layout, settings):
        """The light sets of the last bake (Light Groups), their blend weights, Refresh and Blend."""
        box = layout.box()
        box.label(text="Light Sets", icon='LIGHT')
        custom = getattr(bpy.types, LIGHT_SETS_LIST, None) is not None
        box.template_list(
            LIGHT_SETS_LIST if custom else "UI_UL_list",
            "hhd_light_sets",
            settings,
            "light_sets",
            settings,
            "light_sets_index",
            rows=3,
        )
        if not custom and 0 <= settings.light_sets_index < len(settings.light_sets):
            box.prop(settings.light_sets[settings.light_sets_index], "weight")
        if not settings.light_sets:
            box.label(text="Put lights in Light Groups and bake: one lightmap per group", icon='INFO')
        row = box.row(align=True)
        row.operator("hhd.refresh_light_sets", icon='FILE_REFRESH')
        row.operator("hhd.blend_light_sets", icon='NODE_COMPOSITING')

    @staticmethod
    def draw_output(layout, settings):
        box = layout.box()
        box.label(text="Output", icon='FILE_FOLDER')
        col = box.column()
        col.prop(settings, "output_dir")
        col.prop(settings, "pack_images")
        box.operator("hhd.open_output", icon='FILEBROWSER')
        box.operator("hhd.check_dependencies", icon='CHECKMARK')
