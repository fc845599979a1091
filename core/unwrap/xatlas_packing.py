"""xatlas packing, run in the xatlas child processes (`xatlas_worker`) and by the parent that
drives the fitting (`packing._fit`): `pack` places the charts of several meshes at one density
with xatlas's UV-mesh packer, `fit` searches the largest density at which they fit the atlas.
Charts as in `xatlas_worker` (per mesh: chart (T,) int32, corner (T, 3) int32, uv (U, 2) float32
in metres). No bpy, no package imports: the worker imports it from its own folder when it runs
as a script; numpy and xatlas are imported inside the functions, after the worker has set up
sys.path."""

#: Fitting (`fit`): rounds before giving up on fitting the charts into the atlas. Every round
#: packs as many densities as `fit` is given first fills (one or two, chosen by the charts' size:
#: `packing._fit`), whatever runs them (side by side in two children, or one after the other in
#: one): the densities tried depend on the charts, the resolution and the padding alone, never on
#: the cores, the machine's load or the clock, so the same unwrap gives the same atlas anywhere.
PACK_ROUNDS = 12
#: First densities tried when two are packed a round: those at which the charts' padded bounding
#: boxes would cover these shares of the atlas (`box_density`); one a round: their mean.
FIRST_FILL = (0.95, 0.75)
#: After a round where every density spilled, the next packs at `_shrunk` of the smallest and,
#: two a round, also at SECOND_TRY times that.
SHRINK_MARGIN, SHRINK_MIN, SECOND_TRY = 0.985, 0.98, 0.95
#: Once a density fits, up to REFINE_ROUNDS rounds follow at densities between it and the
#: smallest that spilled (or REFINE_REACH times it), until those two are within REFINE_TOLERANCE
#: of each other. Always run, however long the packs take: the artist gets the densest atlas the
#: search finds, the same on every run, for a few more packs (their cost:
#: bench/results/unwrap.md). No clock is read: a time limit made a busy machine's atlas coarser
#: than a quiet one's (issue 58).
REFINE_ROUNDS, REFINE_REACH, REFINE_TOLERANCE = 3, 1.15, 0.015
#: Pack input units per texel at the first density: large, so that no triangle with any area
#: falls under xatlas's zero-area threshold (FLT_EPSILON in input units), which would drop it.
PACK_UNITS_PER_TEXEL = 1024.0
_NONE = 0xFFFFFFFF
_ATLASES: list = []  # every Atlas (and its input arrays) stays alive until os._exit: no destructor runs


def _signed_area(uv):
    """Signed area (t,) of UV triangles `(t, 3, 2)`, positive counter-clockwise."""
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def pack(charts, texels_per_metre, resolution, padding, units):
    """Pack the charts of several meshes, [(chart, corner, uv)], at texels_per_metre into one
    atlas of resolution² (0: an atlas as large as the charts need). Returns {"fits": False,
    "spilled": share of the used area that went to further atlases} when they did not fit, else
    {"fits": True, "width", "height" (the atlas size), "uv": [(T, 3, 2) float32 per mesh in
    [0, 1]²], "mesh_charts": [charts per mesh], "charts", "utilisation"}. units: pack input units
    per metre (see PACK_UNITS_PER_TEXEL)."""
    import numpy as np

    inputs = [_uv_mesh(chart, corner, uv, units) for chart, corner, uv in charts]
    atlas = _pack_once(inputs, texels_per_metre / units, resolution, padding)
    if resolution and atlas.atlas_count > 1:
        used = np.array([atlas.get_utilization(i) for i in range(atlas.atlas_count)])
        return {"fits": False, "spilled": float(used[1:].sum()) / max(float(used.sum()), 1e-30)}
    return _result(atlas, inputs)


def fit(pack_at, boxes, resolution, padding, fills, progress=None):
    """Search the largest density (texels per metre) at which the charts fit one resolution²
    atlas. pack_at(densities, units) packs the charts at each density (`pack`) and returns the
    results in order (in parallel or not: the search does not depend on it); boxes (C, 2): the
    charts' bounding boxes in metres. Rounds of len(fills) densities, largest first: first at
    the densities whose padded boxes fill `fills` of the atlas; while all spilled, at the
    smallest shrunk by the share of its used area that spilled; once one fits, evenly (in log
    scale) between the best that fit and the smallest that spilled (see the constants above).
    Returns the best fitting pack result plus "texels_per_metre", "packs" and "tries" [(density,
    fitted)], or {"fits": False, "tries"}."""
    import numpy as np

    n = len(fills)
    tries = [box_density(boxes, resolution, padding, fill) for fill in fills]
    units = tries[0] * PACK_UNITS_PER_TEXEL
    best, spilled, log, refined = None, np.inf, [], 0
    for round_ in range(PACK_ROUNDS + REFINE_ROUNDS):
        if progress:
            progress(min(round_ / 4, 0.9), f"xatlas: packing at {tries[0]:.4g} texels/m")
        results = pack_at(tries, units)
        log += [(float(t), bool(r["fits"])) for t, r in zip(tries, results)]
        for t, r in zip(tries, results):
            if r["fits"] and (best is None or t > best[0]):
                best = (t, r)
            elif not r["fits"]:
                spilled = min(spilled, t)
        if best is None:
            if round_ + 1 >= PACK_ROUNDS:
                break
            t = _shrunk(boxes, padding, tries[-1], results[-1]["spilled"])
            tries = [t, t * SECOND_TRY][:n]
            continue
        upper = spilled if np.isfinite(spilled) else best[0] * REFINE_REACH
        if upper <= best[0] * (1.0 + REFINE_TOLERANCE) or refined >= REFINE_ROUNDS:
            return dict(best[1], texels_per_metre=float(best[0]), packs=len(log), tries=log)
        tries = [best[0] * (upper / best[0]) ** ((n - k) / (n + 1)) for k in range(n)]  # largest first
        refined += 1
    return {"fits": False, "tries": log}


def chart_boxes(charts):
    """(total UV area in m², bounding boxes (C, 2) in metres, width and height, of every chart)
    of the charts [(chart, corner, uv)] of several meshes; each chart starts at (0, 0)."""
    import numpy as np

    area, boxes = 0.0, [np.zeros((0, 2))]
    for chart, corner, uv in charts:
        live = chart >= 0
        if not live.any():
            continue
        uv = uv.astype(np.float64)
        area += float(np.abs(_signed_area(uv[corner[live]])).sum())
        vertex_chart = np.zeros(len(uv), dtype=np.int64)
        vertex_chart[corner[live].ravel()] = np.repeat(chart[live], 3)
        box = np.zeros((int(chart.max()) + 1, 2))
        np.maximum.at(box, vertex_chart, uv)
        boxes.append(box)
    return area, np.concatenate(boxes)


def box_density(boxes, resolution, padding, fill):
    """Texels per metre at which the charts' bounding boxes (C, 2) in metres, each grown by its
    padding on both sides and a texel, cover `fill` of a resolution² atlas (see `box_area`).
    None when the padding alone needs that much."""
    return _density_for_area(boxes, padding, fill * resolution * resolution)


def box_area(boxes, padding, t):
    """Texels covered by the charts' bounding boxes (C, 2) at t texels per metre, each grown by
    its padding on both sides and a texel: Σ (w·t + q)(h·t + q), q = 2·padding + 2."""
    q = 2.0 * padding + 2.0
    return float(((boxes[:, 0] * t + q) * (boxes[:, 1] * t + q)).sum())


def _density_for_area(boxes, padding, texels):
    """The density t ≥ 0 at which `box_area` is `texels` (the positive root of a quadratic in
    t), or None when even t = 0 needs more."""
    import numpy as np

    q = 2.0 * padding + 2.0
    a = float((boxes[:, 0] * boxes[:, 1]).sum())
    b = q * float(boxes.sum())
    c = len(boxes) * q * q - texels
    if c >= 0 or a <= 0:
        return None
    return float((-b + np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a))


def _shrunk(boxes, padding, t, spilled):
    """The density to try after t spilled a share `spilled` of its used area into further
    atlases: where the padded boxes cover (1 - spilled)·SHRINK_MARGIN² of what they cover at t
    (so the padding, which does not shrink with t, is accounted for), and t·SHRINK_MIN at most."""
    target = max(1.0 - spilled, 0.25) * SHRINK_MARGIN**2 * box_area(boxes, padding, t)
    shrunk = _density_for_area(boxes, padding, target)
    return min(t * SHRINK_MIN, shrunk if shrunk is not None else 0.5 * t)


def _uv_mesh(chart, corner, uv, units):
    """xatlas UV-mesh arrays of one mesh's charts: (uv (U, 2) float32 in pack units, live corner
    indices (L, 3) uint32, chart per live triangle (L, 1) uint32 as the 'material' that keeps
    charts apart, live triangle mask (T,), corner (T, 3), uv in metres)."""
    import numpy as np

    live = chart >= 0
    return {
        "uv": np.ascontiguousarray(uv.astype(np.float64) * units, dtype=np.float32),
        "indices": np.ascontiguousarray(corner[live], dtype=np.uint32),
        "materials": np.ascontiguousarray(chart[live, None], dtype=np.uint32),
        "live": live,
        "corner": corner,
        "chart": chart,
    }


def _pack_once(inputs, texels_per_unit, resolution, padding):
    import xatlas

    atlas = xatlas.Atlas()
    _ATLASES.append((atlas, inputs))
    for m in inputs:
        atlas.add_uv_mesh(m["uv"], m["indices"], m["materials"])
    options = xatlas.PackOptions()
    options.padding = int(padding)
    options.bilinear = True
    options.texels_per_unit = float(texels_per_unit)
    options.resolution = int(resolution)
    atlas.generate(pack_options=options)
    return atlas


def _result(atlas, inputs):
    import numpy as np

    uv, mesh_charts = [], []
    for k, m in enumerate(inputs):
        _, _, out = atlas[k]
        _, vertex_chart = atlas.get_mesh_vertex_assignment(k)
        vertex_uv = _place_dropped_vertices(
            out.astype(np.float64),
            m["uv"].astype(np.float64),
            np.where(vertex_chart == _NONE, -1, vertex_chart.astype(np.int64)),
            m["corner"][m["live"]],
        )
        corners = np.zeros(m["corner"].shape + (2,), dtype=np.float32)
        corners[m["live"]] = vertex_uv[m["corner"][m["live"]]]
        uv.append(corners)
        mesh_charts.append(int(atlas.get_mesh_chart_count(k)))
    return {
        "fits": True,
        "width": int(atlas.width),
        "height": int(atlas.height),
        "uv": uv,
        "mesh_charts": mesh_charts,
        "charts": int(atlas.chart_count),
        "utilisation": float(atlas.get_utilization(0)),
    }


def _place_dropped_vertices(out, uv_in, vertex_chart, corner):
    """Packed UVs `(U, 2)` with the vertices xatlas left out (only on triangles too small for
    it, which it drops) moved by the same affine map as the packed chart they touch, so such
    triangles stay in place and every loop of the vertex keeps one UV. `vertex_chart` (U,) is
    xatlas's packed chart per vertex (-1: left out); corner (L, 3) the triangles packed."""
    import numpy as np

    used = np.zeros(len(out), dtype=bool)
    used[corner.ravel()] = True
    missing = used & (vertex_chart < 0)
    if not missing.any():
        return out
    chart = vertex_chart.copy()
    for _ in range(16):  # spread chart ids to left-out corners of the same triangle
        tri = chart[corner].max(axis=1)
        fill = (chart[corner] < 0) & (tri[:, None] >= 0)
        if not fill.any():
            break
        chart[corner[fill]] = np.broadcast_to(tri[:, None], corner.shape)[fill]
    out = out.copy()
    out[(chart < 0) & missing] = 0.0  # a chart xatlas dropped whole: it has no area
    todo = missing & (chart >= 0)
    if todo.any():
        known = (vertex_chart >= 0) & np.isin(vertex_chart, np.unique(chart[todo]))
        maps, centre = _affine_fits(uv_in[known], out[known], vertex_chart[known])
        x = np.column_stack([uv_in[todo] - centre[chart[todo]], np.ones(todo.sum())])
        out[todo] = np.einsum("ni,nij->nj", x, maps[chart[todo]])
    return out


def _affine_fits(src, dst, group):
    """Least-squares affine maps taking src (n, 2) to dst (n, 2) per group id: (maps (G, 3, 2)
    acting on [src - centre, 1], centre (G, 2) of each group's src points)."""
    import numpy as np

    n = int(group.max()) + 1
    count = np.maximum(np.bincount(group, minlength=n), 1)
    centre = np.stack([np.bincount(group, weights=src[:, k], minlength=n) for k in range(2)], axis=1)
    centre /= count[:, None]
    x = np.column_stack([src - centre[group], np.ones(len(src))])
    xtx = np.zeros((n, 3, 3))
    xty = np.zeros((n, 3, 2))
    np.add.at(xtx, group, x[:, :, None] * x[:, None, :])
    np.add.at(xty, group, x[:, :, None] * dst[:, None, :])
    return np.linalg.pinv(xtx) @ xty, centre
