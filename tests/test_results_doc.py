"""The generated results document and the README: figures up to date with bench/results, every result
shown, the README short, and every relative link pointing at a file that exists. No bpy."""

import json
import re
from pathlib import Path

import pytest

import results_doc

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOC = ROOT / "docs" / "results.md"
RESULTS = ROOT / "bench" / "results"
MARKDOWN = [README, *sorted((ROOT / "docs").glob("*.md"))]
#: a Markdown link or image: [text](target) / ![alt](target)
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def relative_links(text: str) -> list[str]:
    """The relative link targets of Markdown text, outside code blocks and code spans, without
    their #fragment; anchors within the page and URLs are left out."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    text = re.sub(r"`[^`\n]*`", "", text)
    targets = [t.split("#")[0] for t in LINK.findall(text)]
    return [t for t in targets if t and not re.match(r"^[a-z][a-z0-9+.-]*:", t)]


def test_generated_files_are_up_to_date():
    """`tools/results_doc.py --check` passes: docs/results.md and the README's headline block are what
    bench/results gives (run `make results` after a bench)."""
    assert results_doc.main(["--check"]) == 0


def test_check_reports_stale_files(tmp_path, monkeypatch, capsys):
    """--check exits 1 naming a missing or edited output; a plain run writes it, after which --check
    passes."""
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{results_doc.HEADLINE_BEGIN}\nold figures\n{results_doc.HEADLINE_END}\nend\n")
    monkeypatch.setattr(results_doc, "README", readme)
    monkeypatch.setattr(results_doc, "DOC", tmp_path / "results.md")
    assert results_doc.main(["--check"]) == 1
    assert "results.md" in capsys.readouterr().err
    assert results_doc.main([]) == 0
    assert results_doc.main(["--check"]) == 0
    text = readme.read_text()
    assert "old figures" not in text and text.startswith("intro\n") and text.endswith("end\n")


def test_every_result_file_appears():
    """Every JSON of bench/results has its tables in docs/results.md, and every other file there (the
    benches' Markdown reports, the plots) is linked."""
    text = DOC.read_text()
    missing = [p.name for p in sorted(RESULTS.iterdir()) if f"({results_doc.LINK_BASE}{p.name})" not in text]
    assert not missing, f"not in docs/results.md: {missing}"
    for p in sorted(RESULTS.glob("*.json")):
        assert f"Run: [`{p.name}`]" in text, p.name


def test_a_new_bench_gets_the_generic_tables(tmp_path):
    """A JSON no family claims still appears, as key/value rows of its nested fields; the output does
    not depend on the run."""
    data = {"date": "a run", "scene": {"texels": 1234, "seconds": 0.5}, "profile": list(range(10))}
    (tmp_path / "zz_new.json").write_text(json.dumps(data))
    (tmp_path / "zz_new.png").write_bytes(b"")
    text = results_doc.document(tmp_path)
    assert "## Other results" in text
    assert "Run: [`zz_new.json`](../bench/results/zz_new.json); date a run" in text
    assert "| scene.texels | 1,234 |" in text and "| profile | 10 numbers, 0–9 |" in text
    assert "[`zz_new.png`](../bench/results/zz_new.png)" in text
    assert results_doc.document(tmp_path) == text


def test_readme_is_short():
    """The README is for a user: at most 300 lines; the measurement reports are in docs/results.md."""
    lines = README.read_text().splitlines()
    assert len(lines) <= 300, len(lines)
    assert results_doc.HEADLINE_BEGIN in lines and results_doc.HEADLINE_END in lines


def test_readme_cites_nothing_outside_the_repository():
    """No README line points outside the repository: no path through ../ (the conventions it
    relies on are docs/conventions.md), no link that resolves outside it."""
    bad = [line for line in README.read_text().splitlines() if "../" in line]
    outside = [t for t in relative_links(README.read_text()) if ROOT not in (ROOT / t).resolve().parents]
    assert not bad and not outside, (bad, outside)


@pytest.mark.parametrize("path", MARKDOWN, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_exist(path):
    """Every relative link of README.md and docs/*.md points at a file or folder that exists."""
    dead = [t for t in relative_links(path.read_text()) if not (path.parent / t).exists()]
    assert not dead, f"{path.name}: {dead}"
