"""Synthetic step-wise data: `python -m pipelines.synth --n N --out OUT [--seed S] [--runner local|ray] [--workers W] [--batch B]`.

Samples N physics-verified objects (`factory.sampler`), renders every step and writes sharded
Parquet under OUT (see docs/guides/build-a-dataset.md). Re-running the same command resumes: finished shards are
kept, the rest are built, and the result is byte-identical to an uninterrupted run. A different
config for an existing OUT is refused. Ends with a one-line summary on stdout. `--results DIR`
(off by default): also append the build's time as one row to DIR/builds.jsonl
(`pipelines.report_rows.build_row`; `--results bench/results` for the project's figures).
"""

from __future__ import annotations

import argparse
import os
import sys

from factory import gpus
from factory.cli import (ArgumentParser, add_config_args, add_mps_flag, add_progress_flag,
                         config_from_args as config_of, renamed_flag, run_guarded)
from factory.sampler import SamplerConfig, SamplerConfigError
from pipelines.dataset import (ConfigMismatchError, FolderBusyError, ShardFailedError, ShardInputError, build,
                               summary_line)
from pipelines.dataset.build import growers_of
from pipelines.dataset.config import DatasetConfig
from pipelines.prior_flag import add_prior_flag, apply_prior
from pipelines.report_rows import append_build
from pipelines.result_rows import revision


def _ldraw(arg):
    key = arg or os.environ.get("LDRAWDIR") or None
    return os.path.realpath(os.path.expanduser(key)) if key else None


NOT_FLAGS = ("source", "models", "physics", "sampler.seed", "sampler.check")
"""`DatasetConfig` fields that `pipelines.synth` sets itself: the sampler's seed is the dataset's
seed, and the check thresholds are not settings of a build."""


def add_config_flags(ap: argparse.ArgumentParser, skip=NOT_FLAGS) -> None:
    """The flags of `DatasetConfig`'s fields (`factory.cli.add_config_args`), less `skip`."""
    add_config_args(ap, DatasetConfig, skip=skip)


AUTO = "auto"
"""`--check-backend auto` (the default): the batched checks where a CUDA GPU and JAX's CUDA build
are, else the reference (`gpus.checks_backend`)."""


def add_auto_backend(ap: argparse.ArgumentParser) -> None:
    """`--check-backend` takes `auto` too, and defaults to it."""
    (action,) = [a for a in ap._actions if "--check-backend" in a.option_strings]
    action.choices, action.default = (*action.choices, AUTO), AUTO
    action.help = action.help.replace(" (default:", " Or 'auto': 'jax' where an NVIDIA GPU and JAX's CUDA build (the "
                                      "gpu extra) are, else 'cpu' (default:")


def checks_backend(args) -> tuple[str, str]:
    """The checks' backend of parsed arguments, and why (`auto` resolved for this machine)."""
    chosen = getattr(args, "sampler.backend", AUTO)
    return gpus.checks_backend() if chosen == AUTO else (chosen, "--check-backend " + chosen)


def config_from_args(args) -> DatasetConfig:
    """The synthetic `DatasetConfig` of parsed arguments (`--ldraw` defaults to $LDRAWDIR;
    `--check-backend auto` resolved for this machine)."""
    sampler = config_of(SamplerConfig, args, "sampler.", seed=args.seed, backend=checks_backend(args)[0])
    sampler = apply_prior(args, sampler, _ldraw(args.ldraw), "sampler.", progress=not getattr(args, "no_progress", True))
    return config_of(DatasetConfig, args, source="synthetic", sampler=sampler, ldraw=_ldraw(args.ldraw))


def add_run_args(ap: argparse.ArgumentParser) -> None:
    """How a build runs (not part of the config: the data do not depend on these)."""
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--runner", choices=("local", "ray"), default="local",
                    help="where shards are built: local worker processes (default) or Ray tasks ($RAY_ADDRESS, "
                         "else a local Ray)")
    renamed_flag(ap, "--backend", "--runner", "runner", choices=("local", "ray"))
    ap.add_argument("--workers", type=int, default=1, help="parallel shards (default 1: this process)")
    ap.add_argument("--batch", type=int, default=1,
                    help="synthetic objects grown together in lockstep per grower while the other workers "
                         "render (default 1: each shard grows its own objects, with the jax checks all of "
                         "them together; the data is the same whatever it is)")
    ap.add_argument("--growers", type=int, default=None,
                    help="with --batch > 1: workers that grow objects (default two thirds of --workers)")
    add_mps_flag(ap)
    add_progress_flag(ap)


def run(config, args) -> int:
    synthetic = config.source == "synthetic"
    if args.workers < 1 or args.batch < 1 or (args.growers is not None and args.growers < 1):
        print("error: --workers, --batch and --growers must be >= 1", file=sys.stderr)
        return 2
    if args.batch > 1 and synthetic:
        print(f"growth: {args.batch} objects at a time in each of {growers_of(args.workers, args.growers)} "
              f"growers; {args.workers} workers", file=sys.stderr, flush=True)
    elif synthetic and config.sampler.backend == "jax":
        print(f"growth: each shard's objects (up to {config.objects_per_shard}) together in the worker that "
              f"renders them; {args.workers} worker{'s' if args.workers != 1 else ''}", file=sys.stderr, flush=True)
    if synthetic:
        print(f"physics: {config.sampler.backend} ({checks_backend(args)[1]}; --check-backend cpu|jax|auto); renders: "
              f"{gpus.render_path()}", file=sys.stderr, flush=True)
    results = getattr(args, "results", None)  # pipelines.synth's flag (not pipelines.designs')
    if results and os.path.exists(results) and not os.path.isdir(results):
        print(f"error: --results {results}: not a folder", file=sys.stderr)
        return 2
    rev = revision() if results and synthetic else None  # the code measured: taken at the start
    summary = build(config, args.out, runner=args.runner, workers=args.workers,
                    progress=not args.no_progress, batch=args.batch, growers=args.growers, mps_mode=args.mps)
    print(summary_line(summary), flush=True)
    if results and synthetic:
        auto = checks_backend(args)[1] if getattr(args, "sampler.backend", AUTO) == AUTO else None
        append_build(summary, results, rev, config=config, runner=args.runner, workers=args.workers,
                     backend=config.sampler.backend, auto=auto, batch=args.batch, growers=args.growers)
    return 0


def guarded(body) -> int:
    return run_guarded(body, {ConfigMismatchError: 2, FolderBusyError: 2, SamplerConfigError: 2, ValueError: 2,
                              ShardInputError: 2, ShardFailedError: 1, OSError: 2})


def parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="python -m pipelines.synth", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_flags(ap)
    add_auto_backend(ap)
    add_run_args(ap)
    add_prior_flag(ap)
    ap.add_argument("--results", metavar="DIR",
                    help="append the build's time as one row to DIR/builds.jsonl (e.g. bench/results; default none; "
                         "not for a build that resumed)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return guarded(lambda: run(config_from_args(args), args))


if __name__ == "__main__":
    sys.exit(main())
