"""`make bench` end to end, small: `pipelines.bench --quick` with the CPU backend and no human designs
writes a report whose numbers come from real runs (the oracle scores 1, chance scores below it)."""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np
import pytest

from pipelines import bench


@pytest.mark.slow
def test_quick_bench_writes_report_and_plots(tmp_path, monkeypatch):
    from pipelines import results

    out, rows = tmp_path / "bench", tmp_path / "rows"
    # the repository's rows and page stand in a temporary folder: a quick run must not touch them
    monkeypatch.setattr(results, "RESULTS", tmp_path / "repo-rows")
    monkeypatch.setattr(results, "PAGE", tmp_path / "results.md")
    monkeypatch.setattr(bench, "revision", lambda: "abc1234")
    assert bench.main(["--out", str(out), "--quick", "--backends", "cpu", "--models", "--results", str(rows)]) == 0
    report = json.loads((out / "report.json").read_text())
    for name in ("report.md", "physics.png", "render.png", "eval.png"):
        assert (out / name).stat().st_size > 0, name
    assert set(report["section_s"]) == {"physics", "render", "synth", "scale", "evaluation", "feedback"}
    scale = report["scale"]  # the same objects at 1 and 2 workers
    assert [r["workers"] for r in scale["rows"]] == [1, 2] and scale["rows"][0]["speedup"] == 1.0
    assert scale["rows"][0]["steps"] == scale["rows"][1]["steps"] > 0 and scale["rows"][1]["steps_per_s"] > 0
    assert "## Scale: steps/s against workers" in (out / "report.md").read_text()
    fb = report["feedback"]  # world-feedback simulations: MuJoCo C here, no GPU so no Warp figure
    assert fb["predictions"] == 48 and fb["cpu_per_s"] > 0 and 0 < fb["simulated"] < 48 and fb["warp"] is None
    assert fb["cpu_workers"] == (os.cpu_count() or 1) and fb["cpu_all_per_s"] > 0  # and over every core
    assert 0 < fb["cpu_step_share"] < 1  # what a faster simulator could save
    report_md = (out / "report.md").read_text()
    assert "## World feedback" in report_md and "of its time in `mj_step`" in report_md
    (phys,) = report["physics"]["rows"]
    assert phys["backend"] == "cpu" and phys["checks_per_s"] > 0 and 0 < phys["accepted"] <= phys["batch"]
    (loads,), (sweeps,) = report["physics"]["loads"], report["physics"]["sweeps"]
    assert loads["bricks"] == sweeps["bricks"] == 30 and loads["cpu_per_s"] > 0 and sweeps["cpu_per_s"] > 0
    growth = report["physics"]["growth"]
    assert [g["batch"] for g in growth] == [1, 2] and growth[0]["steps"] == growth[1]["steps"] > 0
    assert "Lockstep growth" in (out / "report.md").read_text()
    assert report["render"]["rows"][0]["rgb_views_per_s"] > 0
    synth = report["synth"]
    assert synth["objects"] == 5 and synth["steps"] >= 30 and synth["steps_per_s"] > 0
    assert synth["usage"]["host"]["cpu_model"] == report["machine"]["cpu_model"]
    assert f"on {report['machine']['cpus']} x {report['machine']['cpu_model']}" in (out / "report.md").read_text()
    ev = report["evaluation"]["synthetic"]["baselines"]
    oracle, rnd = ev["oracle"]["scores"], ev["random"]["scores"]
    for mode in ("strict", "paper", "bc"):
        assert oracle[mode]["overall"]["step_success"] == 1.0
        assert oracle[mode]["overall"]["selection_accuracy"] == 1.0
        assert rnd[mode]["overall"]["step_success"] < 1.0
    assert rnd["feedback"]["revised_steps"] > 0  # random answers get world feedback and a second try
    md = (out / "report.md").read_text()
    assert "| oracle | 1.000 | 1.000 | 0.0 | 0.0 | 1.000 | 1.000 | 1.000 | 0 |" in md
    assert "random + feedback" in md
    # --results: the figures appended as result rows (pipelines.report_rows), which render into a page
    appended = {p.stem: results.read_rows(p) for p in rows.glob("*.jsonl")}
    assert set(appended) == {"bench", "physics", "render"}
    whole, synth_row = appended["bench"][:2]
    assert whole["what"] == "make bench --quick, whole report" and whole["wall_s"] > 0
    assert whole["revision"] == "abc1234"
    assert synth_row["what"] == "make bench --quick synth: 5 objects of 6-10 bricks"
    assert synth_row["steps"] == synth["steps"]
    (oracle_row,) = [r for r in appended["bench"]
                     if r["what"] == "baseline oracle, synthetic test split, make bench --quick"]
    assert oracle_row["selection_accuracy"] == oracle_row["step_success_strict"] == 1.0
    (loads_row,) = [r for r in appended["physics"]
                    if r["what"].startswith("loads, 30 bricks, CPU reference, 1 process")]
    assert loads_row["per_s"] == loads["cpu_per_s"] and loads_row["date"] and loads_row["machine"]
    assert "| make bench --quick, whole report | wall_s" in results.render(rows)
    assert not (tmp_path / "results.md").exists()  # the page shows the repository's rows only
    # a re-run reuses the finished dataset (the builder resumes) and rewrites the report; --quick
    # without --results appends nothing
    assert bench.main(["--out", str(out), "--quick", "--backends", "cpu", "--models"]) == 0
    again = json.loads((out / "report.json").read_text())
    assert again["synth"]["resumed"] is True and again["kept"] == []
    assert not (tmp_path / "repo-rows").exists() and not (tmp_path / "results.md").exists()

    # --resume keeps the sections a run cut short had finished, and runs the rest
    # (the physics section keeps the parts it had finished)
    cut = {k: v for k, v in again.items() if k not in ("synth", "evaluation", "feedback")}
    cut["physics"] = {k: v for k, v in again["physics"].items() if k != "growth"}
    (out / "report.json").write_text(json.dumps(cut))
    assert bench.main(["--out", str(out), "--quick", "--backends", "cpu", "--models", "--resume",
                       "--results", str(rows), "--no-rows"]) == 0
    assert {p.stem: results.read_rows(p) for p in rows.glob("*.jsonl")} == appended  # --no-rows: none
    resumed = json.loads((out / "report.json").read_text())
    assert resumed["kept"] == ["render", "scale", "physics (rows, loads, sweeps, whole)"]
    for key in ("rows", "loads", "sweeps", "whole"):
        assert resumed["physics"][key] == again["physics"][key]
    assert resumed["render"] == again["render"]
    assert [g["batch"] for g in resumed["physics"]["growth"]] == [1, 2]
    assert resumed["physics"]["growth"] != again["physics"]["growth"]  # measured again: other seconds
    assert resumed["evaluation"]["synthetic"]["baselines"]["oracle"]["scores"]["strict"]["overall"]["step_success"] == 1.0
    assert "kept from an earlier run on this machine: render, scale, physics (rows, loads, sweeps, whole)" in (
        out / "report.md").read_text()

    # ... but not those of a report made on another machine
    cut["machine"]["cpus"] = (cut["machine"]["cpus"] or 0) + 1
    (out / "report.json").write_text(json.dumps(cut))
    assert bench.main(["--out", str(out), "--quick", "--backends", "cpu", "--models", "--resume"]) == 0
    assert json.loads((out / "report.json").read_text())["kept"] == []


def test_unknown_backend_is_a_clear_error(tmp_path, capsys):
    assert bench.main(["--out", str(tmp_path), "--backends", "cuda"]) == 2
    assert "unknown backend 'cuda'; valid: cpu, jax, auto" in capsys.readouterr().err


def test_growth_rows_grow_the_same_objects_at_every_batch(capsys):
    """`bench_physics --growth`: one row per batch, each over the same objects (the same parts placed),
    with a positive rate."""
    from pipelines.bench_growth import measure_growth

    rows = measure_growth("cpu", [1, 3], steps=3, objects=3)
    assert "bench_physics: warm-up: 4 objects in" in capsys.readouterr().err  # progress on stderr
    assert [r["batch"] for r in rows] == [1, 3]
    assert rows[0]["steps"] == rows[1]["steps"] > 0
    assert all(r["steps_per_s"] > 0 and r["stage_seconds"]["rules"] > 0 for r in rows)
    # the process's CPU seconds in the window, and their share of it (not bounded here: a loaded
    # machine makes the process wait for a core)
    # (both are rounded to 0.01 s, and these windows are well under a second)
    assert all(0 < r["cpu_seconds"] and r["cpu_share"] == pytest.approx(r["cpu_seconds"] / r["seconds"],
                                                                       abs=0.001 + 0.02 / r["seconds"]) for r in rows)


def test_growth_in_several_processes_grows_the_same_objects(capfd):
    """`bench_physics --growth --procs 2`: the objects split over two grower processes, each
    growing its half, all of them to their length, with each process's stage seconds summed."""
    from pipelines.bench_growth import measure_growth

    (one,) = measure_growth("cpu", [2], steps=3, objects=4)
    (two,) = measure_growth("cpu", [2], steps=3, objects=4, procs=2)
    err = capfd.readouterr().err  # the grower processes' progress, on the inherited stderr
    assert err.count("warm-up in") == 2 and err.count("2 of 2 objects") == 2
    assert two["procs"] == 2 and two["batch"] == 2 and one["procs"] == 1
    assert two["steps"] == one["steps"] == 12 and two["steps_per_s"] > 0 and two["stage_seconds"]["rules"] > 0
    assert two["cpu_seconds"] > 0 and two["cpu_share"] == pytest.approx(two["cpu_seconds"] / (2 * two["seconds"]),
                                                                       abs=0.001 + 0.02 / two["seconds"])


def _noop():
    pass


def _fail_before_the_barrier(span, barrier):
    if span[0] == 0:
        raise ValueError("ran out of device memory in its warm-up")
    barrier.wait()
    return time.time(), time.time()


def test_a_process_that_fails_in_its_warm_up_stops_the_others(monkeypatch):
    """`bench_processes._together`: when one process fails before the barrier, the others stop
    waiting for it and the error reaches the caller at once (on 2026-11-26 a process out of device
    memory left three others waiting until the bench was killed 375 s later)."""
    from pipelines import bench_processes

    monkeypatch.setattr(bench_processes, "BARRIER_S", 120.0)  # without the guard, the wait ends here
    t = time.perf_counter()
    with pytest.raises(ValueError, match="warm-up"):
        bench_processes._together([(0, 1), (1, 2)], _noop, (), _fail_before_the_barrier)
    assert time.perf_counter() - t < 60.0


def test_batched_growth_rows_count_the_compiles_in_their_window():
    """`bench_physics --growth` on the batched path (JAX on the CPU here): each row says how long
    the warm-up took (the first row) and how many JAX compiles fell inside its timed window; a
    second row over the same objects meets no new shape, so it compiles nothing."""
    pytest.importorskip("jax")
    from pipelines.bench_growth import measure_growth

    first, second = measure_growth("jax", [2, 2], steps=3, objects=2)
    assert first["warm_seconds"] > 0 and second["warm_seconds"] is None
    assert first["steps"] == second["steps"] > 0
    assert second["compiles"] == second["compile_cache_misses"] == 0 and second["compile_seconds"] == 0
    assert first["compiles"] >= first["compile_cache_misses"] >= 0

    # the counter itself: a shape never met is one compile, a second call none
    import jax
    import jax.numpy as jnp

    from pipelines import bench_growth

    bench_growth._count_compiles()
    f = jax.jit(lambda x: jnp.cumsum(x * 3.25))
    x = np.ones(1237, np.float32)  # a numpy input: jnp.ones would compile a kernel of its own
    f(x).block_until_ready()
    assert bench_growth._JIT["compiles"] == 1 and bench_growth._JIT["compile_s"] > 0
    f(x).block_until_ready()
    assert bench_growth._JIT["compiles"] == 1


@pytest.mark.slow
def test_grower_processes_load_the_kernels_one_process_compiled(tmp_path, monkeypatch):
    """`bench_physics --growth --procs 2` on the batched path, with an empty compilation cache:
    one process grows the warm-up objects alone first and compiles their kernels into the
    persistent cache; the two grower processes then compile fewer of them each (only those too
    quick to compile to be written), and the row says so."""
    pytest.importorskip("jax")
    from pipelines.bench_growth import measure_growth

    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "jax"))  # the spawned processes' cache
    (row,) = measure_growth("jax", [2], steps=3, objects=2, procs=2)
    assert row["steps"] == 6 and row["cache_fill_seconds"] > 0 and row["cache_fill_misses"] > 0
    # without the shared cache each of the two would compile what the one did (2x); here together at most 1x
    assert row["warm_cache_misses"] <= row["cache_fill_misses"]
    assert any((tmp_path / "jax").iterdir())
    assert row["mps"] is False  # how the growers shared the GPU: no GPU here (factory.mps)


def _too_big_for_memory(rows: int):
    import jax.numpy as jnp

    jnp.zeros((rows,), jnp.float32).block_until_ready()  # far more than any machine holds
    return [{"rows": rows}]


def _rows(n: int):
    return [{"row": i} for i in range(n)]


def _fails(n: int):
    raise ValueError(f"not an out-of-memory error ({n})")


@pytest.mark.slow
def test_a_call_out_of_device_memory_is_listed_and_the_part_goes_on():
    """`bench.part_rows` on a GPU (each call in its own process): a call that runs out of the
    device's memory (a real JAX allocation failure, here of the CPU backend) is listed with its
    part, call and error, and the part keeps the other calls' rows; any other error stops it."""
    import functools

    pytest.importorskip("jax")
    failed = []
    calls = [functools.partial(_too_big_for_memory, 10**13), functools.partial(_rows, 2)]
    assert bench.part_rows("loads", calls, True, failed) == [{"row": 0}, {"row": 1}]
    (entry,) = failed
    assert entry["part"] == "loads" and entry["call"] == "_too_big_for_memory(10000000000000)"
    assert "RESOURCE_EXHAUSTED" in entry["error"]
    with pytest.raises(ValueError, match="not an out-of-memory"):
        bench.part_rows("loads", [functools.partial(_fails, 1)], True, failed)
    assert len(failed) == 1
    md = bench.markdown({"machine": {"cpus": 2, "processor": "x", "gpu": "g", "python": "3", "mujoco_gl": "egl"},
                         "wall_s": 1.0, "section_s": {}, "physics": {"note": "n", "rows": [], "failed": failed}})
    assert "Not measured, out of the device's memory (loads): `_too_big_for_memory(10000000000000)`" in md


def test_the_gpu_is_named_from_the_driver_list_before_any_cuda_library(monkeypatch):
    """`gpu_name` takes the NVIDIA driver's first GPU (`factory.gpus.models`) without starting JAX
    or torch; without one listed it falls back to them (None on this CPU machine)."""
    from factory import gpus

    monkeypatch.setattr(gpus, "models", lambda: ["NVIDIA H200", "NVIDIA H200"])
    assert bench.gpu_name() == "NVIDIA H200"
    monkeypatch.setattr(gpus, "models", lambda: [])
    monkeypatch.setitem(sys.modules, "torch", None)  # importing it fails: no CUDA library asked
    monkeypatch.setitem(sys.modules, "jax", None)
    assert bench.gpu_name() is None


@pytest.mark.slow
def test_the_solver_benchmark_compares_the_batched_solver_with_highs(capsys):
    from pipelines.bench_physics import main

    assert main(["--solver", "--sizes", "120", "--batches", "8"]) == 0
    (row,) = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert row["size"] == 120 and row["problems"] == 8 and row["variables"] >= 120
    assert row["not_optimal"] == 0 and row["verdicts_differing"] == 0 and row["max_objective_error"] < 1e-4


def test_scale_counts_double_up_to_every_core_and_bad_flags_are_refused(tmp_path, capsys):
    from pipelines import bench_scale

    assert bench_scale.worker_counts(16) == [1, 2, 4, 8, 16] and bench_scale.worker_counts(6) == [1, 2, 4, 6]
    assert bench_scale.worker_counts(1) == [1]
    for bad in (["--workers", "2,x"], ["--workers", "0"], ["--n", "0"]):
        with pytest.raises(SystemExit) as e:
            bench_scale.main(["--out", str(tmp_path), *bad])
        assert e.value.code == 2
    assert "--workers" in capsys.readouterr().err
