"""The masked texels of a page around its charts, filled for the filter: the chart mirrored
through its border next to it, a local mean of its texels farther (`_smooth_fill`); box sums
that a band of a page continues from the rows above (`_box_sum`). No bpy."""

from __future__ import annotations

import numpy as np

from ... import dilate

#: Reach in texels of the smooth fill around a chart (`_smooth_fill`).
FILL_BLUR = 2
#: Farther than FILL_BLUR, a masked texel copies the nearest filled one within this many rings.
FILL_RINGS = 16
#: Masked texels within this many rings of a chart texel take the chart texel mirrored through
#: their nearest one (`_mirror`), where there is one, instead of the smooth fill.
MIRROR_RINGS = 2


def _smooth_fill(
    image: np.ndarray,
    source: np.ndarray,
    seed: np.ndarray | None = None,
    keep: int | None = None,
    mean: np.ndarray | None = None,
    fill: bool = True,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """`image` `(h, w, c)` (changed in place) with its non-chart texels filled (float64): within
    MIRROR_RINGS of a chart texel, the chart mirrored through its border where it can be
    (`_mirror`); else within FILL_BLUR texels of one, the mean of the chart texels in the
    (2·FILL_BLUR + 1)² box around it (copying the nearest texel would repeat its noise in
    streaks, which the filter keeps as detail); farther, the nearest such mean (FILL_RINGS
    rings), beyond that the page mean.

    For a band of a page (`_denoise_banded`), rows of it: `seed` `(c, w)`, the column sums of
    the page's masked channels over the rows above the band (`_box_sum`), `keep` a row whose
    column sums to return for the next band, `mean` `(c,)` the page mean (None: the band's), and
    `fill=False` stops before the nearest-texel fill. Returns the image, the kept column sums
    (None without `keep`) and the mask of texels within FILL_BLUR of a chart texel."""
    weight = _box_sum(source.astype(np.float64)[..., None], FILL_BLUR)[0][..., 0]
    near = weight > 0.0
    inv = np.where(near, 1.0 / np.where(near, weight, 1.0), 0.0)
    del weight
    image = image.astype(np.float64, copy=False)
    outside = ~source
    image[outside] = 0.0  # in place: where(source, image, 0)
    kept = None if keep is None else np.empty((image.shape[2], image.shape[1]), np.float64)
    for k in range(image.shape[2]):  # where(source, image, box mean), one channel at a time, in place
        box, column = _box_sum(image[..., k : k + 1], FILL_BLUR, None if seed is None else seed[k : k + 1], keep)
        box = box[..., 0]
        box *= inv
        channel = image[..., k]
        channel[outside] = box[outside]
        if kept is not None and column is not None:
            kept[k] = column[0]
    if not fill:
        return image, kept, near
    filler = dilate.Fill(near, FILL_RINGS)
    if mean is None:
        return _mirror(filler.apply(image), source), kept, near
    # `Fill.apply` with the page's mean for the texels out of reach
    flat = image.reshape((-1, image.shape[2]))
    reached = filler.source >= 0
    flat[filler.empty[reached]] = flat[filler.source[reached]]
    flat[filler.empty[~reached]] = mean
    return _mirror(image, source), kept, near


def _mirror(image: np.ndarray, source: np.ndarray) -> np.ndarray:
    """`image` `(h, w, c)` (changed in place and returned) where each masked texel within
    MIRROR_RINGS of a chart texel `source` `(h, w)` takes the value of the texel mirrored through
    its nearest chart texel (point reflection: 2·nearest − itself), if that one is a chart texel.
    Next to a chart the filter then sees the chart's own noise continued, not a smooth band it
    keeps as an edge (bench/denoise_fill.py). It reads only texels within MIRROR_RINGS rows, so a
    band's rows get the whole page's bits."""
    h, w = source.shape
    nearest = dilate.nearest_source(source, MIRROR_RINGS).reshape(-1)
    empty = np.flatnonzero((nearest >= 0) & ~source.reshape(-1))
    ey, ex = np.divmod(empty, w)
    ny, nx = np.divmod(nearest[empty], w)
    my, mx = 2 * ny - ey, 2 * nx - ex
    inside = (my >= 0) & (my < h) & (mx >= 0) & (mx < w)
    mirrored = np.where(inside, my * w + mx, 0)
    inside &= source.reshape(-1)[mirrored]
    flat = image.reshape((h * w, image.shape[2]))
    flat[empty[inside]] = flat[mirrored[inside]]
    return image


def _box_sum(
    image: np.ndarray, r: int, seed: np.ndarray | None = None, keep: int | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Sum of `image` `(h, w, c)` over the (2r + 1)² box around each texel (zero outside),
    float64, one channel at a time (memory: a few channel images); and, with `keep`, the column
    sums `(c, w)` of rows 0..keep (the summed-area table's, so None without it).

    `seed` `(c, w)`: the image is rows of a larger one, and these are the column sums of its rows
    above: the summed-area table then continues the larger one's, the same additions in the same
    order, so a row r texels or more inside the rows has the bits the larger image gives it."""
    h, w = image.shape[:2]
    out = np.empty(image.shape, np.float64)
    kept = None if keep is None else np.empty((image.shape[2], w), np.float64)
    c = np.zeros((h + 1, w + 1))
    y0, y1 = np.clip(np.arange(h) - r, 0, h), np.clip(np.arange(h) + r + 1, 0, h)
    x0, x1 = np.clip(np.arange(w) - r, 0, w), np.clip(np.arange(w) + r + 1, 0, w)
    for k in range(image.shape[2]):
        if seed is None:
            column = np.cumsum(image[..., k], axis=0, dtype=np.float64)
            np.cumsum(column, axis=1, out=c[1:, 1:])
            if kept is not None and keep is not None:
                kept[k] = column[keep]
        else:
            column = np.cumsum(np.concatenate([seed[k][None], image[..., k]]), axis=0, dtype=np.float64)
            np.cumsum(column, axis=1, out=c[:, 1:])
            if kept is not None and keep is not None:
                kept[k] = column[keep + 1]
        del column
        out[..., k] = c[y1][:, x1] - c[y0][:, x1] - c[y1][:, x0] + c[y0][:, x0]
    return out, kept
