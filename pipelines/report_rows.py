"""The result rows (`pipelines.result_rows`) of a `make bench` report and of a dataset build.

`bench_rows(report)`: rows by file stem, in the shapes and `what` names of the rows kept so far:

- bench: "make bench, whole report" (`wall_s` and each section's seconds, `physics_s`, ...),
  "make bench synth: 20 objects of 6-10 bricks" (`wall_s`, `steps_per_s`, `steps`, `data_mb`; not
  when the build resumed), "make bench growth: 16 objects of 20 parts, <how>" (`steps_per_s`,
  `steps`, `wall_s`, `compile_s`), "make bench realism: ..." (`coverage_share` and one distance
  per table), "baseline <model>, synthetic test split" and "..., designs (all split)" (paper-mode
  `selection_accuracy`, `translation_error_ldu`, `rotation_error_deg`, `step_success_paper`,
  `step_success_strict`);
- physics: "loads|sweeps|whole checks, N bricks, CPU reference, P processes" (`per_s`) and
  "..., batched (jax)" (`per_s_b<batch>_<procs>proc`), "candidate checks, N bricks, <backend>"
  (`checks_per_s_b<batch>`, `loads_per_s_b<batch>`);
- render: "make bench render, <model> (<parts> parts)" (the 256 px figures of `render --bench`).

A `--quick` report's rows say so in their `what` ("make bench --quick, whole report", "loads, 30
bricks, CPU reference, 1 process, make bench --quick"): its sections are smaller, its figures others.

`build_row(summary, ...)`: the row of one `pipelines.synth` build for `builds.jsonl`.
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

from factory import gpus
from pipelines import result_rows, results
from pipelines.dataset.config import DatasetConfig

QUICK = ", make bench --quick"
BATCHED = "batched (jax)"
"""The batched path's name in the physics rows so far (the backend is called `jax` now)."""
PHYSICS = {"loads": "loads", "sweeps": "sweeps", "whole": "whole checks"}


def _figures(**figs) -> dict:
    """The figures given, less those not measured (None, NaN)."""
    return {k: v for k, v in figs.items() if v is not None and not (isinstance(v, float) and not math.isfinite(v))}


def _key(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")


def _physics(section: dict) -> list[dict]:
    rows = []
    checks: dict[tuple, dict] = {}
    for r in section.get("rows") or []:
        label = "CPU reference" if r["backend"] == "cpu" else BATCHED
        figs = checks.setdefault((r["bricks"], label), {})
        figs.update(_figures(**{f"checks_per_s_b{r['batch']}": r.get("checks_per_s"),
                                f"loads_per_s_b{r['batch']}": r.get("loads_per_s")}))
    rows += [{"what": f"candidate checks, {n} bricks, {label}", **f} for (n, label), f in checks.items() if f]
    for part, name in PHYSICS.items():
        grouped: dict[tuple, dict] = {}
        for r in section.get(part) or []:
            batched = r.get("jax_per_s", r.get("gpu_per_s"))
            if batched is not None:
                key = f"per_s_b{r['batch']}_{r.get('procs', 1)}proc"
                grouped.setdefault((r["bricks"], BATCHED), {})[key] = batched
            if r.get("cpu_per_s") is not None and batched is None:  # the reference alone (no GPU)
                p = r.get("cpu_workers", 1)
                grouped.setdefault((r["bricks"], f"CPU reference, {p} process{'es' if p != 1 else ''}"),
                                   {})["per_s"] = r["cpu_per_s"]
        rows += [{"what": f"{name}, {n} bricks, {label}", **f} for (n, label), f in grouped.items()]
    return rows


def _growth(section: dict) -> list[dict]:
    rows, seen = [], set()
    for r in section.get("growth") or []:
        if r["backend"] == "cpu":
            how = "CPU reference one at a time" if r["batch"] == 1 else f"CPU reference at batch {r['batch']}"
        else:
            how = f"batched at batch {r['batch']}, " + ("one process" if r.get("procs", 1) == 1
                                                         else f"{r['procs']} processes")
        key = (r["backend"], r["batch"], r.get("procs", 1))
        how += ", again (shapes compiled)" if key in seen else ""
        seen.add(key)
        rows.append({"what": f"make bench growth: {r['objects']} objects of {r.get('target_steps', r['steps'])} "
                             f"parts, {how}",
                     **_figures(steps_per_s=r["steps_per_s"], steps=r["steps"], wall_s=r["seconds"],
                                compile_s=r.get("compile_seconds"))})
    return rows


def _evaluation(section: dict) -> list[dict]:
    rows = []
    for name, e in section.items():
        split = "synthetic test split" if name == "synthetic" else f"{name} ({e['split']} split)"
        for model, r in e["baselines"].items():
            for label, sc in ((model, r["scores"]), (f"{model} + world feedback", r["scores"].get("feedback"))):
                if not sc:
                    continue
                paper, strict = sc["paper"]["overall"], sc["strict"]["overall"]
                figs = _figures(selection_accuracy=paper.get("selection_accuracy"),
                                translation_error_ldu=paper.get("translation_error_ldu"),
                                rotation_error_deg=paper.get("rotation_error_deg"),
                                step_success_paper=paper.get("step_success"),
                                step_success_strict=strict.get("step_success"))
                if figs:
                    rows.append({"what": f"baseline {label}, {split}", **figs})
    return rows


def bench_rows(report: dict) -> dict[str, list[dict]]:
    """The rows of a finished `pipelines.bench` report, by file stem (no date, machine or revision)."""
    bench: list[dict] = []
    kept = report.get("kept") or []
    bench.append({"what": f"make bench{' --resume' if kept else ''}, whole report",
                  "wall_s": report["wall_s"],
                  **{f"{k}_s": v for k, v in report.get("section_s", {}).items() if v is not None},
                  **({"note": f"kept from an earlier run: {', '.join(kept)}"} if kept else {})})
    s = report.get("synth")
    if s and s.get("steps_per_s") is not None and "synth" not in kept:
        bench.append({"what": f"make bench synth: {s['objects']} objects of 6-10 bricks",
                      "wall_s": s["wall_s"], "steps_per_s": s["steps_per_s"], "steps": s["steps"],
                      "data_mb": round(s["bytes"] / 1e6, 1)})
    sc = report.get("scale")
    if sc and "scale" not in kept:
        bench += [{"what": f"make bench scale: {sc['objects']} objects, {row['workers']} workers of {sc['cores']} cores, "
                           f"{sc['gpus']} GPU(s)", "steps_per_s": row["steps_per_s"], "wall_s": row["wall_s"],
                   "speedup": row["speedup"], "efficiency": row["efficiency"]} for row in sc["rows"]]
    bench += _growth(report.get("physics") or {})
    r = report.get("realism")
    if r and r.get("tables"):
        figs = _figures(coverage_share=r["tables"][0].get("coverage"),
                        **{f"{_key(t['table'])}_{_key(t['distance'])}": t["value"] for t in r["tables"]})
        bench.append({"what": f"make bench realism: synth objects against {len(r['designs'])} real designs", **figs})
    bench += _evaluation(report.get("evaluation") or {})
    f = report.get("feedback")
    if f and "feedback" not in kept:
        w = f.get("warp") or {}
        bench.append({"what": f"make bench feedback: {f['predictions']} predictions settled",
                      **_figures(cpu_per_s=f["cpu_per_s"], warp_per_s=w.get("warp_per_s"),
                                 agreement_share=w.get("agreement"))})
    render = [{"what": f"make bench render, {r['model']} ({r['parts']} parts)",
               **_figures(rgb_views_per_s_256=r.get("rgb_views_per_s"),
                          rgb_views_per_s_256_median=r.get("rgb_views_per_s_median"),
                          seg_views_per_s_256=r.get("seg_views_per_s"), render_step_s_256=r.get("step_render_s"))}
              for r in (report.get("render") or {}).get("rows", []) if r.get("size", 256) == 256]
    out = {"bench": bench, "physics": _physics(report.get("physics") or {}), "render": render}
    if report.get("quick"):
        for row in (row for rows in out.values() for row in rows):
            what = row["what"]
            quick = what.startswith("make bench")
            row["what"] = "make bench --quick" + what[len("make bench"):] if quick else what + QUICK
    return {stem: [row for row in rows if results.figures(row)] for stem, rows in out.items() if rows}


def append_bench(report: dict, results_dir: str | None, quick: bool, skip: bool = False) -> dict[str, int]:
    """Append the report's rows (`bench_rows`): to `results_dir`, else the repository's bench/results
    unless `quick`; none when `skip`. Re-renders docs/results.md when they went to the repository's
    files. Returns rows appended by file stem."""
    folder = None if skip else Path(results_dir) if results_dir else None if quick else results.RESULTS
    if folder is None:
        return {}
    m = report["machine"]
    machine = result_rows.describe_machine(m.get("cpus"), m.get("cpu_model"),
                                           gpus.models() or ([m["gpu"]] if m.get("gpu") else []))
    done = {}
    for stem, rows in bench_rows(report).items():
        rows = [{"revision": report.get("revision"), **r} for r in rows]
        result_rows.append_rows(stem, rows, folder, machine=machine)
        done[stem] = len(rows)
    page = result_rows.write_page(folder)
    print(f"bench: appended {sum(done.values())} result rows to {folder}/"
          f"{{{','.join(done)}}}.jsonl" + (f"; wrote {page}" if page else ""), flush=True)
    return done


# -- a dataset build's row ---------------------------------------------------------------------------
def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def config_changes(config) -> list[str]:
    """What a synthetic config sets other than `make synth`'s (`DatasetConfig.synthetic(n)`), as
    'field value' (the run settings, such as the checks' backend, are not part of it)."""
    made = _flat(DatasetConfig.synthetic(config.n_objects, seed=0).to_json())
    ours = _flat(config.to_json())
    out = []
    for k in sorted(set(made) | set(ours)):
        if k in ("sampler.seed", "schema_version") or made.get(k) == ours.get(k):
            continue
        v = ours.get(k)
        text = Path(v).name if k == "ldraw" and isinstance(v, str) else str(v)
        out.append(f"{k.rsplit('.', 1)[-1]} {text[:37] + '...' if len(text) > 40 else text}")
    return sorted(out)


def build_row(summary: dict, config, runner: str, workers: int, backend: str, auto: str | None = None,
              batch: int = 1, growers: int | None = None) -> dict | None:
    """The `builds.jsonl` row of a synthetic build's summary (`pipelines.dataset.build`), or None
    for a build that found shards already built (its wall time is not the whole build's).
    `backend`: the checks' backend; `auto`: why `--check-backend auto` chose it (None: named)."""
    if summary.get("shards_skipped"):
        return None
    t, wall, used = summary["total"], summary["wall_seconds"], summary.get("usage") or {}
    steps = t["steps"]
    how = f"{runner}, {backend} checks{' by auto' if auto else ''}, {workers} worker{'s' if workers != 1 else ''}"
    if batch > 1:
        how += f", batch {batch}" + (f", {growers} growers" if growers else "")
    changes = config_changes(config)
    what = (f"pipelines.synth --n {config.n_objects} ({how}); {', '.join(changes)}" if changes
            else f"make synth N={config.n_objects} ({how})")
    stages = summary.get("stage_seconds") or {}
    row = {"what": what, "wall_s": round(wall, 1), "steps": steps, "objects": t["objects"], "workers": workers,
           "steps_per_s": round(steps / wall, 2) if wall > 0 else None, "data_mb": round(t["bytes"] / 1e6, 1)}
    if steps:
        row.update({f"{k}_worker_s_per_step": round(v / steps, 3) for k, v in stages.items()})
        row["worker_s_per_step"] = round(sum(stages.values()) / steps, 3)
    cpu = used.get("cpu_seconds")
    if cpu:
        row.update(cpu_s=round(cpu["user"] + cpu["system"]), cpu_system_s=round(cpu["system"]))
    g = used.get("gpus") or []
    for x in g:
        prefix = "gpu" if len(g) == 1 else f"gpu{x['index']}"
        row.update({f"{prefix}_busy_pct": x["busy_mean_pct"], f"{prefix}_mem_max_mib": x["memory_max_mib"]})
    rss = (summary.get("peak_rss_mb") or {}).get("largest_worker")
    if rss:
        row["worker_rss_max_mb"] = rss
    if auto:
        row["note"] = f"auto: {auto}"
    return {k: v for k, v in row.items() if v is not None}


def append_build(summary: dict, results_dir: str, revision: str | None, **how) -> Path | None:
    """Append a build's row (`build_row`, `how` its arguments) to `results_dir/builds.jsonl`; None
    (and a line on stderr saying why) for a build that resumed."""
    row = build_row(summary, **how)
    if row is None:
        print(f"results: no row appended: {summary['shards_skipped']} shard(s) were built before this run, "
              "so its time is not the whole build's", file=sys.stderr)
        return None
    host = (summary.get("usage") or {}).get("host") or {}
    machine = result_rows.describe_machine(host.get("logical_cpus"), host.get("cpu_model"), host.get("gpus") or [])
    path = result_rows.append_rows("builds", [{"revision": revision, **row}], results_dir,
                                   machine=machine if host else None)
    print(f"results: appended a row to {path}", file=sys.stderr)
    return path
