"""Hostile input: the quick subset of tests/hostile/run.py (a few refused-at-once cases, steps and
verify) generated in tmp_path, each in a subprocess under a small time and memory limit. The whole
corpus is `python tests/hostile/run.py --out DIR` (minutes; not run here)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

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


@pytest.mark.slow
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
    assert by["mpd_bomb", "steps"].status == 2 and "more than 200,000 parts" in by["mpd_bomb", "steps"].stderr
    assert by["edge_bomb", "verify"].status == 2 and "edge lines" in by["edge_bomb", "verify"].stderr


def test_designs_exits_2_on_a_bad_part_found_inside_a_shard(tmp_path):
    """A part's reference cycle is found only when a shard expands the part: designs exited 1
    ("re-run to retry", which cannot help); an input error exits 2 wherever it is found."""
    run = _load("run")
    (result,) = run.run_all(tmp_path, cases=["cycle"], commands=["designs"], timeout=60, mem_mb=2048)
    assert result.status == 2 and not result.problem, (result.status, result.first_line)
    assert "reference cycle" in result.stderr and "fix the input" in result.stderr and result.stderr.count("\n") == 1


@pytest.mark.slow
def test_unknown_colours_are_input_errors_in_every_command(tmp_path):
    """A colour code of 10^40 went through steps, verify and render (exit 0) and ended designs in
    an OverflowError ("re-run the same command"); a code no LDConfig.ldr has and no rule allows
    (600) was drawn grey. Both are input errors naming the file and line, in every command."""
    run = _load("run")
    results = run.run_all(tmp_path, cases=["huge_colour", "unknown_colour"], timeout=60, mem_mb=2048)
    assert len(results) == 2 * len(run.COMMANDS)
    for r in results:
        assert r.status == 2 and not r.problem, (r.case, r.command, r.first_line)
        assert f"{r.case}.ldr:3: " in r.first_line
        assert ("up to 0x7FFFFFF" if r.case == "huge_colour" else "unknown colour code 600") in r.first_line


def test_a_million_triangle_part_is_refused_by_the_renders_in_one_line(tmp_path):
    """A part of 1,000,000 triangles took 67.6 s and 4.2 GB to render (and, under a 4 GB limit,
    a 28-line traceback); the render path now has a triangle budget like the collision path's.
    Reading its steps, which needs no mesh on a GPU, still works."""
    run = _load("run")
    results = run.run_all(tmp_path, cases=["million_triangles"], commands=["steps", "render"], timeout=60,
                          mem_mb=2048)
    by = {r.command: r for r in results}
    assert by["steps"].status == 0 and not by["steps"].problem, by["steps"].first_line
    assert by["render"].status == 2 and not by["render"].problem, by["render"].first_line
    assert "1,000,000 triangles; renders take parts of at most 250,000" in by["render"].stderr


@pytest.mark.slow
def test_bad_flag_values_a_zip_library_and_bad_predictions_end_in_one_line(tmp_path):
    """Each ended in a traceback (a weight that is no number, weights whose sum overflows, a
    --predict of nan, 1e308 or a word: also exit 1, not 2); a zip library, now read in place, is
    refused in one line when a member would escape it, is a link, or inflates past the file cap."""
    run = _load("run")
    cases = ["zip_escape", "zip_link", "zip_bomb", "flag_weight_word", "flag_weight_huge", "predict_nan", "predict_huge", "predict_word",
             "predict_singular"]
    results = run.run_extra(tmp_path, cases, timeout=60, mem_mb=2048)
    assert [r.case for r in results] == cases
    for r in results:
        assert r.status == 2 and not r.problem and len(r.stderr_lines) == 1, (r.case, r.stderr)
    said = {r.case: r.stderr for r in results}
    assert "'ldraw/../escape.dat' names a path outside the archive" in said["zip_escape"]
    assert "'ldraw/parts/link.dat' is a symbolic link" in said["zip_link"]
    assert "library.zip!/ldraw/parts/3001.dat" in said["zip_bomb"] and "over 33,554,432 bytes" in said["zip_bomb"]
    assert "expected NAME or NAME:WEIGHT (a number), got '3001:abc'" in said["flag_weight_word"]
    assert "sum to more than a float holds" in said["flag_weight_huge"]
    assert "all finite" in said["predict_nan"] and "within +-10000 LDU" in said["predict_huge"]
    assert "got 'hello'" in said["predict_word"] and "degenerate" in said["predict_singular"]
