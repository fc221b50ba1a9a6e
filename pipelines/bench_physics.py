"""Benchmark the physics checks: candidate checks per second by structure size, batch and backend.
This module is the command line; the measurements are in `bench_checks` and `bench_growth`.

`python -m pipelines.bench_physics [--backends cpu,jax] [--sizes 10,30,60]
[--batches 256,1024,4096] [--out FILE.json]`; with `--sweep`, the buildability sweep alone
(`bench_checks.measure_sweep`: the batched exact JAX path against the CPU reference); with
`--whole`, whole checks (`measure_whole`).

`python -m pipelines.bench_physics --growth --backends jax --batches 1,16,64 --steps 30 --objects 64`:
lockstep growth of the same objects at each batch, steps per second (`bench_growth.measure_growth`).

`python -m pipelines.bench_physics --solver [--batches 64] [--sizes 960]`: the batched LP solver
alone against HiGHS on random load-like programs (`bench_solver.bench`): rate, iterations,
shapes, the objectives' largest difference and the verdicts that differ.

`python -m pipelines.bench_physics --lp --sizes 30,60,90 --batches 1024,4096,16384`: the load check
alone from each candidate's pose (`bench_checks.load_stage`: model, tipping rule, program), the
batched JAX solver against HiGHS (`--cpu-workers K`: the reference in K processes), verdicts
compared.

Structures are grown from a seed with 2x4 bricks (embedded library) by the checker itself, so
they are valid; candidates are feasible attachments of a 2x4 brick (drawn with replacement to fill
a batch): `bench_structures`. Reported per (backend, size, batch) by `bench_checks.measure`: full
check rate (connection, collision, clutch, whole-structure loads), and the load stage alone (each
candidate's load program, models already built): HiGHS one program at a time for `cpu`, the
batched JAX solver for `jax`, with the compiles it made. Processes that start together, and the
rows as they come: `bench_processes`.
"""

from __future__ import annotations

import json
import platform

from factory.atomic import write_atomic
from factory.cli import ArgumentParser, add_mps_flag
from factory.physics.check import backend_arg
from pipelines import bench_processes
from pipelines.bench_checks import measure, measure_lp, measure_sweep, measure_whole
from pipelines.bench_growth import measure_growth


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m pipelines.bench_physics")
    ap.add_argument("--backends", default="cpu", help="check backends, comma-separated: cpu, jax")
    ap.add_argument("--sizes", default="10,30,60")
    ap.add_argument("--batches", default="256")
    ap.add_argument("--full-max", type=int, help="run full checks only for batches up to this size")
    ap.add_argument("--sweep", action="store_true",
                    help="measure the buildability sweep instead: the batched exact JAX path "
                         "(factory.physics.sweep_jax) against the CPU reference (sweep.sweep)")
    ap.add_argument("--cpu-max", type=int, help="with --sweep, --lp or --whole: candidates the CPU reference checks "
                    "(0: none; default 512 for --sweep, 128 for --lp, 256 for --whole)")
    ap.add_argument("--cpu-workers", type=int, default=1, help="with --sweep or --lp: processes the CPU reference runs in")
    ap.add_argument("--reference-only", action="store_true", help="with --sweep or --lp: the CPU reference alone")
    ap.add_argument("--out")
    ap.add_argument("--lp", action="store_true", help="the batched load solver alone, on real load programs")
    ap.add_argument("--solver", action="store_true", help="the batched LP solver alone against HiGHS on random "
                    "load-like programs: one row per (size, batch), --sizes variables, --batches programs")
    ap.add_argument("--whole", action="store_true", help="whole checks (every check a candidate goes through): "
                    "the batched path against the reference on the same candidates, verdicts compared")
    ap.add_argument("--growth", action="store_true",
                    help="lockstep growth: --objects objects of --steps parts each grown --batches at a time "
                         "with the first of --backends, steps per second per batch (same objects in every row)")
    ap.add_argument("--procs", type=int, default=1,
                    help="with --sweep, --lp or --whole: processes that share the device on the batched path, each "
                         "judging a contiguous slice of the batch; with --growth: grower processes, each "
                         "growing a contiguous slice of the objects, BATCH/PROCS at a time (default 1)")
    ap.add_argument("--steps", type=int, default=30, help="with --growth: parts per object (default 30)")
    ap.add_argument("--objects", type=int, default=64, help="with --growth: objects grown (default 64)")
    ap.add_argument("--judge-first", type=int, help="with --growth: the sampler's judge_first (default: its own)")
    ap.add_argument("--check-batch", type=int, help="with --growth: the sampler's check_batch (default: its own)")
    add_mps_flag(ap)
    args = ap.parse_args(argv)
    bench_processes.MPS_MODE = args.mps
    sizes, batches = [int(x) for x in args.sizes.split(",")], [int(x) for x in args.batches.split(",")]
    log = lambda r: print(json.dumps(r), flush=True)
    if args.solver:
        from pipelines.bench_solver import bench  # JAX: only for this measurement

        rows = []
        for size in sizes:
            for n in batches:
                rows.append({"size": size, **bench(n_problems=n, size=size, reference=min(n, 64))})
                log(rows[-1])
    elif args.growth:
        rows = measure_growth(backend_arg(args.backends.split(",")[0]), batches, args.steps, args.objects, log=log,
                              procs=args.procs, judge_first=args.judge_first, check_batch=args.check_batch)
    elif args.sweep:
        rows = measure_sweep(sizes, batches, 512 if args.cpu_max is None else args.cpu_max, log=log,
                             cpu_workers=args.cpu_workers, batched=not args.reference_only, procs=args.procs)
    elif args.whole:
        rows = measure_whole(sizes, batches, log=log, cpu_max=256 if args.cpu_max is None else args.cpu_max,
                             cpu_workers=args.cpu_workers, batched=not args.reference_only, procs=args.procs)
    elif args.lp:
        rows = measure_lp(sizes, batches, log=log, cpu_max=128 if args.cpu_max is None else args.cpu_max,
                          cpu_workers=args.cpu_workers, batched=not args.reference_only, procs=args.procs)
    else:
        rows = measure([backend_arg(b) for b in args.backends.split(",")], sizes, batches, log=log, full_max=args.full_max)
    if args.out:
        meta = {"machine": platform.node(), "processor": platform.processor(), "rows": rows}
        write_atomic(args.out, json.dumps(meta, indent=1).encode())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
