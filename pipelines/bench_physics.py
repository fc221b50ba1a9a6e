"""Benchmark the physics checks: candidate checks per second by structure size, batch and backend.

`python -m pipelines.bench_physics [--backends mujoco,mjx] [--sizes 10,30,60]
[--batches 256,1024,4096] [--out FILE.json]`

Structures are grown from a seed with 2x4 bricks (embedded library) by the checker itself, so
they are valid; candidates are feasible attachments of a 2x4 brick (drawn with replacement to fill
a batch). Reported per (backend, size, batch): full check rate (connection, collision, clutch,
rollout), and the rollout stage alone (objects already built), with the compiles MJX made.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from factory import Pose, get_reader, load_part
from factory.physics.check import CheckConfig, check
from factory.physics.stability import MassAggregate, StabilityConfig, rigid_object, rollout_cpu
from factory.physics.attach import feasible_poses, lowest_y
from factory.physics.structure import Placed, Structure


def grow(n: int, seed: int = 0) -> Structure:
    """A valid structure of n 2x4 bricks, grown compactly on the ground plane and upward."""
    rng = np.random.default_rng(seed)
    brick = load_part(get_reader(), "3001")
    s = Structure([Placed(brick, 4, Pose.identity())])
    while len(s) < n:
        poses = [p for p in feasible_poses(s, brick) if p.t[1] <= 0]  # on top, not hanging
        poses.sort(key=lambda p: (abs(p.t[0]) + abs(p.t[2]), -p.t[1]))
        pick = poses[: max(8, len(poses) // 4)]
        order = rng.permutation(len(pick))
        verdicts = check(s, brick, [pick[i] for i in order[:16]], floor_y=24.0)
        ok = [v for v in verdicts if v.ok]
        if ok:
            s.add(Placed(brick, 4, ok[0].pose))
    return s


def candidates(s: Structure, batch: int, seed: int = 1) -> list[Pose]:
    """`batch` feasible attachments of a 2x4 brick above the ground at y = 24 (as the sampler keeps
    them: one reaching into the ground starts its rollout deep in the floor, which neither backend
    can judge), drawn with replacement."""
    brick = load_part(get_reader(), "3001")
    poses = [p for p in feasible_poses(s, brick)
             if lowest_y(brick, p.R[None], p.t[None])[0] <= 24.0 + CheckConfig().max_penetration_ldu]
    rng = np.random.default_rng(seed)
    return [poses[i] for i in rng.integers(0, len(poses), size=batch)]


def measure(backends, sizes, batches, log=None, full_max: int | None = None,
            config: CheckConfig = CheckConfig(), mjx_impl: str | None = None) -> list[dict]:
    """One row per (size, batch, backend): rollout-only and full-check candidates per second (full
    checks only up to `full_max` candidates: their contact stage runs on the CPU for every backend)."""
    brick = load_part(get_reader(), "3001")
    cfg = config
    rows = []
    for n in sizes:
        t0 = time.perf_counter()
        s = grow(n)
        grow_s = time.perf_counter() - t0
        for batch in batches:
            poses = candidates(s, batch)
            base = MassAggregate.of(s.placed)
            # Candidates repeat (drawn with replacement): each distinct pose is merged once.
            merged = {id(p): rigid_object(base + MassAggregate.of([Placed(brick, 4, p)]), 24.0, cfg.stability)
                      for p in {id(p): p for p in poses}.values()}
            objs = [merged[id(p)] for p in poses]
            for backend in backends:
                if backend == "mjx":
                    from factory.physics.mjx_backend import COMPILES, default_impl, rollout_mjx

                    impl = mjx_impl or default_impl()
                    t = time.perf_counter()
                    rollout_mjx(objs, cfg.stability, impl)  # compile (and warm) this batch's bucket
                    compile_s = time.perf_counter() - t
                    t = time.perf_counter()
                    moves = rollout_mjx(objs, cfg.stability, impl)
                    roll_s = time.perf_counter() - t
                    compiles = len(COMPILES)
                else:
                    compile_s, compiles, impl = 0.0, 0, None
                    t = time.perf_counter()
                    moves = rollout_cpu(objs, cfg.stability)
                    roll_s = time.perf_counter() - t
                row = {
                    "backend": backend, "mjx_impl": impl, "bricks": n, "batch": batch,
                    "rollouts_per_s": round(batch / roll_s, 1),
                    "unstable_in_rollout": int(np.sum(moves > cfg.stability.max_move_ldu)),
                    "compile_s": round(compile_s, 2), "compiles_so_far": compiles,
                    "grow_s": round(grow_s, 1),
                    "solver_iterations": cfg.stability.iterations, "ls_iterations": cfg.stability.ls_iterations,
                }
                if full_max is None or batch <= full_max:
                    t = time.perf_counter()
                    verdicts = check(s, brick, poses, backend=backend, config=cfg, floor_y=24.0)
                    check_s = time.perf_counter() - t
                    row.update(checks_per_s=round(batch / check_s, 1), accepted=sum(v.ok for v in verdicts),
                               rolled_out=sum(v.stable is not None for v in verdicts))
                rows.append(row)
                if log is not None:
                    log(row)
    return rows


def _config(args) -> CheckConfig:
    solver = {k: v for k, v in (("iterations", args.iterations), ("ls_iterations", args.ls_iterations)) if v}
    return CheckConfig(stability=StabilityConfig(**solver))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipelines.bench_physics")
    ap.add_argument("--backends", default="mujoco")
    ap.add_argument("--sizes", default="10,30,60")
    ap.add_argument("--batches", default="256")
    ap.add_argument("--full-max", type=int, help="run full checks only for batches up to this size")
    ap.add_argument("--iterations", type=int, help="solver iterations of the rollout (default: StabilityConfig's)")
    ap.add_argument("--ls-iterations", type=int, help="line-search iterations (default: StabilityConfig's)")
    ap.add_argument("--mjx-impl", choices=("jax", "warp"),
                    help="MJX implementation (default: warp on a CUDA GPU with warp-lang, else jax)")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    if args.mjx_impl:  # the full checks' rollouts (through check()) use it too
        os.environ["BRICK_FACTORY_MJX_IMPL"] = args.mjx_impl
    rows = measure(args.backends.split(","), [int(x) for x in args.sizes.split(",")],
                   [int(x) for x in args.batches.split(",")], log=lambda r: print(json.dumps(r), flush=True),
                   full_max=args.full_max, config=_config(args), mjx_impl=args.mjx_impl)
    if args.out:
        meta = {"machine": platform.node(), "processor": platform.processor(), "rows": rows}
        with open(args.out, "w") as fh:
            json.dump(meta, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
