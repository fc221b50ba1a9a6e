"""Hostile input: the quick subset of tests/hostile/run.py (a few refused-at-once cases, steps and
verify) generated in tmp_path, each in a subprocess under a small time and memory limit. The whole
corpus is `python tests/hostile/run.py --out DIR` (minutes; not run here)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

HOSTILE = Path(__file__).resolve().parent / "hostile"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"hostile_{name}", HOSTILE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_generate_writes_every_case(tmp_path):
    generate = _load("generate")
    cases = generate.generate(tmp_path, big=False)
    assert set(generate.QUICK) <= set(cases)
    assert set(cases) == set(generate.CASES) - {"long_line_50mb", "many_triangles", "many_parts"}
    assert all(p.is_file() for p in cases.values())
    assert (tmp_path / "ldraw" / "parts" / "escape.dat").is_symlink()
    # small files only: the bombs are a few nested lines, not their expansion
    assert sum(p.stat().st_size for p in (tmp_path / "ldraw").rglob("*") if p.is_file()) < 8 << 20


def test_quick_subset_ends_within_limits_without_traceback(tmp_path):
    run = _load("run")
    results = run.run_all(tmp_path, quick=True, timeout=30, mem_mb=2048)
    assert len(results) == len(_load("generate").QUICK) * len(run.QUICK_COMMANDS)
    problems = [f"{r.case} {r.command}: {r.problem} ({r.first_line})" for r in results if r.problem]
    assert not problems, "\n".join(problems)
    for r in results:
        assert r.status in (0, 2) and not r.timed_out
        assert "Traceback" not in r.stderr
    # the bombs are refused, not expanded
    by = {(r.case, r.command): r for r in results}
    assert by["mpd_bomb", "steps"].status == 2 and "parts" in by["mpd_bomb", "steps"].first_line
    assert by["edge_bomb", "verify"].status == 2 and "edge lines" in by["edge_bomb", "verify"].first_line


def test_designs_exits_2_on_a_bad_part_found_inside_a_shard(tmp_path):
    """A part's reference cycle is found only when a shard expands the part: designs exited 1
    ("re-run to retry", which cannot help); an input error exits 2 wherever it is found."""
    run = _load("run")
    (result,) = run.run_all(tmp_path, cases=["cycle"], commands=["designs"], timeout=60, mem_mb=2048)
    assert result.status == 2 and not result.problem, (result.status, result.first_line)
    assert "reference cycle" in result.stderr and "fix the input" in result.stderr and result.stderr.count("\n") == 1
