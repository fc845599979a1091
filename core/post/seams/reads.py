"""Reading the lightmap as the GPU does: the bilinear read of an image at seam samples (texel
centres at i + ½, clamp to edge), the SH and HHD/AHD images read as the preview reads them
(`Reader`), filled rows read on demand (`FilledRows`, `_Stacked`: no atlas-wide copies), and the
hidden texels a seam sample must not read. No bpy."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from .geometry import Seams

if TYPE_CHECKING:
    from ...encoding import EncodedAtlas


def bilinear_taps(xy: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The four texels a bilinear read at `xy (S, 2)` (texel units) takes and their weights:
    flat indices `(S, 4)` int64 (row · width + column) and weights `(S, 4)` float64 summing to 1.
    Texel centres at i + ½, clamp to edge (indices clamped into the image)."""
    f = np.asarray(xy, dtype=np.float64) - 0.5
    base = np.floor(f)
    fx, fy = (f - base).T
    i0 = base[:, 0].astype(np.int64)
    j0 = base[:, 1].astype(np.int64)
    xs = np.clip(np.stack([i0, i0 + 1], 1), 0, width - 1)
    ys = np.clip(np.stack([j0, j0 + 1], 1), 0, height - 1)
    index = np.stack(
        [
            ys[:, 0] * width + xs[:, 0],
            ys[:, 0] * width + xs[:, 1],
            ys[:, 1] * width + xs[:, 0],
            ys[:, 1] * width + xs[:, 1],
        ],
        1,
    )
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return index, weight


def bilinear(image, xy: np.ndarray) -> np.ndarray:
    """GPU bilinear read of `image (H, W, ...)` (an array, or `FilledRows` of one) at texel-unit
    points `xy (S, 2)` -> `(S, ...)` float64 (texel centres at i + ½, clamp to edge; see
    `bilinear_taps`)."""
    (h, w), flat = _grid(image), _flat(image)
    return blend(flat, *bilinear_taps(xy, w, h))


def blend(rows, index: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The bilinear reads of `bilinear_taps` (`index (S, 4)`, `weight (S, 4)`) from texel rows
    `rows (T, ...)` (an array or `FilledRows`/`_Stacked`, `[index]` -> `(S, ...)`) -> `(S, ...)`
    float64: the four taps weighted and added in tap order (whatever `rows` holds the texels,
    the same values). Into buffers made once (an array's rows gathered into one): no new
    pages for every tap's temporaries."""
    tail, shape = rows.shape[1:], (-1,) + (1,) * len(rows.shape[1:])
    out = np.zeros((len(index),) + tail)
    product = np.empty(out.shape)
    taken = np.empty((len(index),) + tail, rows.dtype) if isinstance(rows, np.ndarray) else None
    for k in range(4):
        tap = rows[index[:, k]] if taken is None else np.take(rows, index[:, k], axis=0, out=taken)
        out += np.multiply(weight[:, k].reshape(shape), tap, out=product)
    return out


def _grid(image) -> tuple[int, int]:
    """(H, W) of an image `(H, W, ...)` or of `FilledRows`/`_Stacked` rows."""
    if isinstance(image, (FilledRows, _Stacked)):
        return image.grid  # type: ignore[return-value]
    h, w = image.shape[:2]
    return h, w


def _flat(image):
    """`image`'s texels as rows `(H·W, ...)` (`[index]` gathers them): `FilledRows`/`_Stacked`
    themselves, an array reshaped (a view where it can be)."""
    if isinstance(image, (FilledRows, _Stacked)):
        return image
    h, w = image.shape[:2]
    return np.asarray(image).reshape((h * w,) + image.shape[2:])


class FilledRows:
    """The rows of `fill.apply(image, keep_black)` read on demand, without the filled copy of
    the image (memory: an atlas's SH image is its largest array; stitching reads a few of its
    texels). `flat` `(H·W, ...)`: the image's texels (a view; not written), `fill` the
    `dilate.Fill` of its atlas, `grid` (H, W). `rows[index]` (int array of any shape) gives
    exactly what the filled copy's rows would hold (the same gather, the same mean of the
    sources for texels out of the dilation's reach, the same zeros for black texels) in the
    image's dtype, `(*index.shape, ...)`; `put(index, values)` overrides rows (later reads see
    them)."""

    def __init__(self, flat: np.ndarray, fill, grid: tuple[int, int], keep_black: bool = False):
        self.flat, self.fill, self.grid, self.keep_black = flat, fill, tuple(grid), keep_black
        self.shape, self.dtype = flat.shape, flat.dtype
        self._mean: np.ndarray | None = None
        self._put_index = np.zeros(0, np.int64)
        self._put_values = np.zeros((0,) + flat.shape[1:], flat.dtype)

    def _source_mean(self) -> np.ndarray:
        """`Fill.apply`'s mean of the sources (float64 over them in order, as one `mean`), cast
        as its assignment casts it; summed a block of sources at a time (no gather of them all)."""
        if self._mean is None:
            valid = self.fill.valid
            if not len(valid):
                self._mean = np.zeros(self.flat.shape[1:], self.dtype)
            else:
                total = self.flat[valid[: 1 << 16]].astype(np.float64).sum(axis=0)
                for s in range(1 << 16, len(valid), 1 << 16):
                    part = self.flat[valid[s : s + (1 << 16)]].astype(np.float64)
                    total = np.concatenate([total[None], part]).sum(axis=0)
                self._mean = np.asarray(total / len(valid)).astype(self.dtype)
        return self._mean

    def __getitem__(self, index) -> np.ndarray:
        index = np.asarray(index)
        flat_index = index.reshape(-1).astype(np.int64, copy=False)
        empty, source = self.fill.empty, self.fill.source
        # searched in the fill's own index type (int32 below 2³¹ texels): a search of int64 keys
        # would cast all of `empty` first, an atlas-wide copy per read
        key = flat_index.astype(empty.dtype, copy=False)
        pos = np.minimum(np.searchsorted(empty, key), max(len(empty) - 1, 0))
        is_empty = (empty[pos] == flat_index) if len(empty) else np.zeros(len(flat_index), bool)
        src = flat_index.copy()
        src[is_empty] = source[pos[is_empty]]
        far = src < 0
        out = self.flat[np.where(far, 0, src)]
        if far.any():
            out[far] = self._source_mean()
        if self.keep_black and len(self.fill.black):
            black = self.fill.black
            at = np.minimum(np.searchsorted(black, flat_index.astype(black.dtype, copy=False)), len(black) - 1)
            out[black[at] == flat_index] = 0.0
        if len(self._put_index):
            at = np.minimum(np.searchsorted(self._put_index, flat_index), len(self._put_index) - 1)
            hit = self._put_index[at] == flat_index
            out[hit] = self._put_values[at[hit]]
        return out.reshape(index.shape + self.flat.shape[1:])

    def put(self, index: np.ndarray, values: np.ndarray) -> None:
        """Rows `index` (unique flat indices) read `values` `(len(index), ...)` from now on."""
        order = np.argsort(index, kind="stable")
        self._put_index = np.asarray(index, np.int64)[order]
        self._put_values = np.asarray(values, self.dtype).reshape((len(index),) + self.flat.shape[1:])[order]


class Reader:
    """A way of reading a lightmap as the preview does: called with points `xy (S, 2)` (texel
    units of the atlas) it gives a function of the unit vertex normal `n_v (S, 3)` and shading
    normal `n (S, 3)` there giving irradiance `(S, 3)` (docs/conventions.md#irradiance-units); the
    filtered texels are read once per set of points, the normals applied after.

    In two steps, which a caller reading many sets of points can take itself (`seams.metrics`:
    each texel gathered once): `texels` the image's texel rows (`[flat index]` -> per texel
    values, float, of the `grid` (H, W)), read bilinearly (`blend` of `bilinear_taps` at
    `xy − corner`: the images may be a window of the atlas, `stages.Window`), then
    `shade(filtered (S, ...))` -> the function of (n_v, n)."""

    def __init__(self, texels, shade: Callable, corner: tuple[int, int] = (0, 0)):
        self.texels, self.shade, self.corner = _flat(texels), shade, corner
        self.grid: tuple[int, int] = _grid(texels)

    def __call__(self, xy: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        return self.shade(blend(self.texels, *self.taps(xy)))

    def taps(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`bilinear_taps` of atlas points `xy (S, 2)` on the images (flat indices `(S, 4)`, weights)."""
        h, w = self.grid
        if self.corner != (0, 0):
            xy = xy - np.array(self.corner, np.float64)  # exactly: whole texels
        return bilinear_taps(xy, w, h)

    def placed(self, window) -> Reader:
        """This reader of a window's images (`stages.Window`) reading at atlas positions (the
        window's corner taken off each point); itself without a window."""
        if window is None:
            return self
        return Reader(self.texels, self.shade, (int(window.x0), int(window.y0)))


def sh_reader(sh_image: np.ndarray | FilledRows) -> Reader:
    """Irradiance read from a radiance SH image `(H, W, 9, 3)` (already filled, or `FilledRows`
    of one: `(H·W, 9, 3)` rows filled as they are read), as the L2
    preview does: bilinear SH, bands × 1, 2/3, 1/4, evaluated at n."""
    from ... import sh as _sh

    def shade(radiance_sh):
        irradiance_sh = _sh.convolve_cosine(radiance_sh)
        return lambda n_v, n: np.einsum("sk,skc->sc", _sh.evaluate(n), irradiance_sh)

    return Reader(sh_image, shade)


def hhd_reader(images: Mapping[str, np.ndarray], model: str = "hhd") -> Reader:
    """Irradiance read from an HHD/AHD file's channel images {EXR name: `(H, W)`} (Iz.R/G/B,
    Wa.V or Wa.R/G/B, Direction.X/Y) as the preview's node group does (shaders/node_groups.py):
    each layer bilinear, the octahedral direction decoded per texel before filtering and
    renormalised after (filtering the encoded pair across the map's fold turns it: docs/format.md,
    "Filtering the direction"), d·n_v floored at core.hhd.MIN_COS,
    I = I_z [w_a (1 + n·n_v)/2 + (1 − w_a) max(n·d, 0)/(d·n_v)] (AHD: w_a + …)."""
    from ...encoding import hhd as spec
    from ...hhd import MIN_COS

    wa_names = [k for k in spec.WA_RGB.exr_names if k in images] or spec.WA.exr_names
    plain = _Stacked([images[k] for k in [*spec.IZ.exr_names, *wa_names]])
    packed = _Stacked([images[k] for k in spec.DIRECTION.exr_names], np.float64)
    # the layers at the texels a read takes (memory: no image of all the atlas's decoded layers)
    layers = _Stacked(
        [],
        grid=plain.grid,
        width=plain.shape[1] + 3,
        rows=lambda i: np.concatenate([plain[i], _decoded(packed[i])], -1),
    )
    hhd = model.lower() == "hhd"

    def shade(values):
        iz, wa, d = values[:, :3], values[:, 3:-3], values[:, -3:]
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)

        def at(n_v, n):
            cos_nv = np.einsum("si,si->s", n, n_v)[:, None]
            dnv = np.maximum(np.einsum("si,si->s", d, n_v), MIN_COS)[:, None]
            lobe = np.maximum(np.einsum("si,si->s", n, d), 0.0)[:, None] / dnv
            ambient = (1.0 + cos_nv) * 0.5 if hhd else 1.0
            return iz * (wa * ambient + (1.0 - wa) * lobe)

        return at

    return Reader(layers, shade)


def _decoded(packed: np.ndarray) -> np.ndarray:
    """`octahedral.decode` of packed directions `(..., 2)` -> `(..., 3)`."""
    from ... import octahedral

    return octahedral.decode(packed.reshape(-1, 2)).reshape(packed.shape[:-1] + (3,))


class _Stacked:
    """The rows of `np.stack([image.reshape(-1) for image in images], -1)` (in `dtype`, default
    the stack's) read on demand, `[index]` -> `(*index.shape, len(images))`, without stacking the
    atlas's images (memory). Or, with `rows` (a function of a flat index array) and `width`, the
    rows that gives. `grid`: the images' (H, W)."""

    def __init__(self, images, dtype=None, grid=None, width: int = 0, rows=None):
        self.images = [np.asarray(image) for image in images]  # (H, W), views of a layer's image: not copied
        self.grid = tuple(grid) if grid is not None else self.images[0].shape[:2]
        if rows is None:
            self.dtype = np.result_type(*self.images) if dtype is None else np.dtype(dtype)
            width = len(self.images)
        self.rows = rows
        self.shape = (self.grid[0] * self.grid[1], width)

    def __getitem__(self, index) -> np.ndarray:
        index = np.asarray(index)
        if self.rows is not None:
            flat = index.reshape(-1)
            return self.rows(flat).reshape(index.shape + (self.shape[1],))
        at = np.divmod(index, self.grid[1])  # (row, column): a strided image is gathered, not flattened
        out = np.stack([image[at] for image in self.images], -1)
        return out.astype(self.dtype, copy=False)


def reader_for(source) -> Reader:
    """The Reader of `source`: `encoding.TexelData` (its SH filled as the SH file is),
    `encoding.EncodedAtlas` (its encoding's file), a mapping of HHD channel images, or a radiance
    SH image `(H, W, 9, 3)`."""
    from ...encoding import EncodedAtlas, TexelData

    if isinstance(source, TexelData):
        return sh_reader(source.fill().apply(source.sh.copy(), keep_black=True))
    if isinstance(source, EncodedAtlas):
        return hhd_reader(encoded_images(source), source.settings.get("model", "hhd"))
    if isinstance(source, Mapping):
        return hhd_reader(source)
    return sh_reader(np.asarray(source))


def hidden_texels(coverage: np.ndarray) -> np.ndarray:
    """The texels no one sees, `(H·W,)` bool of `coverage (H, W)` (0 outside charts, -1 buried):
    buried texels with no covered texel of their own chart to take a value from, which the
    encoder leaves black (`TexelData.fill`): a surface inside closed geometry. A seam sample
    that reads one is hidden (`reads_hidden`): its black side is not a seam anyone sees, and
    stitching towards it would darken the side in the open."""
    from ...dilate import Fill

    cov = np.asarray(coverage)
    out = np.zeros(cov.size, bool)
    if (cov < 0.0).any():
        out[Fill(cov > 0.0, 1, black=cov < 0.0, chart=cov != 0.0).black] = True
    return out


def reads_hidden(seams: Seams, hidden: np.ndarray) -> np.ndarray:
    """`(S,)` bool: the samples whose bilinear read on either side takes a `hidden (H·W,)` texel."""
    out = np.zeros(len(seams), bool)
    for xy in (seams.a, seams.b):
        index, weight = bilinear_taps(xy, seams.width, seams.height)
        out |= ((weight > 0.0) & hidden[index]).any(axis=1)
    return out


def encoded_images(atlas: EncodedAtlas) -> dict[str, np.ndarray]:
    """The channel images `(H, W)` of `atlas`'s encoding file (filled and packed, as written)."""
    return atlas.files[atlas.encoding_file.key][1]
