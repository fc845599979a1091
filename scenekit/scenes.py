"""Named whole scenes, built with bpy (scenekit/blender.py's builders). Each replaces the
current scene's content.

- `demo_room`: the README's demo (tools/demo.py, bench/preview.py; bench/tradeoff.py's
  "interior"): a room with a window in its +x wall, a sun shining in, a sky, a red wall and a
  normal-mapped panel, and a camera.
- `outdoor`, `emissive`: with `demo_room` the three scenes of bench/tradeoff.py (`build(name)`,
  `NAMES`), different lighting character, each with a camera and a normal-mapped surface in view.
  outdoor: a courtyard of blocks on open ground, a 2° sun and a blue sky (Background colour).
  emissive: a closed room lit only by an emissive ceiling panel (Emission shader) and a glowing
  wall strip (Principled emission); black world, no lights (`EMITTERS` are not receivers).
- `classroom`, `field`: bench/time_to_error.py's scenes against Cycles, sun + sky; each returns
  its receivers. classroom loads the 104k-triangle classroom's OBJ files (`CLASSROOM`, outside
  the repository); field is ~1M triangles of `meshes.sphere_field` on a ground plane.

bpy is imported inside each function (see scenekit/blender.py).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hhd_lightmapper import blender_compat

from . import blender
from .meshes import sphere_field

# ---- the demo room --------------------------------------------------------------------------
ROOM = (6.0, 4.0, 3.0)  # x, y, z extent in metres, floor at z = 0
WINDOW = (-1.0, 1.0, 1.0, 2.2)  # in the +x wall: y range, z range
SUN_DIRECTION_DEG = (35.0, 20.0)  # elevation, azimuth (from +x towards +y): shines in through the window
SKY_COLOUR = (0.35, 0.55, 1.0)


def demo_room() -> dict:
    """Replace the current scene's content with the demo room; return its key objects."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sx, sy, sz = ROOM
    t = 0.2
    white = blender.material("Plaster", (0.8, 0.8, 0.78))
    red = blender.material("Red Paint", (0.75, 0.12, 0.08))
    panel_mat = blender.material("Panel", (0.6, 0.6, 0.6), normal_image=blender.bumps_normal_map())
    box = blender.box_between
    objs = {
        "floor": box("Floor", (-sx / 2, -sy / 2, -t), (sx / 2, sy / 2, 0.0), white),
        "ceiling": box("Ceiling", (-sx / 2, -sy / 2, sz), (sx / 2, sy / 2, sz + t), white),
        "wall_back": box("Wall -X", (-sx / 2 - t, -sy / 2, 0.0), (-sx / 2, sy / 2, sz), white),
        "wall_red": box("Wall +Y (red)", (-sx / 2, sy / 2, 0.0), (sx / 2, sy / 2 + t, sz), red),
        "wall_front": box("Wall -Y", (-sx / 2, -sy / 2 - t, 0.0), (sx / 2, -sy / 2, sz), white),
    }
    # The +x wall, built around the window opening.
    y0, y1, z0, z1 = WINDOW
    x0, x1 = sx / 2, sx / 2 + t
    for i, (lo, hi) in enumerate(
        [
            ((x0, -sy / 2, 0.0), (x1, y0, sz)),
            ((x0, y1, 0.0), (x1, sy / 2, sz)),
            ((x0, y0, 0.0), (x1, y1, z0)),
            ((x0, y0, z1), (x1, y1, sz)),
        ]
    ):
        objs[f"wall_window_{i}"] = box(f"Wall +X {i}", lo, hi, white)
    objs["panel"] = box("Normal-mapped Panel", (-sx / 2, -0.8, 0.6), (-sx / 2 + 0.05, 0.8, 2.0), panel_mat)
    # 5 W/m² (Cycles units), 1° wide, from the sky through the window (+x side)
    objs["sun"] = blender.sun(*SUN_DIRECTION_DEG, strength=5.0, angle_deg=1.0)
    blender.world(SKY_COLOUR, 1.0, name="Sky")
    blender.camera((2.6, -1.6, 1.6), (-1.0, 0.45, -0.08), lens=16.0)
    return objs


def sun_direction() -> np.ndarray:
    """Unit vector towards the demo room's sun (world space)."""
    e, a = (math.radians(v) for v in SUN_DIRECTION_DEG)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


# ---- bench/tradeoff.py's three scenes ---------------------------------------------------------
NAMES = ("outdoor", "interior", "emissive")
#: objects that emit: occluders and lights, not lightmap receivers
EMITTERS = ("Ceiling Light", "Glow Strip")


def build(name: str) -> None:
    """Replace the current file with the named scene (one of NAMES)."""
    {"outdoor": outdoor, "interior": demo_room, "emissive": emissive}[name]()


def outdoor() -> None:
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    box, material = blender.box_between, blender.material
    stone = material("Stone", (0.55, 0.5, 0.45))
    grass = material("Ground", (0.25, 0.35, 0.15))
    brick = material("Brick", (0.6, 0.25, 0.15))
    panel = material("Panel", (0.6, 0.6, 0.6), normal_image=blender.bumps_normal_map())
    box("Ground", (-10, -10, -0.2), (10, 10, 0.0), grass)
    box("Block A", (-4, 1, 0), (0, 5, 3), stone)
    box("Block B", (1, 2, 0), (4, 4, 5), brick)
    box("Low Wall", (-5, -1.2, 0), (3, -1.0, 1.0), stone)
    for i in range(4):
        box(f"Pillar {i}", (-3 + 2 * i, -4, 0), (-2.6 + 2 * i, -3.6, 2.5), stone)
    box("Normal-mapped Panel", (-4, 0.95, 0.3), (0, 1.0, 2.5), panel)
    blender.sun(40.0, 240.0, 4.0, 2.0)
    blender.world((0.4, 0.6, 1.0), 1.0)
    blender.camera((3.0, -9.0, 3.5), (-0.25, 1.0, -0.35))


def emissive() -> None:
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    box, material = blender.box_between, blender.material
    sx, sy, sz, t = 6.0, 5.0, 3.0, 0.2
    white = material("Plaster", (0.8, 0.8, 0.78))
    blue = material("Blue Paint", (0.15, 0.25, 0.7))
    panel = material("Panel", (0.6, 0.6, 0.6), normal_image=blender.bumps_normal_map())
    box("Floor", (-sx / 2, -sy / 2, -t), (sx / 2, sy / 2, 0), white)
    box("Ceiling", (-sx / 2, -sy / 2, sz), (sx / 2, sy / 2, sz + t), white)
    box("Wall -X", (-sx / 2 - t, -sy / 2, 0), (-sx / 2, sy / 2, sz), white)
    box("Wall +X", (sx / 2, -sy / 2, 0), (sx / 2 + t, sy / 2, sz), blue)
    box("Wall -Y", (-sx / 2, -sy / 2 - t, 0), (sx / 2, -sy / 2, sz), white)
    box("Wall +Y", (-sx / 2, sy / 2, 0), (sx / 2, sy / 2 + t, sz), white)
    box("Table", (-0.8, -0.6, 0.0), (0.8, 0.6, 0.75), white)
    box("Normal-mapped Panel", (-sx / 2, -1.0, 0.5), (-sx / 2 + 0.05, 1.0, 2.2), panel)

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
    box("Ceiling Light", (-1.0, -0.5, sz - 0.35), (1.0, 0.5, sz - 0.3), ceiling_light)

    strip = material("Glow Strip", (0.1, 0.1, 0.1), emission=(0.3, 0.6, 1.0, 6.0))
    box("Glow Strip", (sx / 2 - 0.19, -2.0, 1.9), (sx / 2 - 0.15, 2.0, 2.1), strip)
    blender.camera((2.6, -2.2, 1.7), (-1.0, 0.55, -0.2), lens=16.0)


# ---- bench/time_to_error.py's scenes ----------------------------------------------------------
#: the classroom's OBJ files and scene_v3.xml (a checkout of the shared scenes beside this repository)
CLASSROOM = Path(__file__).resolve().parent.parent.parent / "shared" / "scenes" / "classroom"


def sun_and_sky(sun_rotation=(0.9, 0.0, 2.3), sky=(0.5, 0.7, 1.0)) -> None:
    """The time-to-error scenes' lighting: a 4 W/m² sun of zero angle, a constant sky."""
    blender.light('SUN', rotation=sun_rotation, energy=4.0, name="Sun", angle=0.0)
    blender.world(sky, name="Sky")


def classroom(folder: Path = CLASSROOM) -> list:
    """The classroom (every OBJ of `folder`/scene_v3.xml, one grey diffuse material), sun + sky;
    returns the receivers: the 6 largest room surfaces with few charts (walls, floor, ceiling,
    desks); the backdrop and the many-part furniture only occlude and reflect."""
    import xml.etree.ElementTree as ET

    import bpy

    blender.clear_data(worlds=True)
    grey = bpy.data.materials.new("Diffuse")
    blender_compat.ensure_node_tree(grey)
    grey.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = 1.0
    root = ET.parse(folder / "scene_v3.xml").getroot()
    meshes = []
    for shape in root.iter("shape"):
        if shape.get("type") != "obj":
            continue
        filename = next(s.get("value") for s in shape.iter("string") if s.get("name") == "filename")
        bpy.ops.wm.obj_import(filepath=str(folder / filename))
        for obj in bpy.context.selected_objects:
            obj.data.materials.clear()
            obj.data.materials.append(grey)
            meshes.append(obj)
    sun_and_sky()
    room = [o for o in meshes if max(o.dimensions) < 30.0 and len(o.data.polygons) < 5000]
    return sorted(room, key=lambda o: sum(p.area for p in o.data.polygons))[-6:]


def emissive_room() -> list:
    """`emissive` (a room lit by a ceiling light box and a glow strip, no sky); returns the
    receivers: every mesh but the two emitters."""
    import bpy

    emissive()
    return [o for o in bpy.data.objects if o.type == "MESH" and o.name not in ("Ceiling Light", "Glow Strip")]


def door_room() -> list:
    """A closed white room (6 × 5 × 3 m, walls 0.2 m thick) with a table, lit only through a
    1 × 2.2 m door gap in its -y wall by a sun that shines in onto the floor and a sky colour
    over a grey ground: nearly all its light is indirect. Returns the receivers: the room's
    meshes (not the ground)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    box, material = blender.box_between, blender.material
    white = material("Plaster", (0.8, 0.8, 0.78))
    sx, sy, sz, t = 6.0, 5.0, 3.0, 0.2
    room = [
        box("Floor", (-sx / 2, -sy / 2, -t), (sx / 2, sy / 2, 0), white),
        box("Ceiling", (-sx / 2, -sy / 2, sz), (sx / 2, sy / 2, sz + t), white),
        box("Wall -X", (-sx / 2 - t, -sy / 2, 0), (-sx / 2, sy / 2, sz), white),
        box("Wall +X", (sx / 2, -sy / 2, 0), (sx / 2 + t, sy / 2, sz), white),
        box("Wall +Y", (-sx / 2, sy / 2, 0), (sx / 2, sy / 2 + t, sz), white),
        box("Wall -Y Left", (-sx / 2, -sy / 2 - t, 0), (-0.5, -sy / 2, sz), white),
        box("Wall -Y Right", (0.5, -sy / 2 - t, 0), (sx / 2, -sy / 2, sz), white),
        box("Lintel", (-0.5, -sy / 2 - t, 2.2), (0.5, -sy / 2, sz), white),
        box("Table", (-0.8, -0.6, 0.0), (0.8, 0.6, 0.75), white),
    ]
    box("Ground", (-20, -20, -0.5), (20, 20, -t - 0.01), material("Ground", (0.3, 0.3, 0.3)))
    blender.sun(35.0, 280.0, 4.0, 0.0)
    blender.world((0.5, 0.7, 1.0), 1.0)
    return room


#: The lamp rooms' size (x, y, height) and wall thickness, metres.
LAMP_ROOM = (5.0, 4.0, 2.8, 0.2)


def _lamp_room() -> list:
    """A closed white room (LAMP_ROOM) with a table and a black world, in an empty file; its
    meshes, the receivers."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    box, material = blender.box_between, blender.material
    white = material("Plaster", (0.8, 0.8, 0.78))
    sx, sy, sz, t = LAMP_ROOM
    room = [
        box("Floor", (-sx / 2, -sy / 2, -t), (sx / 2, sy / 2, 0), white),
        box("Ceiling", (-sx / 2, -sy / 2, sz), (sx / 2, sy / 2, sz + t), white),
        box("Wall -X", (-sx / 2 - t, -sy / 2, 0), (-sx / 2, sy / 2, sz), white),
        box("Wall +X", (sx / 2, -sy / 2, 0), (sx / 2 + t, sy / 2, sz), white),
        box("Wall -Y", (-sx / 2, -sy / 2 - t, 0), (sx / 2, -sy / 2, sz), white),
        box("Wall +Y", (-sx / 2, sy / 2, 0), (sx / 2, sy / 2 + t, sz), white),
        box("Table", (-0.8, -0.5, 0.0), (0.8, 0.5, 0.75), white),
    ]
    blender.world((0.0, 0.0, 0.0), 0.0)
    return room


def area_lamp_room() -> list:
    """A closed white room (5 × 4 × 2.8 m, walls 0.2 m thick) with a table, lit only by Blender
    area lights, two of them facing a surface a few centimetres away: a 1.2 × 0.6 m ceiling panel
    facing down, a 3 × 0.1 m cove strip 8 cm below the ceiling along the -y wall facing up, and a
    0.4 m disk 5 cm off the +x wall facing it (a wall washer). The texels in front of the last two
    are where a uniform point on a lamp's surface spikes (1/d²). Returns the receivers: every
    mesh of the room."""
    room = _lamp_room()
    sx, sy, sz, _ = LAMP_ROOM
    blender.light("AREA", (0.5, 0.3, sz - 0.02), energy=200.0, name="Panel", shape="RECTANGLE", size=1.2, size_y=0.6)
    up = blender.rotation_pointing((0.0, 0.0, 1.0))
    blender.light(
        "AREA", (0.0, -sy / 2 + 0.15, sz - 0.08), up, energy=150.0, name="Cove", shape="RECTANGLE", size=3.0, size_y=0.1
    )
    at_wall = blender.rotation_pointing((1.0, 0.0, 0.0))
    blender.light("AREA", (sx / 2 - 0.05, -0.8, 1.6), at_wall, energy=60.0, name="Washer", shape="DISK", size=0.4)
    return room


def lamp_grid_room() -> list:
    """`area_lamp_room`'s room and table lit by nine lamps that all light most of it: six
    0.6 m square ceiling panels in a 3 × 2 grid facing down, two 0.1 m point lights on the ±x
    walls at 1.8 m and a spot over the table: where a shading point picking one lamp
    (`lights.Choice`) has the most to lose against sampling all nine. Returns the receivers."""
    room = _lamp_room()
    sx, _, sz, _ = LAMP_ROOM
    for i, x in enumerate((-1.5, 0.0, 1.5)):
        for j, y in enumerate((-0.9, 0.9)):
            blender.light("AREA", (x, y, sz - 0.02), energy=60.0, name=f"Panel {i}{j}", shape="SQUARE", size=0.6)
    for side in (-1.0, 1.0):
        location = (side * (sx / 2 - 0.15), 0.0, 1.8)
        blender.light("POINT", location, energy=40.0, name=f"Sconce {side:+.0f}", shadow_soft_size=0.1)
    down = blender.rotation_pointing((0.0, 0.0, -1.0))
    spot = dict(spot_size=0.9, spot_blend=0.3, shadow_soft_size=0.05)
    blender.light("SPOT", (0.0, 0.0, 2.2), down, energy=80.0, name="Spot", **spot)
    return room


def panel_room() -> list:
    """`area_lamp_room`'s room and table lit by two subdivided emissive meshes instead of lamps:
    a 1.2 × 0.6 m ceiling panel of 24 × 12 quads hanging 3 cm below the ceiling, and a 3 m
    LED strip of 60 quads (3 cm wide) 4 cm off the -y wall at 2.2 m, facing it; 696 emitting
    triangles, a few centimetres from the surfaces they light, as real lamp meshes are. Each
    of the flat clusters holds a patch of a dozen or more of them; the light tree resolves the
    one under a point. Returns the receivers: the room's meshes (not the emitters)."""
    import bpy

    room = _lamp_room()
    sx, sy, sz, _ = LAMP_ROOM
    panel = blender.material("LED Panel", (0.1, 0.1, 0.1), emission=(1.0, 0.95, 0.85, 15.0))
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=24, y_subdivisions=12, size=1.0, location=(0.5, 0.3, sz - 0.03))
    obj = bpy.context.active_object
    obj.name, obj.scale = "LED Panel", (1.2, 0.6, 1.0)
    obj.data.materials.append(panel)
    strip = blender.material("LED Strip", (0.1, 0.1, 0.1), emission=(0.6, 0.8, 1.0, 20.0))
    location = (0.0, -sy / 2 + 0.04, 2.2)
    bpy.ops.mesh.primitive_grid_add(
        x_subdivisions=60, y_subdivisions=1, size=1.0, location=location, rotation=(1.5708, 0, 0)
    )
    obj = bpy.context.active_object
    obj.name, obj.scale = "LED Strip", (3.0, 0.03, 1.0)
    obj.data.materials.append(strip)
    return room


#: The bulb hall's size (x, y, height), wall thickness, bulbs per row (two rows) and bulb radius, metres.
BULB_HALL = (12.0, 6.0, 3.0, 0.2, 24, 0.05)


def bulb_hall() -> list:
    """A closed white hall (BULB_HALL: 12 × 6 × 3 m) with two tables, lit only by many small
    emissive meshes: two rows of 24 bulbs (icospheres of 80 triangles, 5 cm radius) hanging
    0.4–0.8 m below the ceiling, and twelve 0.2 × 0.3 m emissive plaques 4 cm off the long walls
    at 1.8 m; a black world. 3,984 emitting triangles, far more than the emitters' top clusters
    (`lights.CLUSTERS`), most of them a metre or more from what they light. Returns the
    receivers: the hall's meshes (not the emitters)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    box, material = blender.box_between, blender.material
    white = material("Plaster", (0.8, 0.8, 0.78))
    sx, sy, sz, t, per_row, radius = BULB_HALL
    room = [
        box("Floor", (-sx / 2, -sy / 2, -t), (sx / 2, sy / 2, 0), white),
        box("Ceiling", (-sx / 2, -sy / 2, sz), (sx / 2, sy / 2, sz + t), white),
        box("Wall -X", (-sx / 2 - t, -sy / 2, 0), (-sx / 2, sy / 2, sz), white),
        box("Wall +X", (sx / 2, -sy / 2, 0), (sx / 2 + t, sy / 2, sz), white),
        box("Wall -Y", (-sx / 2, -sy / 2 - t, 0), (sx / 2, -sy / 2, sz), white),
        box("Wall +Y", (-sx / 2, sy / 2, 0), (sx / 2, sy / 2 + t, sz), white),
        box("Table A", (-3.5, -0.6, 0.0), (-1.5, 0.6, 0.75), white),
        box("Table B", (1.5, -0.6, 0.0), (3.5, 0.6, 0.75), white),
    ]
    bulb = material("Bulb", (0.1, 0.1, 0.1), emission=(1.0, 0.85, 0.6, 40.0))
    plaque = material("Plaque", (0.1, 0.1, 0.1), emission=(0.6, 0.8, 1.0, 6.0))
    for row, y in enumerate((-1.2, 1.2)):
        for i in range(per_row):
            x = -sx / 2 + (i + 0.5) * sx / per_row
            z = sz - 0.4 - 0.4 * ((i * 7 + row * 3) % 5) / 4  # 0.4-0.8 m below the ceiling
            bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=radius, location=(x, y, z))
            obj = bpy.context.active_object
            obj.name = f"Bulb {row}{i:02d}"
            obj.data.materials.append(bulb)
    for i in range(6):
        x = -sx / 2 + (i + 0.5) * sx / 6
        for side in (-1.0, 1.0):
            y0 = side * (sy / 2 - 0.04)
            box(
                f"Plaque {i}{side:+.0f}",
                (x - 0.1, min(y0, y0 + side * 0.01), 1.65),
                (x + 0.1, max(y0, y0 + side * 0.01), 1.95),
                plaque,
            )
    blender.world((0.0, 0.0, 0.0), 0.0)
    return room


def field(n_triangles: int = 1_000_000) -> list:
    """`sphere_field(n_triangles)` as one mesh "Field" on a ground plane 1.2× its extent, one
    default diffuse material, sun + sky; returns the receivers: [the ground]."""
    import bpy

    blender.clear_data(worlds=True)
    v, f = sphere_field(n_triangles)
    mesh = bpy.data.meshes.new("Field")
    mesh.from_pydata(v.tolist(), [], f.tolist())
    spheres = bpy.data.objects.new("Field", mesh)
    lo, hi = v.min(0), v.max(0)
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] - 0.01))
    ground = bpy.context.active_object
    ground.scale = ((hi[0] - lo[0]) * 1.2, (hi[1] - lo[1]) * 1.2, 1.0)
    bpy.context.scene.collection.objects.link(spheres)
    mat = bpy.data.materials.new("Diffuse")
    blender_compat.ensure_node_tree(mat)
    for o in (spheres, ground):
        o.data.materials.append(mat)
    sun_and_sky()
    return [ground]
