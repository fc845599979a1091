"""The glTF exporter hook: the baked HHD lightmaps in Blender's own glTF 2.0 export (docs/gltf.md).

Blender's bundled exporter (`io_scene_gltf2`, 4.2 LTS through 5.3) instantiates
`glTF2ExportUserExtension` of every enabled add-on or extension module that exposes it (it looks
the module up in `sys.modules` under its `preferences.addons` key, `bl_ext.<repo>.hhd_lightmapper`
for an extension; the package's `__init__` exposes the class). Its hooks:

- `gather_node_hook` (per node, while gathering): remembers each mesh node and its object;
- `gather_gltf_hook` (after gathering, before the exporter turns objects into indices and the
  buffer): reads the bake's files, checks each receiver, adds the PNG textures, the node
  extensions, per-atlas material copies with the fallback emission and `MOZ_lightmap`, and
  the root extension's content (carried on the active scene's extensions);
- `gather_gltf_extensions_hook` (after): moves that content to the root `extensions`.

Everything is built in the exporter's own objects (`gltf2_io`), so its traversal writes the
images and accessors into the .glb / .bin and lists `extensionsUsed`. Nothing in Blender is
changed. Hook exceptions are logged by the exporter and swallowed: each hook catches its own
and records them (`export_settings["hhd_lightmap"].errors`), which `export()` raises.
"""

from __future__ import annotations

import copy
import json
import math
import os
import sys
from pathlib import Path

import bpy
import numpy as np

from ..core import octahedral
from ..core import sh as core_sh
from ..core.encoding import hhd as hhd_spec
from ..core.encoding import web_packing as wp
from ..core.errors import BakeError
from ..core.files import exr
from ..core.files.lightmap_files import AtlasFiles, read_sidecar
from . import collection_instances, mesh_data

NAME = "HHD_LIGHTMAP"
EXT = "HHD_lightmap"
VERSION = 1
LUM = np.array([0.2126, 0.7152, 0.0722])
#: Blender world (x, y, z) -> glTF world (x, z, -y) (the exporter's +Y up)
TO_GLTF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
LINEAR, CLAMP = 9729, 33071


def _gltf_io():
    from io_scene_gltf2.io.com import gltf2_io
    from io_scene_gltf2.io.com.gltf2_io_extensions import Extension

    try:  # 4.2 – 4.x
        from io_scene_gltf2.io.exp.gltf2_io_binary_data import BinaryData
    except ImportError:  # 5.x
        from io_scene_gltf2.io.exp.binary_data import BinaryData
    return gltf2_io, Extension, BinaryData


class _State:
    """One export's receivers, atlases and warnings."""

    def __init__(self, export_settings):
        self.settings = export_settings
        self.yup = export_settings.get("gltf_yup", True)
        self.nodes: list = []  # (gltf node, blender object name)
        self.instancers: list = []  # (gltf node, name) of the Empties that show a collection
        self.warnings: list[str] = []
        self.errors: list[str] = []
        self.exported: list[str] = []
        self.blender_materials: dict[int, object] = {}
        self.root: dict | None = None
        self.instance_note = False

    def warn(self, text: str) -> None:
        self.warnings.append(text)
        print(f"HHD glTF export: warning: {text}", flush=True)


#: the last export's state, for `export()` (which may find the hook of another copy of the
#: package enabled in Blender: it reads that module's _LAST)
_LAST: dict = {}
#: the folder of the bake `export(out_dir=)` exports ("out_dir"; none: the scene's Output
#: Folder), set on every hook module for the one export, as _LAST is read
_OPTIONS: dict = {}


def _state(export_settings) -> _State:
    state = export_settings.get("hhd_lightmap")
    if state is None:
        state = export_settings["hhd_lightmap"] = _State(export_settings)
        _LAST["state"] = state
    return state


class glTF2ExportUserExtension:  # noqa: N801 (the name the exporter looks up)
    """The hook object the glTF exporter creates per export."""

    def __init__(self):
        self.Extension = _gltf_io()[1]  # the exporter checks this attribute on user extensions

    def gather_node_hook(self, gltf2_node, blender_object, export_settings):
        try:
            if blender_object is not None and getattr(blender_object, "type", "") == "MESH":
                _state(export_settings).nodes.append((gltf2_node, blender_object.name))
            elif blender_object is not None and collection_instances.shows_collection(blender_object):
                _state(export_settings).instancers.append((gltf2_node, blender_object.name))
        except Exception as exc:  # noqa: BLE001 (the exporter would swallow it)
            _state(export_settings).errors.append(f"gather_node_hook: {exc!r}")

    def gather_material_hook(self, gltf2_material, blender_material, export_settings):
        try:
            _state(export_settings).blender_materials[id(gltf2_material)] = blender_material
        except Exception as exc:  # noqa: BLE001
            _state(export_settings).errors.append(f"gather_material_hook: {exc!r}")

    def gather_gltf_hook(self, active_scene_idx, scenes, animations, export_settings):
        state = _state(export_settings)
        try:
            _build(state, scenes[active_scene_idx or 0] if scenes else None)
        except Exception as exc:  # noqa: BLE001
            import traceback

            traceback.print_exc()
            state.errors.append(f"gather_gltf_hook: {exc!r}")

    def gather_gltf_extensions_hook(self, gltf2_plan, export_settings):
        state = _state(export_settings)
        try:
            for scene in gltf2_plan.scenes or []:
                ext = scene.extensions or {}
                if EXT in ext:
                    root = ext.pop(EXT)
                    if gltf2_plan.extensions is None:
                        gltf2_plan.extensions = {}
                    gltf2_plan.extensions[EXT] = root
            if gltf2_plan.extensions and EXT in gltf2_plan.extensions and EXT not in gltf2_plan.extensions_used:
                gltf2_plan.extensions_used.append(EXT)
        except Exception as exc:  # noqa: BLE001
            state.errors.append(f"gather_gltf_extensions_hook: {exc!r}")


# --- reading the bake --------------------------------------------------------------------------


class _Atlas:
    def __init__(self, index: int, files: AtlasFiles, sidecar: dict):
        self.index = index
        self.files = files
        self.sidecar = sidecar
        self.name = sidecar["atlas"]
        self.width = int(sidecar["width"])
        self.height = int(sidecar["height"])
        self.objects = {o["name"]: o for o in sidecar.get("objects", [])}
        self.layers: dict | None = None  # filled by _load
        self.textures: dict = {}

    def load(self) -> None:
        model = self.sidecar.get("encoder", {}).get("model", "hhd")
        if model not in ("hhd", "ahd"):
            raise BakeError(
                f"atlas '{self.name}' is encoded as {model}: the glTF export carries HHD or AHD (docs/gltf.md); "
                "re-encode the atlas as HHD (Re-encode, or `encode --model hhd`) and export again"
            )
        self.layers = _read_layers(self.files, (self.height, self.width))


def _read_layers(files: AtlasFiles, shape) -> dict:
    """I_z (H, W, 3), w_a (H, W) or (H, W, 3), d in glTF frame (H, W, 3): file rows (top first)."""
    ch, _ = exr.read(files.hhd)
    missing = [n for n in hhd_spec.IZ.exr_names + hhd_spec.DIRECTION.exr_names if n not in ch]
    if missing:
        raise BakeError(f"{files.hhd} lacks {missing}: bake again")
    iz = np.stack([ch[n] for n in hhd_spec.IZ.exr_names], axis=-1).astype(np.float64)
    if iz.shape[:2] != tuple(shape):
        raise BakeError(
            f"{files.hhd} is {iz.shape[1]}×{iz.shape[0]}, its sidecar says {shape[1]}×{shape[0]}: bake again"
        )
    (scalar,) = hhd_spec.WA.exr_names
    if scalar in ch:
        wa = ch[scalar].astype(np.float64)
    else:
        wa = np.stack([ch[n] for n in hhd_spec.WA_RGB.exr_names], -1).astype(np.float64)
    e = np.stack([ch[n] for n in hhd_spec.DIRECTION.exr_names], axis=-1).astype(np.float64).reshape(-1, 2)
    d = octahedral.decode(e)
    return {"iz": iz, "wa": wa, "d": d.reshape(iz.shape)}


# --- building the glTF objects ------------------------------------------------------------------


class _Builder:
    def __init__(self, state: _State):
        self.state = state
        self.io, self.Extension, self.BinaryData = _gltf_io()
        self.sampler = self.io.Sampler(
            extensions=None, extras=None, mag_filter=LINEAR, min_filter=LINEAR, name=None, wrap_s=CLAMP, wrap_t=CLAMP
        )

    def texture(self, name: str, png: bytes):
        image = self.io.Image(
            buffer_view=self.BinaryData(png), extensions=None, extras=None, mime_type="image/png", name=name, uri=None
        )
        return self.io.Texture(extensions=None, extras=None, name=name, sampler=self.sampler, source=image)

    def accessor(self, values: np.ndarray, kind: str):
        data = np.ascontiguousarray(values, dtype="<f4")
        count = data.size // {"SCALAR": 1, "VEC3": 3}[kind]
        return self.io.Accessor(
            buffer_view=self.BinaryData(data.tobytes()),
            byte_offset=None,
            component_type=5126,
            count=count,
            extensions=None,
            extras=None,
            max=None,
            min=None,
            name=None,
            normalized=None,
            sparse=None,
            type=kind,
        )

    def ext(self, name: str, body: dict):
        return self.Extension(name, body, required=False)


def _to_frame(d: np.ndarray, yup: bool) -> np.ndarray:
    return d @ TO_GLTF.T if yup else d


def _layer_textures(b: _Builder, label: str, layers: dict, yup: bool) -> dict:
    """The Packed I_z, the w_a and direction references of one set of layers (docs/gltf.md)."""
    iz = layers["iz"]
    range_ = float(max(iz.max(), 1e-6))
    irr = b.texture(f"{label}_Iz", wp.png_encode(wp.encode(iz, wp.CHOSEN, range_)))
    d = _to_frame(layers["d"], yup)
    wa = layers["wa"]
    if wa.ndim == 2:
        dir_tex = b.texture(f"{label}_DirWa", wp.png_encode(wp.encode_direction(d, wa)))
        ambient = {"index": dir_tex, "channels": "b"}
    else:
        dir_tex = b.texture(f"{label}_Dir", wp.png_encode(wp.encode_direction(d, None)))
        ambient = {
            "index": b.texture(f"{label}_Wa", wp.png_encode(np.round(np.clip(wa, 0, 1) * 255).astype(np.uint8))),
            "channels": "rgb",
        }
    return {
        "irradiance": {"index": irr, "packing": wp.CHOSEN, "range": range_},
        "ambientWeight": ambient,
        "direction": {"index": dir_tex, "channels": "rg", "encoding": "octahedral"},
    }


def _uv_bounds(obj, layer: str):
    """(lo, hi) of the lightmap UVs of the faces that can hold texels: faces whose UVs span no
    area are left out. xatlas charts no zero-area face (a degenerate face of the model: its
    corners coincide or lie on a line) and leaves its UVs at (0, 0), where it gets no texel, so
    the box of all UVs would reach (0, 0) while the bake's `uv_rect` (the box of the baked texels)
    does not. None: no such layer (or no faces)."""
    mesh = obj.data
    uvl = mesh.uv_layers.get(layer)
    if uvl is None or len(mesh.loops) == 0 or len(mesh.polygons) == 0:
        return None
    uv = np.zeros(len(mesh.loops) * 2, np.float32)
    uvl.data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2).astype(np.float64)
    n = len(mesh.polygons)
    start = np.zeros(n, np.int64)
    total = np.zeros(n, np.int64)
    mesh.polygons.foreach_get("loop_start", start)
    mesh.polygons.foreach_get("loop_total", total)
    poly = np.repeat(np.arange(n), total)
    loop = np.repeat(start - (np.cumsum(total) - total), total) + np.arange(total.sum())
    first = start[poly]
    nxt = np.where(loop + 1 < first + total[poly], loop + 1, first)
    a, b = uv[loop] - uv[first], uv[nxt] - uv[first]  # the polygon's triangle fan
    area = np.bincount(poly, weights=np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), minlength=n)
    keep = area[poly] > 0.0
    if keep.any():
        uv = uv[loop[keep]]
    return uv.min(axis=0), uv.max(axis=0)


def _check_object(obj, atlas: _Atlas, layer: str) -> str | None:
    """Why the bake of `obj` cannot be exported (None: it can)."""
    if obj.name not in atlas.objects:
        return f"'{obj.name}' is not in the bake of atlas '{atlas.name}' ({atlas.files.sidecar}): bake it"
    bounds = _uv_bounds(obj, layer)
    if bounds is None:
        return f"'{obj.name}' has no lightmap UV layer '{layer}': unwrap and bake it"
    rect = atlas.objects[obj.name].get("uv_rect")
    if rect is None:
        return f"'{obj.name}' has no baked texels in atlas '{atlas.name}': bake it again"
    scale_offset = np.array(mesh_data.lightmap_rect(obj))  # an instance's rectangle (core.unwrap.instances)
    lo, hi = (b * scale_offset[:2] + scale_offset[2:] for b in bounds)
    tx, ty = 1.5 / atlas.width, 1.5 / atlas.height
    outside = lo[0] < rect[0] - tx or lo[1] < rect[1] - ty or hi[0] > rect[2] + tx or hi[1] > rect[3] + ty
    shrunk = lo[0] > rect[0] + tx or lo[1] > rect[1] + ty or hi[0] < rect[2] - tx or hi[1] < rect[3] - ty
    if outside or shrunk:
        w, h = atlas.width, atlas.height
        return (
            f"'{obj.name}': its lightmap UVs no longer lie where the bake put them (unwrapped again "
            f"since the bake?): they span texels x {lo[0] * w:.1f}–{hi[0] * w:.1f}, y {lo[1] * h:.1f}–"
            f"{hi[1] * h:.1f}, the baked texels x {rect[0] * w:.0f}–{rect[2] * w:.0f}, y {rect[1] * h:.0f}–"
            f"{rect[3] * h:.0f}: the bake is stale; bake it again"
        )
    return None


def _mean_albedo(blender_material) -> tuple[float, float, float]:
    if blender_material is None:
        return (0.8, 0.8, 0.8)
    from . import materials

    try:
        cache = materials.TextureCache()
        constant, index, _ = materials.albedo_of(blender_material, cache, [])
        if index >= 0:
            return tuple(float(v) for v in np.clip(cache.images[index].pixels.reshape(-1, 3).mean(axis=0), 0, 1))
        return tuple(float(v) for v in constant)
    except Exception:  # noqa: BLE001 (a material the bake's reader does not know: its viewport colour)
        return tuple(float(v) for v in blender_material.diffuse_color[:3])


def _light_set_weights(scene, names: list[str]) -> list[list[float]]:
    set_weights = {item.name: list(item.weight) for item in getattr(scene.hhd, "light_sets", [])}
    return [set_weights.get(n, [1.0, 1.0, 1.0]) for n in names]


def _probe_volumes(b: _Builder, folder: Path, set_index: dict, yup: bool, state: _State) -> list:
    from ..core import probes

    path = folder / probes.SIDECAR
    if not path.is_file():
        return []
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        state.warn(f"probe volumes not exported: {path} cannot be read ({exc})")
        return []
    rot = TO_GLTF if yup else np.eye(3)
    conv = np.eye(4)
    conv[:3, :3] = rot
    out = []
    for entry in doc.get("volumes", []):
        try:
            _, sh, valid = probes.read(folder, entry["name"])
        except BakeError as exc:
            state.warn(f"probe volume '{entry['name']}' not exported: {exc}")
            continue
        # g(ω_gltf) = f(R^T ω_gltf): rotate with M = R^T per probe
        m = np.broadcast_to(rot.T, (sh.shape[0], 3, 3))
        vol = {
            "name": entry["name"],
            "matrix": (conv @ np.array(entry["to_world"])).T.reshape(-1).tolist(),
            "resolution": list(entry["resolution"]),
            "sh": b.accessor(core_sh.rotate(sh, m).reshape(-1, 3), "VEC3"),
            "validity": b.accessor(valid.astype(np.float32), "SCALAR"),
            "lightSets": [],
        }
        for s in entry.get("light_sets", []):
            if s["name"] not in set_index:
                continue
            _, set_sh, _ = probes.read(folder, entry["name"], s["name"])
            vol["lightSets"].append(
                {"set": set_index[s["name"]], "sh": b.accessor(core_sh.rotate(set_sh, m).reshape(-1, 3), "VEC3")}
            )
        out.append(vol)
    return out


def _build(state: _State, scene_plan) -> None:
    from . import bake_session

    scene = bpy.context.scene
    settings = scene.hhd
    layer_name = settings.uv_layer
    b = _Builder(state)
    try:
        folder = Path(bake_session.output_folder(settings, _OPTIONS.get("out_dir")))
    except BakeError as exc:
        state.warn(f"no lightmaps exported: {exc}")
        return
    # The atlases the scene's mesh objects were unwrapped into, and each receiver's atlas.
    atlases: dict[str, _Atlas] = {}
    broken: dict[str, str] = {}
    receivers: dict[str, _Atlas] = {}
    state.nodes = _instance_names(state)
    names_seen = {name for _, name in state.nodes}
    for name in sorted(names_seen):
        obj = collection_instances.find(name)
        if obj is None or obj.type != 'MESH':
            continue
        if not obj.hhd.atlas and tuple(getattr(obj.hhd, "collection_rect", ())) not in ((), mesh_data.IDENTITY_RECT):
            state.warn(f"'{name}' exported without its lightmap: it was baked as part of collection instances only")
            continue
        atlas_name = obj.hhd.atlas or bake_session.DEFAULT_ATLAS
        has_layer = obj.data.uv_layers.get(layer_name) is not None
        if not (obj.hhd.atlas or has_layer):
            continue  # never unwrapped: not a receiver
        if atlas_name in broken:
            state.warn(f"'{name}' exported without its lightmap: {broken[atlas_name]}")
            continue
        atlas = atlases.get(atlas_name)
        if atlas is None:
            files = AtlasFiles(folder, atlas_name)
            try:
                sidecar = read_sidecar(files.sidecar)
                atlas = _Atlas(len(atlases), files, sidecar)
                atlas.load()
            except BakeError as exc:
                broken[atlas_name] = str(exc)
                state.warn(f"'{name}' exported without its lightmap: {exc}")
                continue
            atlases[atlas_name] = atlas
        problem = _check_object(obj, atlas, layer_name)
        if problem:
            state.warn(f"'{name}' exported without its lightmap: {problem}")
            continue
        receivers[name] = atlas
    used = [a for a in atlases.values() if a in receivers.values()]
    if not receivers:
        if not state.warnings:
            state.warn(f"no baked lightmaps found for the exported objects (output folder {folder})")
        return
    for i, atlas in enumerate(sorted(used, key=lambda a: a.name)):
        atlas.index = i
    used.sort(key=lambda a: a.index)

    # Light sets: the union of the atlases' sets, in sidecar order.
    set_names: list[str] = []
    for atlas in used:
        for entry in atlas.sidecar.get("light_sets", []):
            if entry["name"] not in set_names:
                set_names.append(entry["name"])
    set_index = {n: i for i, n in enumerate(set_names)}

    root_atlases = []
    for atlas in used:
        assert atlas.layers is not None
        layers = atlas.layers
        body = {"name": atlas.name, "width": atlas.width, "height": atlas.height}
        body["model"] = atlas.sidecar.get("encoder", {}).get("model", "hhd")
        body.update(_layer_textures(b, atlas.name, layers, state.yup))
        iz = layers["iz"]
        lum = iz @ LUM
        # fallback textures: MOZ_lightmap (linear I_z / scale), emission (sRGB I_z / E)
        scale = float(max(np.percentile(iz.max(axis=-1), 99.9), 1e-6))
        atlas.textures["moz"] = b.texture(
            f"{atlas.name}_Irradiance", wp.png_encode(np.round(np.clip(iz / scale, 0, 1) * 255).astype(np.uint8))
        )
        atlas.textures["emissive"] = b.texture(
            f"{atlas.name}_Emission", wp.png_encode(wp.srgb_encode(iz / scale), srgb=True)
        )
        atlas.textures["scale"] = scale
        body["fallback"] = {"index": atlas.textures["moz"], "scale": scale}
        body["lightSets"] = []
        for entry in atlas.sidecar.get("light_sets", []):
            set_files = AtlasFiles(atlas.files.folder, entry["atlas"], atlas.name)
            try:
                set_layers = _read_layers(set_files, (atlas.height, atlas.width))
            except BakeError as exc:
                state.warn(f"atlas '{atlas.name}': light set '{entry['name']}' not exported: {exc}")
                continue
            layer_body = {"set": set_index[entry["name"]]}
            layer_body.update(_layer_textures(b, entry["atlas"], set_layers, state.yup))
            body["lightSets"].append(layer_body)
        body["stats"] = {"izMax": float(iz.max()), "izMeanLuminance": float(lum.mean())}
        root_atlases.append(body)

    # Nodes and materials.
    copies: dict[tuple, object] = {}
    for node, name in state.nodes:
        atlas = receivers.get(name)
        if atlas is None or node.mesh is None:
            continue
        obj = collection_instances.find(name)
        k = obj.data.uv_layers.find(layer_name)
        key = f"TEXCOORD_{k}"
        prims = getattr(node.mesh, "primitives", None) or []
        if not prims or any(key not in (p.attributes or {}) for p in prims):
            state.warn(
                f"'{name}' exported without its lightmap: the glTF exporter did not write its UV layer "
                f"'{layer_name}' as {key} (is Include > UVs on?)"
            )
            continue
        if node.extensions is None:
            node.extensions = {}
        rect = mesh_data.lightmap_rect(obj)
        node.extensions[EXT] = b.ext(EXT, {"atlas": atlas.index, "texCoord": k, "scaleOffset": gltf_scale_offset(rect)})
        instanced = rect != mesh_data.IDENTITY_RECT
        if instanced and not state.instance_note:
            state.instance_note = True
            state.warn(
                "instanced meshes (linked duplicates) get no fallback lightmap for viewers without HHD_lightmap: "
                "their nodes share one mesh and its materials, and the fallback textures cannot follow each "
                "node's scaleOffset"
            )
        for p in prims:
            p.material = _material_copy(b, copies, p.material, atlas, k, state, instanced)
        state.exported.append(name)

    weights = _light_set_weights(scene, set_names)
    if settings.preview_filter == 'BSPLINE':
        state.warn(
            "the preview's filter 'B-spline (prefiltered)' needs coefficient textures the export does not "
            "write: the file asks the runtime for Catmull-Rom ('bicubic') instead"
        )
    root = {
        "version": VERSION,
        "frame": "gltf" if state.yup else "blender_z_up",
        "units": "irradiance_over_pi",
        "threeLightMapIntensity": math.pi,
        # the runtime's lightmap filter: what the EEVEE preview shows (web/: the plugin's default)
        "filter": "bicubic" if settings.preview_filter in {'BICUBIC', 'BSPLINE'} else "bilinear",
        "atlases": root_atlases,
        "lightSets": [{"name": n, "weight": w} for n, w in zip(set_names, weights)],
        "probeVolumes": _probe_volumes(b, folder, set_index, state.yup, state),
    }
    if scene_plan is not None:
        if scene_plan.extensions is None:
            scene_plan.extensions = {}
        scene_plan.extensions[EXT] = b.ext(EXT, root)
    state.root = root


def _instance_names(state: _State) -> list:
    """state.nodes with the nodes under a collection instance's node (the exporter writes the
    collection's objects as its children) named as their receivers, "<Empty>/<object>"
    (`collection_instances.Member`)."""
    names = {id(node): name for node, name in state.nodes}
    renamed: dict[int, str] = {}
    for node, instancer in state.instancers:
        stack = list(node.children or [])
        while stack:
            child = stack.pop()
            if isinstance(child, int):  # already an index: not one of this export's node objects
                continue
            if id(child) in names:
                renamed[id(child)] = f"{instancer}{collection_instances.SEPARATOR}{names[id(child)]}"
            stack += list(child.children or [])
    return [(node, renamed.get(id(node), name)) for node, name in state.nodes]


def gltf_scale_offset(rect) -> list[float]:
    """The node's `scaleOffset` in glTF UVs (v flipped: v_gltf = 1 − v) from the object's
    lightmap rectangle (scale u, scale v, offset u, offset v) in Blender's: atlas = uv · scale +
    offset in both, so the v offset becomes 1 − scale v − offset v. Identity stays [1, 1, 0, 0]."""
    su, sv, ou, ov = (float(v) for v in rect)
    return [su, sv, ou, 1.0 - sv - ov]


def _material_copy(b: _Builder, copies: dict, material, atlas: _Atlas, k: int, state: _State, instanced=False):
    """The material copy for receivers of `atlas` with the fallback textures (none for
    `instanced` nodes: an instance's fallback would need its own UV transform)."""
    key = (id(material), atlas.index, k, instanced)
    if key in copies:
        return copies[key]
    blender_material = state.blender_materials.get(id(material)) if material is not None else None
    if material is None:
        material = b.io.Material(
            alpha_cutoff=None,
            alpha_mode=None,
            double_sided=None,
            emissive_factor=None,
            emissive_texture=None,
            extensions=None,
            extras=None,
            name="HHD_default",
            normal_texture=None,
            occlusion_texture=None,
            pbr_metallic_roughness=None,
        )
        new = material
    else:
        new = copy.copy(material)
        new.extensions = dict(material.extensions or {})
        new.name = f"{material.name or 'material'} [{atlas.name}]"
    own = list(material.emissive_factor) if material.emissive_factor else [0.0, 0.0, 0.0]
    scale = atlas.textures["scale"]
    if instanced:
        new.extensions[EXT] = b.ext(EXT, {"fallbackEmission": False, "emissiveFactor": own})
        copies[key] = new
        return new
    if material.emissive_texture is None:
        albedo = _mean_albedo(blender_material)
        strength = max(scale * max(albedo), 1e-6)
        factor = [a * scale / strength for a in albedo]
        new.emissive_texture = b.io.TextureInfo(
            extensions=None, extras=None, index=atlas.textures["emissive"], tex_coord=k
        )
        new.emissive_factor = factor
        new.extensions.pop("KHR_materials_emissive_strength", None)
        if strength > 1.0:
            new.extensions["KHR_materials_emissive_strength"] = b.ext(
                "KHR_materials_emissive_strength", {"emissiveStrength": strength}
            )
        fallback = True
    else:
        fallback = False
        state.warn(f"material '{material.name}' has an emissive texture of its own: no emissive fallback on it")
    new.extensions["MOZ_lightmap"] = b.ext(
        "MOZ_lightmap", {"index": atlas.textures["moz"], "texCoord": k, "intensity": math.pi * scale}
    )
    new.extensions[EXT] = b.ext(EXT, {"fallbackEmission": fallback, "emissiveFactor": own})
    copies[key] = new
    return new


# --- entry points ------------------------------------------------------------------------------


def _hook_modules() -> list:
    """The `bridge.gltf_export` modules of the enabled add-ons/extensions exposing the hook."""
    out = []
    for key in bpy.context.preferences.addons.keys():
        module = sys.modules.get(key)
        if module is not None and hasattr(module, "glTF2ExportUserExtension"):
            out.append(sys.modules.get(f"{key}.bridge.gltf_export"))
    return out


def export(filepath: str, glb: bool = True, out_dir: str | None = None) -> dict:
    """Export the open scene to `filepath` (.glb or .gltf) with the hook (the CLI's `export`),
    the lightmaps from `out_dir` (None: the scene's Output Folder; the scene is not changed).
    Returns {"exported": [...objects with lightmaps], "warnings": [...]}. Raises BakeError for
    a hook failure."""
    root_package = __package__.rsplit(".", 1)[0]
    temporary = None
    modules = _hook_modules()
    if not modules:  # the bpy module: register this package for the exporter's look-up
        temporary = bpy.context.preferences.addons.new()
        temporary.module = root_package
        modules = [sys.modules[__name__]]
    for module in modules:
        if module is not None:
            module._LAST.clear()
            module._OPTIONS.clear()
            if out_dir:
                module._OPTIONS["out_dir"] = out_dir
    try:
        os.makedirs(os.path.dirname(os.path.abspath(filepath)) or ".", exist_ok=True)
        bpy.ops.export_scene.gltf(
            filepath=filepath,
            export_format='GLB' if glb else 'GLTF_SEPARATE',
            use_selection=False,
            export_texcoords=True,
            export_cameras=True,  # the scene camera: a viewer (web/viewer.html) starts from it
            export_yup=True,
        )
    finally:
        for module in modules:
            if module is not None:
                module._OPTIONS.clear()
        if temporary is not None:
            bpy.context.preferences.addons.remove(temporary)
    states = [m._LAST.get("state") for m in modules if m is not None and m._LAST.get("state") is not None]
    if not states:
        raise BakeError("the glTF exporter did not run the HHD Lightmapper hook (is the extension enabled?)")
    state = states[0]
    if state.errors:
        raise BakeError("the glTF export hook failed: " + "; ".join(state.errors))
    return {"exported": state.exported, "warnings": state.warnings}
