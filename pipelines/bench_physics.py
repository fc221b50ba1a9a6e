"""Benchmark the physics checks: candidate checks per second by structure size, batch and backend.

`python -m pipelines.bench_physics [--backends mujoco,mjx] [--sizes 10,30,60]
[--batches 256,1024,4096] [--out FILE.json]`; with `--sweep`, the buildability sweep alone
(`factory.physics.sweep_jax.bench`: the batched exact JAX path against the CPU reference).

Structures are grown from a seed with 2x4 bricks (embedded library) by the checker itself, so
they are valid; candidates are feasible attachments of a 2x4 brick (drawn with replacement to fill
a batch). Reported per (backend, size, batch): full check rate (connection, collision, clutch,
whole-structure loads), and the load stage alone (each candidate's load program, models already
built): HiGHS one program at a time for `mujoco`, the batched JAX solver for `mjx`, with the
compiles it made.
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
from factory.physics.geometry import cache_dir
from factory.physics.check import _unit_connections
from factory.physics.statics import judge_many, load_model
from factory.physics.attach import feasible_poses, lowest_y
from factory.physics.structure import Placed, Structure


GROWN_MAX = 90
"""Bench structures are the first n bricks of one structure grown to this size."""


def grow(n: int, seed: int = 0) -> Structure:
    """A valid structure of n 2x4 bricks: the first n of one grown compactly to `GROWN_MAX` bricks
    (a build's prefix is itself a valid build). Growing 90 bricks through the full checks takes
    minutes, so the poses are cached (`geometry.cache_dir()/bench`, written atomically; delete the
    file to grow again after the checks change)."""
    brick = load_part(get_reader(), "3001")
    total = max(n, GROWN_MAX)
    path = cache_dir() / "bench" / f"grow_3001_{total}_seed{seed}.npy"
    if path.exists():
        poses = np.load(path)
    else:
        grown = _grow(total, seed)
        poses = np.stack([np.concatenate([p.pose.R.ravel(), p.pose.t]) for p in grown.placed])
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npy")
        np.save(tmp, poses)
        os.replace(tmp, path)
    return Structure([Placed(brick, 4, Pose(r[:9].reshape(3, 3), r[9:])) for r in poses[:n]])


def _grow(n: int, seed: int) -> Structure:
    """Grow n 2x4 bricks compactly on the ground plane and upward through the full checks."""
    rng = np.random.default_rng(seed)
    brick = load_part(get_reader(), "3001")
    s = Structure([Placed(brick, 4, Pose.identity())])
    while len(s) < n:
        poses = [p for p in feasible_poses(s, brick) if p.t[1] <= 0]  # on top, not hanging
        poses.sort(key=lambda p: (abs(p.t[0]) + abs(p.t[2]), -p.t[1]))
        # The most compact quarter first, shuffled; then the rest in order of compactness, 16 at a
        # time, until one passes (every compact spot can be taken or unbuildable).
        head = max(8, len(poses) // 4)
        order = list(rng.permutation(head)) + list(range(head, len(poses)))
        for start in range(0, len(order), 16):
            verdicts = check(s, brick, [poses[i] for i in order[start:start + 16]], floor_y=24.0)
            ok = [v for v in verdicts if v.ok]
            if ok:
                s.add(Placed(brick, 4, ok[0].pose))
                break
        else:
            raise RuntimeError(f"no 2x4 brick can be added to the {len(s)}-brick structure (seed {seed})")
    return s


def candidates(s: Structure, batch: int, seed: int = 1) -> list[Pose]:
    """`batch` feasible attachments of a 2x4 brick above the ground at y = 24 (as the sampler keeps
    them), drawn with replacement."""
    brick = load_part(get_reader(), "3001")
    poses = [p for p in feasible_poses(s, brick)
             if lowest_y(brick, p.R[None], p.t[None])[0] <= 24.0 + CheckConfig().max_penetration_ldu]
    rng = np.random.default_rng(seed)
    return [poses[i] for i in rng.integers(0, len(poses), size=batch)]


def load_models(s: Structure, poses: list[Pose], config: CheckConfig = CheckConfig()) -> list:
    """The whole-structure load model of the structure with each candidate (as `check` builds it)."""
    brick = load_part(get_reader(), "3001")
    out = []
    for p in poses:
        conns = _unit_connections(s, [(brick, p)])
        out.append(load_model(s.placed + [Placed(brick, 4, p)], s.connections + conns, 24.0, [len(s)],
                              s.links, config.loads))
    return out


def measure(backends, sizes, batches, log=None, full_max: int | None = None,
            config: CheckConfig = CheckConfig()) -> list[dict]:
    """One row per (size, batch, backend): load-stage and full-check candidates per second (full
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
            models = load_models(s, poses, cfg)
            for backend in backends:
                compile_s, compiles = 0.0, 0
                if backend == "mjx":
                    from factory.physics.lp_jax import COMPILES, solve_batch

                    t = time.perf_counter()
                    judge_many(models, cfg.loads, solve_batch)  # compile (and warm) this batch's bucket
                    compile_s = time.perf_counter() - t
                    t = time.perf_counter()
                    loads = judge_many(models, cfg.loads, solve_batch)
                    load_s = time.perf_counter() - t
                    compiles = len(COMPILES)
                else:
                    t = time.perf_counter()
                    loads = judge_many(models, cfg.loads)
                    load_s = time.perf_counter() - t
                row = {
                    "backend": backend, "bricks": n, "batch": batch,
                    "loads_per_s": round(batch / load_s, 1),
                    "standing": int(sum(v.stands for v in loads)),
                    "compile_s": round(compile_s, 2), "compiles_so_far": compiles,
                    "grow_s": round(grow_s, 1),
                }
                if full_max is None or batch <= full_max:
                    t = time.perf_counter()
                    verdicts = check(s, brick, poses, backend=backend, config=cfg, floor_y=24.0)
                    check_s = time.perf_counter() - t
                    row.update(checks_per_s=round(batch / check_s, 1), accepted=sum(v.ok for v in verdicts),
                               judged_loads=sum(v.stable is not None for v in verdicts))
                rows.append(row)
                if log is not None:
                    log(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipelines.bench_physics")
    ap.add_argument("--backends", default="mujoco")
    ap.add_argument("--sizes", default="10,30,60")
    ap.add_argument("--batches", default="256")
    ap.add_argument("--full-max", type=int, help="run full checks only for batches up to this size")
    ap.add_argument("--sweep", action="store_true",
                    help="measure the buildability sweep instead: the batched exact JAX path "
                         "(factory.physics.sweep_jax.bench) against the CPU reference")
    ap.add_argument("--cpu-max", type=int, default=512, help="with --sweep: candidates the CPU reference sweeps")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    if args.sweep:
        from factory.physics.sweep_jax import bench

        rows = bench([int(x) for x in args.sizes.split(",")], [int(x) for x in args.batches.split(",")],
                     args.cpu_max, log=lambda r: print(json.dumps(r), flush=True))
        if args.out:
            with open(args.out, "w") as fh:
                json.dump({"machine": platform.node(), "processor": platform.processor(), "rows": rows}, fh, indent=1)
        return 0
    rows = measure(args.backends.split(","), [int(x) for x in args.sizes.split(",")],
                   [int(x) for x in args.batches.split(",")], log=lambda r: print(json.dumps(r), flush=True),
                   full_max=args.full_max)
    if args.out:
        meta = {"machine": platform.node(), "processor": platform.processor(), "rows": rows}
        with open(args.out, "w") as fh:
            json.dump(meta, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
