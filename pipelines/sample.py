"""Sample physics-verified objects to LDraw files.

`python -m pipelines.sample --n N --seed S --out DIR [--ldraw DIR] [--check-backend cpu|jax]
[--start I] [--workers W] [--batch B] [--min-steps A --max-steps B --candidates K --check-batch C
--density-weight W --temperature T ...]` (a flag per `SamplerConfig` field, as `pipelines.synth` has)

Writes `DIR/object_00000.ldr ...` (object i of seed S, the same whatever --start, --workers or the
machine) and `DIR/summary.json`: per object its steps, density, end reason, rejections by rule
and time; totals with the distribution of steps per object and objects per minute. Every file is
written atomically (a temporary file, then `os.replace`). Runs on the embedded default library
when no LDraw library is given.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import contextlib
import platform
import sys
import time
from collections import Counter
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from factory import mps
from factory.cli import (ArgumentParser, add_config_args, add_mps_flag, add_progress_flag, config_from_args,
                         renamed_flag, run_guarded)
from factory.physics import pair_kernels
from factory.physics.check import BACKENDS, backend_arg
from factory.sampler import Sampler, SamplerConfig, SamplerConfigError
from factory.atomic import write_atomic
from pipelines import workers
from factory.prior import PriorError
from pipelines.prior_flag import add_prior_flag, apply_prior

_SAMPLER: Sampler | None = None


def _init(config: SamplerConfig, ldraw: str | None) -> None:
    global _SAMPLER
    _SAMPLER = Sampler(config, ldraw)


def _init_worker(counter, parent: int, config: SamplerConfig, ldraw: str | None) -> None:
    """A worker process: numbered and ended with this command (`pipelines.workers`), then its sampler."""
    workers.start_worker(counter, parent)
    _init(config, ldraw)


def _timed(indices: list[int], batch: int):
    """The objects `indices`, `batch` grown together, each as it ends with the seconds since the one
    before it ended (its share of the time)."""
    t0 = time.perf_counter()
    for a in _SAMPLER.grow(indices, batch):
        t1 = time.perf_counter()
        yield a, t1 - t0
        t0 = t1


def _chunk(indices: list[int], batch: int) -> list:
    return list(_timed(indices, batch))


def _chunks(indices: range, batch: int, workers: int) -> list[list[int]]:
    """Consecutive chunks of `batch` objects (one chunk per worker when there are fewer objects)."""
    size = batch if workers == 1 else max(1, min(batch, -(-len(indices) // workers)))
    return [list(indices[a:a + size]) for a in range(0, len(indices), size)]


def _stats(values) -> dict:
    v = np.asarray(values, dtype=np.float64)
    if not len(v):
        return {}
    q = np.percentile(v, [0, 10, 25, 50, 75, 90, 100])
    return {"min": q[0], "p10": q[1], "p25": q[2], "median": q[3], "mean": float(v.mean()), "p75": q[4],
            "p90": q[5], "max": q[6], "sum": float(v.sum())}


def histogram(values, edges) -> dict:
    counts, _ = np.histogram(values, bins=edges)
    return {f"{edges[i]:g}-{edges[i + 1]:g}": int(c) for i, c in enumerate(counts)}


def summarize(records: list[dict], wall: float, config: SamplerConfig, library: str, workers: int) -> dict:
    rejected: Counter = Counter()
    for r in records:
        rejected.update(r["rejected"])
    steps = [r["steps"] for r in records]
    return {
        # (parts and colours as mappings here, as this file has always had them; the dataset's
        # meta/config.json keeps `to_dict`'s ordered pairs)
        "config": {**config.to_dict(), "parts": dict(config.parts), "colours": {str(c): w for c, w in config.colours}},
        "library": library,
        "workers": workers,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "objects": records,
        "totals": {
            "objects": len(records),
            "steps": int(sum(steps)),
            "steps_per_object": _stats(steps),
            "steps_histogram": histogram(steps, list(range(0, max(steps + [config.max_steps]) + 11, 10))),
            "density": _stats([r["density"] for r in records]),
            "end_reasons": dict(Counter(r["end_reason"] for r in records)),
            "rejected": dict(sorted(rejected.items())),
            "seconds_per_object": _stats([r["seconds"] for r in records]),
            "wall_seconds": wall,
            "objects_per_minute": 60.0 * len(records) / wall if wall > 0 else None,
        },
    }


def parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="python -m pipelines.sample", description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, required=True, help="number of objects")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--ldraw", help="LDraw library: a folder or LDraw's complete.zip (default: "
                    "$LDRAWDIR, else the embedded library)")
    ap.add_argument("--start", type=int, default=0, help="index of the first object (default 0)")
    ap.add_argument("--workers", type=int, default=1, help="processes (objects do not depend on it)")
    ap.add_argument("--batch", type=int, default=1,
                    help="objects grown together in lockstep per process, their checks asked in one call "
                         "per step (objects do not depend on it; with the jax checks the round's collision tests, sweeps and load "
                         "programs go to the device together)")
    ap.add_argument("--steps-json", action="store_true", help="also list every step in summary.json")
    add_mps_flag(ap)
    add_progress_flag(ap)
    add_prior_flag(ap)
    # The sampler's settings: the same flags, defaults and check_batch rule as pipelines.synth's.
    add_config_args(ap, SamplerConfig, skip=("check",))
    renamed_flag(ap, "--backend", "--check-backend", "backend", choices=BACKENDS, type=backend_arg)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    if args.n < 0 or args.start < 0 or args.workers < 1 or args.batch < 1:
        ap.error("--n and --start must be >= 0, --workers and --batch >= 1")

    def body() -> int:
        config = apply_prior(args, sampler_config(args), args.ldraw, progress=not args.no_progress)
        _init(config, args.ldraw)  # validates against the library before any work
        return _run(args, config)

    return run_guarded(body, {SamplerConfigError: 2, PriorError: 2})


def sampler_config(args) -> SamplerConfig:
    """The `SamplerConfig` of parsed arguments (a flag per field, as `pipelines.synth` has)."""
    return config_from_args(SamplerConfig, args)


def _run(args, config: SamplerConfig) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    indices = range(args.start, args.start + args.n)
    records: list[dict] = []
    t0 = time.perf_counter()
    pool = None
    chunks = _chunks(indices, args.batch, args.workers)
    # The workers' batched checks share each GPU through MPS where that helps (`factory.mps`).
    sharing = mps.shared_gpu(args.workers, args.mps) if config.backend == "jax" and args.workers > 1 \
        else contextlib.nullcontext()
    with sharing:
        if args.workers > 1:
            ctx = mp.get_context("fork")
            pool = ctx.Pool(args.workers, initializer=_init_worker,
                            initargs=(*workers.numbering(ctx), config, args.ldraw))
            results = (x for done in pool.imap_unordered(partial(_chunk, batch=args.batch), chunks) for x in done)
        else:
            results = (x for c in chunks for x in _timed(c, args.batch))
        try:
            bar = tqdm(results, total=args.n, unit="obj", desc="sampling", dynamic_ncols=True,
                       disable=args.no_progress)
            for assembly, seconds in bar:
                name = f"object_{assembly.index:05d}.ldr"
                assembly.to_ldr(out / name)
                rec = {"file": name, **assembly.to_json(steps=args.steps_json), "seconds": round(seconds, 3)}
                records.append(rec)
                bar.set_postfix(steps=len(assembly), density=f"{assembly.density:.3f}")
        finally:
            if pool is not None:
                pool.terminate()
                pool.join()  # before the MPS daemon (if any) is stopped
    wall = time.perf_counter() - t0
    records.sort(key=lambda r: r["index"])
    summary = summarize(records, wall, config, _SAMPLER.reader.library.description, args.workers)
    summary["batch"] = args.batch
    if args.workers == 1:  # (worker processes keep their own counts)
        summary["totals"]["check_stage_seconds"] = {k: round(v, 3) for k, v in sorted(_SAMPLER.checker.counters()["stage_seconds"].items())}
        if config.backend == "jax":
            from factory.physics import lp_jax  # optional: JAX (the [jax] extra)

            summary["totals"]["compiles"] = {"loads": len(lp_jax.COMPILES), "sweeps": len(pair_kernels.COMPILES)}
    write_atomic(out / "summary.json", (json.dumps(summary, indent=1, default=_json_default) + "\n").encode())
    t = summary["totals"]
    print(f"{t['objects']} objects, {t['steps']} steps, median density "
          f"{t['density'].get('median', 0):.3f}, {t['objects_per_minute'] or 0:.2f} objects/min -> {out}",
          file=sys.stderr)
    return 0


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


if __name__ == "__main__":
    sys.exit(main())
