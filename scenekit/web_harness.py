"""The browser side of the web-runtime tests (tests/test_web_runtime.py), no bpy:

- `Browser`: one headless Chromium (web/test/harness.mjs: Debian's chromium through playwright-core,
  WebGL2 on SwiftShader) kept for many requests; `render` reads back a float RGBA render target.
- `Glb`: a .glb's JSON and its PNG images, and `reference`: the numpy decode of its HHD_lightmap
  layers (core/encoding/web_packing.py, core.hhd.reconstruct, core.light_sets.blend) at the
  lightmap UVs and normals of the browser's G-buffer pass, so the comparison does not depend on
  rasterisation.
- `synthetic_glb`: a small glTF with known HHD layers (a bumpy normal-mapped grid, two light sets),
  to test the runtime without a bake.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np

from hhd_lightmapper.core import hhd, light_sets, octahedral, sh, textures
from hhd_lightmapper.core.encoding import web_packing

ROOT = Path(__file__).resolve().parent.parent
WEB = ROOT / "web"
HOW_TO_GET_CHROMIUM = (
    "no Chromium for the browser tests: install Debian's package (`sudo apt-get install chromium`) "
    "or set HHD_CHROMIUM=/path/to/chromium; `make web-deps` installs the npm packages"
)


def unavailable() -> str | None:
    """Why the browser tests cannot run here (None: they can)."""
    if shutil.which("node") is None:
        return "no Node.js (node) on PATH: the browser harness is a Node script (apt-get install nodejs npm)"
    if not (WEB / "node_modules" / "playwright-core").is_dir() or not (WEB / "node_modules" / "three").is_dir():
        return "web/node_modules is missing: run `make web-deps` (npm ci in web/)"
    chromium = os.environ.get("HHD_CHROMIUM")
    if chromium:
        return None if Path(chromium).exists() else f"HHD_CHROMIUM={chromium} does not exist"
    if (
        not any(shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome"))
        and not Path("/usr/bin/chromium").exists()
    ):
        return HOW_TO_GET_CHROMIUM
    return None


class Browser:
    """web/test/harness.mjs as a subprocess: one JSON request a line, one JSON answer a line."""

    def __init__(self, tmp: Path):
        self.tmp = Path(tmp)
        self.tmp.mkdir(parents=True, exist_ok=True)
        self.proc = subprocess.Popen(
            ["node", str(WEB / "test" / "harness.mjs")],
            cwd=WEB,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        hello = self._read()
        if not hello.get("ok"):
            self.close()
            raise RuntimeError(hello.get("error", hello))
        self.hello = hello
        self._n = 0

    def _read(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read() if self.proc.poll() is not None else ""
            raise RuntimeError(f"the browser harness stopped: {err[-2000:]}")
        return json.loads(line)

    def request(self, **req):
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        answer = self._read()
        if not answer.get("ok"):
            raise RuntimeError(f"{req.get('cmd')}: {answer.get('error')}")
        return answer["result"]

    def load(self, path: Path, plugin: bool = True, **options) -> dict:
        return self.request(cmd="load", file=str(Path(path).resolve()), plugin=plugin, options=options)

    def render(self, mode: str, width: int, height: int, **kw) -> np.ndarray:
        """(H, W, 4) float32, row 0 = top."""
        self._n += 1
        out = self.tmp / f"render{self._n}.f32"
        meta = self.request(cmd="render", mode=mode, width=width, height=height, out=str(out), **kw)
        return np.fromfile(out, np.float32).reshape(meta["height"], meta["width"], 4)

    def blend(self, nv: np.ndarray, sets: list[hhd.HHDParams], weights: np.ndarray) -> tuple[np.ndarray, ...]:
        """The plugin's GLSL blend of `sets` (luminance w_a) at texel normals nv (N, 3), RGB weights
        (K, 3): (I_z (N, 3), w_a (N,), d (N, 3)) read back from a float render target."""
        n = len(nv)
        blocks = [np.concatenate([nv, np.zeros((n, 1))], axis=1)]
        for p in sets:
            blocks.append(np.concatenate([p.irradz, p.ambient_weight[:, None]], axis=1))
            blocks.append(np.concatenate([p.direction, np.zeros((n, 1))], axis=1))
        self._n += 1
        inputs, out = self.tmp / f"blend{self._n}.in.f32", self.tmp / f"blend{self._n}.out.f32"
        np.concatenate(blocks).astype(np.float32).tofile(inputs)
        self.request(
            cmd="blend",
            inputs=str(inputs),
            sets=len(sets),
            texels=n,
            weights=np.asarray(weights).tolist(),
            out=str(out),
        )
        r = np.fromfile(out, np.float32).reshape(n, 8).astype(np.float64)
        return r[:, :3], r[:, 3], r[:, 4:7]

    def errors(self) -> list[str]:
        return self.request(cmd="errors")

    def close(self):
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write(json.dumps({"cmd": "quit"}) + "\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=20)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()


# --- reading a .glb -------------------------------------------------------------------------


class Glb:
    """A .glb's JSON (`json`), binary chunk and decoded images."""

    def __init__(self, path: Path):
        blob = Path(path).read_bytes()
        magic, version, length = struct.unpack("<III", blob[:12])
        assert magic == 0x46546C67 and version == 2, "not a glTF 2.0 binary"
        pos, self.json, self.bin = 12, None, b""
        while pos < length:
            size, kind = struct.unpack("<II", blob[pos : pos + 8])
            data = blob[pos + 8 : pos + 8 + size]
            if kind == 0x4E4F534A:
                self.json = json.loads(data)
            elif kind == 0x004E4942:
                self.bin = data
            pos += 8 + size
        self.ext = (self.json.get("extensions") or {}).get("HHD_lightmap")
        self._images: dict[int, np.ndarray] = {}

    def texture_image(self, texture: int) -> np.ndarray:
        """(H, W, C) uint8 of textures[texture] (row 0 = top = glTF v 0)."""
        source = self.json["textures"][texture]["source"]
        if source not in self._images:
            image = self.json["images"][source]
            view = self.json["bufferViews"][image["bufferView"]]
            start = view.get("byteOffset", 0)
            self._images[source] = web_packing.png_decode(self.bin[start : start + view["byteLength"]])
        return self._images[source]

    def layers(self, layer: dict) -> dict:
        """Decoded float images of one layer set (an atlas or a LightSetLayers): I_z (H, W, 3),
        the direction of every texel decoded to a unit vector (H, W, 3), the w_a texels / 255."""
        packed = layer["irradiance"]
        iz = web_packing.decode(self.texture_image(packed["index"]), packed["packing"], packed["range"])
        raw = self.texture_image(layer["direction"]["index"]).astype(np.float64) / 255.0
        e = raw[..., [CHANNEL[c] for c in layer["direction"].get("channels", "rg")]]
        direction = octahedral.decode(e.reshape(-1, 2) * 2.0 - 1.0).reshape(e.shape[:2] + (3,))
        wa = self.texture_image(layer["ambientWeight"]["index"]).astype(np.float64) / 255.0
        return {
            "iz": iz,
            "dir": direction,
            "wa": wa,
            "wa_channels": layer["ambientWeight"]["channels"],
        }


CHANNEL = {"r": 0, "g": 1, "b": 2, "a": 3}


def sample_direction(direction: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Unit directions (N, 3) at glTF UVs from per-texel unit vectors (H, W, 3): the four texels'
    vectors blended with the bilinear weights and normalised (docs/gltf.md "Filtering"; never the
    encoded bytes, which fold); a blend of length ≤ 1e-6 falls back to the first texel (x0, y0)."""
    s = web_packing.sample_bilinear(direction, uv)
    h, w = direction.shape[:2]
    x0 = np.floor(np.clip(uv[:, 0] * w - 0.5, 0.0, w - 1.0)).astype(int)
    y0 = np.floor(np.clip(uv[:, 1] * h - 0.5, 0.0, h - 1.0)).astype(int)
    length = np.linalg.norm(s, axis=1, keepdims=True)
    return np.where(length > 1e-6, s / np.maximum(length, 1e-30), direction[y0, x0])


#: the lightmap filters of the plugin (web/src/HHDLightmapPlugin.js FILTERS)
FILTERS = ("bilinear", "bicubic")


def sample_params(layers: dict, uv: np.ndarray, filter: str = "bilinear") -> hhd.HHDParams:
    """HHD parameters (N,) at glTF UVs, each texture filtered over decoded texels (docs/gltf.md):
    I_z decoded then blended, d decoded to unit vectors then blended and normalised, w_a (linear
    in its bytes) blended. `filter` "bilinear", or "bicubic": I_z and w_a by
    core.textures.sample_bicubic (Catmull-Rom, clamp to edge), I_z clamped at 0 and w_a to [0, 1]
    (docs/format.md "Bicubic sampling"); d stays bilinear."""
    if filter not in FILTERS:
        raise ValueError(f"unknown filter {filter!r}: one of {FILTERS}")
    d = sample_direction(layers["dir"], uv)
    if filter == "bicubic":
        iz = textures.sample_bicubic(layers["iz"], uv, clamp=True, nonnegative=True)
        wa_all = np.clip(textures.sample_bicubic(layers["wa"], uv, clamp=True), 0.0, 1.0)
    else:
        iz = web_packing.sample_bilinear(layers["iz"], uv)
        wa_all = web_packing.sample_bilinear(layers["wa"], uv)
    wa = wa_all[:, [CHANNEL[c] for c in layers["wa_channels"]]]
    wa = wa[:, 0] if wa.shape[1] == 1 else wa
    return hhd.HHDParams(irradz=iz, ambient_weight=wa, direction=d, model="hhd")


def reference(
    glb: Glb, gbuffer: dict, weights: dict | None = None, blend: bool = False, filter: str = "bilinear"
) -> np.ndarray:
    """The numpy decode of the file at the G-buffer's pixels: albedo × I (H, W, 3), I from
    core.hhd.reconstruct at the browser's shading normal n and vertex normal n_v, I_z / w_a / d
    sampled at its lightmap UV as `filter` says (`sample_params`; and with `blend`,
    core.light_sets.blend of the sets' layers at RGB `weights` {set: rgb})."""
    uvb, nvb, nb, albedo = gbuffer["uv"], gbuffer["nv"], gbuffer["n"], gbuffer["albedo"]
    h, w = uvb.shape[:2]
    out = np.zeros((h, w, 3))
    mask = uvb[..., 3] > 0
    for a, atlas in enumerate(glb.ext["atlases"]):
        sel = mask & (np.rint(uvb[..., 2]) == a)
        if not sel.any():
            continue
        uv = uvb[sel][:, :2].astype(np.float64)
        nv = unit(nvb[sel][:, :3].astype(np.float64))
        n = unit(nb[sel][:, :3].astype(np.float64))
        if blend and atlas["lightSets"]:
            names = [s["name"] for s in glb.ext["lightSets"]]
            params = [sample_params(glb.layers(s), uv, filter) for s in atlas["lightSets"]]
            wts = light_sets.weight_array(
                names, {**{s["name"]: s["weight"] for s in glb.ext["lightSets"]}, **(weights or {})}
            )
            wts = wts[[s["set"] for s in atlas["lightSets"]]]
            p = light_sets.blend(params, nv, wts)
        else:
            p = sample_params(glb.layers(atlas), uv, filter)
        p.model = atlas.get("model", "hhd")
        out[sel] = albedo[sel][:, :3] * hhd.reconstruct(p, nv, n)
    return out


def probe_reference(glb: Glb, position: np.ndarray, normal: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """albedo × irradiance (N, 3) of the first probe volume at world positions and normals (glTF
    frame): trilinear between probe centres, clamped to the outermost probes (docs/format.md),
    L2 SH bands × 1, 2/3, 1/4 evaluated at n (core.sh.irradiance), clamped at 0 as the shader."""
    vol = glb.ext["probeVolumes"][0]
    acc = glb.json["accessors"][vol["sh"]]
    view = glb.json["bufferViews"][acc["bufferView"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    nx, ny, nz = vol["resolution"]
    coeffs = np.frombuffer(glb.bin[start : start + acc["count"] * 12], "<f4").reshape(nz, ny, nx, 9, 3)
    to_world = np.asarray(vol["matrix"], float).reshape(4, 4).T
    local = (np.linalg.inv(to_world) @ np.concatenate([position, np.ones((len(position), 1))], axis=1).T).T[:, :3]
    q = (local * 0.5 + 0.5) * np.array([nx, ny, nz]) - 0.5
    lo = np.floor(q)
    f = np.clip(q - lo, 0.0, 1.0)
    i0 = np.clip(lo.astype(int), 0, np.array([nx, ny, nz]) - 1)
    i1 = np.clip(lo.astype(int) + 1, 0, np.array([nx, ny, nz]) - 1)
    sh_ = np.zeros((len(position), 9, 3))
    for cx, wx in ((i0[:, 0], 1 - f[:, 0]), (i1[:, 0], f[:, 0])):
        for cy, wy in ((i0[:, 1], 1 - f[:, 1]), (i1[:, 1], f[:, 1])):
            for cz, wz in ((i0[:, 2], 1 - f[:, 2]), (i1[:, 2], f[:, 2])):
                sh_ += (wx * wy * wz)[:, None, None] * coeffs[cz, cy, cx]
    return albedo * np.maximum(sh.irradiance(sh_, unit(normal)), 0.0)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def gbuffer(browser: Browser, width: int, height: int, **kw) -> dict:
    return {m: browser.render(m, width, height, **kw) for m in ("uv", "nv", "n", "albedo")}


def relative_errors(got: np.ndarray, want: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-pixel |got − want| / |want| (RGB norms) over `mask` where `want` is not black."""
    g, r = got[mask][:, :3].astype(np.float64), want[mask][:, :3]
    norm = np.linalg.norm(r, axis=1)
    lit = norm > 1e-3 * max(np.median(norm), 1e-12)
    return np.linalg.norm(g - r, axis=1)[lit] / norm[lit]


# --- a synthetic file -----------------------------------------------------------------------


def _smooth_field(rng, shape, channels, octaves=3):
    """Smooth positive noise (H, W, C) in about [0, 1]."""
    h, w = shape
    out = np.zeros((h, w, channels))
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    for o in range(octaves):
        f = 2**o
        for c in range(channels):
            px, py = rng.uniform(0, 2 * np.pi, 2)
            out[..., c] += np.sin(2 * np.pi * f * x + px) * np.cos(2 * np.pi * f * y + py) / f
    return (out - out.min()) / (out.max() - out.min())


def _lookat_quaternion(eye, target, up=(0.0, 1.0, 0.0)):
    """glTF node rotation (x, y, z, w) turning the camera's -Z onto target − eye."""
    f = unit(np.asarray(target, float) - np.asarray(eye, float))
    r = unit(np.cross(f, up))
    u = np.cross(r, f)
    m = np.stack([r, u, -f], axis=1)  # columns: camera x, y, z in world
    t = np.trace(m)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k]) * 2
        q = [0.0, 0.0, 0.0, 0.0]
        q[i] = 0.25 * s
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
        q[3] = (m[k, j] - m[j, k]) / s
    return [float(v) for v in q]


def synthetic_glb(
    path: Path,
    seed: int = 0,
    size: int = 64,
    with_sets: bool = True,
    probes: bool = True,
    fold: bool = False,
    edge: bool = False,
) -> Path:
    """A bumpy 2 m grid (normal-mapped, on TEXCOORD_0) receiving a size² HHD atlas on TEXCOORD_1,
    RGBM I_z, octahedral d + luminance w_a in one PNG, and (with_sets) two light sets; (probes) a
    box without a lightmap inside a 4×3×4 probe volume of random L2 SH; a camera. With `fold` the
    directions straddle the octahedral map's fold: glTF z < 0 (the folded half) and x changing
    sign every few texels, so neighbouring texels' encodings lie on opposite edges of the map.
    With `edge` a sharp shadow: inside a disc (not aligned with the texel grid) I_z drops to 2 % and
    w_a steps from 0 to 1, where Catmull-Rom overshoots (I_z < 0, w_a outside [0, 1] before the
    clamps) and differs most from bilinear."""
    rng = np.random.default_rng(seed)
    n = 24
    gx, gz = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    amp, k = 0.08, 2.2
    gy = amp * np.sin(k * gx * np.pi) * np.cos(k * gz * np.pi * 0.7)
    dydx = amp * k * np.pi * np.cos(k * gx * np.pi) * np.cos(k * gz * np.pi * 0.7)
    dydz = -amp * k * np.pi * 0.7 * np.sin(k * gx * np.pi) * np.sin(k * gz * np.pi * 0.7)
    pos = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3)
    nrm = unit(np.stack([-dydx, np.ones_like(gx), -dydz], axis=-1)).reshape(-1, 3)
    uv0 = np.stack([(gx + 1) * 2, (gz + 1) * 2], axis=-1).reshape(-1, 2)  # material UV: tiles twice
    # the lightmap UV: the grid inset by a margin in the atlas, glTF convention (v down)
    uv1 = np.stack([0.05 + 0.9 * (gx + 1) / 2, 0.05 + 0.9 * (gz + 1) / 2], axis=-1).reshape(-1, 2)
    idx = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i, (j + 1) * (n + 1) + i + 1
            idx += [a, c, b, b, c, d]  # counter-clockwise seen from +y
    idx = np.asarray(idx, np.uint16)

    def layer_images(scale):
        iz = (0.05 + 2.0 * _smooth_field(rng, (size, size), 3)) * scale
        # directions within 45° of up (+y), w_a in [0.15, 0.85]
        t = _smooth_field(rng, (size, size), 3)
        d = unit(np.stack([(t[..., 0] - 0.5) * 1.6, np.ones((size, size)), (t[..., 1] - 0.5) * 1.6], axis=-1))
        if fold:  # within 40° of up, z < 0, x's sign flipping along bands ~3 texels wide
            x = 0.35 * np.sign(np.sin(np.pi * (np.arange(size)[None, :] + 8.0 * t[..., 0]) / 3.0))
            d = unit(np.stack([x * (0.6 + 0.4 * t[..., 1]), np.ones((size, size)), -0.3 - 0.3 * t[..., 1]], -1))
        wa = 0.15 + 0.7 * t[..., 2]
        if edge:
            yy, xx = np.mgrid[0:size, 0:size] + 0.5
            shadow = np.hypot(xx - 0.53 * size, yy - 0.47 * size) < 0.29 * size
            iz = np.where(shadow[..., None], 0.02 * iz, iz)
            wa = np.where(shadow, 1.0, 0.0)
        return iz, d, wa

    layers = [layer_images(1.0)]
    if with_sets:
        layers += [layer_images(0.6), layer_images(0.9)]

    buf = bytearray()
    views, accessors, images = [], [], []

    def add_view(data: bytes, target=None):
        while len(buf) % 4:
            buf.append(0)
        view = {"buffer": 0, "byteOffset": len(buf), "byteLength": len(data)}
        if target:
            view["target"] = target
        buf.extend(data)
        views.append(view)
        return len(views) - 1

    def add_accessor(array, kind, component=5126, target=34962):
        a = np.ascontiguousarray(array)
        acc = {"bufferView": add_view(a.tobytes(), target), "componentType": component, "count": len(a), "type": kind}
        if kind == "VEC3" and component == 5126:
            acc["min"] = a.min(axis=0).tolist()
            acc["max"] = a.max(axis=0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    def add_png(image, srgb=False):
        images.append({"bufferView": add_view(web_packing.png_encode(image, srgb=srgb)), "mimeType": "image/png"})
        return len(images) - 1

    attributes = {
        "POSITION": add_accessor(pos.astype(np.float32), "VEC3"),
        "NORMAL": add_accessor(nrm.astype(np.float32), "VEC3"),
        "TEXCOORD_0": add_accessor(uv0.astype(np.float32), "VEC2"),
        "TEXCOORD_1": add_accessor(uv1.astype(np.float32), "VEC2"),
    }
    indices = add_accessor(idx, "SCALAR", component=5123, target=34963)
    # a normal map of bumps (tangent space, +y green up as glTF)
    bu, bv = np.meshgrid(np.linspace(0, 4 * np.pi, 32), np.linspace(0, 4 * np.pi, 32))
    tn = unit(np.stack([0.35 * np.cos(bu), 0.35 * np.sin(bv), np.ones_like(bu)], axis=-1))
    normal_png = add_png(np.round((tn * 0.5 + 0.5) * 255).astype(np.uint8))
    samplers = [
        {"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071},
        {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497},
    ]
    textures = [{"source": normal_png, "sampler": 1}]

    def add_texture(image):
        textures.append({"source": add_png(image), "sampler": 0})
        return len(textures) - 1

    packed = []
    for iz, d, wa in layers:
        rng_ = float(np.ceil(iz.max()))
        iz_tex = add_texture(web_packing.encode(iz, "rgbm", rng_))
        dw_tex = add_texture(web_packing.encode_direction(d, wa))
        packed.append(
            {
                "irradiance": {"index": iz_tex, "packing": "rgbm", "range": rng_},
                "ambientWeight": {"index": dw_tex, "channels": "b"},
                "direction": {"index": dw_tex, "channels": "rg", "encoding": "octahedral"},
            }
        )
    set_names = ["Lamps", "Sky"] if with_sets else []
    atlas = {"name": "Lightmap", "width": size, "height": size, "model": "hhd", **packed[0]}
    atlas["lightSets"] = [{"set": i, **packed[1 + i]} for i in range(len(set_names))]
    ext = {
        "version": 1,
        "frame": "gltf",
        "units": "irradiance_over_pi",
        "threeLightMapIntensity": float(np.pi),
        "atlases": [atlas],
        "lightSets": [{"name": s, "weight": [1.0, 1.0, 1.0]} for s in set_names],
        "probeVolumes": [],
    }
    nodes = [0, 1]
    meshes = [{"name": "Grid", "primitives": [{"attributes": attributes, "indices": indices, "material": 0}]}]
    if probes:
        # a box (no lightmap) on the grid, lit by the probe volume
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        bpos, bnrm, bidx = [], [], []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                face = corners[corners[:, axis] == sign]
                normal = np.zeros(3)
                normal[axis] = sign
                a, b = [i for i in range(3) if i != axis]
                face = face[np.lexsort((face[:, b], face[:, a]))]  # (−,−), (−,+), (+,−), (+,+)
                o = len(bpos)
                bpos += list(face)
                bnrm += [normal] * 4
                tri = [0, 2, 1, 1, 2, 3]
                if np.dot(np.cross(face[2] - face[0], face[1] - face[0]), normal) < 0:
                    tri = [0, 1, 2, 1, 3, 2]
                bidx += [o + t for t in tri]
        box_pos = np.asarray(bpos) * np.array([0.3, 0.3, 0.3]) + np.array([0.2, 0.35, 0.1])
        box_attr = {
            "POSITION": add_accessor(box_pos.astype(np.float32), "VEC3"),
            "NORMAL": add_accessor(np.asarray(bnrm, np.float32), "VEC3"),
        }
        box_idx = add_accessor(np.asarray(bidx, np.uint16), "SCALAR", component=5123, target=34963)
        meshes.append({"name": "Box", "primitives": [{"attributes": box_attr, "indices": box_idx, "material": 1}]})
        nodes.append(2)
        res = (4, 3, 4)
        count = res[0] * res[1] * res[2]
        coeffs = rng.normal(0.0, 0.25, (count, 9, 3))
        coeffs[:, 0, :] = rng.uniform(1.5, 3.0, (count, 3))
        sh_acc = add_accessor(coeffs.reshape(-1, 3).astype(np.float32), "VEC3")
        del accessors[sh_acc]["min"], accessors[sh_acc]["max"]
        validity = add_accessor(np.ones(count, np.float32), "SCALAR")
        # volume-local [-1, 1]³ -> world: scale, then translate (column-major)
        matrix = np.diag([1.2, 0.6, 1.2, 1.0])
        matrix[:3, 3] = [0.0, 0.5, 0.0]
        ext["probeVolumes"] = [
            {
                "name": "Volume",
                "matrix": matrix.T.reshape(-1).tolist(),
                "resolution": list(res),
                "sh": sh_acc,
                "validity": validity,
                "lightSets": [],
            }
        ]
    eye = (1.6, 1.7, 2.2)
    doc = {
        "asset": {"version": "2.0", "generator": "scenekit/web_harness.py synthetic_glb"},
        "extensionsUsed": ["HHD_lightmap"],
        "extensions": {"HHD_lightmap": ext},
        "scene": 0,
        "scenes": [{"nodes": nodes}],
        "nodes": [
            {
                "name": "Grid",
                "mesh": 0,
                "extensions": {"HHD_lightmap": {"atlas": 0, "texCoord": 1, "scaleOffset": [1, 1, 0, 0]}},
            },
            {
                "name": "Camera",
                "camera": 0,
                "translation": list(eye),
                "rotation": _lookat_quaternion(eye, (0, -0.1, 0)),
            },
            {"name": "Box", "mesh": 1},
        ][: len(nodes)],
        "cameras": [
            {"type": "perspective", "perspective": {"yfov": 0.75, "aspectRatio": 1.0, "znear": 0.05, "zfar": 50}}
        ],
        "meshes": meshes,
        "materials": [
            {
                "name": "Ochre",
                "pbrMetallicRoughness": {
                    "baseColorFactor": [0.8, 0.6, 0.4, 1.0],
                    "metallicFactor": 0.0,
                    "roughnessFactor": 0.8,
                },
                "normalTexture": {"index": 0, "texCoord": 0, "scale": 1.0},
            },
            {"name": "Teal", "pbrMetallicRoughness": {"baseColorFactor": [0.3, 0.7, 0.6, 1.0], "metallicFactor": 0.0}},
        ],
        "textures": textures,
        "samplers": samplers,
        "images": images,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(buf)}],
    }
    return write_glb(path, doc, bytes(buf))


def write_glb(path: Path, doc: dict, binary: bytes) -> Path:
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    out = struct.pack("<III", 0x46546C67, 2, total)
    out += struct.pack("<II", len(js), 0x4E4F534A) + js
    out += struct.pack("<II", len(binary), 0x004E4942) + binary
    Path(path).write_bytes(out)
    return Path(path)
