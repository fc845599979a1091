"""docs/format.md's channel tables, generated from the channel spec. No bpy.

Each file's table sits in docs/format.md between `begin_marker(key)` and END_MARKER;
tests/test_encoding_spec.py checks they are current, and

    python -m hhd_lightmapper.core.encoding.doc_tables [path/to/format.md]

rewrites them (default: the repository's docs/format.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

from .registry import documented_files
from .spec import FLOAT, HALF, HALF_OR_FLOAT, Channel, FileSpec

TYPE_TEXT = {HALF: "half", FLOAT: "float32", HALF_OR_FLOAT: "half, or float32 if any value > 65504"}
END_MARKER = "<!-- end of generated channel table -->"


def begin_marker(key: str) -> str:
    return f"<!-- channel table `{key}`: generated from core/encoding (python -m hhd_lightmapper.core.encoding.doc_tables) -->"


def _names(group: list[Channel]) -> str:
    first = ", ".join(f"`{n}`" for n in group[0].exr_names)
    if len(group) == 1:
        text = first
    else:
        text = f"{first} … " + ", ".join(f"`{n}`" for n in group[-1].exr_names)
    when = group[0].when
    return text + (f" ({when[0]} = {when[1]})" if when else "")


def table(spec: FileSpec) -> str:
    """Markdown table `| channel | type | meaning |` of `spec`; consecutive layers alike but for
    their name (SH0 … SH8) share a row."""
    groups: list[list[Channel]] = []
    for ch in spec.channels:
        prev = groups[-1][-1] if groups else None
        if prev is not None and (prev.dtype, prev.meaning, prev.when) == (ch.dtype, ch.meaning, ch.when):
            groups[-1].append(ch)
        else:
            groups.append([ch])
    rows = ["| channel | type | meaning |", "|---|---|---|"]
    rows += [f"| {_names(g)} | {TYPE_TEXT[g[0].dtype]} | {g[0].meaning} |" for g in groups]
    return "\n".join(rows)


def block(spec: FileSpec) -> str:
    """The marked block of `spec`'s table, as docs/format.md holds it."""
    return f"{begin_marker(spec.key)}\n{table(spec)}\n{END_MARKER}"


def blocks() -> list[str]:
    return [block(spec) for spec in documented_files()]


def update(text: str) -> str:
    """`text` with each file's marked block replaced by the current one (blocks not in `text` are
    left for the author to place)."""
    for spec in documented_files():
        start = text.find(begin_marker(spec.key))
        if start < 0:
            continue
        end = text.index(END_MARKER, start) + len(END_MARKER)
        text = text[:start] + block(spec) + text[end:]
    return text


def main(argv: list[str]) -> int:
    path = Path(argv[0]) if argv else Path(__file__).resolve().parents[2] / "docs" / "format.md"
    text = path.read_text(encoding="utf-8")
    new = update(text)
    if new != text:
        path.write_text(new, encoding="utf-8")
    print(f"{path}: {'updated' if new != text else 'current'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
