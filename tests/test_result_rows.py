"""Result rows appended by programs (`pipelines.result_rows`, `pipelines.report_rows`): filled with
the date, machine and revision, checked as `pipelines.results` reads them, rendered into the page;
a build's row (`pipelines.synth --results`) and a bench report's rows.

No git command runs here against the checkout: the revision is faked, or read through a stand-in
`git` on PATH."""

from __future__ import annotations

import datetime
import json
import stat
import threading

import pytest

from pipelines import report_rows, result_rows, results
from pipelines.results import ResultsError


@pytest.fixture(autouse=True)
def fixed_revision(monkeypatch):
    monkeypatch.setattr(result_rows, "revision", lambda root=None: "abc1234")


def _read(path):
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def test_rows_are_filled_and_render_into_the_page(tmp_path):
    path = result_rows.append_rows("builds", [{"what": "make synth N=3 (local, cpu checks, 1 worker)",
                                               "wall_s": 12.5, "steps_per_s": 3.2, "note": "tiny"},
                                              {"what": "other", "steps": 40, "revision": None,
                                               "machine": "1x NVIDIA H200, 16 cores", "date": "2026-11-30"}],
                                   tmp_path)
    assert path == tmp_path / "builds.jsonl"
    first, second = _read(path)
    assert list(first) == ["date", "machine", "revision", "what", "wall_s", "steps_per_s", "note"]
    assert first["date"] == datetime.datetime.now(datetime.timezone.utc).date().isoformat()
    assert first["machine"] == result_rows.this_machine() and first["revision"] == "abc1234"
    assert second["revision"] is None and second["machine"] == "1x NVIDIA H200, 16 cores"  # given: kept
    assert results.read_rows(path) == [first, second]
    page = results.render(tmp_path)
    assert "## Whole builds" in page
    assert (f"| make synth N=3 (local, cpu checks, 1 worker) | wall_s 12.5, steps_per_s 3.2 (tiny) | "
            f"{first['machine']} | `abc1234` | {first['date']} |") in page
    # a second call appends; a file whose last line lost its newline gets one first
    with path.open("a") as f:
        f.write(json.dumps({**second, "what": "by hand"}))
    result_rows.append_rows("builds", [{"what": "third", "wall_s": 1}], tmp_path)
    assert [r["what"] for r in results.read_rows(path)] == [first["what"], "other", "by hand", "third"]


@pytest.mark.parametrize("row, message", [
    ({"what": "no figures", "note": "only text"}, "no numeric figure"),
    ({"what": "a flag is no figure", "ok": True}, "ok=True: not a number"),
    ({"what": "not measured", "wall_s": None, "steps": 3}, "wall_s=None: not a number"),
    ({"what": "", "wall_s": 1}, "'what' must name the measurement"),
    ({"what": "nan", "wall_s": float("nan")}, "not finite"),
    ({"what": "bad date", "date": "30.11.2026", "wall_s": 1}, "'date' must be YYYY-MM-DD"),
])
def test_a_row_that_would_not_read_is_refused_and_nothing_is_written(tmp_path, row, message):
    with pytest.raises(ResultsError, match=message) as err:
        result_rows.append_rows("bench", [{"what": "good", "wall_s": 1}, row], tmp_path)
    assert "bench.jsonl row 2 of 2" in str(err.value)  # names the row
    assert not (tmp_path / "bench.jsonl").exists()  # the good row was not written either
    with pytest.raises(ResultsError, match="plain name"):
        result_rows.append_rows("../escape", [{"what": "x", "wall_s": 1}], tmp_path)


def test_concurrent_appends_do_not_interleave(tmp_path):
    """Threads appending rows of a few KB each at once: every line is one whole row."""
    pad = "x" * 4000

    def writer(k):
        for i in range(20):
            result_rows.append_rows("bench", [{"what": f"w{k} {i}", "note": pad, "n": i}] * 3, tmp_path,
                                    machine="m")

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    rows = results.read_rows(tmp_path / "bench.jsonl")
    assert len(rows) == 4 * 20 * 3
    whats = [r["what"] for r in rows]
    assert all(whats[i] == whats[i + 1] == whats[i + 2] for i in range(0, len(whats), 3))  # a call's rows together


def _fake_git(tmp_path, monkeypatch, top, status):
    """A `git` on PATH answering `rev-parse` with `top` and a commit, `status` with `status`."""
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    git = bin_ / "git"
    git.write_text("#!/bin/sh\n"
                   f'case "$1" in rev-parse) printf "%s\\n" "{top}" 1a2b3c4;; '
                   f'status) echo "$GIT_OPTIONAL_LOCKS $*" > {tmp_path}/status-args; printf "{status}";; esac\n')
    git.chmod(git.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", str(bin_))


def test_the_revision_is_the_commit_dirty_when_a_tracked_file_differs(tmp_path, monkeypatch):
    monkeypatch.undo()  # the real `revision`, with a stand-in git
    repo = tmp_path / "repo"
    repo.mkdir()
    _fake_git(tmp_path, monkeypatch, repo, "")
    assert result_rows.revision(repo) == "1a2b3c4"
    args = (tmp_path / "status-args").read_text()
    assert args.startswith("0 status --porcelain --untracked-files=no") and ":(exclude)bench/results" in args
    (tmp_path / "bin" / "git").unlink()
    (tmp_path / "bin").rmdir()
    _fake_git(tmp_path, monkeypatch, repo, " M pipelines/bench.py\\n")
    assert result_rows.revision(repo) == "1a2b3c4+dirty"
    assert result_rows.revision(tmp_path) is None  # a checkout above the folder is not its own
    monkeypatch.setenv("PATH", str(tmp_path / "nothing"))
    assert result_rows.revision(repo) is None  # no git


def test_machine_in_the_words_of_the_rows_so_far():
    assert result_rows.describe_machine(16, "Intel(R) Xeon(R) Platinum 8480+", ["NVIDIA H200"]) == \
        "1x NVIDIA H200, 16 cores"
    assert result_rows.describe_machine(32, None, ["NVIDIA H200"] * 2) == "2x NVIDIA H200, 32 cores"
    assert result_rows.describe_machine(2, "AMD EPYC 7B13 64-Core Processor", []) == "2 AMD EPYC 7B13 cores, no GPU"


def _scores(selection, success):
    overall = {"selection_accuracy": selection, "translation_error_ldu": 1.5, "rotation_error_deg": 2.0,
               "step_success": success}
    return {m: {"overall": overall, "counts": {"unparseable": 0}} for m in ("strict", "paper", "bc")}


REPORT = {
    "quick": False, "revision": "def5678", "wall_s": 300.0,
    "machine": {"cpus": 2, "cpu_model": "AMD EPYC", "gpu": None},
    "section_s": {"physics": 90.0, "render": 10.0, "synth": 40.0, "evaluation": 20.0},
    "kept": [],
    "physics": {
        "rows": [{"backend": "cpu", "bricks": 10, "batch": 256, "checks_per_s": 50.0, "loads_per_s": 80.0}],
        "loads": [{"bricks": 30, "batch": 1024, "cpu_workers": 2, "cpu_per_s": 85.0}],
        "sweeps": [{"bricks": 30, "batch": 1024, "cpu_workers": 2, "cpu_per_s": 950.0}],
        "whole": [{"bricks": 30, "batch": 1024, "cpu_workers": 2, "cpu_per_s": 550.0}],
        "growth": [{"backend": "cpu", "batch": 1, "procs": 1, "objects": 8, "target_steps": 10, "steps": 80,
                    "seconds": 10.0, "steps_per_s": 8.0},
                   {"backend": "cpu", "batch": 8, "procs": 1, "objects": 8, "target_steps": 10, "steps": 80,
                    "seconds": 5.0, "steps_per_s": 16.0}]},
    "render": {"rows": [{"model": "tower.mpd", "parts": 11, "size": 256, "rgb_views_per_s": 90.0,
                         "rgb_views_per_s_median": 80.0, "seg_views_per_s": 500.0, "step_render_s": 0.3}]},
    "synth": {"objects": 20, "steps": 160, "bytes": 20_400_000, "wall_s": 41.3, "steps_per_s": 3.874},
    "evaluation": {"synthetic": {"split": "test", "baselines": {
        "oracle": {"scores": _scores(1.0, 1.0)},
        "random": {"scores": {**_scores(0.1, 0.0), "feedback": _scores(0.1, 0.0)}}}}},
}


def test_a_bench_report_gives_the_rows_of_the_files_so_far(tmp_path):
    rows = report_rows.bench_rows(REPORT)
    whats = {stem: [r["what"] for r in rs] for stem, rs in rows.items()}
    assert whats == {
        "bench": ["make bench, whole report", "make bench synth: 20 objects of 6-10 bricks",
                  "make bench growth: 8 objects of 10 parts, CPU reference one at a time",
                  "make bench growth: 8 objects of 10 parts, CPU reference at batch 8",
                  "baseline oracle, synthetic test split", "baseline random, synthetic test split",
                  "baseline random + world feedback, synthetic test split"],
        "physics": ["candidate checks, 10 bricks, CPU reference", "loads, 30 bricks, CPU reference, 2 processes",
                    "sweeps, 30 bricks, CPU reference, 2 processes",
                    "whole checks, 30 bricks, CPU reference, 2 processes"],
        "render": ["make bench render, tower.mpd (11 parts)"]}
    # the shapes of the rows kept so far (bench/results/bench.jsonl, physics.jsonl)
    assert rows["bench"][0] == {"what": "make bench, whole report", "wall_s": 300.0, "physics_s": 90.0,
                                "render_s": 10.0, "synth_s": 40.0, "evaluation_s": 20.0}
    assert rows["bench"][1] == {"what": "make bench synth: 20 objects of 6-10 bricks", "wall_s": 41.3,
                                "steps_per_s": 3.874, "steps": 160, "data_mb": 20.4}
    assert rows["bench"][4] == {"what": "baseline oracle, synthetic test split", "selection_accuracy": 1.0,
                                "translation_error_ldu": 1.5, "rotation_error_deg": 2.0, "step_success_paper": 1.0,
                                "step_success_strict": 1.0}
    assert rows["physics"][1] == {"what": "loads, 30 bricks, CPU reference, 2 processes", "per_s": 85.0}

    # appended where asked, with the report's revision; a quick report's only where asked
    assert report_rows.append_bench(REPORT, str(tmp_path), quick=False) == {"bench": 7, "physics": 4, "render": 1}
    (row,) = [r for r in _read(tmp_path / "physics.jsonl") if r["what"].startswith("loads")]
    assert row["revision"] == "def5678" and row["machine"] == "2 AMD EPYC cores, no GPU"
    assert "| make bench synth: 20 objects of 6-10 bricks | wall_s 41.3, steps_per_s 3.874" in results.render(tmp_path)
    assert report_rows.append_bench(REPORT, str(tmp_path), quick=False, skip=True) == {}
    assert report_rows.append_bench({**REPORT, "quick": True}, None, quick=True) == {}
    quick = report_rows.bench_rows({**REPORT, "quick": True})
    assert quick["bench"][0]["what"] == "make bench --quick, whole report"
    assert quick["physics"][1]["what"] == "loads, 30 bricks, CPU reference, 2 processes, make bench --quick"


def test_a_resumed_bench_says_what_it_kept_and_leaves_the_synth_rate_out():
    report = {**REPORT, "kept": ["physics"], "synth": {**REPORT["synth"], "steps_per_s": None}}
    bench = report_rows.bench_rows(report)["bench"]
    assert bench[0]["what"] == "make bench --resume, whole report"
    assert bench[0]["note"] == "kept from an earlier run: physics"
    assert not any(r["what"].startswith("make bench synth") for r in bench)


def test_a_gpu_report_gives_the_batched_rows_by_batch_and_processes():
    physics = {"loads": [{"bricks": 30, "batch": 1024, "jax_per_s": 3168.0},
                         {"bricks": 30, "batch": 4096, "procs": 4, "jax_per_s": 4174.0}],
               "whole": [{"bricks": 30, "batch": 1024, "gpu_per_s": 900.0}],
               "growth": [{"backend": "jax", "batch": 16, "procs": 1, "objects": 16, "target_steps": 20, "steps": 320,
                           "seconds": 50.9, "steps_per_s": 6.28, "compile_seconds": 27.9},
                          {"backend": "jax", "batch": 16, "procs": 1, "objects": 16, "target_steps": 20, "steps": 320,
                           "seconds": 30.0, "steps_per_s": 10.7, "compile_seconds": 0.0}]}
    rows = report_rows.bench_rows({**REPORT, "physics": physics})
    assert rows["physics"] == [{"what": "loads, 30 bricks, batched (jax)", "per_s_b1024_1proc": 3168.0,
                                "per_s_b4096_4proc": 4174.0},
                               {"what": "whole checks, 30 bricks, batched (jax)", "per_s_b1024_1proc": 900.0}]
    growth = [r for r in rows["bench"] if "growth" in r["what"]]
    assert growth == [{"what": "make bench growth: 16 objects of 20 parts, batched at batch 16, one process",
                       "steps_per_s": 6.28, "steps": 320, "wall_s": 50.9, "compile_s": 27.9},
                      {"what": "make bench growth: 16 objects of 20 parts, batched at batch 16, one process, "
                               "again (shapes compiled)", "steps_per_s": 10.7, "steps": 320, "wall_s": 30.0,
                       "compile_s": 0.0}]


def test_synth_results_appends_one_row_of_the_build(tmp_path, monkeypatch, capsys):
    """`pipelines.synth --results DIR`: the build's row in DIR/builds.jsonl; a re-run that finds the
    build done appends nothing."""
    from pipelines import synth

    monkeypatch.setattr(synth, "revision", lambda: "abc1234+dirty")
    args = ["--n", "2", "--out", str(tmp_path / "out"), "--min-steps", "1", "--max-steps", "2", "--size", "64",
            "--tile", "32", "--candidates", "16", "--objects-per-shard", "1", "--no-progress",
            "--check-backend", "cpu", "--results", str(tmp_path / "rows")]
    assert synth.main(args) == 0
    (row,) = results.read_rows(tmp_path / "rows" / "builds.jsonl")
    assert row["what"] == ("pipelines.synth --n 2 (local, cpu checks, 1 worker); candidates_per_step 16, "
                           "max_steps 2, min_steps 1, objects_per_shard 1, size 64, tile 32")
    assert row["revision"] == "abc1234+dirty" and row["machine"] == result_rows.this_machine()
    info = json.loads((tmp_path / "out" / "meta" / "info.json").read_text())
    assert row["objects"] == 2 and row["workers"] == 1 and row["steps"] == info["total"]["steps"] > 0
    assert row["wall_s"] > 0 and row["steps_per_s"] > 0 and row["worker_s_per_step"] > 0 and row["cpu_s"] >= 0
    assert "| pipelines.synth --n 2 (local, cpu checks, 1 worker); " in results.render(tmp_path / "rows")
    assert synth.main(args) == 0  # resumed: every shard built already
    assert "no row appended: 2 shard(s) were built before this run" in capsys.readouterr().err
    assert len(results.read_rows(tmp_path / "rows" / "builds.jsonl")) == 1
    assert synth.main(args[:-2] + ["--results", str(tmp_path / "out" / "meta" / "info.json")]) == 2


def test_make_synths_own_config_is_named_as_make_synth(tmp_path):
    from factory.sampler import SamplerConfig
    from pipelines.dataset.config import DatasetConfig

    summary = {"shards_skipped": 0, "wall_seconds": 10.0, "total": {"objects": 8, "steps": 400, "bytes": 9_000_000},
               "stage_seconds": {"check": 8.0, "render": 12.0}, "peak_rss_mb": {"main": 500.0, "largest_worker": 700.0},
               "usage": {"host": {"cpu_model": "x", "logical_cpus": 16, "gpus": ["NVIDIA H200"]},
                         "cpu_seconds": {"user": 100.4, "system": 5.2},
                         "gpus": [{"index": 0, "busy_mean_pct": 40.5, "memory_max_mib": 16501, "samples": 10}]}}
    config = DatasetConfig.synthetic(8, seed=0, sampler=SamplerConfig(backend="jax"))
    row = report_rows.build_row(summary, config, "local", 16, "jax", auto="1 NVIDIA GPU(s) and JAX's CUDA build")
    assert row == {"what": "make synth N=8 (local, jax checks by auto, 16 workers)", "wall_s": 10.0, "steps": 400,
                   "objects": 8, "workers": 16, "steps_per_s": 40.0, "data_mb": 9.0, "check_worker_s_per_step": 0.02,
                   "render_worker_s_per_step": 0.03, "worker_s_per_step": 0.05, "cpu_s": 106, "cpu_system_s": 5,
                   "gpu_busy_pct": 40.5, "gpu_mem_max_mib": 16501, "worker_rss_max_mb": 700.0,
                   "note": "auto: 1 NVIDIA GPU(s) and JAX's CUDA build"}
    assert report_rows.build_row({**summary, "shards_skipped": 1}, config, "local", 16, "jax") is None
    path = report_rows.append_build(summary, tmp_path, "abc1234", config=config, runner="local", workers=16,
                                    backend="jax")
    (written,) = _read(path)
    assert written["machine"] == "1x NVIDIA H200, 16 cores" and written["revision"] == "abc1234"  # the build's host
