"""Scene settings of HHD Lightmapper: `bpy.context.scene.hhd`."""

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from .bridge import probe_mode
from .core import hhd, presets

# Blender 4.5+ wants path properties that accept "//" to say so (4.2-4.4 do not know the flag).
_BLEND_RELATIVE = {'PATH_SUPPORTS_BLEND_RELATIVE'} if bpy.app.version >= (4, 5, 0) else set()


def _knobs(settings) -> tuple[int, int, float, bool]:
    """The settings a preset sets, as `presets.Preset.knobs()` gives them."""
    return settings.samples, settings.bounces, round(settings.noise_target / 100.0, 6), settings.denoise


_applying_preset = False  # the knobs' update callbacks fire while a preset sets them


def _apply_preset(self, _context):
    global _applying_preset
    if self.preset == 'CUSTOM':
        return
    samples, bounces, noise, denoise = presets.get(self.preset).knobs()
    _applying_preset = True
    try:
        self.samples, self.bounces, self.noise_target = samples, bounces, 100.0 * noise
        self.denoise = denoise
    finally:
        _applying_preset = False


def _mark_custom(self, _context):
    if not _applying_preset and self.preset != 'CUSTOM' and presets.get(self.preset).knobs() != _knobs(self):
        self.preset = 'CUSTOM'


def _probe_mode_changed(self, context):
    """The probe preview's node groups read the mode as a number from a scene custom property
    (a View Layer Attribute node): mirror the enum there, so every material relights live."""
    probe_mode.mirror(context.scene, self.probe_mode)


class HHDLightSet(bpy.types.PropertyGroup):
    """One light set of the last bake (`scene.hhd.light_sets`): `name` is the set's name in the
    atlas sidecars' "light_sets" (a Light Group, or core.scene.DEFAULT_LIGHT_SET), `weight` its RGB
    blend weight. The EEVEE live blend reads the weight by RNA path (`bridge.light_sets.weight_path`), so keyframes
    on it play back in the viewport and in renders."""

    weight: FloatVectorProperty(
        name="Weight",
        size=3,
        subtype='COLOR',
        min=0.0,
        max=1000.0,  # core.light_sets.MAX_WEIGHT: larger weights overflow the blended lightmap
        soft_max=1.0,
        default=(1.0, 1.0, 1.0),
        description="RGB weight of this light set in the blend (1 = as baked, 0 = off; animatable)",
    )


class HHDSettings(bpy.types.PropertyGroup):
    target: EnumProperty(
        name="Receivers",
        default='SELECTED',
        items=[
            ('SELECTED', "Selected Objects", "The selected mesh objects receive lightmaps"),
            ('COLLECTION', "Collection", "The mesh objects of a collection receive lightmaps"),
        ],
        description="Objects that get lightmap texels; every render-visible object occludes and "
        "bounces light either way",
    )
    target_collection: PointerProperty(
        name="Collection",
        type=bpy.types.Collection,
        description="Collection whose mesh objects receive lightmaps (child collections included)",
    )
    uv_layer: StringProperty(
        name="Lightmap UV Layer",
        default="HHD_Lightmap",
        description="UV layer the unwrap writes and the bake reads; no other UV layer is touched",
    )
    resolution: IntProperty(
        name="Resolution", default=1024, min=256, max=8192, description="Atlas width and height in texels"
    )
    texel_density: FloatProperty(
        name="Texel Density",
        default=0.0,
        min=0.0,
        soft_max=200.0,
        unit='NONE',
        description="Texels per metre; 0 uses the fixed Resolution instead",
    )
    atlas_mode: EnumProperty(
        name="Atlas",
        default='SHARED',
        items=[
            ('SHARED', "Shared", "All target objects in one atlas"),
            ('PER_OBJECT', "Per Object", "One atlas per object"),
        ],
    )
    mip_levels: IntProperty(
        name="Mip Levels",
        default=2,
        min=0,
        max=6,
        description="Mip levels the padding must survive (padding = 2 × 2^levels texels)",
    )
    padding: IntProperty(
        name="Padding", default=0, min=0, max=64, description="Texels between charts; 0 derives it from Mip Levels"
    )
    unwrap_summary: StringProperty(name="Last Unwrap", default="", options={'SKIP_SAVE'})
    preset: EnumProperty(
        name="Quality",
        default='PRODUCTION',
        update=_apply_preset,
        items=[(k, k.title(), p.description) for k, p in presets.PRESETS.items()]
        + [('CUSTOM', "Custom", "Samples, bounces, noise target and denoising as set below")],
        description="Samples, bounces, noise target and denoising from the measured speed/accuracy "
        "presets (README: Speed vs accuracy)",
    )
    samples: IntProperty(
        name="Samples",
        default=256,
        min=4,
        max=65536,
        update=_mark_custom,
        description="Hemisphere samples per lightmap texel",
    )
    bounces: IntProperty(
        name="Bounces",
        default=8,
        min=0,
        max=16,
        update=_mark_custom,
        description="Diffuse interreflection bounces after the first hit",
    )
    noise_target: FloatProperty(
        name="Noise Target",
        default=0.0,
        min=0.0,
        max=50.0,
        precision=1,
        subtype='PERCENTAGE',
        update=_mark_custom,
        description="Stop a texel early once the standard error of its irradiance is below this "
        "percentage of it (Samples is then the most a texel takes); 0 = every texel "
        "takes every sample",
    )
    denoise: BoolProperty(
        name="Denoise",
        default=presets.PRESETS['PRODUCTION'].denoise,  # the default preset's (on)
        update=_mark_custom,
        description="Filter the baked lighting with Open Image Denoise's lightmap filter (Blender's "
        "own library) before encoding: less noise for the same samples. The SH EXR keeps the "
        "lighting as traced, so Re-encode can switch it off or on without baking again",
    )
    stitch_seams: BoolProperty(
        name="Stitch Seams",
        default=True,
        description="Make the lighting agree on both sides of each UV seam of a smooth surface (least "
        "squares on the baked SH, before encoding), so no line shows where a surface is split "
        "between charts. Hard edges are left alone. Re-encode can switch it off or on without "
        "baking again",
    )
    inward_faces: EnumProperty(
        name="Faces Pointing In",
        items=[
            (
                'OPEN_SIDE',
                "Bake from the Open Side",
                "Faces whose normals point into their own closed object are baked on the side light "
                "reaches (their n_v turned round), as Cycles' two-sided shading shows them",
            ),
            (
                'AS_MODELLED',
                "Keep as Modelled",
                "Bake such faces along their own normals (their lightmap is black there), with a warning",
            ),
            ('REFUSE', "Refuse", "Stop the bake with an error naming the objects with such faces"),
        ],
        default='OPEN_SIDE',
        description="Faces whose normals point into their own closed object (an inside-out mesh: Blender "
        "shades both sides, so it looks right there): what the bake does with them. A closed object "
        "holding a light or an emitter is a room seen from inside and is left as it is",
    )
    inward_report: StringProperty(
        name="Faces Pointing In",
        default="",
        options={'SKIP_SAVE'},
        description="Objects whose faces point inwards, found by Check Normals or the last bake (one per line)",
    )
    time_budget: FloatProperty(
        name="Time Budget",
        default=0.0,
        min=0.0,
        soft_max=3600.0,
        unit='TIME_ABSOLUTE',
        description="Stop tracing after this many seconds (the first pass always completes); 0 = no limit",
    )
    output_dir: StringProperty(
        name="Output Folder",
        default="//lightmaps",
        subtype='DIR_PATH',
        options=_BLEND_RELATIVE,
        description="Where the EXR files and JSON sidecar are written (relative to the .blend)",
    )
    pack_images: BoolProperty(
        name="Pack Images",
        default=False,
        description="Pack the baked images into the .blend (by default they stay external files)",
    )
    preview_mode: EnumProperty(
        name="Preview",
        default='HHD',
        items=[
            ('HHD', "HHD", "The HHD encoding (as the bake wrote it)"),
            ('AHD', "AHD", "The AHD reconstruction of the same texels (needs an AHD bake or re-encode to match)"),
            ('L1', "L1 SH", "Irradiance from the first 4 SH coefficients"),
            ('L2', "L2 SH", "Irradiance from all 9 SH coefficients"),
            ('SCALAR', "Scalar", "I_z only: no response to normal maps"),
            (
                'ENCODED',
                "Encoded",
                "The model each atlas was encoded in (HHD, AHD, SH, HL2, H-basis, SG), from its own files, "
                "reconstructed as its runtime would",
            ),
        ],
        description="Which reconstruction the EEVEE preview shows (A/B the encodings on the same object)",
    )
    preview_term: EnumProperty(
        name="Term",
        default='DIFFUSE',
        items=[
            ('DIFFUSE', "Diffuse", "Albedo × irradiance (the lightmap's diffuse reconstruction)"),
            (
                'SPECULAR',
                "Specular",
                "GGX specular from the lightmap (HHD, AHD, L1/L2 SH, SG; docs/format.md): "
                "Principled Roughness (α = R²) and F0 (IOR, Specular IOR Level, Metallic)",
            ),
            ('BOTH', "Both", "Albedo × (1 − Metallic) × irradiance + specular"),
        ],
        description=(
            "What the EEVEE preview shows; HL2, H-basis and Scalar have no specular model: they show diffuse, "
            "with a warning naming them (applies at Show Preview)"
        ),
    )
    preview_filter: EnumProperty(
        name="Filter",
        default='BILINEAR',
        items=[
            ('BILINEAR', "Bilinear", "EEVEE's bilinear filtering of the lightmap (what most runtimes do)"),
            (
                'BICUBIC',
                "Bicubic",
                "Catmull-Rom over 4 × 4 texels (docs/format.md, \"Bicubic sampling\"): sharper, smoother shadow "
                "edges at low resolution; needs 2 texels of gutter (Mip Levels ≥ 1)",
            ),
            (
                'BSPLINE',
                "B-spline (prefiltered)",
                "The cubic B-spline whose mean over every texel is the texel (docs/format.md, \"Prefiltered "
                "B-spline\"): closest to a sharp shadow at low resolution; reads coefficient images made from the "
                "preview images on first use; needs 2 texels of gutter",
            ),
        ],
        description="How the EEVEE preview samples the lightmap images (applies at Show Preview)",
    )
    scheduler: StringProperty(
        name="Dask Scheduler",
        default="",
        description="tcp://HOST:PORT of a Dask scheduler: the bake points and the tracing run on its workers, "
        "with the same files as a bake here (docs/farm.md); empty: bake on this machine",
    )
    probe_mode: EnumProperty(
        name="Probe Lighting",
        default='HLSH_CONE',
        items=[
            ('SH', "Plain SH", "Irradiance of the probes' L2 SH at the shading normal (leaks light from behind)"),
            ('HLSH', "HLSH", "The talk's hemisphere multiply around the geometric normal"),
            ('HLSH_CONE', "HLSH + Cone", "The hemisphere narrowed to the visibility cone of EEVEE's ambient occlusion"),
        ],
        update=_probe_mode_changed,
        description="How objects previewed with the probes are lit (compare the talk's occlusion modes)",
    )
    view_mode: EnumProperty(
        name="View",
        default='LIGHTING',
        items=[
            ('LIGHTING', "Lighting", "The baked lighting (Show Preview, in the Preview mode below)"),
            (
                'DENSITY',
                "Texel Density",
                "Texels per metre against the target, before any bake: blue half, green on target, red double",
            ),
            ('CHECKER', "Texel Checker", "A checker of exactly one texel per cell, before any bake"),
            (
                'PROBLEMS',
                "Problems",
                "Texels shared by two charts, flipped or degenerate UV faces, objects with too few texels, before any bake",
            ),
        ],
        description="What Show Preview shows: the baked lighting, or a view of the lightmap UVs that needs no bake",
    )
    view_summary: StringProperty(name="Last View", default="", options={'SKIP_SAVE'})
    preview_self_bounce: BoolProperty(
        name="Self Bounce",
        default=False,
        description="Add the light the surface's own bumps bounce back (HHD/AHD preview)",
    )
    seed: IntProperty(name="Seed", default=0, min=0, description="Random seed: the same seed gives the same bake")
    bake_summary: StringProperty(name="Last Bake", default="", options={'SKIP_SAVE'})
    stale_report: StringProperty(
        name="What Changed",
        default="",
        options={'SKIP_SAVE'},
        description="What changed since the last bake in the output folder (What Changed), one line per kind",
    )
    model: EnumProperty(
        name="Model",
        default='HHD',
        items=[
            ('HHD', "HHD", "Hemisphere light + highlight direction (IrradZ)"),
            ('AHD', "AHD", "Constant ambient + highlight direction (IrradZ)"),
            ('SH_L1', "L1 SH", "Radiance SH, 4 coefficients per colour (Baking Lab; docs/format.md)"),
            ('SH_L2', "L2 SH", "Radiance SH, 9 coefficients per colour (Baking Lab; docs/format.md)"),
            ('HL2', "Half-Life 2", "Three colours along the Half-Life 2 basis in the tangent frame of n_v"),
            ('HBASIS_L1', "L1 H-basis", "Hemispherical basis, 4 coefficients per colour (Habel & Wimmer)"),
            ('HBASIS_L2', "L2 H-basis", "Hemispherical basis, 6 coefficients per colour (Habel & Wimmer)"),
            ('SG5', "SG5", "5 spherical Gaussians with fixed lobes (Baking Lab), fitted by the Solve setting"),
            ('SG6', "SG6", "6 spherical Gaussians with fixed lobes (Baking Lab), fitted by the Solve setting"),
            ('SG9', "SG9", "9 spherical Gaussians with fixed lobes (Baking Lab), fitted by the Solve setting"),
            ('SG12', "SG12", "12 spherical Gaussians with fixed lobes (Baking Lab), fitted by the Solve setting"),
        ],
        description="The encoding written (the raw SH file is always written too); the EEVEE preview shows "
        "it in Preview mode Encoded",
    )
    solve: EnumProperty(
        name="SG Solve",
        default='NNLS',
        items=[
            ('ADHOC', "Ad-hoc", "Ad-hoc projection onto the lobes (Baking Lab's, normalised)"),
            ('LS', "Least Squares", "Least-squares fit to the radiance the L2 SH holds"),
            ('NNLS', "Non-negative LS", "Non-negative least squares: no negative lobe"),
        ],
        description="How an SG encoding fits its lobes (docs/format.md)",
    )
    direction: EnumProperty(
        name="Direction",
        default='SEARCHED',
        items=[
            ('SEARCHED', "Searched", "Golden-section search for the least-error direction"),
            ('OPTIMAL_LINEAR', "Optimal Linear", "Direction of the SH linear band (baseline)"),
        ],
    )
    ambient: EnumProperty(
        name="Ambient Weight",
        default='LUMINANCE',
        items=[
            ('LUMINANCE', "Luminance", "One ambient weight per texel"),
            ('RGB', "RGB", "One ambient weight per colour channel"),
        ],
    )
    phi_search: BoolProperty(
        name="Search Azimuth",
        default=False,
        description="Also search the highlight direction's azimuth (slower, slightly lower error)",
    )
    light_sets: CollectionProperty(
        type=HHDLightSet,
        name="Light Sets",
        description="The light sets of the last bake (its Light Groups) and their blend weights",
    )
    light_sets_index: IntProperty(name="Active Light Set", default=0, min=0)
    golden_iterations: IntProperty(
        name="Search Steps",
        default=hhd.GOLDEN_ITERATIONS,
        min=0,
        max=40,
        description="Golden-section steps refining the highlight direction's elevation after a "
        "9-point scan (0: the best scan point)",
    )


class HHDObjectSettings(bpy.types.PropertyGroup):
    """Per-object overrides: `object.hhd`. An object with an override gets its own atlas."""

    resolution: IntProperty(
        name="Resolution Override",
        default=0,
        min=0,
        max=8192,
        description="Own atlas of this size; 0 uses the scene settings",
    )
    texel_density: FloatProperty(
        name="Texel Density Override",
        default=0.0,
        min=0.0,
        soft_max=200.0,
        description="Own atlas at this many texels per metre; 0 uses the scene settings",
    )
    atlas: StringProperty(
        name="Atlas", default="", description="Atlas the last unwrap put this object in (the bake's file name stem)"
    )
    atlas_width: IntProperty(name="Atlas Width", default=0, min=0)
    atlas_height: IntProperty(name="Atlas Height", default=0, min=0)
    lightmap_rect: FloatVectorProperty(
        name="Lightmap Rectangle",
        size=4,
        default=(1.0, 1.0, 0.0, 0.0),
        description="Where this object's lightmap lies in its atlas, set by Unwrap: atlas UV = lightmap UV × "
        "(x, y) + (z, w). Identity for an object with its own mesh; a linked duplicate (an instance) shares its "
        "mesh's lightmap UVs and gets its own rectangle. On an Empty that shows a collection: where its copy of "
        "the collection's block lies in the atlas",
    )
    collection_rect: FloatVectorProperty(
        name="Collection Rectangle",
        size=4,
        default=(1.0, 1.0, 0.0, 0.0),
        description="For an object of a collection that Empties show (collection instances), set by Unwrap: where "
        "its lightmap lies in the collection's block (block UV = lightmap UV × (x, y) + (z, w)); each Empty's "
        "Lightmap Rectangle places the block in the atlas",
    )
    collection_instance: FloatProperty(
        name="Collection Instance",
        default=0.0,
        min=0.0,
        max=1.0,
        description="1 on an Empty whose collection was unwrapped as collection instances (read by the preview)",
    )


classes = (HHDLightSet, HHDSettings, HHDObjectSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.hhd = bpy.props.PointerProperty(type=HHDSettings)
    bpy.types.Object.hhd = bpy.props.PointerProperty(type=HHDObjectSettings)
    # Bake progress lives on the window manager: it is UI state, never saved in the .blend.
    bpy.types.WindowManager.hhd_progress = FloatProperty(name="Bake Progress", min=0.0, max=1.0, subtype='FACTOR')
    bpy.types.WindowManager.hhd_status = StringProperty(name="Bake Status")


def unregister():
    del bpy.types.WindowManager.hhd_status
    del bpy.types.WindowManager.hhd_progress
    del bpy.types.Object.hhd
    del bpy.types.Scene.hhd
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
