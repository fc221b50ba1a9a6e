"""Synthetic step-wise data: `python -m pipelines.synth --n N --out OUT [--seed S] [--backend local|ray] [--workers W] [--batch B]`.

Samples N physics-verified objects (`factory.sampler`), renders every step and writes sharded
Parquet under OUT (see docs/dataset.md). Re-running the same command resumes: finished shards are
kept, the rest are built, and the result is byte-identical to an uninterrupted run. A different
config for an existing OUT is refused. Ends with a one-line summary on stdout.
"""

from __future__ import annotations

import argparse
import os
import sys

from factory.cli import run_guarded


def _ldraw(arg):
    key = arg or os.environ.get("LDRAWDIR") or None
    return os.path.realpath(os.path.expanduser(key)) if key else None


def config_from_args(args):
    from factory import gpus
    from factory.sampler import SamplerConfig, default_check_batch
    from pipelines.dataset import DatasetConfig
    from pipelines.dataset.sources import sampler_config_json

    if args.check_backend == "auto":
        args.check_backend = "mujoco"
        print(f"physics: mujoco, MuJoCo C in each worker (auto: the faster whole build, measured in "
              f"docs/dataset.md; --check-backend mjx asks for the batched JAX checks); renders: "
              f"{gpus.render_path()}", file=sys.stderr, flush=True)
    kw = dict(seed=args.seed, min_steps=args.min_steps, max_steps=args.max_steps,
              backend=args.check_backend)
    if args.candidates is not None:
        kw["candidates_per_step"] = args.candidates
    kw["check_batch"] = args.check_batch or default_check_batch(args.check_backend, kw.get(
        "candidates_per_step", SamplerConfig.candidates_per_step))
    if args.parts:
        kw["parts"] = [p.strip() for p in args.parts.split(",") if p.strip()]
    sampler = SamplerConfig(**kw)
    return DatasetConfig("synthetic", args.n, seed=args.seed, size=args.size, tile=args.tile, png_compress_level=args.png_level,
                         objects_per_shard=args.objects_per_shard, sampler=sampler_config_json(sampler),
                         ldraw=_ldraw(args.ldraw), **({"dataset_id": args.dataset_id} if args.dataset_id else {}))


DEFAULT_GPU_BATCH = 16
"""Objects grown together per grower with the batched checks (`--batch`'s default with mjx)."""


def add_run_args(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--backend", choices=("local", "ray"), default="local",
                    help="local worker processes (default) or Ray tasks ($RAY_ADDRESS, else a local Ray)")
    ap.add_argument("--workers", type=int, default=1, help="parallel shards (default 1: this process)")
    ap.add_argument("--batch", type=int, default=None,
                    help="synthetic objects grown together in lockstep per grower while the other workers "
                         "render (default: 16 with the mjx checks, else 1: each shard grows its own; the data "
                         "is the same whatever it is)")
    ap.add_argument("--growers", type=int, default=None,
                    help="with --batch > 1: workers that grow objects (default two thirds of --workers)")
    ap.add_argument("--size", type=int, default=256, help="pixels per view (default 256)")
    ap.add_argument("--tile", type=int, default=128, help="pixels per catalog tile (default 128)")
    ap.add_argument("--png-level", type=int, default=6,
                    help="deflate level of the PNG images, 0-9 (default 6; libdeflate, no row filter: "
                         "level 1 is no faster here and 16%% larger)")
    ap.add_argument("--objects-per-shard", type=int, default=4, help="objects per shard (default 4)")
    ap.add_argument("--ldraw", help="LDraw library folder (default: $LDRAWDIR, else the embedded library)")
    ap.add_argument("--dataset-id", help="name written in every row")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(config, args) -> int:
    from pipelines.dataset import build, summary_line
    from pipelines.dataset.build import growers_of

    synthetic = config.source == "synthetic"
    if args.batch is None:
        args.batch = DEFAULT_GPU_BATCH if synthetic and config.sampler.get("backend") == "mjx" else 1
    if args.workers < 1 or args.batch < 1 or (args.growers is not None and args.growers < 1):
        print("error: --workers, --batch and --growers must be >= 1", file=sys.stderr)
        return 2
    if args.batch > 1 and synthetic:
        print(f"growth: {args.batch} objects at a time in each of {growers_of(args.workers, args.growers)} "
              f"growers; {args.workers} workers", file=sys.stderr, flush=True)
    summary = build(config, args.out, backend=args.backend, workers=args.workers,
                    progress=not args.no_progress, batch=args.batch, growers=args.growers)
    print(summary_line(summary), flush=True)
    return 0


def guarded(body) -> int:
    from factory.sampler import SamplerConfigError
    from pipelines.dataset import ConfigMismatchError, FolderBusyError, ShardFailedError, ShardInputError

    return run_guarded(body, {ConfigMismatchError: 2, FolderBusyError: 2, SamplerConfigError: 2, ValueError: 2,
                              ShardInputError: 2, ShardFailedError: 1, OSError: 2})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipelines.synth", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, required=True, help="number of objects")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--min-steps", type=int, default=20, help="fewest parts per object (default 20)")
    ap.add_argument("--max-steps", type=int, default=90, help="most parts per object (default 90)")
    ap.add_argument("--candidates", type=int, help="feasible attachments checked per part draw")
    ap.add_argument("--check-batch", type=int,
                    help="candidates per checker call (default 1 with mujoco, --candidates with mjx); the "
                         "objects do not depend on it")
    ap.add_argument("--parts", help="comma-separated part set (default: the sampler's)")
    ap.add_argument("--check-backend", choices=("auto", "mujoco", "mjx"), default="auto",
                    help="physics checks one candidate at a time on the CPU in every worker (mujoco), or batched in "
                         "JAX: collision, sweeps and load programs (mjx, for a GPU); auto (default): mujoco, the "
                         "faster whole build measured on a 16-core H100 machine (renders use the GPUs either way)")
    add_run_args(ap)
    args = ap.parse_args(argv)
    return guarded(lambda: run(config_from_args(args), args))


if __name__ == "__main__":
    sys.exit(main())
