"""The stitch stage's second half, on an HHD/AHD atlas's encoded layers (`stitch_encoded`): the
encoding is not linear in the SH, so a stitched SH seam reopens a little in the preview; this
closes it as the preview reads it. No bpy."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ... import parallel
from ...encoding import hhd as hhd_spec
from ...progress import ticker
from .geometry import Seams
from .metrics import _brief, _metric, recorded
from .reads import _Stacked, bilinear, hhd_reader, hidden_texels, reads_hidden
from .solve import _solve, _system

if TYPE_CHECKING:
    from ...encoding import EncodedAtlas

#: `stitch_encoded` stitches the packed direction only where its two sides' reads differ by at
#: most this much (each coordinate): farther apart, the two reads straddle the octahedral fold.
FOLD_GAP = 0.25


def stitch_encoded(
    atlas: EncodedAtlas,
    seams: Seams,
    coverage: np.ndarray,
    check=None,
    threads: int = 0,
    window=None,
) -> tuple[EncodedAtlas, dict]:
    """Least-squares seam stitching of an HHD/AHD atlas's encoded layers, as the preview filters
    them: I_z, w_a and the octahedral direction (packed: the GPU interpolates the packed values),
    each read bilinearly on both sides of every seam sample and made equal, the texels pulled
    towards their encoded values (covered texels, `coverage (H, W)` > 0, firmly; gutter and
    buried ones weakly; hidden samples, `reads_hidden`, left out). After the SH
    stitch the encoding's non-linearity (each texel's own n_v in I_z, the fitted w_a and d)
    leaves a small step; this closes it for every shading normal. The direction is stitched only
    at samples whose two packed reads lie within FOLD_GAP of each other (across the octahedral
    fold, packed values of nearby directions are far apart and averaging them would be wrong).
    Values stay in range (I_z ≥ 0, w_a in [0, 1], packed direction in [-1, 1]).
    Returns the atlas with the encoding file's images replaced, and a record: enabled, texels
    (changed), iterations, seconds, and the HHD-read `seam_metric` before and after.
    `window` (`stages.Window`): the images and `coverage` are that rectangle of the atlas
    `seams` are of (`TexelData.window`). `atlas` is this stage's (`core.memory`): the stitched
    texels are written into its own images, after the "before" measure."""
    start = time.perf_counter()
    tick = ticker(check)
    atlas_seams, seams = seams, seams.within(window)
    if len(seams) == 0:  # nothing to stitch: the same atlas and record, without the image copies
        nothing = _brief(_metric(lambda xy: None, seams))  # type: ignore[arg-type]
        record0 = {"enabled": True, "texels": 0, "iterations": 0, "before": nothing, "after": dict(nothing)}
        return atlas, {**record0, "seconds": time.perf_counter() - start}
    key = atlas.encoding_file.key
    spec, images = atlas.files[key]
    weights = hhd_spec.WA.exr_names + hhd_spec.WA_RGB.exr_names
    names = [n for n in hhd_spec.IZ.exr_names + weights if n in images]
    directions = hhd_spec.DIRECTION.exr_names
    h, w = images[names[0]].shape
    cover = np.asarray(coverage).reshape(-1)
    out = dict(images)  # the stitched layers: the atlas's own images, written into
    model = atlas.settings.get("model", "hhd")
    shown = ~reads_hidden(seams, hidden_texels(np.asarray(coverage)))
    visible = recorded(atlas_seams.select(shown))
    measure, *solves, after = tick.split([0.1, 0.4, 0.4, 0.1])
    measure.at(0.0, "measuring the seams")
    before = _metric(hhd_reader(images, model).placed(window), visible, worst=0)
    packed = _Stacked([images[n] for n in directions], np.float64)
    gap = np.abs(bilinear(packed, seams.a) - bilinear(packed, seams.b)).max(axis=1)
    iterations, changed = 0, np.zeros(h * w, bool)
    workers = parallel.resolve_threads(threads)
    layers: list[tuple[list[str], np.ndarray]] = [(list(names), shown), (list(directions), shown & (gap <= FOLD_GAP))]
    for part, (layer, use) in zip(solves, layers):
        part.at(0.0, "setting up")
        prior = _Stacked([images[n] for n in layer], np.float64)  # read where the system reads (memory)
        system = _system(seams, cover, prior, use)
        delta, k = _solve(system, prior, part, workers)
        iterations = max(iterations, k)
        new = prior[system.texels] + delta
        at = np.divmod(system.texels, w)  # (row, column): the images may be strided views
        for i, n in enumerate(layer):
            low, high = (-1.0, 1.0) if n in directions else (0.0, 1.0 if n in weights else np.inf)
            values = np.clip(new[:, i], low, high).astype(out[n].dtype)
            changed[system.texels] |= values != out[n][at]
            out[n][at] = values
    files = dict(atlas.files)
    files[key] = (spec, out)
    after.at(0.0, "measuring the seams")
    record = {
        "enabled": True,
        "texels": int(np.count_nonzero(changed)),
        "iterations": iterations,
        "before": _brief(before),
        "after": _brief(_metric(hhd_reader(out, model).placed(window), visible, worst=0)),
        "seconds": time.perf_counter() - start,
    }
    return replace(atlas, files=files), record
