"""The encode stage: an atlas's texel images → the images of its files. No bpy.

Input: `TexelData`, float32 images of the traced atlas (rows bottom-up, as Blender's), the same
whether fresh from a bake (`TexelData.from_traced`) or read back from the files, so encoding
either way gives identical files. Output: `EncodedAtlas`, per file the images of its EXR
channels (still bottom-up and in the values' dtype; `lightmap_files` lays them out). Steps:
  1. the Encoding encodes the baked texels in chunks of at most ENCODE_CHUNK (bounding its float64
     copies), on every core;
  2. each layer is filled where there is no bake value, as its Channel says (`dilate.Fill`: the
     nearest chart texel within DILATE_RINGS, the atlas mean beyond; buried texels black);
  3. layers with a `pack` are packed (the highlight direction: unit vector → octahedral).
The raw files' layers (SH, texels) come straight from the TexelData, filled one EXR channel at a
time (memory: one channel's copy).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import dilate as _dilate
from ..memory import releasable_zeros, release_rows
from ..stages import PlacedImage, Window, placed
from .filled import FilledChannel, FilledLayer, filled_channels
from .raw import NOISE_UNKNOWN, SH_FILE, TEXELS_FILE
from .spec import DILATE_BURIED_BLACK, NO_FILL, Channel, Encoding, FileSpec

if TYPE_CHECKING:
    from ..bakepoints import BakePoints
    from ..stages import TracedAtlas

#: Dilation reach in texels: enough for bilinear filtering down several mip levels; farther
#: empty texels take the atlas mean.
DILATE_RINGS = 16

#: Rows of a compact SH imaged before they are given back (`TexelData.from_traced`).
IMAGE_ROWS = 1 << 18

#: Texels encoded per Encoding.encode call: bounds the float64 copies an encoding makes.
ENCODE_CHUNK = 1 << 17
#: A smaller atlas is encoded in this many chunks (`encode_chunk_texels`), so every core has some.
ENCODE_SPLIT = 8
#: ... of at least this many texels (fewer are not worth a task).
MIN_ENCODE_CHUNK = 1 << 12

#: Texels around the baked ones a window (`window_of`) keeps: more than any stage reaches from a
#: baked texel (the dilation's DILATE_RINGS from a stitched gutter texel, itself next to a chart;
#: the denoiser's page margin), so every texel outside it takes the mean fill (or none), as in
#: the whole atlas.
WINDOW_MARGIN = DILATE_RINGS + 8


def window_of(texel: np.ndarray, height: int, width: int) -> Window | None:
    """The rectangle of an atlas `height` × `width` holding its baked texels (flat indices `texel`)
    and WINDOW_MARGIN texels around them, clipped to the atlas: the images a bake's stages work
    on (`TexelData.from_traced(..., crop=True)`); None when it is the whole atlas. Outside it
    every texel is farther than the dilation reaches from any texel a stage writes, so every
    stage gives there what it gives the whole atlas (the mean fill, or nothing), and the files
    are the same."""
    if len(texel) == 0:
        return None
    rows, cols = texel // width, texel % width
    y0, y1 = max(int(rows.min()) - WINDOW_MARGIN, 0), min(int(rows.max()) + 1 + WINDOW_MARGIN, height)
    x0, x1 = max(int(cols.min()) - WINDOW_MARGIN, 0), min(int(cols.max()) + 1 + WINDOW_MARGIN, width)
    if (y1 - y0, x1 - x0) == (height, width):
        return None
    return Window(y0, x0, y1 - y0, x1 - x0, (height, width))


@dataclass
class TexelData:
    """An atlas's per-texel inputs to the encoder, as float32 images `(H, W, ...)` (rows
    bottom-up): sh (9, 3) radiance SH, normal (3,) n_v, coverage (0 outside charts, -1 buried);
    sh_error (9, 3) the standard error of sh, when the caller asked for it (no file holds it yet);
    extra_sources `(H, W)` bool, optional: texels outside the charts a post stage gave a value
    of their own (seam stitching's gutter texels, `core.post.seams`): encoded and dilated from like
    baked texels instead of being filled; noise `(H, W)`, optional: the standard error of each
    texel's luminance L0 (radiance) as traced, NaN where unknown (`TracedAtlas.noise`), as
    the texels file keeps it (the denoiser's noise clamp reads it). float32 as in the files, so
    encoding a fresh bake and re-encoding its files agree exactly.
    window: None when the images are the whole atlas; else the rectangle of the atlas they are
    (`window_of`: an almost empty atlas), every texel outside it empty (no chart, no value).
    The stages work on the window's images; the files are written whole (`stages.PlacedImage`)."""

    sh: np.ndarray
    normal: np.ndarray
    coverage: np.ndarray
    sh_error: np.ndarray | None = None
    extra_sources: np.ndarray | None = None
    noise: np.ndarray | None = None
    window: Window | None = None

    @property
    def atlas_shape(self) -> tuple[int, int]:
        """(height, width) of the atlas (the images' own without a window)."""
        return self.coverage.shape if self.window is None else self.window.atlas

    @property
    def baked(self) -> np.ndarray:
        """Texels with a bake value of their own (covered, not buried, or `extra_sources`): the
        dilation sources."""
        baked = self.coverage > 0.0
        return baked if self.extra_sources is None else baked | self.extra_sources

    @classmethod
    def from_points(
        cls,
        points: BakePoints,
        sh: np.ndarray,
        sh_error: np.ndarray | None = None,
        noise: np.ndarray | None = None,
        crop: bool = False,
    ) -> TexelData:
        """Images of per-point `sh` `(P, 9, 3)` (and optionally its standard error and the
        `noise` (P,) of `TracedAtlas.noise`) at `points`; noise is NaN outside the charts. Its
        arguments are only read (a bake images its traced atlas with `from_traced`, which spends
        it). `crop`: the images are of the atlas's `window_of` its texels (the whole atlas where
        that is all of it)."""
        texel, h, w, window = _placement(points, crop)
        if sh_error is None:
            error = None
        elif window is None:
            error = points.image(sh_error, dtype=np.float32)
        else:  # the window's image: `points.image`'s values, placed there
            error = _image_at(sh_error, texel, h, w)
        coverage = np.where(points.buried, -1.0, points.coverage)
        return cls._imaged(texel, h, w, window, points.normal, coverage, sh, noise, error)

    @classmethod
    def from_traced(cls, traced: TracedAtlas, crop: bool = False) -> TexelData:
        """The images of `traced` (`from_points` of its bake points, SH and `noise()`), which it
        owns (`core.memory`) and spends: its bake points are dropped (`traced.points` None) once
        their normals and coverage are taken, before any image is made (they are as large as the
        SH image; another reference, a light set's `TracedAtlas.light_set`, keeps them); its SH
        and standard error are given back a part at a time as the SH is imaged (IMAGE_ROWS rows,
        `memory.release_rows`: the compact SH and its image are not both whole at once), then
        dropped (empty arrays). `crop` as `from_points`'."""
        points = traced.points
        noise = traced.noise()
        texel, h, w, window = _placement(points, crop)
        # float32 casts of what is left to image: the values the images take
        coverage = np.where(points.buried, -1.0, points.coverage).astype(np.float32)
        normal = points.normal.astype(np.float32)
        del points
        traced.points = None  # type: ignore[assignment]
        data = cls._imaged(texel, h, w, window, normal, coverage, traced.sh, noise, None, (traced.sh, traced.sh_error))
        traced.sh = np.zeros((0, 9, 3))
        traced.sh_error = np.zeros((0, 9, 3), np.float32)
        return data

    @classmethod
    def _imaged(cls, texel, h, w, window, normal, coverage, sh, noise, error, spent=()) -> TexelData:
        """The TexelData of per-texel values at flat indices `texel` of `h` × `w` images (as
        `BakePoints.image`), the SH imaged IMAGE_ROWS rows at a time, each part's rows of the
        arrays `spent` given back once imaged (`memory.release_rows`)."""
        normal, coverage = _image_at(normal, texel, h, w), _image_at(coverage, texel, h, w)
        noise = None if noise is None else _image_at(noise, texel, h, w, fill=np.nan)
        # as `BakePoints.image`; its pages outside the charts can go back once written (`raw_files`)
        image = releasable_zeros((h * w,) + sh.shape[1:], np.float32)
        for s in range(0, len(texel), IMAGE_ROWS):
            image[texel[s : s + IMAGE_ROWS]] = sh[s : s + IMAGE_ROWS]
            for a in spent:
                release_rows(a, min(s + IMAGE_ROWS, len(texel)))
        return cls(
            sh=image.reshape((h, w) + sh.shape[1:]),
            normal=normal,
            coverage=coverage,
            sh_error=error,
            noise=noise,
            window=window,
        )

    def fill(self) -> _dilate.Fill:
        """The dilation of this atlas: buried texels (invalid: their hemisphere is closed by
        back faces) from the nearest baked texel of their own chart (black only where the chart
        has none within `dilate.CHART_RINGS`), then the empty texels outside charts."""
        return _dilate.Fill(self.baked, DILATE_RINGS, black=self.coverage < 0.0, chart=self.coverage != 0.0)

    def layers(self) -> dict[str, np.ndarray]:
        """The raw files' layers as `(H, W, components)` views: SH0 … SH8, Normal, Coverage,
        Noise (NOISE_UNKNOWN where unknown: files hold no NaN)."""
        out = {ch.name: self.sh[:, :, k] for k, ch in enumerate(SH_FILE.channels)}
        normal, coverage, noise = TEXELS_FILE.channels
        out.update({normal.name: self.normal, coverage.name: self.coverage[..., None]})
        if self.noise is None:
            noise_image = np.full(self.coverage.shape, NOISE_UNKNOWN, np.float32)
        else:
            noise_image = np.where(np.isnan(self.noise), np.float32(NOISE_UNKNOWN), self.noise)
        out[noise.name] = noise_image[..., None]
        return out

    def placed(self, name: str, image, fill: _dilate.Fill | None = None, unfilled=None):
        """One raw file's channel image `(h, w)` of the window (layer `name`, `layers`) as the
        atlas's: itself without a window, else a `PlacedImage` whose texels outside the window
        hold what the whole atlas's would: the layer's mean fill (`fill` given: a filled
        channel, `background`, taken from `unfilled` if given: the channel before filling, whose
        sources are the same), unknown noise (NOISE_UNKNOWN), else 0."""
        if self.window is None:
            return image
        value: np.ndarray | float
        if fill is not None:
            value = background(fill, image if unfilled is None else unfilled)
        else:
            value = NOISE_UNKNOWN if name == TEXELS_FILE.channels[2].name else 0.0
        return placed(image, self.window, value)


def _placement(points: BakePoints, crop: bool) -> tuple[np.ndarray, int, int, Window | None]:
    """(flat indices of `points`' texels in the images, the images' height and width, their
    window: `window_of` with `crop`, None for the whole atlas)."""
    texel, h, w = points.texel, points.height, points.width
    window = window_of(texel, h, w) if crop else None
    if window is not None:
        texel, h, w = window.local(texel), window.h, window.w
    return texel, h, w, window


def _image_at(values: np.ndarray, texel: np.ndarray, h: int, w: int, fill: float = 0.0) -> np.ndarray:
    """`BakePoints.image` of `values` at flat indices `texel` of an `h` × `w` image, float32."""
    if fill == 0.0 and not np.signbit(fill):  # pages outside the charts never written: not resident (memory)
        out = releasable_zeros((h * w,) + values.shape[1:], np.float32)
    else:
        out = np.full((h * w,) + values.shape[1:], fill, np.float32)
    out[texel] = values
    return out.reshape((h, w) + values.shape[1:])


def background(fill: _dilate.Fill, image: np.ndarray) -> np.ndarray:
    """The value `fill.apply` gives `image` `(h, w, ...)` (any strides)'s texels out of every
    source's reach, in its dtype: the mean of its sources (0 without any). Outside a window,
    every texel is one of those."""
    if not len(fill.valid):
        return np.zeros(image.shape[2:], image.dtype)
    flat = image.reshape((-1,) + image.shape[2:])  # a copy of a strided view: a window's, small
    return np.asarray(flat[fill.valid].mean(axis=0, dtype=np.float64)).astype(image.dtype)


@dataclass
class EncodedAtlas:
    """One atlas after the encode stage. files: per sidecar key, (FileSpec, {EXR channel name:
    `(H, W)` image, rows bottom-up}), the encoding's file first, then the raw files if encoded;
    encoding_file: the encoding's FileSpec; settings: the sidecar's `encoder`; stats: the sidecar's
    `stats` (texels_baked, texels_buried, then the encoding's summary)."""

    width: int
    height: int
    files: dict[str, tuple[FileSpec, dict[str, np.ndarray]]]  # images: PlacedImage where windowed
    encoding_file: FileSpec
    settings: dict
    stats: dict


def encode_atlas(
    data: TexelData,
    encoding: Encoding,
    raw: bool = True,
    fill: _dilate.Fill | None = None,
    tick=None,
    threads: int = 0,
    release_sh: bool = False,
) -> EncodedAtlas:
    """Encode `data` with `encoding` and fill its layers; with `raw`, also the SH and texels
    files' images of `data` (False: a bake that wrote them before its post stages, `raw_files`,
    or a re-encode, which keeps the files it read). `fill`: `data.fill()`, if the caller has it.
    `data` is this stage's (`core.memory`): its SH is taken out of it (`encode_images`: an empty
    `data.sh` afterwards), none of its arrays written. `tick` (`core.progress.Tick`): progress and cancel per chunk of texels
    encoded and per layer filled. `threads`: workers encoding chunks of texels (0 = every core,
    `parallel.resolve_threads`); the files do not depend on it. `release_sh`: the SH's own
    memory is spent too, given back behind the chunks encoded (`encode_images`): the caller
    holds no other TexelData of the same SH (a bake, which reads it no more)."""
    h, w = data.atlas_shape
    fill = data.fill() if fill is None else fill
    raw_file_images = {}
    if raw:  # first: the encoding takes the SH
        layers = data.layers()
        raw_file_images = {
            spec.key: (spec, raw_images(spec, layers, fill, data=data)) for spec in (SH_FILE, TEXELS_FILE)
        }
        del layers
    images, summary = encode_images(data, encoding, fill, tick=tick, threads=threads, release_sh=release_sh)
    files = {encoding.file.key: (encoding.file, images), **raw_file_images}
    stats = {"texels_baked": int(len(fill.valid)), "texels_buried": int(len(fill.invalid)), **summary}
    return EncodedAtlas(w, h, files, encoding.file, dict(encoding.settings), stats)


@contextmanager
def raw_files(
    data: TexelData, fill: _dilate.Fill
) -> Iterator[dict[str, tuple[FileSpec, dict[str, np.ndarray | PlacedImage | FilledChannel]]]]:
    """The raw files' images of `data` (as `EncodedAtlas.files`: {sidecar key: (FileSpec, {EXR
    channel name: `(H, W)` image})}) for the duration of the block, which writes them: the SH
    channels filled a band of rows at a time as the writer asks for them (`filled.FilledChannel`:
    `data` is only read, no copy of the atlas's SH, none of its empty texels written); the
    texels file's channels are views. `fill`: `data.fill()`. With a window
    (`TexelData.window`) the images are `stages.PlacedImage`s of the whole atlas around the
    window's."""
    layers = data.layers()
    yield {spec.key: (spec, raw_images(spec, layers, fill, banded=True, data=data)) for spec in (SH_FILE, TEXELS_FILE)}


def encode_images(
    data: TexelData, encoding: Encoding, fill: _dilate.Fill, tick=None, threads: int = 0, release_sh: bool = False
) -> tuple[dict, dict]:
    """The encoding's channel images `(H, W)` (filled, packed) and its summary statistics.
    `data.sh` is taken (an empty image afterwards) once the texels are encoded, before the
    layers are filled (memory: the atlas's SH is its largest image). With a window
    (`TexelData.window`) the images are `stages.PlacedImage`s of the whole atlas. `tick`
    (`core.progress.Tick`): reported per chunk (`encode_chunk_texels`) and per layer filled. The chunks
    are encoded on `threads` workers (0 = every core; numpy releases the GIL in the fit's array
    operations), each chunk as it would be alone, and written in order: the same images and
    statistics whatever the thread count. `release_sh`: the SH image's rows (texels) before the
    first baked texel of the chunks still to encode are given back as each chunk is written
    (`memory.release_rows`: the SH image and the encoded values are not both whole at once);
    they read 0 afterwards, in any TexelData of that SH."""
    from ..parallel import resolve_threads
    from ..progress import ticker

    h, w = data.coverage.shape
    baked = fill.valid
    sh, normal = data.sh.reshape(h * w, 9, -1), data.normal.reshape(h * w, 3)
    channels = encoding.file.channels
    # the baked texels' values only (their order in `baked`): the SH image and dense value
    # images are never both whole at once (memory); placed in the images once the SH is taken
    values = {ch.name: np.zeros((len(baked), ch.value_width), np.float32) for ch in channels}
    stats: list[dict] = []
    # the fill and packing of a layer: about a fifth of encoding its texels (per atlas texel, not baked)
    texels_part, layers_part = ticker(tick).split([len(baked), 0.2 * h * w * len(channels)])
    step = texels_part.counter(len(baked), lambda done, of: f"encoding texels {done} of {of}")
    chunk = encode_chunk_texels(len(baked))
    starts = range(0, len(baked), chunk)

    def encoded(s: int):
        rows = baked[s : s + chunk]
        return slice(s, s + len(rows)), encoding.encode(sh[rows], normal[rows])

    workers = min(resolve_threads(threads), len(starts))
    with ThreadPoolExecutor(max_workers=max(workers, 1)) as pool:
        # at most two chunks ahead of the one written per worker (memory: each holds float64 copies)
        pending: deque = deque()
        done = 0
        for s in starts:
            pending.append(pool.submit(encoded, s))
            while len(pending) > 2 * workers or (s == starts[-1] and pending):
                done += _take(pending.popleft().result(), values, stats)
                if release_sh:  # the chunks still to encode read texels baked[done] on (sorted)
                    release_rows(sh, int(baked[done]) if done < len(baked) else len(sh))
                step(done)
    sh = data.sh = np.zeros((0, 0) + data.sh.shape[2:], np.float32)  # taken: the SH goes (memory)
    images = {}
    step = layers_part.counter(len(channels), lambda done, of: f"filling layer {done} of {of}")
    for k, ch in enumerate(channels):
        image = np.zeros((h * w, ch.value_width), np.float32)
        image[baked] = values.pop(ch.name)
        images.update(layer_images(ch, image.reshape(h, w, ch.value_width), fill, data.window))
        del image
        step(k + 1)
    return images, encoding.summary(stats, len(baked))


def encode_chunk_texels(texels: int) -> int:
    """Texels per chunk `encode_images` encodes for `texels` baked texels: ENCODE_CHUNK, or
    for fewer than ENCODE_SPLIT such chunks, an ENCODE_SPLIT-th of them (at least
    MIN_ENCODE_CHUNK). A function of the texels only: the statistics summed per chunk do not
    depend on the thread count."""
    return min(ENCODE_CHUNK, max(MIN_ENCODE_CHUNK, -(-texels // ENCODE_SPLIT)))


def _take(result, values: dict, stats: list) -> int:
    """One encoded chunk (`encode_images`' `encoded`: its texels' slice of the baked texels and
    their values) into the baked texels' values, in chunk order; its texel count."""
    rows, out = result
    for name, v in out.values.items():
        values[name][rows] = v
    stats.append(out.stats)
    return rows.stop - rows.start


def layer_images(
    ch: Channel, image: np.ndarray, fill: _dilate.Fill, window: Window | None = None
) -> dict[str, np.ndarray | PlacedImage]:
    """One layer's value image `(H, W, value_width)` (a contiguous array of the caller's, filled
    in place), filled as a whole then packed, as {EXR channel name: `(H, W)` view}. With a
    `window` (of the TexelData the image is of), each a `stages.PlacedImage` of the atlas whose
    texels outside the window hold what the whole atlas's would: the layer's mean fill (0
    unfilled), packed as the rest."""
    outside = None
    if window is not None:
        outside = background(fill, image) if ch.fill != NO_FILL else np.zeros(image.shape[2:], image.dtype)
        if ch.pack is not None:
            outside = ch.pack(outside.reshape(1, -1))[0]
    if ch.fill != NO_FILL:
        image = fill.apply(image, keep_black=ch.fill == DILATE_BURIED_BLACK)
    if ch.pack is not None:  # ENCODE_CHUNK texels at a time: a pack's float64 temporaries stay small
        h, w = image.shape[:2]
        flat = image.reshape(h * w, -1)
        packed = ch.pack(flat[:ENCODE_CHUNK])
        if len(flat) > ENCODE_CHUNK:
            part, packed = packed, np.empty((len(flat),) + packed.shape[1:], packed.dtype)
            packed[:ENCODE_CHUNK] = part
            for s in range(ENCODE_CHUNK, len(flat), ENCODE_CHUNK):
                packed[s : s + ENCODE_CHUNK] = ch.pack(flat[s : s + ENCODE_CHUNK])
        image = packed.reshape(h, w, len(ch.components))
    if outside is None:
        return {name: image[..., k] for k, name in enumerate(ch.exr_names)}
    return {name: placed(image[..., k], window, outside[k]) for k, name in enumerate(ch.exr_names)}


def _whole_sh(
    spec: FileSpec, layers: dict[str, np.ndarray], data: TexelData | None, fill: _dilate.Fill
) -> FilledLayer | None:
    """For the SH file's layers (SH0 … SH8: `data.sh[:, :, c]`, strided views), one FilledLayer
    of the whole SH `(H, W, 9·C)` (a view) that every channel reads a band from: a band gathers
    each empty texel's 9·C values from its source at once, not one layer at a time (a gather per
    texel and layer of a strided view costs more than the values it copies). None for another
    file, without `data`, where `layers` are not those views, where the layers are filled in
    different ways, or where the SH's coefficients and colours are not one run of memory per
    texel (the view would be a copy)."""
    if spec is not SH_FILE or data is None or len({ch.fill for ch in spec.channels}) != 1:
        return None
    sh = data.sh
    if spec.channels[0].fill == NO_FILL or sh.shape[2:] != (len(spec.channels), len(spec.channels[0].exr_names)):
        return None
    if sh.strides[2] != sh.shape[3] * sh.strides[3] or not all(
        _same_view(layers[ch.name], sh[:, :, c]) for c, ch in enumerate(spec.channels)
    ):
        return None
    return FilledLayer(sh.reshape(sh.shape[0], sh.shape[1], -1), fill, spec.channels[0].fill == DILATE_BURIED_BLACK)


def _same_view(a: np.ndarray, b: np.ndarray) -> bool:
    """`a` and `b` are the same view of the same memory (start, shape, strides, dtype)."""
    return (
        a.shape == b.shape
        and a.strides == b.strides
        and a.dtype == b.dtype
        and a.__array_interface__["data"][0] == b.__array_interface__["data"][0]
    )


def raw_images(
    spec: FileSpec,
    layers: dict[str, np.ndarray],
    fill: _dilate.Fill,
    banded: bool = False,
    data: TexelData | None = None,
) -> dict[str, np.ndarray | PlacedImage | FilledChannel]:
    """A raw file's channel images `(H, W)` from `layers` (`TexelData.layers`), each filled on
    its own when its Channel says so (unfilled ones are views of the TexelData). `banded`: the
    filled ones made a band of rows at a time as they are read (`filled.filled_channels`, the
    same values), else filled copies. `data`: the TexelData of `layers`, whose window (if any)
    places them in the atlas (`TexelData.placed`)."""
    out: dict[str, np.ndarray | PlacedImage | FilledChannel] = {}
    whole = _whole_sh(spec, layers, data, fill) if banded else None
    for c, ch in enumerate(spec.channels):
        keep_black = ch.fill == DILATE_BURIED_BLACK
        lazy: list[FilledChannel] | None = None
        if whole is not None:  # layer c is data.sh[:, :, c]: its channels follow one another in `whole`
            lazy = [FilledChannel(whole, c * len(ch.exr_names) + k) for k in range(len(ch.exr_names))]
        elif banded and ch.fill != NO_FILL:
            lazy = filled_channels(layers[ch.name], fill, keep_black)
        for k, name in enumerate(ch.exr_names):
            image = layers[ch.name][..., k]
            filled: np.ndarray | FilledChannel
            if ch.fill == NO_FILL:
                filled = image
            elif lazy is not None:
                filled = lazy[k]
            else:
                filled = fill.apply(image.copy(), keep_black=keep_black)  # a view of `layers`
            if data is None or data.window is None:
                out[name] = filled
            else:  # the background from the sources, which filling leaves as they are
                out[name] = data.placed(ch.name, filled, None if ch.fill == NO_FILL else fill, unfilled=image)
    return out
