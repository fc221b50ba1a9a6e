"""Parity of the batched settling on MuJoCo Warp (`settle_mjx.settle_many`) with the MuJoCo C
reference (`settle.settle_all`) on predictions like the baselines' and perturbed true placements.

    python -m pipelines.bench_settle --n 500 --out settle_parity.json

Structures and true next parts come from the sampler (`factory.grow`, embedded library): object
`i`'s first `k` parts are a structure, its part `k + 1` the true next one. Per (structure, part)
scene, `--per-scene` predictions of that part (so that a scene compiles once in MJX): the true
pose; shifted 1-3 LDU across (near a connection: snaps); lifted 5-40 LDU (falls, then snaps or
rests); shifted 8-12 LDU and lifted (between stud positions); moved out past the structure's edge by
0-20 LDU and lifted (near the edge: rests on it or falls); turned 15-60 degrees about the vertical
and lifted; the heuristic baseline's pose (24 LDU above the last part, unturned); the random
baseline's (a 20 LDU grid translation within 200 LDU, one of the 24 axis rotations). Writes the
share of equal outcomes (all, and those both simulated), the pose differences of equal outcomes,
per-outcome counts, every disagreement with its case, and both throughputs.

    python -m pipelines.bench_settle --n 2000 --seed 2 --throughput cpu,warp --workers 1,16 --out tp.json

`--throughput ENGINES` measures each engine alone over worker processes instead ('cpu': MuJoCo C,
`settle_all`; 'warp': MuJoCo Warp, `settle_many`, every worker on the same device): the scenes
dealt out round robin, each worker's kernels loaded and first cases settled before a common start,
the wall time from that start until the last worker is done. Same seed, same predictions: the
outcomes' digest says so. For MuJoCo C it also gives the seconds inside `mj_step` against the
whole (`cpu.step_share`): only that share is simulation; the rest is host work both engines do.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import multiprocessing
import sys
import time
from collections import Counter
from queue import Empty

import numpy as np

from factory import SamplerConfig, get_reader, grow, load_part
from factory.physics.linked import linked
from factory.physics.settle import SettleConfig, SettleStats, settle_all
from factory.physics.settle_mjx import BATCH, MjxStats, settle_many
from factory.physics.structure import Placed, Structure
from factory.pose import Pose
from factory.symmetry import axis_rotations, rotation_about
from pipelines.workers import one_thread_each_meanwhile

KINDS = ("true", "shift", "lift", "between", "edge", "turn", "heuristic", "random")


def _predictions(structure: Structure, true: Pose, rng: np.random.Generator, n: int) -> list[tuple[str, Pose]]:
    up = np.array([0.0, -1.0, 0.0])
    rots = axis_rotations()
    pts = np.concatenate([p.pose.apply(p.part.hull_points) for p in structure.placed])
    centre = pts.mean(axis=0)
    out = []
    for j in range(n):
        kind = KINDS[j % len(KINDS)]
        d = rng.normal(size=3)
        d[1] = 0.0
        d /= np.linalg.norm(d) or 1.0
        if kind == "true":
            pose = true if j < len(KINDS) else Pose(true.R, true.t + d * rng.uniform(0, 0.5))
        elif kind == "shift":
            pose = Pose(true.R, true.t + d * rng.uniform(1, 3))
        elif kind == "lift":
            pose = Pose(true.R, true.t + up * rng.uniform(5, 40))
        elif kind == "between":
            pose = Pose(true.R, true.t + d * rng.uniform(8, 12) + up * rng.uniform(0, 6))
        elif kind == "edge":
            out_dir = true.t - centre
            out_dir[1] = 0.0
            out_dir = out_dir / (np.linalg.norm(out_dir) or 1.0) if np.linalg.norm(out_dir) > 1 else d
            reach = float(np.max((pts - true.t) @ out_dir))
            pose = Pose(true.R, true.t + out_dir * (reach * rng.uniform(0.3, 1.0) + rng.uniform(0, 20))
                        + up * rng.uniform(2, 10))
        elif kind == "turn":
            pose = Pose(rotation_about((0, 1, 0), float(rng.uniform(15, 60))) @ true.R, true.t + up * rng.uniform(0, 10))
        elif kind == "heuristic":
            last = structure.placed[-1].pose
            pose = Pose(np.eye(3), last.t + np.array([0.0, -24.0, 0.0]))
        else:
            t = rng.integers(-10, 11, size=3) * 20.0
            pose = Pose(rots[int(rng.integers(len(rots)))], t)
        out.append((kind, pose))
    return out


def cases(n: int, per_scene: int, seed: int, parts_range=(2, 4)) -> list[dict]:
    """`n` prediction cases (dicts: scene, kind, structure, part, pose, floor_y), `per_scene` per
    (structure, part) scene, from objects grown with `seed`."""
    rng = np.random.default_rng(seed)
    reader = get_reader()
    want = -(-n // per_scene)
    out: list[dict] = []
    index = 0
    while len(out) < n and index < 20 * want + 20:
        # Grown only as far as the scenes need: a whole object (20-90 parts) costs seconds each.
        (assembly,) = grow(1, SamplerConfig(seed=seed, min_steps=parts_range[1] + 1, max_steps=parts_range[1] + 1),
                           start=index)
        index += 1
        steps = assembly.steps
        if len(steps) < parts_range[0] + 1:
            continue
        k = int(rng.integers(parts_range[0], min(parts_range[1], len(steps) - 1) + 1))
        structure = linked(Placed(load_part(reader, s.part), s.colour, s.pose) for s in steps[:k])
        part = load_part(reader, steps[k].part)
        floor_y = structure.floor_y()
        scene = len({c["scene"] for c in out})
        for kind, pose in _predictions(structure, steps[k].pose, rng, min(per_scene, n - len(out))):
            out.append(dict(scene=scene, kind=kind, structure=structure, part=part, pose=pose, floor_y=floor_y))
    return out


def _pose_diff(a: Pose, b: Pose) -> tuple[float, float]:
    cos = np.clip((np.trace(a.R.T @ b.R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(a.t - b.t)), float(np.degrees(np.arccos(cos)))


def run(n: int, per_scene: int, seed: int, config: SettleConfig = SettleConfig(), device: str | None = None,
        worlds: int = BATCH) -> dict:
    t0 = time.perf_counter()
    cs = cases(n, per_scene, seed)
    print(f"{len(cs)} predictions in {len({c['scene'] for c in cs})} scenes made in {time.perf_counter() - t0:.1f} s",
          file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    ref = settle_all([(c["structure"], c["part"], c["pose"], c["floor_y"]) for c in cs], config)
    cpu_s = time.perf_counter() - t0
    print(f"MuJoCo C: {cpu_s:.1f} s", file=sys.stderr, flush=True)
    stats = MjxStats()
    t0 = time.perf_counter()
    got = settle_many([(c["structure"], c["part"], c["pose"], c["floor_y"]) for c in cs], config, device=device, batch=worlds,
                      stats=stats)
    mjx_s = time.perf_counter() - t0
    simulated = [i for i, r in enumerate(ref) if r.seconds > 0 or got[i].seconds > 0]
    same = [a.outcome == b.outcome for a, b in zip(ref, got)]
    diffs = [_pose_diff(a.pose, b.pose) for a, b, s in zip(ref, got, same) if s]
    disagreements = [dict(index=i, scene=c["scene"], kind=c["kind"], part=c["part"].name,
                          structure=[p.part.name for p in c["structure"].placed],
                          pose_t=c["pose"].t.tolist(), pose_R=c["pose"].R.tolist(), floor_y=c["floor_y"],
                          cpu=dict(outcome=a.outcome, t=a.pose.t.tolist(), seconds=a.seconds, at_rest=a.at_rest),
                          mjx=dict(outcome=b.outcome, t=b.pose.t.tolist(), seconds=b.seconds, at_rest=b.at_rest))
                     for i, (c, a, b) in enumerate(zip(cs, ref, got)) if a.outcome != b.outcome]
    return dict(
        n=len(cs), scenes=len({c["scene"] for c in cs}), seed=seed, per_scene=per_scene,
        agreement=float(np.mean(same)) if cs else None,
        simulated=len(simulated),
        agreement_simulated=float(np.mean([same[i] for i in simulated])) if simulated else None,
        pose_diff_ldu=dict(mean=float(np.mean([d[0] for d in diffs])) if diffs else None,
                           max=float(np.max([d[0] for d in diffs])) if diffs else None),
        pose_diff_degrees=dict(mean=float(np.mean([d[1] for d in diffs])) if diffs else None,
                               max=float(np.max([d[1] for d in diffs])) if diffs else None),
        outcomes=dict(cpu=dict(Counter(r.outcome for r in ref)), mjx=dict(Counter(r.outcome for r in got))),
        kinds=dict(Counter(c["kind"] for c in cs)),
        disagreements=disagreements,
        throughput=dict(cpu_per_s=len(cs) / cpu_s, mjx_per_s=len(cs) / mjx_s, cpu_s=cpu_s, mjx_s=mjx_s,
                        mjx_first_chunk_s=stats.first_chunk_s, mjx_run_s=stats.run_s, mjx_prepare_s=stats.prepare_s,
                        device=stats.device),
        mjx=dict(batches=stats.batches, simulated=stats.simulated, fallbacks=stats.fallbacks, diverged=stats.diverged,
                 contacts_dropped=stats.contacts_dropped, refused=stats.refused),
    )


def _share(engine: str, batch: list, device: str | None, barrier, queue, index: int, worlds: int = BATCH) -> None:
    """One worker of `throughput`: warm up, wait for the others, settle its share, report."""
    warm = batch[:8]
    if engine == "warp":
        settle_many(warm, device=device)  # Warp's kernels loaded (compiled the first time on a machine)
    else:
        settle_all(warm)
    barrier.wait()
    stats = MjxStats() if engine == "warp" else SettleStats()
    t0 = time.perf_counter()  # CLOCK_MONOTONIC: one clock for every process of the machine
    got = (settle_many(batch, device=device, stats=stats, batch=worlds) if engine == "warp"
           else settle_all(batch, stats=stats))
    t1 = time.perf_counter()
    queue.put((index, t0, t1, [(r.outcome, r.seconds > 0) for r in got], stats.__dict__))


def throughput(cs: list[dict], engine: str, workers: int, device: str | None = None, worlds: int = BATCH) -> dict:
    """Predictions settled per second by `engine` ('cpu' or 'warp') over `workers` processes
    (`per_case`: each case's outcome, in order)."""
    ctx = multiprocessing.get_context("spawn")  # not fork: CUDA and JAX hold state a fork breaks
    barrier, queue = ctx.Barrier(workers), ctx.Queue()
    shares = [[i for i, c in enumerate(cs) if c["scene"] % workers == k] for k in range(workers)]
    procs = [ctx.Process(target=_share, args=(engine, [(cs[i]["structure"], cs[i]["part"], cs[i]["pose"],
                                                          cs[i]["floor_y"]) for i in share],
                                              device, barrier, queue, k, worlds))
             for k, share in enumerate(shares)]
    with one_thread_each_meanwhile():  # as the factory's own workers: the processes fill the cores
        for p in procs:
            p.start()
    reports: list = []
    while len(reports) < len(procs):
        try:
            reports.append(queue.get(timeout=5))
        except Empty:
            failed = [p.exitcode for p in procs if p.exitcode not in (None, 0)]
            if failed:
                for p in procs:
                    p.terminate()
                raise RuntimeError(f"a worker of the {engine} throughput run failed (exit code {failed[0]})") from None
    for p in procs:
        p.join()
    outcomes: list[str | None] = [None] * len(cs)
    simulated = 0
    for k, _, _, got, _ in reports:
        for i, (o, ran) in zip(shares[k], got):
            outcomes[i] = o
            simulated += ran
    wall = max(r[2] for r in reports) - min(r[1] for r in reports)
    keys = (("prepare_s", "first_chunk_s", "run_s", "step_s", "rules_s", "simulated", "fallbacks", "diverged",
             "contacts_dropped", "batches") if engine == "warp" else ("total_s", "step_s"))
    summed = {key: round(sum(r[4][key] for r in reports), 3) for key in keys}
    stats = summed if engine == "warp" else None
    # MuJoCo C's own stepping against its whole time: the share a faster simulator could save (the
    # checks, snapping verdicts, scene models and rules are the same host work for both engines).
    cpu = None if engine == "warp" else {**summed, "step_share": round(summed["step_s"] / max(summed["total_s"], 1e-9), 3)}
    return dict(engine=engine, workers=workers, predictions=len(cs), wall_s=round(wall, 3),
                per_s=round(len(cs) / wall, 1), outcomes=dict(Counter(outcomes)),
                outcomes_sha256=hashlib.sha256("\n".join(map(str, outcomes)).encode()).hexdigest()[:16],
                busiest_s=round(max(r[2] - r[1] for r in reports), 3), simulated=simulated, warp=stats, cpu=cpu,
                device=device, per_case=outcomes)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=500, help="predictions")
    ap.add_argument("--per-scene", type=int, default=50, help="predictions per (structure, part) scene")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default=None, help="Warp device ('cpu', 'cuda:0'; default: the GPU if any)")
    ap.add_argument("--worlds", default=str(BATCH),
                    help="Warp's worlds at once, a world whose part stops taking the next prediction "
                         "(with --throughput, a list: '256,4096' runs each)")
    ap.add_argument("--throughput", default=None,
                    help="measure these engines ('cpu', 'warp' or 'cpu,warp') alone over --workers processes, no parity")
    ap.add_argument("--workers", default="1", help="processes of --throughput (a list: '1,16' runs each)")
    ap.add_argument("--out", required=True, help="JSON file to write")
    args = ap.parse_args(argv)
    if args.throughput:
        engines = args.throughput.split(",")
        for engine in engines:
            if engine not in ("cpu", "warp"):
                ap.error(f"--throughput: unknown engine {engine!r}; choose from cpu, warp")
        try:
            counts = [int(w) for w in args.workers.split(",")]
            worlds = [int(w) for w in args.worlds.split(",")]
        except ValueError:
            ap.error(f"--workers, --worlds: expected whole numbers separated by commas, got {args.workers!r}, "
                     f"{args.worlds!r}")
        t0 = time.perf_counter()
        cs = cases(args.n, args.per_scene, args.seed)
        print(f"{len(cs)} predictions made in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        results = []
        for engine in engines:
            for workers, w in ((k, w) for k in counts for w in (worlds if engine == "warp" else worlds[:1])):
                result = throughput(cs, engine, workers, args.device if engine == "warp" else None, w)
                result.update(seed=args.seed, per_scene=args.per_scene, worlds=w if engine == "warp" else None)
                del result["per_case"]
                results.append(result)
                print(json.dumps(result), flush=True)
        with open(args.out, "w", encoding="utf-8") as f:
            json.dump(results, f, indent=1)
        return
    try:
        worlds = int(args.worlds)
    except ValueError:
        ap.error(f"--worlds: expected a whole number without --throughput, got {args.worlds!r}")
    result = run(args.n, args.per_scene, args.seed, device=args.device, worlds=worlds)
    with open(args.out, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    brief = {k: result[k] for k in ("n", "scenes", "agreement", "simulated", "agreement_simulated", "outcomes",
                                    "throughput", "mjx")}
    print(json.dumps(brief, indent=1))
    print(f"{len(result['disagreements'])} disagreements; written to {args.out}")


if __name__ == "__main__":
    main()
