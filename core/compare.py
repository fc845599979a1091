"""Every encoding against a reference render from one camera: bytes per texel, diffuse and
specular error, images for a contact sheet (Baking Lab's comparison, issue 59). No bpy.

The pixels. Camera rays through the pixel centres (`Camera`) hit the scene's geometry; a pixel
is *compared* where the closest hit is a receiver of the atlas, seen from its front, and its
four neighbours hit the same object (a render averages an edge pixel over both sides; a ray
through its centre sees one). Per compared pixel: the lightmap UV, the vertex normal n_v (the
shading normal n: normal maps are off on both sides of the comparison), the view direction v
and the albedo (`GBuffer`).

The encodings. The atlas's raw SH file goes through the post stages its bake ran (denoise,
stitch) once, then through each encoding's encoder in memory (nothing is written): the layers a
file of that model would hold, rounded to half where the channel spec stores half. A pixel reads
them bilinearly at its lightmap UV (the HHD direction as a unit vector, renormalised, as the
preview does) and reconstructs, in the units of docs/conventions.md:
  diffuse   I(n): the irradiance an albedo multiplies (`Basis.irradiance`, `hhd.reconstruct`);
  specular  S(n, v; α) with F0 = 1 (`Basis.specular`, `encoding.hhd_specular.specular`, GGX α =
            roughness²), for the encodings that model it.
The reference: a render whose camera rays see a white Lambertian surface (diffuse: I exactly)
or a white GGX surface of the roughness (specular), every other ray the scene's own materials
(`bridge.compare` builds it in Cycles, clamps off). Errors are relative RMSE of the luminance
over the compared pixels, relative to the reference's mean luminance there.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import encoding, post
from .colour import LUMINANCE
from .encoding import hhd as hhd_spec
from .encoding.hhd_specular import specular as hhd_specular
from .encoding.registry import basis_of
from .encoding.spec import FLOAT
from .hhd.lobes import HHDParams, reconstruct
from .rays import RayScene
from .textures import sample_bilinear

#: The encodings compared, in table order.
MODELS = ("hhd", "ahd", "sh_l1", "sh_l2", "hl2", "hbasis_l1", "hbasis_l2", "sg5", "sg6", "sg9", "sg12")
#: Bytes of one stored component of each dtype (half-or-float counted as half).
COMPONENT_BYTES = {"half": 2, "half_or_float": 2, "float": 4}
#: A receiver hit counts as visible when it is no farther than the closest hit by this share.
VISIBLE_SLACK = 1e-4


@dataclass(frozen=True)
class Camera:
    """position (3,) world space, metres; rotation (3, 3) camera to world (columns: right, up,
    backwards: the camera looks along −column 2, as Blender's); width × height pixels; kind
    'PERSP' or 'ORTHO'; half_extent (x, y): the image plane's half size at distance 1 (PERSP:
    tangents of the half angles) or in metres (ORTHO)."""

    position: np.ndarray
    rotation: np.ndarray
    width: int
    height: int
    kind: str
    half_extent: tuple[float, float]

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """(origins, unit directions) `(H·W, 3)` through the pixel centres, row 0 at the top."""
        j, i = np.mgrid[0 : self.height, 0 : self.width]
        x = ((i + 0.5) / self.width * 2.0 - 1.0).ravel() * self.half_extent[0]
        y = (1.0 - (j + 0.5) / self.height * 2.0).ravel() * self.half_extent[1]
        r = np.asarray(self.rotation, np.float64)
        p = np.asarray(self.position, np.float64)
        if self.kind == 'ORTHO':
            origins = p + np.outer(x, r[:, 0]) + np.outer(y, r[:, 1])
            return origins, np.broadcast_to(-r[:, 2], origins.shape).copy()
        d = np.outer(x, r[:, 0]) + np.outer(y, r[:, 1]) - r[:, 2]
        return np.broadcast_to(p, d.shape).copy(), d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass
class GBuffer:
    """The compared pixels (module doc) of a width × height image: index (P,) flat pixel index
    (row 0 at the top); uv (P, 2) lightmap UVs; n_v (P, 3) unit vertex normals; view (P, 3) unit
    directions to the camera; albedo (P, 3)."""

    width: int
    height: int
    index: np.ndarray
    uv: np.ndarray
    n_v: np.ndarray
    view: np.ndarray
    albedo: np.ndarray

    def image(self, values: np.ndarray, background: float = 0.0) -> np.ndarray:
        """`(H, W, C)` image of per-pixel `values (P, C)`, `background` elsewhere."""
        out = np.full((self.height * self.width, values.shape[1]), background, np.float64)
        out[self.index] = values
        return out.reshape(self.height, self.width, -1)


def gbuffer(camera: Camera, scene, surface) -> GBuffer:
    """The compared pixels of `camera` for the receivers `surface` (`bakepoints.SurfaceTriangles`,
    one atlas) among `scene`'s geometry (`core.scene.BakeScene`)."""
    origins, dirs = camera.rays()
    t_all, prim_all, _, u_all, v_all = RayScene(scene.triangles).intersect(origins, dirs, barycentrics=True)
    t, prim, _, u, v = RayScene(surface.positions).intersect(origins, dirs, barycentrics=True)
    hit = (prim >= 0) & (prim_all >= 0) & (t <= t_all * (1.0 + VISIBLE_SLACK) + 1e-6)
    w = np.stack([1.0 - u - v, u, v], axis=1)
    p = np.where(hit, prim, 0)
    n_v = np.einsum("pk,pki->pi", w, surface.normals[p])
    n_v /= np.maximum(np.linalg.norm(n_v, axis=1, keepdims=True), 1e-30)
    hit &= np.einsum("pi,pi->p", n_v, dirs) < 0.0  # seen from its front
    obj = np.where(hit, surface.object_index[p], -1).reshape(camera.height, camera.width)
    same = np.zeros_like(obj, dtype=bool)
    same[1:-1, 1:-1] = (
        (obj[1:-1, 1:-1] >= 0)
        & (obj[1:-1, 1:-1] == obj[:-2, 1:-1])
        & (obj[1:-1, 1:-1] == obj[2:, 1:-1])
        & (obj[1:-1, 1:-1] == obj[1:-1, :-2])
        & (obj[1:-1, 1:-1] == obj[1:-1, 2:])
    )
    index = np.flatnonzero(same.ravel())
    uv = np.einsum("pk,pki->pi", w[index], surface.uv[prim[index]])
    albedo = scene.albedo_at(prim_all[index], u_all[index], v_all[index])
    return GBuffer(camera.width, camera.height, index, uv, n_v[index], -dirs[index], np.asarray(albedo, np.float64))


def bytes_per_texel(model: str, settings=None) -> int:
    """Bytes a texel takes in the encoding's file (its channels of these settings; half-or-float
    channels counted as half)."""
    spec = encoding.for_settings(_settings(model, settings)).file
    return sum(len(ch.components) * COMPONENT_BYTES[ch.dtype] for ch in spec.channels)


def _settings(model: str, settings=None):
    base = settings if settings is not None else encoding.EncoderSettings()
    return replace(base, model=model)


@dataclass
class Reconstruction:
    """One encoding's images at the compared pixels: diffuse (P, 3) I(n); specular {roughness:
    (P, 3) S(n, v)} for the encodings that model it (empty otherwise); bytes per texel."""

    model: str
    bytes_per_texel: int
    diffuse: np.ndarray
    specular: dict = field(default_factory=dict)


def post_stages(data, pipeline, seams, check=None, raw_sh=None):
    """(`data` after the post stages of `pipeline`, their records): `reconstruct_model`'s input. `data`
    is the stages' (they write into it); `check` and `raw_sh` (the raw SH file read back) as
    `post.apply` takes them."""
    return post.apply(data, pipeline, check=check, seams=seams, raw_sh=raw_sh)


def reconstruct_model(model: str, data, records: dict, pipeline, seams, g: GBuffer, roughness=()) -> Reconstruction:
    """One model's reconstruction at `g`'s pixels from `post_stages`' output (not changed)."""
    settings = _settings(model, pipeline.encoder)
    enc = encoding.for_settings(settings)
    encoded = encoding.encode_atlas(replace(data), enc, raw=False)  # it takes the SH out of a TexelData of its own
    encoded = post.stitch_encoded(encoded, data.coverage, pipeline, seams, dict(records))
    spec, images = encoded.files[encoded.encoding_file.key]
    layers = {ch.name: _layer(ch, images, g.uv) for ch in spec.channels if ch.applies(settings)}
    return _reconstruction(model, settings, layers, g, roughness)


def _layer(channel, images: dict, uv: np.ndarray) -> np.ndarray:
    """A channel's value `(P, width)` read bilinearly at `uv`: its stored components (half where
    stored as half), unpacked (a direction: a unit vector blended, then renormalised)."""
    stack = np.stack([np.asarray(images[name], np.float32) for name in channel.exr_names], -1)
    if channel.dtype != FLOAT:
        half = stack.astype(np.float16)
        stack = np.where(np.isfinite(half), half.astype(np.float32), stack)
    h, w = stack.shape[:2]
    if channel.unpack is not None:
        stack = channel.unpack(stack.reshape(h * w, -1)).reshape(h, w, -1)
    value = sample_bilinear(stack.astype(np.float64), uv, clamp=True)
    if channel.unpack is not None:
        value /= np.maximum(np.linalg.norm(value, axis=1, keepdims=True), 1e-30)
    return value


def _reconstruction(model, settings, layers: dict, g: GBuffer, roughness) -> Reconstruction:
    size = bytes_per_texel(model, settings)
    if model in ("hhd", "ahd"):
        wa = layers[hhd_spec.WA.name]
        p = HHDParams(
            irradz=layers[hhd_spec.IZ.name],
            ambient_weight=wa[:, 0] if wa.shape[1] == 1 else wa,
            direction=layers[hhd_spec.DIRECTION.name],
            model=model,
            invalid=np.zeros(len(g.index), bool),
            clamped_irradz=np.zeros(len(g.index), bool),
        )
        specular = {r: hhd_specular(p, g.n_v, g.n_v, g.view, r * r, model=model) for r in roughness}
        return Reconstruction(model, size, reconstruct(p, g.n_v, g.n_v, model), specular)
    basis = basis_of(settings)
    c = np.stack([layers[name] for name in layers], axis=1)  # (P, K, 3) in the file's layer order
    diffuse = basis.irradiance(c, g.n_v, g.n_v)
    specular = {}
    if basis.SPECULAR:
        for r in roughness:
            specular[r] = basis.specular(c, g.n_v, g.n_v, g.view, r * r)
    return Reconstruction(model, size, diffuse, specular)


def relative_rmse(values: np.ndarray, reference: np.ndarray) -> float:
    """RMSE of the luminance of `values (P, 3)` against `reference (P, 3)`, over the reference's
    mean luminance (NaN without pixels or light)."""
    a, b = np.asarray(values) @ LUMINANCE, np.asarray(reference) @ LUMINANCE
    mean = float(b.mean()) if len(b) else 0.0
    return float(np.sqrt(np.mean((a - b) ** 2)) / mean) if mean > 0 else float("nan")


def noise_removed(error: float, floor: float) -> float:
    """An error with a reference's own noise `floor` left out in quadrature: √max(e² − f², 0)
    (both relative RMSE; the reference's noise and the encoding's error are independent)."""
    return float(np.sqrt(max(error * error - floor * floor, 0.0)))
