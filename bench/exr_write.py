"""EXR writing off one core measured: the OpenEXR binding's writer against `zip_exr` (issue 58).

    .venv/bin/python bench/exr_write.py LIGHTMAP_FOLDER [--scratch DIR] [--repeats 2]

Reads a bake's EXRs (`<atlas>_sh.exr`, `<atlas>_hhd.exr` and the previews in
`<atlas>_preview/`) and writes each again:

* `binding`: the writer `exr.write_file` used before, the binding's `OpenEXR.OutputFile`
  fed WRITE_ROWS scanlines per `writePixels` call, its pool at 2 threads (as a bake sets it);
* `zip_exr` at 1 and 2 threads and `zip_exr.ZIP_LEVEL` (`exr.write_file`);

interleaved, `--repeats` times each, and then `zip_exr` at 2 threads with each level of its
deflate (`zip_exr.DEFLATER`: ISA-L 0 … 3, or zlib 1 … 6) once (`zip_exr.ZIP_LEVEL` set for the write). Per write: wall seconds, CPU seconds of the process (every thread), the file's
size, and the 1-minute load average before it. The first `zip_exr` file of each input is read
back and its channels compared bit for bit with the input's. Writes bench/results/exr_write.json
and .md (ratios against the binding's median in the same run).

    .venv/bin/python bench/exr_write.py LIGHTMAP_FOLDER --alternatives

measures instead other deflate libraries on the SH file's blocks (every 8th block, packed and
predicted as `zip_exr` does; CPU seconds and sizes scaled by 8): Python's zlib, and libdeflate
(`deflate`, what OpenEXR uses) and ISA-L (`isal`) where installed. Writes
bench/results/exr_write_alternatives.json and .md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

from hhd_lightmapper.core.files import exr, zip_exr

#: The levels swept for each block compressor `zip_exr` may use (`zip_exr.DEFLATER`).
LEVELS = {"isal": range(4), "zlib": range(1, 7)}[zip_exr.DEFLATER]


def binding_write(path: Path, channels: dict[str, np.ndarray]) -> None:
    """What `exr.write_file` was before `zip_exr`: the binding's scanline writer, a band at a time."""
    import Imath
    import OpenEXR

    types = {np.dtype(np.float16): Imath.PixelType.HALF, np.dtype(np.float32): Imath.PixelType.FLOAT}
    height, width = next(iter(channels.values())).shape
    header = OpenEXR.Header(width, height)
    header["compression"] = Imath.Compression(Imath.Compression.ZIP_COMPRESSION)
    header["channels"] = {n: Imath.Channel(Imath.PixelType(types[d.dtype])) for n, d in channels.items()}
    header["type"] = b"scanlineimage"
    out = OpenEXR.OutputFile(str(path), header)
    try:
        for start in range(0, height, exr.WRITE_ROWS):
            band = slice(start, min(start + exr.WRITE_ROWS, height))
            for name, data in channels.items():
                exr._check_finite(path, name, data[band])
            out.writePixels({n: d[band].tobytes() for n, d in channels.items()}, band.stop - start)
    finally:
        out.close()


def timed(label: str, write, path: Path) -> dict:
    load = os.getloadavg()[0]
    wall, cpu = time.perf_counter(), time.process_time()
    write(path)
    row = {
        "writer": label,
        "wall_s": round(time.perf_counter() - wall, 3),
        "cpu_s": round(time.process_time() - cpu, 3),
        "bytes": path.stat().st_size,
        "load": round(load, 2),
    }
    print(row, flush=True)
    return row


def same_values(path: Path, channels: dict[str, np.ndarray]) -> bool:
    back, _ = exr.read(path)
    return back.keys() == channels.keys() and all(
        back[n].dtype == d.dtype and back[n].tobytes() == d.tobytes() for n, d in channels.items()
    )


def measure(source: Path, scratch: Path, repeats: int) -> dict:
    import OpenEXR

    channels, _ = exr.read(source)
    out = scratch / f"exr_write_{source.name}"
    writers = {
        "binding": lambda p: binding_write(p, channels),
        "zip_exr 1 thread": lambda p: exr.write_file(p, channels, threads=1),
        "zip_exr 2 threads": lambda p: exr.write_file(p, channels, threads=2),
    }
    OpenEXR.set_global_thread_count(2)
    rows, exact = [], None
    for rep in range(repeats):
        for label, write in writers.items():
            rows.append({**timed(label, write, out), "level": zip_exr.ZIP_LEVEL, "repeat": rep})
            if exact is None and label != "binding":
                exact = same_values(out, channels)
    for level in LEVELS:
        zip_exr.ZIP_LEVEL, chosen = level, zip_exr.ZIP_LEVEL
        try:
            rows.append(
                {
                    **timed(f"zip_exr 2 threads, level {level}", writers["zip_exr 2 threads"], out),
                    "level": level,
                    "repeat": 0,
                }
            )
        finally:
            zip_exr.ZIP_LEVEL = chosen
    out.unlink()
    h, w = next(iter(channels.values())).shape
    kinds = sorted({str(d.dtype) for d in channels.values()})
    return {
        "file": source.name,
        "width": w,
        "height": h,
        "channels": len(channels),
        "dtypes": kinds,
        "values_identical": exact,
        "rows": rows,
    }


def predicted_blocks(channels: dict[str, np.ndarray], every: int) -> list[np.ndarray]:
    """Every `every`-th ZIP block of `channels`, reordered and predicted (what is deflated)."""
    names = sorted(channels, key=lambda n: n.encode("utf-8"))
    h = next(iter(channels.values())).shape[0]
    return [
        zip_exr.predicted([np.ascontiguousarray(channels[n][y : y + zip_exr.BLOCK_ROWS]) for n in names])[1]
        for y in range(0, h, zip_exr.BLOCK_ROWS * every)
    ]


def alternatives(source: Path, every: int = 8) -> dict:
    import zlib

    channels, _ = exr.read(source)
    blocks = predicted_blocks(channels, every)
    del channels
    libraries = {"zlib": lambda d, lv: zlib.compress(d, lv)}
    try:
        import deflate

        libraries["libdeflate"] = lambda d, lv: deflate.zlib_compress(d.tobytes(), lv)
    except ImportError:
        pass
    try:
        from isal import isal_zlib

        libraries["isal"] = lambda d, lv: isal_zlib.compress(d, lv)
    except ImportError:
        pass
    levels = {"zlib": (1, 3, 4, 6), "libdeflate": (1, 4, 6), "isal": (0, 1, 2, 3)}
    rows = []
    for library, compress in libraries.items():
        for level in levels[library]:
            load, cpu = os.getloadavg()[0], time.process_time()
            size = sum(len(compress(d, level)) for d in blocks)
            cpu = time.process_time() - cpu
            rows.append(
                {
                    "library": library,
                    "level": level,
                    "cpu_s": round(cpu * every, 2),
                    "bytes": size * every,
                    "load": round(load, 2),
                }
            )
            print(rows[-1], flush=True)
    return {"file": source.name, "every": every, "rows": rows}


def median(rows: list[dict], writer: str, key: str) -> float:
    return statistics.median(r[key] for r in rows if r["writer"] == writer)


def report(docs: list[dict], load: tuple[float, float]) -> list[str]:
    lines = [
        "# EXR writing off one core (issue 58)",
        "",
        "`python bench/exr_write.py /tmp/big/lightmaps`: the files of a 4096² bake of the bedroom (4 samples), each written "
        "again by the OpenEXR 3.5.3 binding's scanline writer (`OutputFile.writePixels`, its pool at 2 threads: "
        f"what `exr.write_file` was) and by `zip_exr` (what it is now; deflate: {zip_exr.DEFLATER}, level {zip_exr.ZIP_LEVEL}) "
        "at 1 and 2 threads, interleaved; medians of "
        f"the repeats. 2 cores shared with other jobs: load average {load[0]:.2f} → {load[1]:.2f} over the run "
        "(each row's own in the JSON). CPU s: the process's, every thread. Ratios: against the binding in the same "
        "run. Values: the `zip_exr` file read back by the binding gives every channel bit for bit.",
        "",
        "| file | channels | writer | wall s | CPU s | MB | wall / binding | CPU / binding | MB / binding |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for doc in docs:
        rows = doc["rows"]
        base = {k: median(rows, "binding", k) for k in ("wall_s", "cpu_s", "bytes")}
        for writer in ("binding", "zip_exr 1 thread", "zip_exr 2 threads"):
            m = {k: median(rows, writer, k) for k in base}
            lines.append(
                f"| {doc['file']} | {doc['channels']} {'/'.join(doc['dtypes'])} | {writer} | {m['wall_s']:.2f} | "
                f"{m['cpu_s']:.2f} | {m['bytes'] / 1e6:.1f} | {m['wall_s'] / base['wall_s']:.2f} | "
                f"{m['cpu_s'] / base['cpu_s']:.2f} | {m['bytes'] / base['bytes']:.3f} |"
            )
    lines += [
        "",
        f"{zip_exr.DEFLATER} levels (`zip_exr` at 2 threads, one write each; OpenEXR's own default is libdeflate's level 4):",
        "",
        "| file | level | wall s | CPU s | MB | MB / binding | CPU / binding |",
        "|---|---|---|---|---|---|---|",
    ]
    for doc in docs:
        rows = doc["rows"]
        base_cpu, base_bytes = median(rows, "binding", "cpu_s"), median(rows, "binding", "bytes")
        for level in LEVELS:
            [r] = [r for r in rows if r["writer"] == f"zip_exr 2 threads, level {level}"]
            lines.append(
                f"| {doc['file']} | {level} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | {r['bytes'] / 1e6:.1f} | "
                f"{r['bytes'] / base_bytes:.3f} | {r['cpu_s'] / base_cpu:.2f} |"
            )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--scratch", type=Path, default=Path("/tmp"))
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "exr_write")
    ap.add_argument("--alternatives", action="store_true")
    args = ap.parse_args()
    if args.alternatives:
        return alternatives_report(args)
    sources = sorted(args.folder.glob("*_sh.exr")) + sorted(args.folder.glob("*_hhd.exr"))
    sources += sorted(args.folder.glob("*_preview/*.exr"))
    load = os.getloadavg()[0]
    docs = [measure(s, args.scratch, args.repeats) for s in sources]
    loads = (load, os.getloadavg()[0])
    doc = {
        "folder": str(args.folder),
        "cores": os.cpu_count(),
        "deflater": zip_exr.DEFLATER,
        "level": zip_exr.ZIP_LEVEL,
        "load": loads,
        "files": docs,
    }
    args.out.with_suffix(".json").write_text(json.dumps(doc, indent=1) + "\n")
    args.out.with_suffix(".md").write_text("\n".join(report(docs, loads)) + "\n")
    return 0


def alternatives_report(args) -> int:
    [source] = sorted(args.folder.glob("*_sh.exr"))
    doc = alternatives(source)
    out = args.out.with_name(args.out.name + "_alternatives")
    out.with_suffix(".json").write_text(json.dumps(doc, indent=1) + "\n")
    zlib3 = next(r for r in doc["rows"] if r["library"] == "zlib" and r["level"] == 3)
    lines = [
        "# EXR writing: deflate libraries on the raw SH file's blocks (issue 58)",
        "",
        f"`python bench/exr_write.py {args.folder} --alternatives`: every {doc['every']}th ZIP block of "
        f"{source.name} packed and predicted as `zip_exr` does, deflated on one thread; CPU seconds and sizes "
        f"times {doc['every']} (an estimate of the whole file's). Load average in the JSON.",
        "",
        "| library | level | CPU s | MB | CPU / zlib level 3 | MB / zlib level 3 |",
        "|---|---|---|---|---|---|",
    ]
    for r in doc["rows"]:
        lines.append(
            f"| {r['library']} | {r['level']} | {r['cpu_s']:.2f} | {r['bytes'] / 1e6:.1f} | "
            f"{r['cpu_s'] / zlib3['cpu_s']:.2f} | {r['bytes'] / zlib3['bytes']:.3f} |"
        )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
