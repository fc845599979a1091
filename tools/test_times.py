"""The test suites' times, as `make test` ends: reads what tests/conftest.py wrote for each suite
(out/test-times/<suite>.json), prints each suite's wall time, counts and ten slowest tests, and
writes them with the whole run's wall time to out/test-times/summary.json.

    python tools/test_times.py [--wall SECONDS] [--folder out/test-times] [--slowest 10]

Plain Python 3.11+, no bpy. A suite that wrote no file (it crashed before its end) is named.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SUITES = ("bpy-5.3.0", "bpy-4.2.23")


def summary(folder: Path, wall: float | None, slowest: int) -> dict:
    """{'wall_seconds', 'suites': {name: record or None}} for the suites found in folder."""
    names = sorted({*SUITES, *(p.stem for p in folder.glob("*.json") if p.stem != "summary")})
    suites: dict[str, dict | None] = {}
    for name in names:
        path = folder / f"{name}.json"
        record = json.loads(path.read_text()) if path.exists() else None
        if record is not None and "slowest" not in record:
            continue  # not a suite's record
        if record is not None:
            record.pop("all", None)
            record["slowest"] = record["slowest"][:slowest]
        suites[name] = record
    return {"wall_seconds": wall, "suites": suites}


def report(doc: dict) -> str:
    """The summary as text: a line per suite, then each suite's slowest tests."""
    lines = ["== test suites"]
    for name, rec in doc["suites"].items():
        if rec is None:
            lines.append(f"  {name}: no record (the suite did not run to its end)")
            continue
        lines.append(
            f"  {name} (Python {rec['python']}, -m '{rec['markers'] or 'all'}'): {rec['wall_seconds']:.0f} s, "
            f"{rec['tests']} tests: {rec['passed']} passed, {rec['failed']} failed, {rec['skipped']} skipped"
        )
    if doc["wall_seconds"] is not None:
        lines.append(f"  make test: {doc['wall_seconds']:.0f} s wall (the suites run side by side)")
    for name, rec in doc["suites"].items():
        if rec:
            lines.append(f"== {name}: the {len(rec['slowest'])} slowest tests (setup + call + teardown)")
            lines += [f"  {t['seconds']:7.1f} s  {t['test']}" for t in rec["slowest"]]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--wall", type=float, help="the whole run's wall time, seconds")
    ap.add_argument("--folder", type=Path, default=ROOT / "out" / "test-times")
    ap.add_argument("--slowest", type=int, default=10)
    args = ap.parse_args()
    doc = summary(args.folder, args.wall, args.slowest)
    (args.folder / "summary.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(report(doc))


if __name__ == "__main__":
    main()
