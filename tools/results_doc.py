"""docs/results.md and the README's headline table, generated from bench/results/*.json.

    python tools/results_doc.py            # write docs/results.md and the README block (make results)
    python tools/results_doc.py --check    # exit 1 if either is out of date

Every file of bench/results appears in docs/results.md: each JSON as tables (a renderer per bench
family, `generic` for a JSON no family claims), the bench's own Markdown reports and plots as
links. A file belongs to the family whose stem is the longest prefix of its name. The README's
block between HEADLINE_BEGIN and HEADLINE_END is rewritten from time_to_error.json and
memory.json. The output depends on the files only (no clock, sorted where order is free).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
DOC = ROOT / "docs" / "results.md"
README = ROOT / "README.md"
#: bench/results as a link from docs/
LINK_BASE = "../bench/results/"
HEADLINE_BEGIN = "<!-- results:headline -->"
HEADLINE_END = "<!-- /results:headline -->"
#: the time-to-error scenes the README's headline shows, in its order
HEADLINE_SCENES = ("classroom", "field", "staircase2", "bedroom")
LEVELS = ("0.2", "0.1", "0.05")

Lines = list[str]


# -- formatting ------------------------------------------------------------------------------


def num(x, digits: int = 1) -> str:
    """x with `digits` decimals; "—" for None or NaN; never "-0.0"."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    text = f"{x:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def pct(x, digits: int = 1) -> str:
    """The fraction x as a percentage with `digits` decimals (no % sign); "—" for None."""
    return "—" if x is None else num(100 * x, digits)


def percent(x, digits: int = 2) -> str:
    """x, already in percent, as "1.23%"; "—" for None."""
    return "—" if x is None else f"{num(x, digits)}%"


def secs(x) -> str:
    """Seconds with 2, 1 or 0 decimals by size; "—" for None."""
    if x is None:
        return "—"
    return num(x, 2 if x < 10 else 1 if x < 100 else 0)


def times(x, digits: int = 2) -> str:
    """A ratio as "2.36×"; "—" for None."""
    return "—" if x is None else f"{num(x, digits)}×"


def mega(x, digits: int = 2) -> str:
    """x in millions."""
    return "—" if x is None else num(x / 1e6, digits)


def gb(mb) -> str:
    """Megabytes (2^20 bytes, as the benches record them) as GB of 2^30 bytes, 2 decimals."""
    return "—" if mb is None else num(mb / 1024, 2)


def span(values, fmt: Callable = num) -> str:
    """The range of `values` as "lo–hi" (one value if they agree); "—" if empty."""
    values = [v for v in values if v is not None]
    if not values:
        return "—"
    lo, hi = fmt(min(values)), fmt(max(values))
    return lo if lo == hi else f"{lo}–{hi}"


def count(n) -> str:
    """An integer with thousands separators."""
    return "—" if n is None else f"{int(n):,}"


def short(n) -> str:
    """A count as 104k / 1.0M."""
    if n >= 1e6:
        return f"{n / 1e6:.1f}M"
    return f"{n / 1e3:.0f}k" if n >= 1e4 else count(n)


def cell(x) -> str:
    """A table cell: text with pipes escaped and newlines flattened."""
    return str(x).replace("|", "\\|").replace("\n", " ")


def table(header, rows) -> Lines:
    """A Markdown table, then a blank line."""
    out = ["| " + " | ".join(cell(h) for h in header) + " |", "|" + " --- |" * len(header)]
    out += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    return out + [""]


def link(name: str) -> str:
    """A Markdown link from docs/ to bench/results/NAME."""
    return f"[`{name}`]({LINK_BASE}{name})"


def load_average(value) -> str:
    """A load-average triple (or one number) as its first value, "—" if absent."""
    if value is None:
        return "—"
    return num(value[0] if isinstance(value, list) else value, 1)


def run_line(name: str, date=None, **settings) -> Lines:
    """The line naming the run a table comes from: the file, its stored date, its settings."""
    parts = [f"date {date}" if date else "no date stored"]
    parts += [f"{k.replace('_', ' ')} {v}" for k, v in settings.items() if v not in (None, "", [])]
    return [f"Run: {link(name)}; " + "; ".join(parts) + ".", ""]


# -- time to error (bench/time_to_error.py) ---------------------------------------------------


def level_cell(entry: dict, level: str) -> str:
    """Time to `level` as "Cycles/ours× (ours / Cycles s)", or why there is no ratio."""
    t = entry["time_to_error"].get(level) or {}
    ours, cycles = t.get("ours"), t.get("cycles")
    if ours and cycles:
        return f"{times(cycles / ours)} ({secs(ours)} / {secs(cycles)} s)"
    below = {side: min(r["rmse"] for r in entry[side]) < float(level) for side in ("ours", "cycles")}
    start = {side: min(entry[side], key=lambda r: r["samples"])["rmse"] < float(level) for side in ("ours", "cycles")}
    if start["ours"] and start["cycles"]:
        return "both start below"
    most = max(r["samples"] for r in entry["ours"] + entry["cycles"])
    if not below["ours"] and not below["cycles"]:
        return f"neither within {most} spp"
    if ours:
        return f"ours {secs(ours)} s; Cycles " + ("starts below" if start["cycles"] else "not reached")
    if cycles:
        return f"Cycles {secs(cycles)} s; ours " + ("starts below" if start["ours"] else "not reached")
    return "—"


def tte_headline(data: dict) -> Lines:
    """The README's table: time to each error level per headline scene."""
    rows = []
    for name in HEADLINE_SCENES:
        e = data.get(name)
        if e:
            rows.append([name, short(e["triangles"]), short(e["texels"])] + [level_cell(e, lv) for lv in LEVELS])
    header = ["scene", "triangles", "texels"] + [f"{pct(float(lv), 0)}% I_z error" for lv in LEVELS]
    return table(header, rows)


def render_time_to_error(name: str, data: dict) -> Lines:
    """Speed, time to error and the sample rows of every scene entry."""
    entries = ordered(data, HEADLINE_SCENES)
    out = run_line(
        name,
        entries="each from its own run, which the file does not date",
        bounces="3 unless the entry's name says otherwise",
        atlas="512² unless the entry's name says otherwise",
    )
    out += ["Speed and per-sample noise (our rays/s and texel-samples/s at the most samples):", ""]
    rows = []
    for key in entries:
        e = data[key]
        last = e["ours"][-1]
        v = e.get("variance_per_sample", {}).values()
        sy = e.get("systematic") or {}
        rows.append(
            [
                key,
                count(e["triangles"]),
                count(e["texels"]),
                mega(e["raw_rays_per_s"], 1),
                f"{mega(last['rays_per_s'])} ({pct(last['rays_per_s'] / e['raw_rays_per_s'], 0)}%)",
                mega(last["texel_samples_per_s"]),
                span([x["variance"] for x in v], lambda x: num(x, 2)),
                span([x["rate"] for x in v], lambda x: num(x, 1)),
                f"{pct(sy.get('rmse'))}% / {num(sy.get('mean_ratio'), 3)} / {pct(sy.get('top_percent_share'), 0)}%",
                e["reference"]["samples"],
                load_average(e.get("load_average")),
            ]
        )
    out += table(
        [
            "entry",
            "triangles",
            "texels",
            "raw embreex M rays/s",
            "our M rays/s (% of raw)",
            "our M texel-samples/s",
            "per-sample variance ours / Cycles",
            "texel-sample rate ours / Cycles",
            "converged ours vs Cycles: RMS / mean ratio / share in top 1%",
            "Cycles reference spp",
            "load",
        ],
        rows,
    )
    out += ["Time to each I_z error level, Cycles' time over ours (ours / Cycles seconds):", ""]
    rows = [[key] + [level_cell(data[key], lv) for lv in LEVELS] for key in entries]
    out += table(["entry"] + [f"{pct(float(lv), 0)}%" for lv in LEVELS], rows)
    out += ["Every sample count (I_z error %, each engine against its own reference, its noise removed):", ""]
    rows = []
    for key in entries:
        e = data[key]
        theirs = {r["samples"]: r for r in e["cycles"]}
        for r in e["ours"]:
            c = theirs.get(r["samples"], {})
            against = (r.get("against_cycles") or {}).get("rmse")
            rows.append(
                [key, r["samples"], secs(r["seconds"]), pct(r["rmse"]), secs(c.get("seconds")), pct(c.get("rmse"))]
                + [pct(against)]
            )
    header = ["entry", "spp", "ours s", "ours error %", "Cycles s", "Cycles error %", "ours vs Cycles' reference %"]
    return out + table(header, rows)


def ordered(data: dict, first) -> list[str]:
    """The keys of data: those of `first` in its order, then the rest sorted."""
    return [k for k in first if k in data] + sorted(k for k in data if k not in first)


# -- tradeoff and presets (bench/tradeoff.py) ------------------------------------------------


def tradeoff_rows(data: dict) -> list[tuple[str, str]]:
    """(knob, label) of every row, in the first scene's order."""
    seen: list[tuple[str, str]] = []
    for scene in data["scenes"].values():
        for r in scene["rows"]:
            if (r["knob"], r["label"]) not in seen:
                seen.append((r["knob"], r["label"]))
    return seen


def find_row(scene: dict, knob: str, label: str) -> dict:
    """The scene's row of (knob, label), {} if it has none."""
    return next((r for r in scene["rows"] if r["knob"] == knob and r["label"] == label), {})


def render_tradeoff(name: str, data: dict) -> Lines:
    """Scenes, every knob, denoising pairs, adaptive stopping, encoders, memory."""
    s, scenes = data["settings"], data["scenes"]
    base = ", ".join(f"{k.replace('_', ' ')} {value_text(v)}" for k, v in data["base"].items())
    out = run_line(name, s.get("date"), reference=f"{s['reference_samples']} spp", cycles=f"{s['cycles_samples']} spp")
    out += [f"Base setting of every knob: {base}.", ""]
    rows = []
    for sc, d in scenes.items():
        ref = d["reference"]
        rows.append(
            [sc, count(d["texels"]), num(d["density"], 0), secs(ref["seconds"]), num(d["iz_noise_floor"], 2)]
            + [num(ref["image_rmse"]), secs(d["cycles_seconds"]), num(d["cycles_noise_floor"])]
        )
    out += table(
        ["scene", "texels", "texels/m", "reference s", "reference's own I_z noise %"]
        + ["reference image %", "Cycles render s", "Cycles render's noise %"],
        rows,
    )
    runs = {r.get("run") for d in scenes.values() for r in d["rows"]}
    extra = ["run"] if len(runs) > 1 else []
    out += ["Every knob: time s / I_z error % / image error % (— where not measured):", ""]
    rows = []
    for knob, label in tradeoff_rows(data):
        if knob == "encoder":
            continue
        found = [find_row(d, knob, label) for d in scenes.values()]
        cells = [f"{secs(r.get('seconds'))} / {num(r.get('iz_rmse'))} / {num(r.get('image_rmse'))}" for r in found]
        rows.append([knob, label, *cells] + ([found[0].get("run", "—")] if extra else []))
    out += table(["knob", "setting", *scenes] + extra, rows)
    out += denoise_pairs(scenes)
    out += ["Adaptive stopping and time budget against fixed sample counts at the same bounces:", ""]
    rows = []
    for sc, items in data.get("adaptive", {}).items():
        for a in items:
            fixed = ("~" if a.get("extrapolated") else "") + secs(a.get("fixed_seconds_same_error"))
            rows.append(
                [sc, a["label"], secs(a["seconds"]), num(a["mean_samples"], 0), num(a["iz_rmse"])]
                + [fixed, times(a.get("speedup"))]
            )
    out += table(["scene", "setting", "s", "mean spp", "I_z %", "fixed counts: s to the same error", "speed-up"], rows)
    out += ["Encoders on the reference SH: hemispherical error % / encode s / re-encode s:", ""]
    rows = []
    for knob, label in tradeoff_rows(data):
        if knob == "encoder":
            found = [find_row(d, knob, label) for d in scenes.values()]
            rows.append([label] + [encoder_cell(r) for r in found])
    out += table(["encoder", *scenes], rows)
    out += ["Peak memory of the numpy allocations (MB) by texel density:", ""]
    rows = [
        [key]
        + [
            f"{count(d['memory'][key]['texels'])} texels: {num(d['memory'][key]['peak_memory_mb'], 0)}"
            for d in scenes.values()
        ]
        for key in next(iter(scenes.values())).get("memory", {})
    ]
    return out + table(["density × (or denoise)", *scenes], rows)


def encoder_cell(r: dict) -> str:
    """An encoder row: hemispherical error % on the reference SH / encode s / re-encode s."""
    return (
        f"{num(r.get('hemispherical_rmse_of_reference'), 2)} / {secs(r.get('encode_seconds'))} / "
        f"{secs(r.get('reencode_seconds'))}"
    )


def denoise_pairs(scenes: dict) -> Lines:
    """I_z error raw → denoised at equal samples and bounces, with the denoise stage's seconds."""
    first = next(iter(scenes.values()))
    pairs = []
    for r in first["rows"]:
        if r["knob"] != "denoise":
            continue
        raw = [
            x
            for x in first["rows"]
            if not x["denoise"]
            and x["knob"] in ("samples", "bounces", "samples × bounces")
            and (x["samples"], x["bounces"]) == (r["samples"], r["bounces"])
        ]
        if raw:
            pairs.append((raw[0]["knob"], raw[0]["label"], r["label"]))
    rows = []
    for knob, raw_label, label in pairs:
        cells = []
        for d in scenes.values():
            raw, den = find_row(d, knob, raw_label), find_row(d, "denoise", label)
            cells.append(
                f"{num(raw.get('iz_rmse'))} → {num(den.get('iz_rmse'))} ({secs(den.get('denoise_seconds'))} s)"
            )
        rows.append([label.removesuffix(" denoised"), *cells])
    if not rows:
        return []
    head = ["What denoising buys: I_z error % raw → denoised at equal samples (denoise stage s):", ""]
    return head + table(["setting", *scenes], rows)


def render_presets(name: str, data: dict) -> Lines:
    """Each preset's knobs and its measurements per scene."""
    scenes = sorted({sc for p in data.values() for sc in p["per_scene"]}, key=["outdoor", "interior", "emissive"].index)
    out = run_line(name, written_by="bench/tradeoff.py from tradeoff.json; core/presets.py must match (a test)")
    rows = []
    for preset, p in data.items():
        cells = []
        for sc in scenes:
            m = p["per_scene"].get(sc, {})
            cells.append(
                f"{secs(m.get('seconds'))} / {num(m.get('iz_rmse'))} / {num(m.get('image_rmse'))} / "
                f"{num(m.get('peak_memory_mb'), 0)}"
            )
        on = "on" if p["denoise"] else "off"
        rows.append([preset.title(), f"{num(p['level'], 0)}%", p["samples"], p["bounces"], on, *cells])
    header = ["preset", "worst-scene I_z ≤", "spp", "bounces", "denoise"]
    header += [f"{sc}: s / I_z % / image % / MB" for sc in scenes]
    return out + table(header, rows)


# -- memory (bench/memory.py) ----------------------------------------------------------------


def is_run(d) -> bool:
    """Whether d is one bench/memory.py run (it has stages and a peak)."""
    return isinstance(d, dict) and "stages" in d and "peak_rss_mb" in d


def resolve(data: dict, ref):
    """A run, or the run a string like "runs.4096_no_post.after" names in data; None if neither."""
    if not isinstance(ref, str):
        return ref
    node = data
    for part in ref.split("."):
        node = node.get(part) if isinstance(node, dict) else None
    return node


def rounds(data: dict) -> list[tuple[str, dict]]:
    """(label, runs) of memory.json's rounds in order: the top-level runs, then round2, round3 …"""
    out = [("round 1", data["runs"])] if "runs" in data else []
    numbered = sorted((k for k in data if k.startswith("round")), key=lambda k: int(k[5:]))
    return out + [(k.replace("round", "round "), data[k]["runs"]) for k in numbered]


def latest_runs(data: dict) -> dict:
    """The runs of memory.json's last round."""
    return rounds(data)[-1][1]


def stage_table(run: dict) -> Lines:
    """One run's stages: wall s, CPU s, peak and resident memory after."""
    rows = [
        [stage, secs(s["seconds"]), secs(s.get("cpu_seconds")), gb(s["peak_rss_mb"]), gb(s.get("rss_after_mb"))]
        for stage, s in run["stages"].items()
    ]
    return table(["stage", "wall s", "CPU s", "peak GB", "resident after GB"], rows)


def run_summary(run: dict) -> str:
    """A memory run's set-up in words."""
    post = "post stages on (denoise, stitch)" if run.get("denoise") else "no post stages"
    return (
        f"{run['resolution']}² atlas, {count(run['texels'])} texels, {count(run['triangles'])} triangles, "
        f"{run['samples']} spp, {run['bounces']} bounce(s), {post}; peak {gb(run['peak_rss_mb'])} GB; "
        f"load {load_average(run.get('load_average_before'))} → {load_average(run.get('load_average_after'))}"
    )


def render_memory(name: str, data: dict) -> Lines:
    """memory.json's rounds before → after and the last round's stages, or one run's stages."""
    if is_run(data):
        return run_line(name) + [run_summary(data) + ".", ""] + stage_table(data)
    out = run_line(name, scene=data.get("scene"), machine=data.get("machine"))
    rows = []
    for label, runs in rounds(data):
        for key, value in runs.items():
            pairs = value.items() if not is_run(value) else [("run", value)]
            for which, run in pairs:
                run = resolve(data, run)
                if is_run(run):
                    rows.append(
                        [label, key, which, run["resolution"], "on" if run["denoise"] else "off"]
                        + [gb(run["peak_rss_mb"])]
                    )
    out += ["Peak resident memory of every run (GB):", ""]
    out += table(["round", "run", "which", "atlas", "post stages", "peak GB"], rows)
    last_label, last = rounds(data)[-1]
    for key in sorted(last):
        run = last[key].get("after") if not is_run(last[key]) else None
        if is_run(run):
            out += [f"Stages of the {last_label} run `{key}` (after): {run_summary(run)}.", ""] + stage_table(run)
    return out


# -- denoising (bench/denoise*.py) ------------------------------------------------------------


def time_cell(t: dict) -> str:
    """A time-to-error entry: seconds, "~s (extrap.)" or "not reached (best x%)"."""
    if t.get("seconds") is None:
        return f"not reached (best {num(t.get('best'))}%)" if t.get("best") is not None else "not reached"
    return ("~" if t.get("how") == "extrapolated" else "") + secs(t["seconds"]) + " s"


def speedup_cell(s: dict) -> str:
    """A speed-up entry with its flags."""
    if s.get("speedup") is None:
        return "—"
    flags = [f for f in s.get("flags", []) if f]
    return times(s["speedup"]) + (f" ({', '.join(flags)})" if flags else "")


def denoise_rows(scene: dict) -> Lines:
    """Every method at every sample count: s / error % (noise removed) / bias %."""
    rows_of = scene["rows"]
    methods = list(rows_of)
    spps = sorted({r["samples"] for rows in rows_of.values() for r in rows})
    rows = []
    for spp in spps:
        cells = []
        for m in methods:
            r = next((x for x in rows_of[m] if x["samples"] == spp), None)
            if r is None:
                cells.append("")
                continue
            den = f" ({secs(r['denoise_seconds'])})" if r.get("denoise_seconds") is not None else ""
            cells.append(f"{secs(r['seconds'])}{den} / {num(r['rmse_corrected'])} / {num(r['bias'], 2)}")
        rows.append([spp, *cells])
    return table(["spp"] + [f"{m}: s (denoise s) / error % / bias %" for m in methods], rows)


def denoise_levels(scene: dict) -> Lines:
    """Time to each level per method and the speed-ups, against each engine's own reference."""
    tte = scene["time_to_error"]
    methods = list(next(iter(tte.values()))["times"])
    pairs = list(next(iter(tte.values()))["speedups"])
    rows = [
        [f"{pct(float(lv), 0)}%"]
        + [time_cell(tte[lv]["times"][m]) for m in methods]
        + [speedup_cell(tte[lv]["speedups"][p]) for p in pairs]
        for lv in tte
    ]
    return table(["level", *methods, *pairs], rows)


def render_denoise(name: str, data: dict) -> Lines:
    """Per scene: references, every row, time to error, the goal; the shadow-edge fixture."""
    s, oidn = data["settings"], data.get("oidn", {})
    out = run_line(
        name,
        atlas=f"{s['resolution']}², padding {s['padding']}",
        bounces=data.get("bounces"),
        OIDN=f"{oidn.get('version')} ({oidn.get('threads')} threads)",
        load=f"{load_average(data.get('load_average_start'))} → {load_average(data.get('load_average_end'))}",
        wall=f"{num(data.get('wall_seconds', 0) / 60)} min",
    )
    for sc, d in data["scenes"].items():
        ref, cref = d["reference"], d["cycles_reference"]
        out += [
            f"**{sc}**: {count(d['triangles'])} triangles, {count(d['texels'])} texels "
            f"({count(d['buried_texels'])} buried, {count(d['measured_texels'])} measured); our reference "
            f"{ref['samples']} spp ({secs(ref['seconds'])} s), its noise {num(ref['floor'], 2)}%; Cycles' "
            f"{cref['samples']} spp, its noise {num(cref['floor'], 2)}%."
            + (f" Note stored with it: {d['note']}" if d.get("note") else ""),
            "",
        ]
        out += denoise_rows(d) + denoise_levels(d)
        g = d.get("goal", {})
        verdict = "met" if g.get("met") else "not met"
        out += [
            f"Goal (ours denoised ≥ 4× sooner than ours raw to 5%, |bias| ≤ 2%): **{verdict}**; speed-up "
            f"{speedup_cell(g)}, bias where 5% is reached {percent(g.get('bias_where_reached'))}, worst |bias| "
            f"{percent(g.get('worst_abs_bias'))}.",
            "",
        ]
    if "edge" in data:
        out += edge_table(data["edge"])
    return out


def edge_table(edge: dict) -> Lines:
    """The shadow-edge fixture: edge and contact-line errors and the edge's 10–90% width."""
    rows = [
        [r["method"], r["samples"], num(r["edge"]["rmse_corrected"], 2), num(r["edge"]["bias"], 2)]
        + [num(r["contact"]["rmse_corrected"], 2), num(r["contact"]["bias"], 2), num(r["width_10_90"], 2)]
        for r in edge["rows"]
    ]
    head = [f"Shadow-edge fixture ({count(edge['texels'])} texels, reference {edge['reference']['samples']} spp):", ""]
    return head + table(
        [
            "method",
            "spp",
            "edge error %",
            "edge bias %",
            "contact error %",
            "contact bias %",
            "edge 10–90% width (texels)",
        ],
        rows,
    )


def render_denoise_fill(name: str, data: dict) -> Lines:
    """Smooth fill against the mirrored chart, per ring of texels."""
    s = data["settings"]
    out = run_line(
        name, atlas=f"{s['resolution']}²", reference=f"{s['reference']} spp", mirror_rings=data.get("mirror_rings")
    )
    rows = []
    for sc, d in data["scenes"].items():
        for r in d["rows"]:
            cells = [
                f"{num(r['raw'][k]['rmse_corrected'])} / {num(r['smooth'][k]['rmse_corrected'])} / "
                f"{num(r['mirrored'][k]['rmse_corrected'])}"
                for k in d["measured_per_subset"]
            ]
            rows.append([sc, r["samples"], *cells])
    subsets = list(next(iter(data["scenes"].values()))["measured_per_subset"])
    out += ["I_z error % (noise removed), raw / smooth fill / mirrored, per subset of texels:", ""]
    return out + table(["scene", "spp", *subsets], rows)


def render_denoise_pages(name: str, data: dict) -> Lines:
    """Each packing and clamp variant's denoised error, mean over seeds."""
    s = data["settings"]
    out = run_line(
        name,
        atlas=f"{s['resolution']}²",
        reference=f"{s['reference']} spp",
        seeds=", ".join(map(str, s["seeds"])),
        small_chart=data.get("small_chart"),
        edge_rings=data.get("edge_rings"),
        edge_clamp=data.get("edge_clamp"),
    )
    variants: list[str] = []
    rows = []
    for sc, d in data["scenes"].items():
        for r in d["rows"]:
            variants = [k for k in r if k not in ("samples", "raw")]
            cells = [num(statistics.fmean(r[v]["error"]), 2) for v in variants]
            rows.append([sc, r["samples"], num(statistics.fmean(r["raw"]), 2), *cells])
    out += ["I_z error % (noise removed), mean over the seeds:", ""]
    out += table(["scene", "spp", "raw", *variants], rows)
    rows = []
    for sc, d in data["scenes"].items():
        for v in variants:
            secs_all = [x for r in d["rows"] for x in r[v]["seconds"]]
            rows.append([sc, v, count(d["rows"][0][v]["page_texels"]), secs(statistics.median(secs_all))])
    return out + table(["scene", "variant", "page texels", "denoise s (median)"], rows)


def render_denoise_preview(name: str, data: dict) -> Lines:
    """EEVEE preview against Cycles, raw and denoised, with and without the worst 1% of pixels."""
    s = data["settings"]
    out = run_line(
        name,
        atlas=f"{s['resolution']}²",
        cycles=f"{s['cycles_samples']} spp",
        load=f"{load_average(data.get('load_average_start'))} → {load_average(data.get('load_average_end'))}",
    )
    rows = []
    for sc, d in data["scenes"].items():
        w = d["without_outliers"]
        clean = {r["samples"]: r for r in w["rows"]}
        for r in d["rows"]:
            c = clean.get(r["samples"], {})
            rows.append(
                [sc, r["samples"], f"{num(r['raw']['corrected'])} → {num(r['denoised']['corrected'])}"]
                + [f"{num(c.get('raw', {}).get('corrected'))} → {num(c.get('denoised', {}).get('corrected'))}"]
                + [f"{num(d['reference']['floor'])}", f"{pct(w['squared_error_share'], 0)}%"]
            )
    out += ["Image error % (the Cycles render's noise removed), raw → denoised:", ""]
    header = [
        "scene",
        "spp",
        "all pixels",
        "without the worst 1%",
        "reference noise %",
        "squared error in the worst 1%",
    ]
    return out + table(header, rows)


# -- seams, leaks (bench/seams.py, bench/leaks.py) -------------------------------------------------


def render_seams(name: str, data: dict) -> Lines:
    """Seam ratio before → after per scene and row, interior error, cost."""
    s = data["settings"]
    goal = data.get("goal", {})
    out = run_line(
        name,
        atlas=f"{s['resolution']}²",
        bake=f"{s['samples']} spp",
        reference=f"{s['reference']} spp",
        bounces=data.get("bounces"),
        goal=f"ratio ≤ {goal.get('ratio')}, interior ≤ {pct(goal.get('interior_worse'), 0)}% worse",
    )
    rows, inner, cost = [], [], []
    for sc, d in data["scenes"].items():
        hidden = d["rows"]["raw"]["hhd"]["before"].get("hidden", 0)
        for row, r in d["rows"].items():
            h = r["hhd"]
            rows.append(
                [sc, row, f"{count(d['seam_samples'])} ({count(hidden)})"]
                + [f"{num(h['before']['ratio'], 2)} → {num(h['after']['ratio'], 2)}"]
                + [f"{num(h['before']['tilted']['ratio'], 2)} → {num(h['after']['tilted']['ratio'], 2)}"]
                + [num(h["after_sh_stitch"]["ratio"], 2)]
            )
            if "interior_error_hhd" in r:
                i = r["interior_error_hhd"]
                inner.append(
                    [sc, row, num(i["all"]["before"], 2), num(i["all"]["after"], 2), pct(i["all"]["worse"], 2)]
                )
        c = d["cost"]
        cost.append([sc, secs(c["stitch_seconds"]), num(c["seconds_per_megatexel"], 1), count(c["stitched_texels"])])
    out += ["Seam ratio of the HHD file as the preview reads it (≤ 1: no more visible than the texel grid):", ""]
    out += table(["scene", "row", "seam samples (hidden)", "ratio", "normal tilted 30°", "SH stitch only"], rows)
    out += ["Interior I_z error % against the reference, before → after stitching:", ""]
    out += table(["scene", "row", "before", "after", "worse %"], inner)
    return out + table(["scene", "stitch s", "s per M atlas texels", "texels stitched"], cost)


def leak_pair(r: dict) -> str:
    """Leaking / darker texels, crossed ones in brackets."""
    return f"{r['leaking']} ({r['leaking_crossed']}) / {r['darker']} ({r['darker_crossed']})"


def render_leaks(name: str, data: dict) -> Lines:
    """Fixtures and shared scenes, before → after the leak fixes, and Cycles."""
    s, rule = data["settings"], data["rule"]
    out = run_line(
        name,
        scenes=f"{s['resolution']}², {s['samples']} spp ours, {s['cycles_samples']} spp Cycles",
        fixtures=f"{s['fixture_samples']} spp",
        rule=f"{rule['K']} standard errors and {pct(rule['X'], 0)}% of the local level, {rule['bounces']} bounces",
    )
    rows = [
        [fx, d["bounces"], count(d["before"]["judged"])]
        + [f"{d[w]['light']} / {d[w]['dark']}" for w in ("before", "after", "cycles")]
        for fx, d in data["fixtures"].items()
    ]
    out += ["Fixtures with an exact answer: texels leaking light / dark halo:", ""]
    out += table(["fixture", "bounces", "judged texels", "before", "after", "Cycles"], rows)
    out += ["Shared scenes against Cycles: leaking (crossed) / darker (crossed):", ""]
    rows = []
    for label, scenes in (("audit", data["scenes"]), ("re-run", data.get("reruns", {}))):
        for sc in sorted(scenes):
            d = scenes[sc]
            rows.append(
                [sc, label, count(d["compared"]), count(d["crossed_compared"])]
                + [leak_pair(d["before"]), leak_pair(d["after"]), leak_pair(d["cycles_whole_footprint"])]
            )
    out += table(["scene", "run", "compared", "crossed", "before", "after", "Cycles' own texels"], rows)
    why = [f"- {sc}: {d['why']}" for sc, d in sorted(data.get("reruns", {}).items()) if d.get("why")]
    return out + (["Re-runs, as stored:", "", *why, ""] if why else [])


# -- sampling (light_sampling, roulette, estimator) ------------------------------------------


def render_light_sampling(name: str, data: dict) -> Lines:
    """Each emitter-sampling step's per-sample variance and rate against Cycles."""
    out = run_line(name, atlas="256²")
    rows = []
    for mode in sorted(data):
        for sc, d in data[mode].items():
            ref = d["reference"]
            for r in d["rows"]:
                v, rate = r.get("variance_vs_cycles"), r.get("rate_vs_cycles")
                rows.append(
                    [mode, sc, f"{ref['samples']} ({pct(ref['floor'])}%)", r["method"], r["samples"]]
                    + [pct(r["rmse"]), num(v, 2), num(rate, 2), times(rate / v if v and rate else None)]
                )
    header = ["bounces", "scene", "Cycles reference spp (noise)", "method", "spp", "I_z error %"]
    header += ["variance / Cycles'", "rate / Cycles'", "equal error, × Cycles"]
    return out + table(header, rows)


def render_roulette(name: str, data: dict) -> Lines:
    """Each way of ending paths: variance, rays, seconds and efficiency against the first way."""
    out = run_line(name, atlas="512²")
    rows = []
    for case, d in data.items():
        for way, w in d["ways"].items():
            rows.append(
                [case, way, num(w["variance"], 3), mega(w["rays"], 1), secs(w["seconds"])]
                + [num(w["efficiency_rays"], 2), num(w["efficiency_seconds"], 2)]
            )
    header = ["scene, bounces, spp", "way", "per-sample I_z variance", "M rays", "trace s"]
    header += ["variance × rays", "variance × seconds"]
    return (
        out
        + ["Efficiency against the first way of each case (below 1: the same error sooner):", ""]
        + table(header, rows)
    )


def render_estimator(name: str, data: dict) -> Lines:
    """Per-sample variance of I_z, band 0 and band 1 for every variant and sample count."""
    out = run_line(name, atlas="256²")
    rows = []
    for sc, d in data.items():
        spps = sorted({r["samples"] for r in d["rows"]})
        variants = list(dict.fromkeys(r["variant"] for r in d["rows"]))
        for v in variants:
            by = {r["samples"]: r for r in d["rows"] if r["variant"] == v}
            cells = [
                f"{num(by[n]['iz'], 2)} / {num(by[n]['band0'], 2)} / {num(by[n]['band1'], 2)}" if n in by else ""
                for n in spps
            ]
            rows.append([f"{sc} ({d['seeds']} seeds, reference {d['reference']} spp)", v, *cells])
    spps = sorted({r["samples"] for d in data.values() for r in d["rows"]})
    out += ["Per-sample variance relative to the mean², I_z / band 0 / band 1:", ""]
    return out + table(["scene", "variant", *[f"{n} spp" for n in spps]], rows)


# -- tracer (tracer, trace_profile), bake points, unwrap --------------------------------------


def render_tracer(name: str, data: dict) -> Lines:
    """Tracer against raw Embree, and 8-ray packets against one ray per query."""
    out = run_line(name, triangles=count(data["triangles"]), texels=count(data["texels"]), samples=data["samples"])
    rows = [
        ["raw embreex, 1 thread (M rays/s)", mega(data["raw_rays_per_s_1_thread"])],
        ["raw embreex, 2 threads (M rays/s)", mega(data["raw_rays_per_s_2_threads"])],
        ["our Embree binding, 2 threads (M rays/s)", mega(data["our_binding_rays_per_s_2_threads"])],
        ["bake, 2 threads (M rays/s, shadow rays included)", mega(data["bake_rays_per_s"])],
        ["bake over raw embreex, 2 threads", f"{pct(data['bake_over_raw_2_threads'], 0)}%"],
        ["bake (M texel-samples/s)", mega(data["bake_texel_samples_per_s"])],
        ["bake s, 8-ray packets (median)", secs(data["bake_seconds"])],
        ["bake s, one ray per query (median)", secs(data["bake_seconds_one_ray_per_query"])],
        ["packets' speed-up", times(data["packets_speedup"])],
    ]
    return out + table(["measure", "value"], rows)


def render_trace_profile(name: str, data: dict) -> Lines:
    """Where a one-thread trace's time goes, and Embree's own rate on the bake's rays."""
    out = run_line(
        name, samples=data["samples"], atlas=f"{data['resolution']}²", load=load_average(data.get("load_average"))
    )
    rows = []
    for sc, d in data["scenes"].items():
        parts = d["parts"]
        emit = sum(p["seconds"] for k, p in parts.items() if k.startswith(("sample_emitters", "emitter_pdf")))
        kernels = sum(p["seconds"] for k, p in parts.items() if not k.startswith("embree.")) - emit
        t = d["trace_seconds"]
        rows.append(
            [sc, secs(t), f"{mega(d['rays_per_s'])} ({pct(d['rays_per_s'] / d['raw_embreex_rays_per_s'], 0)}%)"]
            + [mega(d["raw_embreex_rays_per_s"]), f"{pct(d['embree_share'], 0)}%"]
            + [f"{mega(d['embree_rays_per_s'])} ({pct(d['embree_rays_per_s'] / d['raw_embreex_rays_per_s'], 0)}%)"]
            + [f"{pct(emit / t, 0)}%", f"{pct(kernels / t, 0)}%", f"{pct(d['other_seconds'] / t, 0)}%"]
        )
    header = ["scene", "trace s", "bake M rays/s (% of raw)", "raw embreex M rays/s", "Embree's share"]
    header += ["Embree on the bake's rays (% of raw)", "emitter sampling", "other kernels", "numpy / Python"]
    return out + table(header, rows)


def render_bake_points(name: str, data: dict) -> Lines:
    """Bake points per resolution, compiled against numpy, and the phases of the largest."""
    out = run_line(name, data.get("date"), cpus=data.get("cpus"), fill=data.get("fill"), change=data.get("what"))
    out += bake_point_runs(data["runs"])
    big = max(data["runs"], key=lambda r: r["resolution"])
    out += [f"Phases at {big['resolution']}² (wall s / CPU s):", ""]
    rows = [[k, f"{secs(big['new']['wall'][k])} / {secs(big['new']['cpu'][k])}"] for k in big["new"]["wall"]]
    out += table(["phase", "compiled"], rows)
    ba = data.get("before_after_4096")
    if ba:
        out += [f"Same process, 4096²: {ba['what']}", ""]
        rows = [
            [r["which"], secs(r["total_wall"]), secs(r["total_cpu"]), load_average(r["load_before"])]
            for r in ba["runs"]
        ]
        out += table(["run", "wall s", "CPU s", "load"], rows)
    for h in data.get("history", []):
        out += [f"Earlier run ({h.get('date')}):", ""] + bake_point_runs(h["runs"])
    return out


def bake_point_runs(runs: list) -> Lines:
    """Wall and CPU seconds per resolution, compiled against the numpy path where it ran."""
    rows = []
    for r in runs:
        old = r.get("old") or {}
        same = r.get("identity")
        identical = "—" if same is None else num(all(v == "identical" for v in same.values()))
        rows.append(
            [
                f"{r['resolution']}²",
                count(r["texels"]),
                f"{secs(r['new']['total_wall'])} / {secs(r['new']['total_cpu'])}",
            ]
            + [f"{secs(old.get('total_wall'))} / {secs(old.get('total_cpu'))}", identical]
        )
    return table(["atlas", "texels", "compiled: wall / CPU s", "numpy: wall / CPU s", "identical arrays"], rows)


def render_unwrap_raster(name: str, data: list) -> Lines:
    """Unwrap and bake-point times and peak memory per mesh size."""
    rows = [
        [count(r["triangles"]), f"{r['resolution']}²", count(r["charts"]), num(r["utilisation_percent"], 0)]
        + [count(r["texels"]), secs(r["unwrap_s"]), secs(r["bake_points_s"]), num(r["bake_points_peak_MiB"], 0)]
        + [secs(r.get("buried_test_s")), count(r.get("buried_texels"))]
        for r in data
    ]
    header = ["triangles", "atlas", "charts", "atlas used %", "texels", "unwrap s", "bake points s"]
    header += ["bake points peak MB", "buried test s", "buried texels"]
    return run_line(name) + table(header, rows)


# -- encoder, preview, light sets, probes, farm ------------------------------------------------


def render_encoder(name: str, data: dict) -> Lines:
    """Error per environment and variant, the direction search against brute force, throughput."""
    out = run_line(name, texels=data.get("texels"), min_cos=data.get("min_cos"))
    envs = list(data["error_percent"])
    variants = list(data["error_percent"][envs[0]])
    rows = [[v] + [num(data["error_percent"][e][v], 2) for e in envs] for v in variants]
    out += ["Hemispherical RMSE, % of the mean I_z:", ""] + table(["variant", *envs], rows)
    keys = list(data["search"][envs[0]])
    rows = [[e] + [num(data["search"][e][k], 3) for k in keys] for e in envs]
    out += table(["environment", *keys], rows)
    rows = [[v, num(data["texels_per_second"][v] / 1e3, 1)] for v in data["texels_per_second"]]
    return out + table(["variant", "k texels/s, one core"], rows)


def render_preview(name: str, data: dict) -> Lines:
    """Image error of each preview mode against Cycles."""
    s = data["settings"]
    out = run_line(
        name,
        bake=f"{s['samples']} spp, {s['bounces']} bounces, {s['resolution']}²",
        cycles=f"{s['cycles_samples']} spp",
    )
    parts = list(next(iter(data["rmse_percent"].values())))
    rows = [[mode] + [num(v[p], 2) for p in parts] for mode, v in data["rmse_percent"].items()]
    return out + ["Image RMSE, % of the reference mean:", ""] + table(["preview", *parts], rows)


def render_light_sets(name: str, data: dict) -> Lines:
    """Blend accuracy per tilt (mean over the weight pairs) and the cost of sets."""
    c = data["config"]
    out = run_line(
        name, atlas=f"{c['resolution']}²", samples=c["samples"], bounces=c["bounces"], texels=count(data["texels"])
    )
    keys = (
        "linear_sh_blend",
        "parameter_blend",
        "direct_encode",
        "linear_sh_blend_vs_direct",
        "parameter_blend_vs_direct",
    )
    rows = []
    for tilt in map(str, c["tilts"]):
        rows.append(
            [f"{tilt}°"] + [pct(statistics.fmean(a["errors"][tilt][k] for a in data["accuracy"]), 2) for k in keys]
        )
    out += ["Irradiance RMSE % relative to the mean, mean over the weight pairs:", ""]
    out += table(
        ["tilt", "(a) linear-SH blend", "(b) parameter blend", "(c) direct encode", "(a) vs (c)", "(b) vs (c)"], rows
    )
    rows = [
        [k, len(v["sets"]), mega(v["rays"], 1), secs(v["seconds"]), times(v["seconds_ratio"])]
        + [times(v["cpu_seconds_ratio"]), num(v["heap_peak_mb"], 0), times(v["heap_peak_mb_ratio"])]
        for k, v in data["cost"].items()
    ]
    header = ["run", "sets", "M rays", "trace s", "time / 1 set", "CPU / 1 set", "heap peak MB", "heap / 1 set"]
    return out + table(header, rows)


def render_probes(name: str, data: dict) -> Lines:
    """Image error of each probe lighting mode, and the probe bake's rate."""
    s, rate = data["settings"], data["bake_rate"]
    out = run_line(
        name,
        probe_samples=s["samples"],
        bounces=s["bounces"],
        cycles=f"{s['cycles_samples']} spp",
        normal_map="off" if s.get("flat") else "on",
    )
    rows = []
    for mode, refs in data["rmse_percent"].items():
        for ref, v in refs.items():
            rows.append([mode, ref, num(v["block"]), num(v["shaded_face"]), num(v["rest"]), num(v["mean_ratio"], 2)])
    out += ["Image RMSE % of the block against Cycles (reference: the whole scene, or the environment as probed):", ""]
    out += table(["mode", "reference", "block", "face turned from the sun", "rest", "mean ratio"], rows)
    return out + [
        f"Probe bake: {rate['probes']} probes at {rate['samples']} samples, {rate['bounces']} bounces, "
        f"{rate['threads']} threads: {secs(rate['seconds'])} s ({num(rate['probes_per_second'], 0)} probes/s).",
        "",
    ]


def render_farm(name: str, data: dict) -> Lines:
    """Local against farm bakes on this machine, and the projection for a real farm."""
    a = data["args"]
    out = run_line(
        name,
        machine=data.get("machine"),
        scene=f"{count(a['triangles'])} triangles, {a['resolution']}², {a['samples']} spp, {a['bounces']} bounces",
        load=f"{num(data.get('load_before'))} → {num(data.get('load_after'))}",
    )
    rows = [
        [k, secs(data[k]["cold"]), secs(data[k]["warm"]), secs(data[k].get("task_seconds"))]
        for k in ("local_1", "local_2", "farm_1", "farm_2")
    ]
    out += table(["run", "cold s", "warm s", "tasks' own s"], rows)
    flat = {k: v for k, v in data.items() if not isinstance(v, (dict, list))}
    out += table(["measure", "value"], [[k, value_text(v)] for k, v in sorted(flat.items())])
    p = data["projection"]
    return (
        out + ["Projection for a farm:", ""] + table(["measure", "value"], [[k, value_text(v)] for k, v in p.items()])
    )


# -- generic fallback --------------------------------------------------------------------------


def value_text(v) -> str:
    """A leaf value: numbers with 4 significant digits, long lists summarised."""
    if isinstance(v, bool) or v is None:
        return num(v) if isinstance(v, bool) else "—"
    if isinstance(v, int):
        return count(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        if all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v) and len(v) > 6:
            return f"{len(v)} numbers, {value_text(min(v))}–{value_text(max(v))}"
        return ", ".join(value_text(x) for x in v)
    return str(v)


def flatten(data, prefix: str = "") -> list[tuple[str, object]]:
    """(dotted key, leaf) pairs of nested dicts; lists of dicts by index."""
    if isinstance(data, dict):
        return [pair for k, v in data.items() for pair in flatten(v, f"{prefix}{k}.")]
    if isinstance(data, list) and data and all(isinstance(x, dict) for x in data):
        return [pair for i, v in enumerate(data) for pair in flatten(v, f"{prefix}{i}.")]
    return [(prefix.rstrip("."), data)]


def render_generic(name: str, data) -> Lines:
    """Any JSON as key/value rows (a list of flat dicts as a table)."""
    out = run_line(name, data.get("date") if isinstance(data, dict) else None)
    if isinstance(data, list) and data and all(isinstance(x, dict) for x in data):
        keys = list(dict.fromkeys(k for x in data for k in x))
        if all(not isinstance(x.get(k), (dict, list)) for x in data for k in keys):
            return out + table(keys, [[value_text(x.get(k)) for k in keys] for x in data])
    return out + table(["key", "value"], [[k, value_text(v)] for k, v in flatten(data)])


# -- families ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Family:
    """A bench's results: files whose name starts with `stem` (the longest matching stem wins)."""

    stem: str
    title: str
    about: str
    command: str
    render: Callable[[str, object], Lines] | None = None


SCENES_NOTE = "classroom, staircase2 and bedroom are external test scenes, not part of this repository"

FAMILIES = (
    Family(
        "time_to_error",
        "Time to equal error against Cycles",
        "Our bake against Cycles' Diffuse bake: each engine's I_z error against its own converged bake at "
        "increasing samples, the time each needs to reach 20%, 10% and 5%, and the ray rates against raw "
        "Embree measured in the same run. Our time counts the Embree scene, the bake points and the tracing. "
        "An entry named with brackets ran at another atlas size, bounce count or α, or over the texels no "
        f"geometry crosses. ({SCENES_NOTE}.)",
        ".venv/bin/python bench/time_to_error.py [--scenes NAME …] [--resolution 256]",
        render_time_to_error,
    ),
    Family(
        "tradeoff",
        "Speed against accuracy: every knob",
        "Three scenes (outdoor, interior, emissive) baked as the Bake button runs it, one knob at a time around "
        "a base setting: wall time, peak memory, the I_z error against a converged reference and the EEVEE "
        "preview's image error against a Cycles render.",
        ".venv/bin/python bench/tradeoff.py [--knobs KNOB …] [--replot]",
        render_tradeoff,
    ),
    Family(
        "presets",
        "Quality presets",
        "For each error level, the cheapest measured setting whose worst-scene I_z error is within it; "
        "`core/presets.py` holds the same knobs (tests/test_presets.py).",
        ".venv/bin/python bench/tradeoff.py --replot",
        render_presets,
    ),
    Family(
        "memory",
        "Memory of a 4096² atlas",
        "Peak resident memory and time, stage by stage, of a bake through the product's own path: a wavy "
        "sheet filling 60% of the atlas, with and without the post stages (denoise, stitch).",
        ".venv/bin/python bench/memory.py [--resolution 4096] [--no-post]",
        render_memory,
    ),
    Family(
        "denoise",
        "Denoising",
        "Our bake raw and denoised against Cycles' Diffuse bake raw and denoised (one whole-atlas OIDN call), "
        "each scored against its own reference with that reference's noise removed; time to 20/10/5% and the "
        f"goal of 4× sooner to 5%. Files named after a scene are single-scene runs. ({SCENES_NOTE}.)",
        ".venv/bin/python bench/denoise.py [--scenes NAME …] [--reference N --ours N …]",
        render_denoise,
    ),
    Family(
        "denoise_fill",
        "Denoising: what the filter sees beside each chart",
        "The denoised error with a smooth fill beside each chart against the chart mirrored through its border, "
        "per ring of texels from the chart's edge.",
        ".venv/bin/python bench/denoise_fill.py",
        render_denoise_fill,
    ),
    Family(
        "denoise_pages",
        "Denoising: pages, small charts and chart edges",
        "Each change to the denoiser's page packing and noise clamp, one on top of the other, on the same bakes.",
        ".venv/bin/python bench/denoise_pages.py",
        render_denoise_pages,
    ),
    Family(
        "denoise_preview",
        "Denoising: what the artist sees",
        "The EEVEE preview against a Cycles render of each scene's camera view, raw and denoised.",
        ".venv/bin/python bench/denoise_preview.py [--cycles-cache DIR]",
        render_denoise_preview,
    ),
    Family(
        "seams",
        "Seam stitching",
        "How visible smooth UV seams are before and after stitching (the seam ratio: the difference across a "
        "seam over the same difference one texel inside the charts), and what stitching costs the interior.",
        ".venv/bin/python bench/seams.py",
        render_seams,
    ),
    Family(
        "leaks",
        "Leaks",
        "Texels that receive light they should not, before and after the leak fixes: on fixtures with an exact "
        "answer, and on the shared scenes against Cycles.",
        ".venv/bin/python bench/leaks.py",
        render_leaks,
    ),
    Family(
        "light_sampling",
        "Emitter sampling",
        "What each part of the emitter sampling saves: per-sample I_z variance and texel-sample rate against "
        "Cycles' Diffuse bake at the same samples (their ratio is the speed to equal error).",
        ".venv/bin/python bench/light_sampling.py [--scenes NAME …] [--direct]",
        render_light_sampling,
    ),
    Family(
        "roulette",
        "Russian roulette",
        "Ways of ending paths compared by per-sample variance times rays and times trace seconds.",
        ".venv/bin/python bench/roulette.py [--bounces 8]",
        render_roulette,
    ),
    Family(
        "estimator",
        "Hemisphere estimator",
        "Variants of the texel estimator (stratification across passes, the mixture's uniform share α) by "
        "per-sample variance against our own converged bake.",
        ".venv/bin/python bench/estimator.py",
        render_estimator,
    ),
    Family(
        "tracer",
        "Tracer throughput",
        "The bake's rays/s against raw Embree measured in the same run, and Embree queried in 8-ray packets "
        "against one ray per query.",
        ".venv/bin/python bench/tracer.py",
        render_tracer,
    ),
    Family(
        "trace_profile",
        "Where a trace's time goes",
        "One 16-spp trace on one thread with every Embree query and compiled kernel timed; Embree's rate on the "
        "bake's own rays is the ceiling of the bake's ray rate.",
        ".venv/bin/python bench/trace_profile.py",
        render_trace_profile,
    ),
    Family(
        "threads",
        "Threads",
        "The bake's parallel stages (tracing, bake points, EXR writing) on one thread against every core; "
        "this bench writes Markdown only.",
        ".venv/bin/python bench/threads.py",
    ),
    Family(
        "bake_points",
        "Bake points",
        "The bake-point stage phase by phase at 1024², 2048² and 4096², the compiled path against the numpy one.",
        ".venv/bin/python bench/bake_points.py --compare",
        render_bake_points,
    ),
    Family(
        "unwrap_raster",
        "Unwrap and bake points by mesh size",
        "xatlas unwrap and bake-point times and peak memory at 10k, 100k and 1M triangles.",
        ".venv/bin/python bench/unwrap_raster.py",
        render_unwrap_raster,
    ),
    Family(
        "unwrap",
        "Unwrap",
        "The unwrap alone, from an empty chart cache and cached, and on whole scenes; Markdown only.",
        ".venv/bin/python bench/unwrap_raster.py --unwrap-only",
    ),
    Family(
        "encoder",
        "Encoder",
        "Reconstruction error of every encoder variant over random vertex normals with hemisphere-sampled SH, "
        "the direction search against a brute-force scan, and throughput on one core.",
        ".venv/bin/python bench/encoder.py (or make bench)",
        render_encoder,
    ),
    Family(
        "preview",
        "Preview fidelity",
        "The demo room baked, rendered by EEVEE in each preview mode, against Cycles diffuse only.",
        ".venv/bin/python bench/preview.py",
        render_preview,
    ),
    Family(
        "light_sets",
        "Light sets",
        "Blending two light sets as Call of Duty does (through linear SH) against blending the HHD parameters, "
        "both against a direct encode of the blended lighting; and the cost of sets in one trace.",
        ".venv/bin/python bench/light_sets.py",
        render_light_sets,
    ),
    Family(
        "probes",
        "Probe volumes",
        "A normal-mapped block lit from probes in each mode (plain SH, HLSH, HLSH + cone) against Cycles; "
        "`probes_flat` is the same without the normal map.",
        ".venv/bin/python bench/probes.py [--flat]",
        render_probes,
    ),
    Family(
        "farm",
        "Farm bakes",
        "The bake on a local Dask cluster of 1 and 2 workers against the local bake, a task's overhead, and a "
        "projection for a real farm from the measured costs (set-up: docs/farm.md).",
        ".venv/bin/python bench/farm.py",
        render_farm,
    ),
)
#: files of bench/results no stem claims, and the family they belong to
EXTRA_FILES = {"demo_preview_4_vs_16_spp.png": "tradeoff"}


def family_of(name: str) -> str | None:
    """The stem of the family a results file belongs to, None if none claims it."""
    if name in EXTRA_FILES:
        return EXTRA_FILES[name]
    stems = [f.stem for f in FAMILIES if name.startswith(f.stem)]
    return max(stems, key=len) if stems else None


def section(family: Family, names: list[str], results: Path) -> Lines:
    """A family's heading, what it measures, how to re-run it, its links and its tables."""
    out = [f"## {family.title}", "", family.about, "", f"Re-run: `{family.command}`.", ""]
    others = [n for n in names if not n.endswith(".json")]
    if others:
        out += ["The bench's own reports and plots: " + ", ".join(link(n) for n in others) + ".", ""]
    for n in (n for n in names if n.endswith(".json")):
        data = json.loads((results / n).read_text())
        render = family.render or render_generic
        if sum(x.endswith(".json") for x in names) > 1:
            out += [f"### `{n}`", ""]
        out += render(n, data)
    return out


INTRO = [
    "# Results",
    "",
    "Generated by `tools/results_doc.py` from `bench/results/*.json`: do not edit by hand. `make results`",
    "rewrites this file and the README's headline table; `python tools/results_doc.py --check` fails when",
    "either is out of date. Each table names the run (the JSON file, its stored date and settings) it",
    "comes from; a bench's own Markdown report, linked beside its tables, has more columns and the",
    "analysis of that run.",
    "",
    "Measured on one 2-core x86_64 machine, often shared with other work (the load average is recorded",
    "where the bench stores it): compare ratios measured in the same run, not seconds across runs.",
    "Unless a table says otherwise, an error is the relative RMSE of the luminance of I_z over fully",
    "covered, unburied texels, each texel over max(reference, 0.1 × the reference's mean), in %; a",
    "reference is two half bakes with their own seeds, and half their RMS difference, its own noise, is",
    "removed from each error in quadrature.",
    "",
]


def document(results: Path = RESULTS) -> str:
    """The text of docs/results.md."""
    names = sorted(p.name for p in results.iterdir() if p.is_file() and not p.name.startswith("."))
    groups: dict[str | None, list[str]] = {}
    for n in names:
        groups.setdefault(family_of(n), []).append(n)
    out = list(INTRO)
    for f in FAMILIES:
        if groups.get(f.stem):
            out += section(f, groups[f.stem], results)
    if groups.get(None):
        other = Family("", "Other results", "Results no bench family renders yet.", "see the bench that wrote them")
        out += section(other, groups[None], results)
    return "\n".join(out).rstrip("\n") + "\n"


# -- the README's headline ---------------------------------------------------------------------


def headline(results: Path = RESULTS) -> Lines:
    """The README's generated lines: time to error against Cycles and memory at 4096²."""
    tte = json.loads((results / "time_to_error.json").read_text())
    out = [
        "How much sooner our bake reaches an I_z error level than Cycles' Diffuse bake: Cycles' time over ours,",
        "in brackets ours / Cycles in seconds (512² atlas, 3 bounces, 2 cores, each engine against its own",
        "converged bake; `bench/results/time_to_error.json`). \"Both start below\": both are under that error at",
        "the fewest samples measured; \"neither within N spp\": neither reached it.",
        "",
    ]
    out += tte_headline(tte)
    memory = json.loads((results / "memory.json").read_text())
    last = latest_runs(memory)
    post, plain = last.get("4096_post", {}).get("after"), last.get("4096_no_post", {}).get("after")
    if is_run(post) and is_run(plain):
        out += [
            f"Peak memory of a synthetic 4096² sheet ({num(post['texels'] / 1e6)} M texels, `bench/results/memory.json`): "
            f"{gb(post['peak_rss_mb'])} GB with the Production post stages, {gb(plain['peak_rss_mb'])} GB without;",
            _level_memory(results),
            "",
        ]
    return out + ["All figures, and how to re-run them: [docs/results.md](docs/results.md)."]


def _level_memory(results: Path) -> str:
    """The headline's line on a real level's whole bake (bench/end_to_end.py's bedroom at 4096²
    Production): the synthetic sheet alone would promise less than a level takes."""
    path = results / "end_to_end.json"
    run = json.loads(path.read_text()).get("bedroom-4096-production", {}) if path.exists() else {}
    if not run.get("peak_rss_mb"):
        return "a real level's whole bake: not measured (`bench/end_to_end.py`)."
    return (
        f"the shared bedroom's whole CLI bake at 4096² Production ({num(run['texels_baked'] / 1e6)} M texels, "
        f"`bench/results/end_to_end.json`): {gb(run['peak_rss_mb'])} GB."
    )


def with_headline(readme: str, results: Path = RESULTS) -> str:
    """readme with the block between the headline markers regenerated; unchanged if it has none."""
    start, end = readme.find(HEADLINE_BEGIN), readme.find(HEADLINE_END)
    if start < 0 or end < start:
        return readme
    body = "\n".join(headline(results))
    return readme[: start + len(HEADLINE_BEGIN)] + "\n" + body + "\n" + readme[end:]


# -- command line ------------------------------------------------------------------------------


def outputs() -> dict[Path, str]:
    """Each generated file (DOC, README) and the text it should hold, from RESULTS."""
    return {DOC: document(RESULTS), README: with_headline(README.read_text(), RESULTS)}


def shown(path: Path) -> str:
    """path relative to the repository when it is inside it."""
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def main(argv: list[str] | None = None) -> int:
    """Write the stale outputs (or with --check, report them); the exit status."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/results.md or the README block is out of date")
    args = ap.parse_args(argv)
    stale = [(path, text) for path, text in outputs().items() if not path.exists() or path.read_text() != text]
    if args.check:
        if stale:
            names = ", ".join(shown(path) for path, _ in stale)
            print(f"out of date: {names}; run `python tools/results_doc.py` (make results)", file=sys.stderr)
        return 1 if stale else 0
    for path, text in stale:
        path.write_text(text)
        print(f"wrote {shown(path)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
