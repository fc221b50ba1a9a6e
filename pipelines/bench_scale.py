"""How a build's throughput grows with the machine: the same objects built with 1, 2, 4, ... worker
processes up to every core (the `scale` section of `make bench`), each into a folder of its own,
with steps per second, the speed-up and efficiency against one worker, and each stage's
worker-seconds per step (where a stage's cost per step grows with the workers, something is
shared: a GPU's EGL, memory bandwidth, hyperthreads).

    python -m pipelines.bench_scale --out out/scale [--n 64] [--workers 1,2,4,8,16]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

from factory.atomic import write_atomic
from factory import gpus
from factory.sampler.config import SamplerConfig
from pipelines.dataset import DatasetConfig, build


def worker_counts(cores: int | None = None) -> list[int]:
    """1, 2, 4, ... and every core (the last: the machine as `make synth` runs it)."""
    cores = max(1, cores or os.cpu_count() or 1)
    counts, k = [], 1
    while k < cores:
        counts.append(k)
        k *= 2
    return counts + [cores]


def scale_rows(work: Path, n: int, counts: list[int], min_steps: int = 6, max_steps: int = 10,
               check_backend: str = "auto") -> list[dict]:
    """One row per worker count: the same `n` objects (seed 0, `min_steps`-`max_steps` bricks, one
    object a shard) built from nothing with that many worker processes."""
    rows: list[dict] = []
    backend = gpus.checks_backend()[0] if check_backend == "auto" else check_backend
    for workers in counts:
        config = DatasetConfig.synthetic(n, seed=0, sampler=SamplerConfig(min_steps=min_steps, max_steps=max_steps,
                                                                          backend=backend),
                                         objects_per_shard=1, dataset_id="bench-scale")
        out = work / f"scale-{workers}"
        shutil.rmtree(out, ignore_errors=True)  # from nothing: a resumed folder would time nothing
        summary = build(config, out, workers=workers, progress=False)
        steps, wall = summary["total"]["steps"], summary["wall_seconds"]
        row = {"workers": workers, "objects": n, "steps": steps, "wall_s": wall,
               "steps_per_s": round(steps / wall, 3),
               "stage_worker_s_per_step": {k: round(v / max(1, steps), 4) for k, v in summary["stage_seconds"].items()},
               "checks": backend}
        base = rows[0] if rows else row
        row["speedup"] = round(row["steps_per_s"] / base["steps_per_s"], 3)
        row["efficiency"] = round(row["speedup"] * base["workers"] / workers, 3)
        rows.append(row)
        print(f"  scale {json.dumps(row)}", flush=True)
        shutil.rmtree(out, ignore_errors=True)
    return rows


def scale_section(work: Path, quick: bool) -> dict:
    """The bench's scale section: 32 objects of 6-10 bricks at 1, 2, 4, ... workers up to every
    core (quick: 2 objects of 3-4 bricks at 1 and 2 workers)."""
    if quick:
        return _section(work, 2, worker_counts(min(2, os.cpu_count() or 1)), 3, 4)
    return _section(work, 32, worker_counts(), 6, 10)


def _section(work: Path, n: int, counts: list[int], lo: int = 6, hi: int = 10, check_backend: str = "auto") -> dict:
    return {"objects": n, "config": f"objects of {lo}-{hi} bricks, seed 0, one object a shard",
            "gpus": gpus.count(), "cores": os.cpu_count(),
            "rows": scale_rows(work, n, counts, lo, hi, check_backend=check_backend)}


def markdown(section: dict) -> list[str]:
    lines = ["## Scale: steps/s against workers", "",
             f"The same {section['objects']} objects ({section['config']}) built with each number of worker "
             f"processes on {section['cores']} cores and {section['gpus']} GPU(s); worker-seconds per step by stage.", "",
             "| workers | steps/s | speed-up | efficiency | wall s | " + " | ".join(
                 f"{k} s/step" for k in section["rows"][0]["stage_worker_s_per_step"]) + " |",
             "|" + "---:|" * (5 + len(section["rows"][0]["stage_worker_s_per_step"]))]
    for r in section["rows"]:
        lines.append(f"| {r['workers']} | {r['steps_per_s']} | {r['speedup']} | {r['efficiency']} | {r['wall_s']} | "
                     + " | ".join(str(v) for v in r["stage_worker_s_per_step"].values()) + " |")
    return lines + [""]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipelines.bench_scale", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the builds (removed after each) and scale.json")
    ap.add_argument("--n", type=int, default=32, help="objects built at each worker count")
    ap.add_argument("--workers", default=None, help="worker counts, comma-separated (default: 1, 2, 4, ... every core)")
    ap.add_argument("--check-backend", default="auto", help="the checks' backend (auto, cpu, jax)")
    args = ap.parse_args(argv)
    try:
        counts = [int(w) for w in args.workers.split(",")] if args.workers else worker_counts()
    except ValueError:
        ap.error(f"--workers: comma-separated integers, got {args.workers!r}")
    if any(w < 1 for w in counts) or args.n < 1:
        ap.error("--workers and --n must be at least 1")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    section = _section(out, args.n, counts, check_backend=args.check_backend)
    write_atomic(out / "scale.json", json.dumps(section, indent=1).encode())
    print("\n".join(markdown(section)), file=sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
