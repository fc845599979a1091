"""Peak memory of a CLI bake, stage by stage and within the stitch (issue 58, part 4); run by hand.

    python bench/cli_memory.py --blend COPY.blend --dir OUT_DIR --out RESULT.json --objects-file NAMES.txt
                               [--samples 4] [--tag NAME]

Runs `python -m hhd_lightmapper.cli COPY.blend bake --preset production --samples N --out OUT_DIR
--objects <names>` in a child with bench/end_to_end.py's stage markers, plus markers around the
stitch's steps (its system, solve, bound, metric) and the encoder; samples the resident memory
of the whole process tree every 20 ms (psutil). Writes RESULT.json: the peak and seconds per
stage, every marker's time, the memory series and the console log. Bake a copy of the .blend
(the bake writes into it). The result for `bench/results/memory_cuts.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path


def child(argv: list[str]) -> int:
    from hhd_lightmapper.bench import end_to_end
    from hhd_lightmapper.core.bake import finishing
    from hhd_lightmapper.core.post.seams import stitching

    for owner, attr, name in (
        (stitching, "_system", "stitch system"),
        (stitching, "_solve", "stitch solve"),
        (stitching, "_bounded", "stitch bound"),
        (stitching, "_metric", "stitch metric"),
        (finishing.encoding, "encode_atlas", "encode_atlas"),
        (finishing.post, "stitch_encoded", "stitch_encoded"),
    ):
        f = getattr(owner, attr)

        def marked(*a, _f=f, _n=name, **k):
            print(f"@sub {_n}", flush=True)
            try:
                return _f(*a, **k)
            finally:
                print(f"@sub /{_n}", flush=True)

        setattr(owner, attr, marked)
    return end_to_end.child(argv)


def main() -> int:
    import psutil

    from hhd_lightmapper.bench import end_to_end

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--blend", required=True)
    ap.add_argument("--dir", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--objects-file", required=True)
    ap.add_argument("--samples", default="4")
    ap.add_argument("--tag", default="")
    a = ap.parse_args()
    objects = Path(a.objects_file).read_text().split()
    argv = [a.blend, "bake", "--preset", "production", "--samples", a.samples, "--out", a.dir, "--objects", *objects]
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    command = [sys.executable, "-u", __file__, "--child", "--", *argv]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    root = psutil.Process(proc.pid)
    series: list[tuple[float, float]] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            total = 0
            try:
                procs = [root, *root.children(recursive=True)]
            except psutil.Error:
                procs = []
            for p in procs:
                try:
                    total += p.memory_info().rss
                except psutil.Error:
                    pass
            series.append((round(time.perf_counter() - t0, 3), round(total / 2**20, 1)))
            stop.wait(0.02)

    watcher = threading.Thread(target=sample, daemon=True)
    watcher.start()
    events, stage, traced, log = [(0.0, "start")], "start", False, []
    assert proc.stdout is not None
    for line in proc.stdout:
        now = time.perf_counter() - t0
        line = line.rstrip("\n")
        log.append(f"{now:9.3f} {line}")
        if line.startswith("@sub "):
            events.append((round(now, 3), line))
            continue
        new = line[5:] if line.startswith("@e2e ") else None
        if new is None and line.startswith("["):
            new = end_to_end._stage_of(line.split("]", 1)[-1].strip())
        if new == "other":
            new = "other after trace" if traced else "other before trace"
        traced = traced or new == "trace"
        if new is not None and new != stage:
            stage = new
            events.append((round(now, 3), stage))
    code = proc.wait()
    end = time.perf_counter() - t0
    stop.set()
    watcher.join()
    stages = [(t, s) for t, s in events if not s.startswith("@sub")]
    peaks: dict[str, float] = {}
    seconds: dict[str, float] = {}
    for (t, s), (t1, _) in zip(stages, stages[1:] + [(end, "")]):
        seconds[s] = seconds.get(s, 0.0) + t1 - t
        peaks[s] = max(peaks.get(s, 0.0), max([m for tt, m in series if t <= tt <= t1] or [0.0]))
    result = {
        "tag": a.tag,
        "exit": code,
        "total": end,
        "peak": max(m for _, m in series),
        "peaks": peaks,
        "seconds": seconds,
        "load": [load0, os.getloadavg()],
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "events": events,
        "series": series,
        "log": log,
    }
    Path(a.out).write_text(json.dumps(result))
    print(json.dumps({k: result[k] for k in ("tag", "exit", "total", "peak", "peaks", "seconds", "load")}, indent=1))
    return 0 if code == 0 else 1


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        sys.exit(child(sys.argv[3:]))
    sys.exit(main())
