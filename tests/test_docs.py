"""The docs say what is true now; measurements are data.

No dated or "Measured" headings, no page over 300 lines (the generated `docs/results.md` aside),
every relative link in README.md and docs/ resolves (file and, where given, heading), the results
page is what `pipelines.results` renders from `bench/results/*.jsonl`, and every result row has
its date, machine, revision and a figure.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from pipelines import apiref, results

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.rglob("*.md"))
GENERATED = DOCS / "results.md"
MAX_LINES = 300

LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~)")


def _prose(path: Path) -> list[str]:
    """The page's lines outside fenced code blocks."""
    out, fenced = [], False
    for line in path.read_text().splitlines():
        if FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        if not fenced:
            out.append(line)
    return out


def _headings(path: Path) -> list[str]:
    return [line for line in _prose(path) if re.match(r"#{1,6} ", line)]


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"^#{1,6} ", "", heading).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for h in _headings(path):
        s = slug(h)
        n = seen.get(s, 0)
        out.add(s if n == 0 else f"{s}-{n}")
        seen[s] = n + 1
    return out


def test_pages_exist():
    assert (DOCS / "index.md").exists() and GENERATED.exists() and len(PAGES) > 5


@pytest.mark.parametrize("path", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_dated_or_measured_heading(path):
    bad = [h for h in _headings(path) if re.search(r"\b20\d\d\b", h) or re.search(r"measured", h, re.I)]
    assert not bad, f"{path.relative_to(ROOT)}: dated or 'Measured' headings {bad}; measurements go to bench/results"


@pytest.mark.parametrize("path", [p for p in PAGES if p not in (GENERATED, apiref.PAGE)],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_are_short(path):
    n = len(path.read_text().splitlines())
    assert n <= MAX_LINES, f"{path.relative_to(ROOT)} has {n} lines (at most {MAX_LINES}): split it"


@pytest.mark.parametrize("path", [ROOT / "README.md", *PAGES], ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    broken = []
    for line in _prose(path):
        for m in LINK.finditer(line):
            target = m.group(1) or m.group(2)
            if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
                continue
            file, _, anchor = target.partition("#")
            dest = (path.parent / file).resolve() if file else path
            if not dest.exists():
                broken.append(f"{target} (no file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                broken.append(f"{target} (no heading '{anchor}')")
    assert not broken, f"{path.relative_to(ROOT)}: broken links {broken}"


def test_slug_is_githubs():
    assert slug("## The staged recipe: `make train RECIPE=staged`") == "the-staged-recipe-make-train-recipestaged"
    assert slug("### FSDP: full fine-tuning (`--shard fsdp`)") == "fsdp-full-fine-tuning---shard-fsdp"


def test_api_reference_is_the_docstrings():
    """docs/reference/api.md is what `python -m pipelines.apiref` writes from `factory`'s public
    names: one section each, dataclass fields with the docstrings under them."""
    text = apiref.render()
    assert apiref.PAGE.read_text() == text, "docs/reference/api.md is stale: run python -m pipelines.apiref"
    assert apiref.main(["--check"]) == 0
    import factory

    assert all(f"### `{name}` (" in text for name in factory.__all__)
    assert "| `max_penetration_ldu` | `float` | `0.5` | Deepest overlap accepted (LDU)" in text


def test_results_page_is_not_stale():
    assert GENERATED.read_text() == results.render(), "docs/results.md is stale: run python -m pipelines.results"
    assert results.main(["--check"]) == 0


def test_result_rows_have_date_machine_revision_and_a_figure():
    files = sorted(results.RESULTS.glob("*.jsonl"))
    assert files, "no bench/results/*.jsonl"
    for path in files:
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            row = json.loads(line)
            where = f"{path.relative_to(ROOT)}:{n}"
            assert {"date", "machine", "revision", "what"} <= row.keys(), where
            assert re.fullmatch(r"20\d\d-\d\d-\d\d", row["date"]), where
            assert row["revision"] is None or re.fullmatch(r"[0-9a-f]{7,40}", row["revision"]), where
            assert results.figures(row), f"{where}: no numeric figure"


def test_results_keep_the_latest_row_per_measurement_and_machine(tmp_path):
    rows = [{"date": "2026-01-01", "machine": "m", "revision": None, "what": "w", "wall_s": 2.0},
            {"date": "2026-01-02", "machine": "m", "revision": "abc1234", "what": "w", "wall_s": 1.0},
            {"date": "2026-01-01", "machine": "n", "revision": None, "what": "w", "wall_s": 3.0}]
    (tmp_path / "x.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    page = results.render(tmp_path)
    assert "wall_s 1.0" in page and "wall_s 2.0" not in page and "wall_s 3.0" in page
    (tmp_path / "y.jsonl").write_text(json.dumps({"date": "2026-01-01", "machine": "m", "revision": None,
                                                  "what": "w"}) + "\n")
    with pytest.raises(results.ResultsError, match="no numeric figure"):
        results.render(tmp_path)
    for bad, message in [('{"date": "2026-01-01"', "y.jsonl:2: not JSON"), ("[1]", "y.jsonl:2: expected a JSON object"),
                         ('{"date": "2026-01-01", "wall_s": 1}', "y.jsonl:2: missing key(s) machine, revision, what")]:
        (tmp_path / "y.jsonl").write_text(json.dumps(rows[0]) + "\n" + bad + "\n")
        with pytest.raises(results.ResultsError, match=re.escape(message)):
            results.render(tmp_path)
