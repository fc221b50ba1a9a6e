"""`make bench`: one report of what the factory does per second and how the baselines score.

`python -m pipelines.bench [--out bench] [--ldraw DIR] [--models FILE ...] [--quick] [--results DIR] [--no-rows]`

Sections, each timed and written as soon as it ends (a later failure loses nothing before it):

- machine: CPU count, GPU (through JAX or torch when they see one), package versions;
- physics: candidate checks per second per backend present (`cpu` always; `jax` when JAX is
  installed; larger batches when a GPU is present), from `pipelines.bench_checks.measure`; load
  checks and sweeps at 30-90 bricks; lockstep growth of the same objects (`measure_growth`: on a
  GPU the batched path at batch 16, twice (the second row every shape compiled), against the CPU
  reference one object at a time);
- render: views per second of the embedded example model and, where given, of human designs;
- synth: a small `make synth` build end to end (steps per second, per-stage seconds, bytes);
- scale: steps per second of the same objects at 1, 2, 4, ... workers up to every core, with the
  speed-up, efficiency and each stage's worker-seconds per step (`pipelines.bench_scale`);
- realism: how far that build's objects are from real designs (`pipelines.distance`: coverage of
  the designs' placements, one distance per table), against ../shared/designs read with
  ../shared/ldraw_library.zip where present (`--quick`: the human designs given, if any);
- feedback: world-feedback simulations per second (`pipelines.bench_settle`'s predictions):
  MuJoCo C in one process and over every core, and MuJoCo Warp on the same predictions where a
  GPU is;
- evaluation: the baselines (`oracle`, `heuristic`, `random`, and `random` revised under world
  feedback) scored on that build's test split and on the human designs, in the three modes
  (strict, paper, and bc: BC-Bench's released scorer, `eval.bc`).

Outputs: `OUT/report.json`, `OUT/report.md`, `OUT/physics.png`, `OUT/render.png`, `OUT/eval.png`, and
the work folders under `OUT/work/` (the datasets and prediction files, reused by a re-run: the
dataset builder resumes). A finished run appends its figures to bench/results/*.jsonl and re-renders
docs/results.md (`pipelines.report_rows`; `--results DIR`: to DIR/*.jsonl instead; `--quick`: only
there; `--no-rows`: none). The defaults took 258 s on a 2-core CPU with the six designs of
`../shared/ldraw_models` (2026-11-26, the parts' decompositions already cached): physics 89 s,
renders 14 s, synth 28 s, designs 81 s, evaluation 43 s.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import os
import platform
import sys
import time
from importlib import metadata
from pathlib import Path

from eval.data import DatasetError
from eval.predict import predict_file
from eval.score import score_file
from factory import gpus
from factory.atomic import write_atomic, write_figure
from factory.cli import ArgumentParser, run_guarded
from factory.ldraw import get_reader
from factory.physics.check import BACKENDS, OLD_BACKEND_NAMES, backend_arg
from factory.sampler import SamplerConfig, SamplerConfigError
from pipelines.bench_checks import measure, measure_lp, measure_sweep, measure_whole
from pipelines.bench_growth import measure_growth
from pipelines.bench_processes import in_own_process
from pipelines.bench_scale import markdown as scale_markdown, scale_section
from pipelines.bench_settle import cases, throughput
from pipelines.dataset import ConfigMismatchError, DatasetConfig, build, usage
from pipelines.designs import design_config
from pipelines.realism import Collection, compare, read_collection
from pipelines.report_rows import append_bench
from pipelines.result_rows import revision
from pipelines.render import view_rates

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "factory" / "data" / "examples" / "tower.mpd"
SHARED = ROOT.parent / "shared"
BASELINES = ("oracle", "heuristic", "random")
PACKAGES = ("numpy", "mujoco", "jax", "jaxlib", "coacd", "trimesh", "pyarrow", "torch", "transformers")


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def gpu_name() -> str | None:
    """The first GPU the NVIDIA driver lists (`factory.gpus.models`, no CUDA started), else the first
    JAX or torch can see, else None (never initialises CUDA when neither is installed)."""
    listed = gpus.models()
    if listed:
        return listed[0]
    try:
        import jax  # optional: the [jax] extra

        devices = [d for d in jax.devices() if d.platform == "gpu"]
        if devices:
            return str(getattr(devices[0], "device_kind", devices[0]))
    except Exception:  # no JAX, or JAX without a GPU backend
        pass
    try:
        import torch  # optional: the [train] extra

        if torch.cuda.is_available():
            return torch.cuda.get_device_name(0)
    except Exception:
        pass
    return None


def machine() -> dict:
    return {
        "node": platform.node(), "processor": platform.processor() or platform.machine(),
        "cpu_model": usage.cpu_model(),
        "cpus": os.cpu_count(), "python": platform.python_version(), "gpu": gpu_name(),
        "mujoco_gl": os.environ.get("MUJOCO_GL") or "unset (renders pick EGL, else OSMesa)",
        "packages": {p: _version(p) for p in PACKAGES},
    }


GPU_PROCS = 4
"""Processes sharing the GPU in the second set of batched rows (`bench_physics --procs`)."""


PHYSICS_PARTS = ("rows", "loads", "sweeps", "whole", "growth")
"""The physics section's parts, each kept in report.json as soon as it is measured (`--resume`)."""


def _log_row(kind: str, row: dict) -> None:
    print(f"  {kind} {json.dumps(row)}", flush=True)


def _memory_error(exc: BaseException) -> str | None:
    """The line of `exc`'s message saying the device ran out of memory, None if it does not."""
    return next((line[:300] for line in str(exc).splitlines()
                 if "RESOURCE_EXHAUSTED" in line or "out of memory" in line.lower()), None)


def _describe(call) -> str:
    """A part's call as `fn(arguments)`, for the report's list of calls that did not fit."""
    args = [repr(a) for a in call.args] + [f"{k}={v!r}" for k, v in call.keywords.items() if k != "log"]
    return f"{call.func.__name__}({', '.join(args)})"


def part_rows(name: str, calls, isolated: bool, failed: list) -> list:
    """The rows of each call, in order. `isolated` (on a GPU): each call in a process of its own,
    and a call that runs out of device memory is listed in `failed` (part, call, error) and the
    part goes on with the next call: a card with less memory than the one the batches were chosen
    for measures what fits. Any other error stops the bench."""
    rows = []
    for call in calls:
        try:
            rows += in_own_process(call) if isolated else call()
        except Exception as exc:  # noqa: BLE001 - only out of memory is kept going, below
            error = _memory_error(exc) if isolated else None
            if error is None:
                raise
            failed.append({"part": name, "call": _describe(call), "error": error})
            print(f"  {name}: {failed[-1]['call']} ran out of the device's memory; going on", flush=True)
    return rows


def physics_section(gpu: bool, quick: bool, backends: list[str] | None = None, done: dict | None = None,
                    save=None) -> dict:
    """The physics section; parts already in `done` (a resumed run's) are kept, and `save(part)`
    is called with the section so far after each part."""
    if backends is None:
        backends = ["cpu"] + (["jax"] if _version("jax") else [])
    section = {"backends": backends, **{k: v for k, v in (done or {}).items() if k in PHYSICS_PARTS}}
    section["failed"] = [f for f in (done or {}).get("failed", []) if f["part"] in section]
    log = lambda kind: functools.partial(_log_row, kind)

    def part(name, *calls):
        """The part `name`: the rows of each call, in order."""
        if name not in section:
            # On a GPU each call runs in a process of its own: JAX keeps the device memory it has
            # grown until its process ends, and the next call's processes need it (2026-11-26, one
            # H200: the shared load rows ran out of memory behind the one-process rows, twice:
            # behind the bench's own process, then behind the part's).
            section[name] = part_rows(name, calls, gpu, section["failed"])
            if save is not None:
                save(section)

    P = functools.partial  # parts are picklable calls: on a GPU they run in a process of their own
    sizes = [10] if quick else [10, 30]
    # On a GPU the batched load stage is timed up to a batch that fills it; the CPU reference's rate
    # does not depend on the batch, so it is timed at the smallest (16,384 of its load programs
    # take minutes). Whole checks stop at 4,096 here; the whole-check rows below go further.
    part("rows", P(measure, backends, sizes, [256, 4096] if gpu else [256], log=log("physics"), full_max=4096,
                   reference_max=256))
    # The two expensive checks alone at 30, 60 and 90 bricks: on a GPU the batched path in one
    # process and in GPU_PROCS processes sharing the device (the host's cores select pairs and
    # build programs while another process's launch runs, as the factory's workers do; the CPU
    # reference's rates come from a machine without one: docs/results.md compares them); without
    # one, the CPU reference in two processes.
    check_sizes = [30] if quick else [30, 60, 90]
    if gpu:
        one, shared = [1024, 16384], [16384]
        part("loads", P(measure_lp, check_sizes, one, log=log("loads"), cpu_max=0),
             # Four processes of 4,096 load programs of 90 bricks each do not fit an H200's
             # memory (2026-11-26), so the shared load rows stop at 4,096.
             P(measure_lp, check_sizes, [4096], log=log("loads"), cpu_max=0, procs=GPU_PROCS))
        part("sweeps", P(measure_sweep, check_sizes, one, cpu_max=0, log=log("sweep")),
             P(measure_sweep, check_sizes, shared, cpu_max=0, log=log("sweep"), procs=GPU_PROCS))
        part("whole", P(measure_whole, check_sizes, one, log=log("whole"), cpu_max=0),
             P(measure_whole, check_sizes, [4096, 16384], log=log("whole"), cpu_max=0, procs=GPU_PROCS))
    else:
        workers = 1 if quick else 2
        part("loads", P(measure_lp, check_sizes, [1024], log=log("loads"), cpu_max=16 if quick else 128,
                        cpu_workers=workers, batched=False))
        part("sweeps", P(measure_sweep, check_sizes, [1024], cpu_max=32 if quick else 512, log=log("sweep"),
                         cpu_workers=workers, batched=False))
        part("whole", P(measure_whole, check_sizes, [1024], log=log("whole"), cpu_max=32 if quick else 256,
                        cpu_workers=workers, batched=False))
    # Lockstep growth of the same objects: on a GPU the batched path at one batch against the CPU
    # reference one object at a time; without one, the reference at two batches (the objects are
    # the same whatever the batch, only the cost moves). The batched path grows them twice: its
    # first row holds the compiles of the shapes its warm-up objects did not meet (36 kernels, 28 s
    # of a 51 s row on an H100, 2026-11-26), the second, every shape compiled, its steady rate.
    if gpu and "jax" in backends:
        part("growth", P(measure_growth, "jax", [16, 16], steps=20, objects=16, log=log("growth")),
             P(measure_growth, "cpu", [1], steps=20, objects=16, log=log("growth")))
    else:
        objects, steps = (2, 3) if quick else (8, 10)
        part("growth", P(measure_growth, "cpu", [1, objects], steps=steps, objects=objects, log=log("growth")))
    section["note"] = ("candidates of a 2x4 brick on grown 2x4-brick structures; loads/s is the "
                       "whole-structure load program alone (HiGHS for cpu, the batched JAX solver for jax), "
                       "checks/s the whole check (connection, contacts, clutch, loads)")
    return section


def render_section(models: list[tuple[Path, str | None]]) -> dict:
    rows = []
    for model, ldraw in models:
        for r in view_rates(model, ldraw, [256]):
            print(f"  render {json.dumps(r)}", flush=True)
            rows.append(r)
    return {"rows": rows}


def synth_section(work: Path, quick: bool) -> dict:
    """A small synthetic build: objects of 6-10 bricks so that it runs in about a minute here."""
    n = 5 if quick else 20
    config = DatasetConfig.synthetic(n, seed=0, sampler=SamplerConfig(min_steps=6, max_steps=10), objects_per_shard=1,
                                     dataset_id="bench-synth")
    out = work / "synth"
    summary = build(config, out, workers=min(2, os.cpu_count() or 1), progress=False)
    steps = summary["total"]["steps"]
    built = summary["shards_built"]
    return {
        "out": str(out), "objects": summary["total"]["objects"], "steps": steps,
        "bytes": summary["total"]["bytes"], "counts": summary["counts"],
        "wall_s": summary["wall_seconds"], "stage_seconds": summary["stage_seconds"],
        "steps_per_s": round(steps / summary["wall_seconds"], 3) if built == summary["total"]["objects"] else None,
        "resumed": built < summary["total"]["objects"],
        "config": "objects of 6-10 bricks, 256 px views, 128 px catalog tiles, seed 0",
        "usage": summary["usage"],
    }


def feedback_section(gpu: bool, quick: bool) -> dict:
    """World-feedback simulations per second (`pipelines.bench_settle`'s predictions): MuJoCo C in
    one process and over every core of this machine (`bench_settle.throughput`), with the share of
    its time inside `mj_step` (what a faster simulator can save), and where a GPU
    is, MuJoCo Warp batched in one process (`settle_mjx.settle_many`) on the same predictions with
    the share of outcomes equal to MuJoCo C's. Warp on a CPU is left out (it runs, slowly:
    `bench_settle --device cpu`)."""
    n, seed = (48, 1) if quick else (500, 1)
    cs = cases(n, 8, seed)
    cores = os.cpu_count() or 1
    one = throughput(cs, "cpu", 1)
    every = throughput(cs, "cpu", cores)
    out = {"predictions": len(cs), "scenes": len({c["scene"] for c in cs}), "seed": seed,
           "simulated": one["simulated"], "cpu_s": one["wall_s"], "cpu_per_s": one["per_s"],
           "cpu_workers": cores, "cpu_all_s": every["wall_s"], "cpu_all_per_s": every["per_s"],
           "cpu_step_share": one["cpu"]["step_share"], "warp": None}
    if gpu and importlib.util.find_spec("warp") is None:
        out["warp"] = {"error": "MuJoCo Warp not available: the [warp] extra is not installed"}
    elif gpu:
        got = throughput(cs, "warp", 1)
        out["warp"] = {"device": got["device"] or "default", "warp_s": got["wall_s"], "warp_per_s": got["per_s"],
                       "agreement": round(sum(a == b for a, b in zip(one["per_case"], got["per_case"])) / len(cs), 4)}
    return out


def designs_section(work: Path, models: list[Path], ldraw: str) -> dict:
    # No physics replay: the baselines need the targets and images only, and the replay would first
    # decompose every real part with coacd (minutes on a new machine; docs/concepts/collision.md, pipelines.verify).
    config = design_config(models, ldraw, seed=0, physics=False, objects_per_shard=1, dataset_id="bench-designs")
    out = work / "designs"
    summary = build(config, out, workers=1, progress=False)
    return {"out": str(out), "objects": summary["total"]["objects"], "steps": summary["total"]["steps"],
            "wall_s": summary["wall_seconds"], "counts": summary["counts"]}


def _real_designs(models: list[Path], ldraw: str | None) -> tuple[list[Path], str | None]:
    """The real designs the realism section compares with: the 19 of ../shared/designs with the
    library they resolve against, where both are present; else the human designs of this run."""
    designs, library = SHARED / "designs", SHARED / "ldraw_library.zip"
    if designs.is_dir() and library.is_file():
        return sorted(p for p in designs.iterdir() if p.suffix.lower() in (".ldr", ".mpd")), str(library)
    return models, ldraw


def realism_section(objects: str, designs: list[Path], ldraw: str | None) -> dict:
    """How far the synth section's objects are from real designs (`pipelines.realism`): coverage of
    the designs' placements, and one distance per table."""
    reader = get_reader(ldraw)
    real = Collection("real designs")
    for d in designs:
        real.objects += read_collection(d, reader).objects
    tables = compare(read_collection(objects, reader), real, reader, top=10)
    return {"designs": [str(d) for d in designs], "ldraw": ldraw, "tables": [t.to_json() for t in tables],
            "note": "objects of 6-10 bricks each, so parts per object differs by design"}


def evaluation_section(datasets: dict[str, tuple[str, str | None]], work: Path) -> dict:
    """Baselines on each dataset (name -> (folder, split)), in every mode, plus random under feedback."""
    out = {}
    for name, (folder, split) in datasets.items():
        res = {}
        for model in BASELINES:
            preds = work / f"preds-{name}-{model}.jsonl"
            feedback = model == "random"
            t = time.perf_counter()
            predict_file(folder, f"baseline:{model}", preds, split=split, seed=0, feedback=feedback,
                         progress=False)
            seconds = time.perf_counter() - t
            res[model] = {"scores": score_file(folder, preds, split=split, mode="all"),
                          "predict_s": round(seconds, 2)}
            print(f"  eval {name} {model}: {_headline(res[model]['scores'])}", flush=True)
        out[name] = {"data": folder, "split": split or "all", "baselines": res}
    return out


def _headline(scores: dict) -> str:
    p = scores["paper"]["overall"]
    return (f"selection {_fmt(p['selection_accuracy'])}, step success (paper) {_fmt(p['step_success'])}, "
            f"strict {_fmt(scores['strict']['overall']['step_success'])}")


def _fmt(v, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def _table(header: list[str], rows: list[list]) -> list[str]:
    """A markdown table: the first column left-aligned, the numbers right-aligned."""
    return ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1),
            *("| " + " | ".join(str(c) for c in row) + " |" for row in rows)]


# -- report ---------------------------------------------------------------------------------------


def plots(report: dict, out: Path) -> list[str]:
    import matplotlib  # optional: the [bench] extra

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    phys = report.get("physics", {}).get("rows", [])
    if phys:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        keys = sorted({(r["backend"], r["batch"]) for r in phys})
        for backend, batch in keys:
            rs = [r for r in phys if r["backend"] == backend and r["batch"] == batch and "checks_per_s" in r]
            if not rs:
                continue
            ax.plot([r["bricks"] for r in rs], [r["checks_per_s"] for r in rs], marker="o",
                    label=f"{backend}, batch {batch}")
        ax.set_xlabel("bricks in the structure")
        ax.set_ylabel("candidate checks / s")
        ax.set_yscale("log")
        ax.set_title("Physics checker throughput")
        ax.legend()
        fig.tight_layout()
        write_figure(fig, out / "physics.png", dpi=100)
        plt.close(fig)
        written.append("physics.png")
    rend = report.get("render", {}).get("rows", [])
    if rend:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        labels = [f"{r['model']}\n({r['parts']} parts)" for r in rend]
        x = range(len(rend))
        ax.bar([i - 0.2 for i in x], [r["rgb_views_per_s"] for r in rend], 0.4, label="RGB")
        ax.bar([i + 0.2 for i in x], [r["seg_views_per_s"] for r in rend], 0.4, label="segmentation")
        ax.set_xticks(list(x), labels)
        ax.set_ylabel("views / s at 256 px")
        ax.set_title("Render throughput")
        ax.legend()
        fig.tight_layout()
        write_figure(fig, out / "render.png", dpi=100)
        plt.close(fig)
        written.append("render.png")
    ev = report.get("evaluation", {})
    if ev:
        fig, axes = plt.subplots(1, len(ev), figsize=(5 * len(ev), 3.5), squeeze=False)
        for ax, (name, e) in zip(axes[0], ev.items()):
            models = list(e["baselines"])
            metrics = [("selection", lambda s: s["paper"]["overall"]["selection_accuracy"]),
                       ("success paper", lambda s: s["paper"]["overall"]["step_success"]),
                       ("success strict", lambda s: s["strict"]["overall"]["step_success"])]
            w = 0.8 / len(metrics)
            for j, (label, get) in enumerate(metrics):
                ax.bar([i + (j - 1) * w for i in range(len(models))],
                       [get(e["baselines"][m]["scores"]) or 0.0 for m in models], w, label=label)
            ax.set_xticks(range(len(models)), models)
            ax.set_ylim(0, 1.05)
            ax.set_title(f"Baselines on {name} ({e['split']})")
        axes[0][0].legend(fontsize=8)
        fig.tight_layout()
        write_figure(fig, out / "eval.png", dpi=100)
        plt.close(fig)
        written.append("eval.png")
    return written


def markdown(report: dict) -> str:
    m = report["machine"]
    lines = ["# Brick Factory benchmark", "",
             f"Machine: {m['cpus']} CPUs ({m.get('cpu_model') or m['processor']}), GPU: {m['gpu'] or 'none'}, "
             f"Python {m['python']}, MUJOCO_GL={m['mujoco_gl']}. Total {report['wall_s']:.0f} s"
             + (f" in this run; kept from an earlier run on this machine: {', '.join(report['kept'])}."
                if report.get("kept") else "."), ""]
    if "physics" in report:
        lines += ["## Physics checker", "", report["physics"]["note"] + ".", ""]
        lines += _table(["backend", "bricks", "batch", "checks/s", "loads/s", "accepted", "compile s"],
                        [[r["backend"], r["bricks"], r["batch"], r.get("checks_per_s", "-"), r["loads_per_s"],
                          r.get("accepted", "-"), r["compile_s"]] for r in report["physics"]["rows"]])
        lines += ["", "![physics](physics.png)", ""]
        for key, title in (("loads", "Load checks (from the candidates' connections)"),
                           ("sweeps", "Buildability sweeps (from the candidates' connections)"),
                           ("whole", "Whole checks (every check a candidate goes through)")):
            rows = report["physics"].get(key) or []
            if rows:
                lines += [f"### {title}", "", "GPU: the batched path on the default JAX device, in one process "
                          "or several sharing it; CPU: the reference (HiGHS / `sweep.sweep` / `check` with "
                          f"MuJoCo C) in {rows[0].get('cpu_workers', '-')} process(es).", ""]
                lines += _table(["bricks", "batch", "GPU processes", "GPU per s", "CPU reference per s"],
                                [[r["bricks"], r["batch"], r.get("procs", 1) if "cpu_per_s" not in r else "-",
                                  r.get("jax_per_s", r.get("gpu_per_s", "-")), r.get("cpu_per_s", "-")] for r in rows])
                lines += [""]
    for f in report.get("physics", {}).get("failed") or []:
        lines += [f"Not measured, out of the device's memory ({f['part']}): `{f['call']}`: {f['error']}", ""]
    growth = report.get("physics", {}).get("growth") or []
    if growth:
        lines += ["### Lockstep growth (`bench_physics --growth`)", "",
                  "The same objects (default config, exactly the given parts each) grown a batch at a time "
                  "in one process; steps per second over the whole growth.", ""]
        lines += _table(["backend", "batch", "objects", "steps", "seconds", "steps/s", "warm-up s",
                         "compiles in the window (compiled here), s"],
                        [[r["backend"], r["batch"], r["objects"], r["steps"], r["seconds"], r["steps_per_s"],
                          _fmt(r.get("warm_seconds"), 2),
                          f"{r['compiles']} ({r['compile_cache_misses']}), {r['compile_seconds']}" if "compiles" in r
                          else "-"] for r in growth])
        lines += [""]
    if "render" in report:
        lines += ["## Renders", "", "Best of 3 passes over 7 views (6 orthographic, 1 isometric) at 256 px; "
                  "a step render is every image of one step except the catalog.", ""]
        lines += _table(["model", "parts", "RGB views/s", "segmentation views/s", "step render s"],
                        [[r["model"], r["parts"], r["rgb_views_per_s"], r["seg_views_per_s"], r["step_render_s"]]
                         for r in report["render"]["rows"]])
        lines += ["", "![render](render.png)", ""]
    if "realism" in report:
        r = report["realism"]
        cov = r["tables"][0]
        lines += ["## How far from real designs (`pipelines.distance`)", "",
                  f"The synth section's objects beside {len(r['designs'])} real designs ({r['note']}): they use part "
                  f"families covering {cov['coverage']:.1%} of the designs' placements "
                  f"({cov['covered_placements']} of {cov['real_placements']}).", ""]
        lines += _table(["table", "distance", "value"], [[t["table"], t["distance"], _fmt(t["value"])]
                                                        for t in r["tables"]])
        lines += [""]
    if "synth" in report:
        s = report["synth"]
        stages = ", ".join(f"{k} {v} s" for k, v in s["stage_seconds"].items())
        rate = f"{s['steps_per_s']} steps/s" if s["steps_per_s"] is not None else "resumed, rate not measured"
        lines += ["## End to end (`make synth`)", "",
                  f"{s['objects']} objects ({s['config']}): {s['steps']} steps "
                  f"({s['counts']['train']['steps']} train, {s['counts']['test']['steps']} test), "
                  f"{s['bytes'] / 1e6:.1f} MB, wall {s['wall_s']} s, {rate}. Stage seconds summed over "
                  f"workers: {stages}." + (f" Used: {usage.describe(s['usage'])}." if s.get("usage") else ""), ""]
    if "scale" in report:
        lines += scale_markdown(report["scale"])
    if "designs" in report:
        d = report["designs"]
        lines += [f"Human designs: {d['objects']} models, {d['steps']} steps, built in {d['wall_s']} s "
                  "(without the physics replay).", ""]
    if "evaluation" in report:
        lines += ["## Baselines", "",
                  "`paper`: per-axis |dt| <= 10 LDU and rotation < 45 degrees; `strict`: within 0.5 LDU and "
                  "1 degree; `bc`: BC-Bench's released scorer (`eval.bc`: a selection is right by name or "
                  "cell, step success reads the pose only, unanswered steps drop out). Overall = mean over "
                  "objects of per-object means. `random + feedback`: the random baseline's pose answers after "
                  "one world-feedback revision.", ""]
        def scores(label, sc, unparseable):
            paper, strict, bc = (sc[m]["overall"] for m in ("paper", "strict", "bc"))
            return [label, _fmt(paper["selection_accuracy"]), _fmt(bc["selection_accuracy"]),
                    _fmt(paper["translation_error_ldu"], 1), _fmt(paper["rotation_error_deg"], 1),
                    _fmt(paper["step_success"]), _fmt(strict["step_success"]), _fmt(bc["step_success"]),
                    unparseable]

        for name, e in report["evaluation"].items():
            rows = []
            for model, r in e["baselines"].items():
                sc = r["scores"]
                rows.append(scores(model, sc, sc["paper"]["counts"]["unparseable"]))
                fb = sc.get("feedback")
                if fb:
                    rows.append(scores(f"{model} + feedback ({fb['revised_steps']} revised)", fb, "-"))
            lines += [f"### {name} ({e['split']} split)", ""]
            lines += _table(["model", "selection", "selection bc", "transl. err LDU", "rot. err deg",
                             "success paper", "success strict", "success bc", "unparseable"], rows)
            lines.append("")
        lines += ["![baselines](eval.png)", ""]
    if "feedback" in report:
        f = report["feedback"]
        w = f.get("warp") or {}
        warp = (f"MuJoCo Warp on {w['device']}: {w['warp_per_s']} per s, {w['agreement']:.1%} of outcomes equal "
                "to MuJoCo C's" if "warp_per_s" in w else w.get("error", "MuJoCo Warp: no GPU here, not measured"))
        lines += ["## World feedback (`factory.physics.settle`)", "",
                  f"{f['predictions']} predicted placements in {f['scenes']} scenes (`pipelines.bench_settle`, seed "
                  f"{f['seed']}; {f['simulated']} simulated, the others decided before simulating): MuJoCo C "
                  f"{f['cpu_per_s']} per s in one process ({f['cpu_s']} s), {f['cpu_all_per_s']} per s over "
                  f"{f['cpu_workers']} processes ({f['cpu_all_s']} s)"
                  + (f", {f['cpu_step_share']:.0%} of its time in `mj_step` (the rest is host work both engines do)"
                     if f.get("cpu_step_share") is not None else "") + f". {warp}.", ""]
    lines += ["Sections and their seconds: " + ", ".join(f"{k} {v:.0f}" for k, v in report["section_s"].items()), ""]
    return "\n".join(lines)


SECTIONS = ("physics", "render", "synth", "scale", "realism", "designs", "evaluation", "feedback")


def _earlier_report(out: Path, report: dict, quick: bool) -> dict:
    """The sections of OUT/report.json that a resumed run keeps: those of a run on this machine
    (CPUs, GPU, Python) with the same `--quick`; {} when there is none or it was made elsewhere."""
    path = out / "report.json"
    if not path.exists():
        return {}
    try:
        earlier = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not JSON ({e}); remove it or run without --resume") from None
    same = earlier.get("schema_version") == report["schema_version"] and earlier.get("quick", False) == quick and all(
        earlier.get("machine", {}).get(k) == report["machine"][k] for k in ("cpus", "gpu", "python"))
    if not same:
        print(f"bench: {path} was made on another machine or with other options; starting again", file=sys.stderr)
        return {}
    kept = {k: earlier[k] for k in SECTIONS if k in earlier}
    kept["section_s"] = earlier.get("section_s", {})
    return kept


def run(args) -> int:
    out = Path(args.out)
    work = out / "work"
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    report: dict = {"schema_version": 1, "quick": bool(args.quick), "machine": machine(), "section_s": {},
                    "revision": revision()}  # the code measured: taken at the start
    gpu = report["machine"]["gpu"] is not None
    ldraw = args.ldraw or (str(SHARED / "ldraw") if (SHARED / "ldraw" / "parts").is_dir() else None)
    models = [Path(m) for m in args.models] if args.models is not None else sorted(
        p for p in (SHARED / "ldraw_models").glob("*") if p.suffix.lower() in (".ldr", ".mpd"))
    if models and ldraw is None:
        print("bench: human designs need an LDraw library (--ldraw or ../shared/ldraw); skipping them",
              file=sys.stderr)
        models = []
    report["designs_models"] = [str(m) for m in models]

    earlier = _earlier_report(out, report, args.quick) if args.resume else {}
    # A physics section cut short keeps the parts it finished (each saved as it ends).
    partial = None
    if "physics" in earlier and not set(PHYSICS_PARTS) <= earlier["physics"].keys():
        partial = earlier.pop("physics")

    def save() -> None:
        write_atomic(out / "report.json", json.dumps(report, indent=1).encode())
    report["kept"] = [k for k in SECTIONS if k in earlier] + (
        [f"physics ({', '.join(k for k in PHYSICS_PARTS if k in partial)})"] if partial else [])

    def section(name, fn):
        if name in earlier:
            print(f"bench: {name}: kept from the earlier run in {out / 'report.json'}", flush=True)
            report[name] = earlier[name]
            report["section_s"][name] = earlier["section_s"].get(name)
            return
        print(f"bench: {name} ...", flush=True)
        t = time.perf_counter()
        report[name] = fn()
        report["section_s"][name] = round(time.perf_counter() - t, 1)
        report["wall_s"] = round(time.perf_counter() - t0, 1)
        save()

    named = [] if args.backends == "auto" else [b.strip() for b in args.backends.split(",") if b.strip()]
    for b in named:
        if b not in BACKENDS and b not in OLD_BACKEND_NAMES:
            raise ValueError(f"unknown backend {b!r}; valid: {', '.join(BACKENDS)}, auto")
    backends = [backend_arg(b) for b in named] or None

    def save_physics(part: dict) -> None:
        report["physics"] = part
        save()

    section("physics", lambda: physics_section(gpu, args.quick, backends, done=partial, save=save_physics))
    render_models = [(EXAMPLE, None)] + ([(m, ldraw) for m in models] if not args.quick else [])
    section("render", lambda: render_section(render_models))
    report["machine"]["mujoco_gl"] = os.environ.get("MUJOCO_GL", report["machine"]["mujoco_gl"])
    section("synth", lambda: synth_section(work, args.quick))
    section("scale", lambda: scale_section(work, args.quick))
    real, real_ldraw = _real_designs(models, ldraw) if not args.quick else (models, ldraw)
    if real:
        section("realism", lambda: realism_section(report["synth"]["out"], real, real_ldraw))
    datasets = {"synthetic": (report["synth"]["out"], "test")}
    if models:
        section("designs", lambda: designs_section(work, models, ldraw))
        datasets["designs"] = (report["designs"]["out"], None)
    section("evaluation", lambda: evaluation_section(datasets, work))
    section("feedback", lambda: feedback_section(gpu, args.quick))
    report["wall_s"] = round(time.perf_counter() - t0, 1)
    report["plots"] = plots(report, out)
    save()
    write_atomic(out / "report.md", markdown(report).encode())
    print(f"bench: wrote {out / 'report.md'} and {out / 'report.json'} in {report['wall_s']:.0f} s")
    append_bench(report, args.results, args.quick, skip=args.no_rows)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m pipelines.bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench", help="report folder (default bench)")
    ap.add_argument("--ldraw", help="LDraw library for the human designs (default ../shared/ldraw when present)")
    ap.add_argument("--models", nargs="*", help="human-designed models to render and evaluate "
                    "(default: ../shared/ldraw_models/*.ldr|*.mpd when present)")
    ap.add_argument("--quick", action="store_true", help="smaller sections (a smoke run, for tests)")
    ap.add_argument("--resume", action="store_true",
                    help="keep the sections that OUT/report.json already holds from a run on this machine with the "
                         "same --quick, and run the rest (a bench cut short goes on where it stopped)")
    ap.add_argument("--backends", default="auto",
                    help="physics backends to time: comma-separated cpu,jax, or auto (default: every one installed)")
    ap.add_argument("--results", metavar="DIR", help="add rows to DIR/*.jsonl (default bench/results; --quick: none)")
    ap.add_argument("--no-rows", action="store_true", help="append no result rows (and leave docs/results.md)")
    args = ap.parse_args(argv)
    return run_guarded(lambda: run(args), {DatasetError: 2, ConfigMismatchError: 2, SamplerConfigError: 2,
                                           OSError: 2, ValueError: 2})


if __name__ == "__main__":
    sys.exit(main())
