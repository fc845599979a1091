"""The three bench scenes of bench/tradeoff.py, built with bpy (no files needed): different
lighting character, each with a camera and a normal-mapped surface in view.

- outdoor:  a courtyard of blocks on open ground, a 2° sun and a blue sky (Background colour).
- interior: the demo room (tools/demo_scene.py): sun and sky through one window.
- emissive: a closed room lit only by an emissive ceiling panel (Emission shader) and a glowing
            wall strip (Principled emission); black world, no lights.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import demo_scene  # noqa: E402
from hhd_lightmapper import blender_compat

NAMES = ("outdoor", "interior", "emissive")
#: objects that emit: occluders and lights, not lightmap receivers
EMITTERS = ("Ceiling Light", "Glow Strip")


def build(name: str) -> None:
    """Replace the current file with the named scene."""
    {"outdoor": outdoor, "interior": demo_scene.build, "emissive": emissive}[name]()


def _sun(elevation_deg, azimuth_deg, strength, angle_deg):
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    data = bpy.data.lights.new("Sun", "SUN")
    data.energy, data.angle = strength, math.radians(angle_deg)
    sun = bpy.data.objects.new("Sun", data)
    towards = (math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e))
    sun.rotation_euler = demo_scene._rotation_pointing(tuple(-c for c in towards))
    bpy.context.scene.collection.objects.link(sun)


def _world(colour, strength):
    world = bpy.data.worlds.new("World")
    blender_compat.ensure_node_tree(world)
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*colour, 1.0)
    bg.inputs["Strength"].default_value = strength
    bpy.context.scene.world = world


def _camera(location, direction, lens=18.0):
    data = bpy.data.cameras.new("Camera")
    data.lens = lens
    cam = bpy.data.objects.new("Camera", data)
    cam.location = location
    cam.rotation_euler = demo_scene._rotation_pointing(direction)
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam


def outdoor() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    stone = demo_scene._material("Stone", (0.55, 0.5, 0.45))
    grass = demo_scene._material("Ground", (0.25, 0.35, 0.15))
    brick = demo_scene._material("Brick", (0.6, 0.25, 0.15))
    panel = demo_scene._material("Panel", (0.6, 0.6, 0.6), demo_scene._bumps_normal_map())
    demo_scene._box("Ground", (-10, -10, -0.2), (10, 10, 0.0), grass)
    demo_scene._box("Block A", (-4, 1, 0), (0, 5, 3), stone)
    demo_scene._box("Block B", (1, 2, 0), (4, 4, 5), brick)
    demo_scene._box("Low Wall", (-5, -1.2, 0), (3, -1.0, 1.0), stone)
    for i in range(4):
        demo_scene._box(f"Pillar {i}", (-3 + 2 * i, -4, 0), (-2.6 + 2 * i, -3.6, 2.5), stone)
    demo_scene._box("Normal-mapped Panel", (-4, 0.95, 0.3), (0, 1.0, 2.5), panel)
    _sun(40.0, 240.0, 4.0, 2.0)
    _world((0.4, 0.6, 1.0), 1.0)
    _camera((3.0, -9.0, 3.5), (-0.25, 1.0, -0.35))


def emissive() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sx, sy, sz, t = 6.0, 5.0, 3.0, 0.2
    white = demo_scene._material("Plaster", (0.8, 0.8, 0.78))
    blue = demo_scene._material("Blue Paint", (0.15, 0.25, 0.7))
    panel = demo_scene._material("Panel", (0.6, 0.6, 0.6), demo_scene._bumps_normal_map())
    demo_scene._box("Floor", (-sx / 2, -sy / 2, -t), (sx / 2, sy / 2, 0), white)
    demo_scene._box("Ceiling", (-sx / 2, -sy / 2, sz), (sx / 2, sy / 2, sz + t), white)
    demo_scene._box("Wall -X", (-sx / 2 - t, -sy / 2, 0), (-sx / 2, sy / 2, sz), white)
    demo_scene._box("Wall +X", (sx / 2, -sy / 2, 0), (sx / 2 + t, sy / 2, sz), blue)
    demo_scene._box("Wall -Y", (-sx / 2, -sy / 2 - t, 0), (sx / 2, -sy / 2, sz), white)
    demo_scene._box("Wall +Y", (-sx / 2, sy / 2, 0), (sx / 2, sy / 2 + t, sz), white)
    demo_scene._box("Table", (-0.8, -0.6, 0.0), (0.8, 0.6, 0.75), white)
    demo_scene._box("Normal-mapped Panel", (-sx / 2, -1.0, 0.5), (-sx / 2 + 0.05, 1.0, 2.2), panel)

    ceiling_light = bpy.data.materials.new("Ceiling Light")
    blender_compat.ensure_node_tree(ceiling_light)
    nodes = ceiling_light.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (1.0, 0.9, 0.75, 1.0)
    emission.inputs["Strength"].default_value = 12.0
    ceiling_light.node_tree.links.new(emission.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    # hanging below the ceiling and off the wall: no emitter touches a receiver (a contact makes
    # the irradiance of the texels along it unbounded, and any estimator's variance with it)
    demo_scene._box("Ceiling Light", (-1.0, -0.5, sz - 0.35), (1.0, 0.5, sz - 0.3), ceiling_light)

    strip = demo_scene._material("Glow Strip", (0.1, 0.1, 0.1))
    bsdf = strip.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Emission Color"].default_value = (0.3, 0.6, 1.0, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 6.0
    demo_scene._box("Glow Strip", (sx / 2 - 0.19, -2.0, 1.9), (sx / 2 - 0.15, 2.0, 2.1), strip)
    _camera((2.6, -2.2, 1.7), (-1.0, 0.55, -0.2), lens=16.0)
