"""Benchmark the physics checks: candidate checks per second by structure size, batch and backend.

`python -m pipelines.bench_physics [--backends cpu,jax] [--sizes 10,30,60]
[--batches 256,1024,4096] [--out FILE.json]`; with `--sweep`, the buildability sweep alone
(`measure_sweep`: the batched exact JAX path against the CPU reference).

`python -m pipelines.bench_physics --growth --backends jax --batches 1,16,64 --steps 30 --objects 64`:
lockstep growth of the same objects at each batch, steps per second (`measure_growth`).

`python -m pipelines.bench_physics --lp --sizes 30,60,90 --batches 1024,4096,16384`: the load check
alone from each candidate's pose (`load_stage`: model, tipping rule, program), the batched JAX
solver against HiGHS (`--cpu-workers K`: the reference in K processes), verdicts compared.

Structures are grown from a seed with 2x4 bricks (embedded library) by the checker itself, so
they are valid; candidates are feasible attachments of a 2x4 brick (drawn with replacement to fill
a batch). Reported per (backend, size, batch): full check rate (connection, collision, clutch,
whole-structure loads), and the load stage alone (each candidate's load program, models already
built): HiGHS one program at a time for `cpu`, the batched JAX solver for `jax`, with the
compiles it made.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import json
import multiprocessing
import os
import platform
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from factory import Pose, get_reader, load_part, mps
from factory.atomic import write_atomic
from factory.cli import ArgumentParser, add_mps_flag
from factory.physics import check as check_mod
from factory.physics import sweep_jax
from factory.physics.check import STAGE_SECONDS, CheckConfig, backend_arg, backend_name, check
from factory.physics import collide as collide_mod
from factory.physics.collide import CollisionScene
from factory.physics.check import _unit_connections
from factory.physics.statics import _ALONE, LoadBase, judge_many, judge_on_base
from factory.physics.attach import feasible_poses, lowest_y
from factory.physics.structure import Placed, Structure
from factory.physics.sweep import _boxes, seating_from_connections, sweep
from factory.sampler import Sampler, SamplerConfig


GROWN = Path(__file__).with_name("grown_3001.json")
"""The poses `grow(90, seed=0)` placed, in order (a structure of n bricks is the first n): growing
90 takes minutes."""


def grown(n: int, seed: int = 0) -> Structure:
    """`grow(n, seed)`, from `GROWN` where it holds it."""
    if seed == 0 and GROWN.exists():
        poses = json.loads(GROWN.read_text())
        if len(poses) >= n:
            brick = load_part(get_reader(), "3001")
            return Structure([Placed(brick, 4, Pose(np.array(p["R"]), np.array(p["t"]))) for p in poses[:n]])
    return grow(n, seed)


def grow(n: int, seed: int = 0) -> Structure:
    """A valid structure of n 2x4 bricks, grown compactly on the ground plane and upward.

    Each step checks 16 of the nearest quarter of the attachments; once a step finds none valid
    (near 50 bricks almost every near attachment collides: 14 of 4,130 were valid at 48), the
    attachments whose boxes overlap a placed brick's are left out first, and the rest checked 16
    at a time until one is valid. Until a step fails 20 times in a row, the structure is the one
    the plain rule grows."""
    rng = np.random.default_rng(seed)
    brick = load_part(get_reader(), "3001")
    s = Structure([Placed(brick, 4, Pose.identity())])
    stalled, failed = False, 0
    while len(s) < n:
        poses = [p for p in feasible_poses(s, brick) if p.t[1] <= 0]  # on top, not hanging
        poses.sort(key=lambda p: (abs(p.t[0]) + abs(p.t[2]), -p.t[1]))
        if stalled:
            poses = _clear_of(s, brick, poses)
        pick = poses[: max(8, len(poses) // 4)] if not stalled else poses
        order = rng.permutation(len(pick))
        for start in range(0, len(order) if stalled else 1, 16):
            verdicts = check(s, brick, [pick[i] for i in order[start:start + 16]], floor_y=24.0)
            ok = [v for v in verdicts if v.ok]
            if ok:
                s.add(Placed(brick, 4, ok[0].pose))
                failed = 0
                break
        else:
            if stalled:
                raise RuntimeError(f"no valid attachment at {len(s)} bricks")
            failed += 1
            stalled = failed >= 20
    return s


def _clear_of(s: Structure, brick, poses: list[Pose]) -> list[Pose]:
    """The poses whose bounding box overlaps no placed brick's (by more than 1 LDU across, 4.5 LDU
    in height: a brick's studs stand 4 LDU into the one above)."""
    placed = _boxes([(q.part, q.pose) for q in s.placed])  # (k, 2, 3)
    boxes = _boxes([(brick, p) for p in poses])
    overlap = np.minimum(boxes[:, None, 1], placed[None, :, 1]) - np.maximum(boxes[:, None, 0], placed[None, :, 0])
    clear = ~(overlap > [1.0, 4.5, 1.0]).all(axis=2).any(axis=1)
    return [p for p, ok in zip(poses, clear) if ok]


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
    base = LoadBase(s.placed, s.connections, 24.0, s.links, config.loads)
    return [base.model([Placed(brick, 4, p)], _unit_connections(s, [(brick, p)])) for p in poses]


def measure(backends, sizes, batches, log=None, full_max: int | None = None,
            config: CheckConfig = CheckConfig(), reference_max: int | None = None) -> list[dict]:
    """One row per (size, batch, backend): load-stage and full-check candidates per second (full
    checks only up to `full_max` candidates: their contact stage runs on the CPU for every backend;
    the `cpu` reference only up to `reference_max`)."""
    backends = [backend_name(b) for b in backends]
    brick = load_part(get_reader(), "3001")
    cfg = config
    rows = []
    for n in sizes:
        t0 = time.perf_counter()
        s = grown(n)
        grow_s = time.perf_counter() - t0
        for batch in batches:
            poses = candidates(s, batch)
            models = load_models(s, poses, cfg)
            for backend in backends:
                if backend == "cpu" and reference_max is not None and batch > reference_max:
                    continue
                compile_s, compiles = 0.0, 0
                if backend == "jax":
                    from factory.physics.lp_jax import COMPILES, solve_loads  # optional: JAX (the [jax] extra)

                    t = time.perf_counter()
                    judge_many(models, cfg.loads, solve_loads)  # compile (and warm) this batch's bucket
                    compile_s = time.perf_counter() - t
                    t = time.perf_counter()
                    loads = judge_many(models, cfg.loads, solve_loads)
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
                _emit(rows, log, row)
    return rows


def sweep_pool(s: Structure, scene) -> list[tuple]:
    """The distinct feasible attachments of a 2x4 brick on `s` whose final pose the collision
    check accepts, each as (unit, parts it connects to, seating directions), as `check_units`
    hands them to the sweep."""

    brick = load_part(get_reader(), "3001")
    pool = []
    for p in {tuple(np.round(q.t, 3)) + tuple(np.round(q.R, 3).ravel()): q for q in candidates(s, 4096)}.values():
        world = [(brick, p)]
        outer = [c for c in _unit_connections(s, world) if min(c[0], c[1]) < len(s)]
        touched = {min(c[0], c[1]) for c in outer}
        if scene.penetration(p, touched)[0] <= 0.5:
            pool.append((world, touched, seating_from_connections(outer, len(s))))
    return pool


def load_stage(s: Structure, poses: list[Pose], batched: bool = False, config: CheckConfig = CheckConfig(),
               conns: list | None = None) -> list:
    """The load check of each candidate from its connections (`conns`, found here if None), as
    `check_units` runs it: the CPU reference builds each model (`statics.LoadBase.model`) and
    solves its program with HiGHS (`judge_many`); the batched path (`batched`) judges them all on
    the structure's shared columns (`judge_on_base` with `lp_jax.solve_on_base`). Failing
    connections are not sought (`explain=False`, as the sampler asks)."""

    brick = load_part(get_reader(), "3001")
    if conns is None:
        conns = [_unit_connections(s, [(brick, p)]) for p in poses]
    base = LoadBase(s.placed, s.connections, 24.0, s.links, config.loads)
    units = [[Placed(brick, 4, p)] for p in poses]
    if batched:
        from factory.physics.lp_jax import solve_on_base  # optional: JAX (the [jax] extra)

        return judge_on_base(base, units, conns, config.loads, solve_on_base, explain=False)
    return judge_many([base.model(u, c) for u, c in zip(units, conns)], config.loads, explain=False)


# The CPU reference in worker processes (`cpu_workers`): each builds its inputs once, from the
# same seeds as the parent, so both time the same candidates.
_CTX: dict = {}


def _ctx_init(kind: str, n: int, batch: int) -> None:

    s = grown(n)
    _CTX.update(kind=kind, s=s)
    if kind == "whole":
        _CTX["poses"] = candidates(s, batch)
    elif kind == "loads":
        brick = load_part(get_reader(), "3001")
        _CTX["poses"] = candidates(s, batch)
        _CTX["conns"] = [_unit_connections(s, [(brick, p)]) for p in _CTX["poses"]]
    else:
        brick = load_part(get_reader(), "3001")
        scene = CollisionScene(s, [(brick, Pose.identity())], 1e6)
        pool = sweep_pool(s, scene)
        rng = np.random.default_rng(0)
        _CTX.update(scene=scene, cases=[pool[i] for i in rng.integers(0, len(pool), batch)])


def _ctx_run(span: tuple[int, int]) -> list:

    a, b = span
    if _CTX["kind"] == "whole":
        brick = load_part(get_reader(), "3001")
        return [(v.ok, v.reason) for v in check(_CTX["s"], brick, _CTX["poses"][a:b], floor_y=24.0, explain=False)]
    if _CTX["kind"] == "loads":
        return [(v.stands, v.reason) for v in load_stage(_CTX["s"], _CTX["poses"][a:b], conns=_CTX["conns"][a:b])]
    return [sweep(_CTX["scene"], _CTX["s"], w, c).buildable for w, c, _ in _CTX["cases"][a:b]]


def _batched_answers(a: int, b: int) -> list:
    """The batched path's answers for candidates a..b-1 of this process's inputs (`_ctx_init`), as
    the reference's `_ctx_run` gives them."""
    kind, s = _CTX["kind"], _CTX["s"]
    if kind == "whole":
        got = check(s, load_part(get_reader(), "3001"), _CTX["poses"][a:b], backend="jax", floor_y=24.0, explain=False)
        return [(v.ok, v.reason) for v in got]
    if kind == "loads":
        return [(v.stands, v.reason) for v in load_stage(s, _CTX["poses"][a:b], True, conns=_CTX["conns"][a:b])]
    cases = _CTX["cases"][a:b]
    got = sweep_jax.sweep_many(_CTX["scene"], s, [c[0] for c in cases], [c[1] for c in cases],
                               directions=[c[2] for c in cases])
    return [r.buildable for r in got]


def _shared_run(span: tuple[int, int], barrier) -> tuple[float, float, list]:
    """One process's share of a batch on the batched path (`batched_processes`): its slice judged
    once (compiles its shapes, untimed), then again once every process is ready; (start, end,
    answers)."""
    a, b = span
    _batched_answers(a, b)
    gc.collect()
    gc.freeze()
    _ALONE.clear()  # the warm-up's clutch answers: the timed call finds its own
    barrier.wait()
    t = time.time()
    got = _batched_answers(a, b)
    return t, time.time(), got


def batched_processes(kind: str, n: int, batch: int, procs: int) -> tuple[list, float, bool]:
    """(answers, seconds, mps): the batch on the batched path ('whole', 'loads' or 'sweep') in
    `procs` processes that share the default JAX device, each on a contiguous slice, so that one
    process's host work overlaps another's device work, as the factory's workers do. Seconds from
    the first start to the last end, every process compiled and waiting at a barrier before the
    clock starts; `mps`: whether they shared the GPU through MPS (`factory.mps`, `MPS_MODE`)."""

    done, seconds, sharing = _together(_spans(batch, procs), _ctx_init, (kind, n, batch), _shared_run, gpu=True)
    return [x for *_, got in done for x in got], seconds, sharing.mps


def _spans(n: int, procs: int) -> list[tuple[int, int]]:
    """0..n-1 cut into at most `procs` contiguous (start, end) slices."""
    step = -(-n // procs)
    return [(a, min(a + step, n)) for a in range(0, n, step)]


def _call(fn):
    return fn()


def in_own_process(fn):
    """fn() in a new process (spawned: JAX's threads may hold locks across a fork), so that the
    device memory JAX grows for it is given back when it ends."""
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_call, fn).result()


MPS_MODE: str | None = None
"""`--mps`: how `_together`'s JAX processes share a GPU (`factory.mps.shared_gpu`; None: its default)."""


def _together(spans, init, initargs, run, *args, gpu: bool = False) -> tuple[list, float, mps.Sharing]:
    """`run(span, *args, barrier)` for each span, each in a new process of its own (`init(*initargs)`
    first), the clocks started together at the barrier: (each run's result, seconds from the first
    start to the last end, how the processes shared the GPU; every result begins with its start
    and end times). `gpu`: the processes run JAX kernels (on a GPU, through MPS where
    `factory.mps` finds it useful)."""
    spawn = multiprocessing.get_context("spawn")  # not fork: JAX's threads may hold locks
    sharing = mps.shared_gpu(len(spans), MPS_MODE, say=_say) if gpu else contextlib.nullcontext(
        mps.Sharing(False, "no GPU work"))
    with sharing as shared, spawn.Manager() as manager, ProcessPoolExecutor(
            len(spans), mp_context=spawn, initializer=init, initargs=initargs) as pool:
        barrier = manager.Barrier(len(spans), timeout=BARRIER_S)  # every task waits for all: one task per process
        done = list(pool.map(functools.partial(_guarded, run), spans, *[[a] * len(spans) for a in args],
                             [barrier] * len(spans)))
    return done, max(d[1] for d in done) - min(d[0] for d in done), shared


BARRIER_S = 900.0
"""Seconds a process of `_together` waits at the barrier for the others to be warm, at most."""


def _guarded(run, span, *args):
    """`run(span, *args)`; if it fails, the barrier (the last of `args`) is broken, so that the
    other processes stop waiting for this one and fail too (a process that ran out of device
    memory in its warm-up had left the others waiting until the run was killed, 2026-11-26)."""
    try:
        return run(span, *args)
    except BaseException:
        args[-1].abort()
        raise


def _shared_row(kind: str, row: dict, procs: int, cpu_max: int, cpu_workers: int, counts) -> dict:
    """`row` ({"bricks", "batch", ...}) with its batch judged on the batched path by `procs`
    processes sharing the device (`batched_processes`): `procs`, `jax_per_s`, `counts(answers)`,
    and with `cpu_max` the reference's rate and how many answers agree."""
    n, batch = row["bricks"], row["batch"]
    answers, seconds, on_mps = batched_processes(kind, n, batch, procs)
    row.update(procs=procs, mps=on_mps, jax_per_s=round(batch / seconds, 1), **counts(answers))
    if cpu_max:
        _with_reference(row, kind, n, batch, cpu_max, cpu_workers, (seconds, answers))
    return row


SAY_EVERY_S = 10.0
"""Seconds between a grower process's progress lines."""


def _say(message: str) -> None:
    """Progress of a long measurement on stderr (the rows go to stdout): a run cut short by a
    time limit still shows how far it got."""
    print(f"bench_physics: {message}", file=sys.stderr, flush=True)


def _emit(rows: list, log, row: dict) -> None:
    """Keep `row`, and log it as it comes."""
    rows.append(row)
    if log is not None:
        log(row)


def cpu_reference(kind: str, n: int, batch: int, count: int, workers: int) -> tuple[list, float]:
    """(answers, seconds): the CPU reference on the first `count` of the batch's candidates, split
    over `workers` processes (started and warmed before the clock starts)."""

    if workers <= 1:
        _ctx_init(kind, n, batch)
        _ctx_run((0, 1))
        t = time.perf_counter()
        out = _ctx_run((0, count))
        return out, time.perf_counter() - t
    spawn = multiprocessing.get_context("spawn")  # not fork: JAX's threads may hold locks
    with ProcessPoolExecutor(workers, mp_context=spawn, initializer=_ctx_init, initargs=(kind, n, batch)) as pool:
        list(pool.map(_ctx_run, [(0, 1)] * workers))  # every worker started and warm
        step = -(-count // (4 * workers))
        t = time.perf_counter()
        parts = list(pool.map(_ctx_run, [(a, min(a + step, count)) for a in range(0, count, step)]))
        seconds = time.perf_counter() - t
    return [x for p in parts for x in p], seconds


def _with_reference(row: dict, kind: str, n: int, batch: int, cpu_max: int, cpu_workers: int,
                    batched: tuple[float, list] | None) -> None:
    """Add the CPU reference's rate on the batch's first `cpu_max` candidates to `row`, and with
    `batched` (its seconds for the whole batch, its answers) the speed-up and how many answers
    agree."""
    ref, cpu_s = cpu_reference(kind, n, batch, min(cpu_max, batch), cpu_workers)
    row.update(cpu_workers=cpu_workers, cpu_per_s=round(len(ref) / cpu_s, 1), cpu_compared=len(ref))
    if batched is not None:
        seconds, answers = batched
        row.update(speedup=round(batch / seconds / (len(ref) / cpu_s), 2),
                   agree=sum(a == b for a, b in zip(ref, answers)))


def measure_lp(sizes, batches, log=None, cpu_max: int = 128, cpu_workers: int = 1,
               config: CheckConfig = CheckConfig(), batched: bool = True, procs: int = 1) -> list[dict]:
    """Load checks per second from the candidates' connections (`load_stage`; the sweep is timed
    from them too): the batched path (default JAX device) on each batch, the CPU reference (HiGHS)
    on its first `cpu_max` candidates in `cpu_workers` processes; verdicts compared on those.
    `batched=False`: the reference alone. `procs` > 1: the batched path in that many processes
    sharing the device (`batched_processes`), with the default config."""
    from factory.physics import lp_jax  # optional: JAX (the [jax] extra)

    rows = []
    for n in sizes:
        s = grown(n)
        brick = load_part(get_reader(), "3001")
        for batch in batches:
            poses = candidates(s, batch)
            row = {"bricks": n, "batch": batch}
            if batched and procs > 1:
                _emit(rows, log, _shared_row("loads", row, procs, cpu_max, cpu_workers,
                                             lambda got: {"overloaded": sum(r == "overload" for _, r in got)}))
                continue
            if batched:
                conns = [_unit_connections(s, [(brick, p)]) for p in poses]
                compiles = len(lp_jax.COMPILES)
                t = time.perf_counter()
                load_stage(s, poses, True, config, conns)  # compiles this batch's shapes
                first_s = time.perf_counter() - t
                fallbacks = lp_jax.FALLBACKS[0]
                t = time.perf_counter()
                got = load_stage(s, poses, True, config, conns)
                jax_s = time.perf_counter() - t
                row.update(jax_per_s=round(batch / jax_s, 1),
                           first_call_s=round(first_s, 2), new_compiles=len(lp_jax.COMPILES) - compiles,
                           fallbacks=lp_jax.FALLBACKS[0] - fallbacks, tipping=sum(v.reason == "unstable" for v in got),
                           overloaded=sum(v.reason == "overload" for v in got))
            if cpu_max:
                _with_reference(row, "loads", n, batch, cpu_max, cpu_workers,
                                (jax_s, [(v.stands, v.reason) for v in got]) if batched else None)
            _emit(rows, log, row)
    return rows


def measure_whole(sizes, batches, log=None, cpu_max: int = 256, cpu_workers: int = 1,
                  config: CheckConfig = CheckConfig(), batched: bool = True, procs: int = 1) -> list[dict]:
    """Whole checks per second (every check a candidate goes through: connection, collision,
    clutch, buildability sweep, whole-structure loads; `check` as the sampler calls it, failing
    connections not sought): the batched path (`backend='jax'`, default JAX device) on each batch
    and the reference (`'cpu'`, in `cpu_workers` processes) on its first `cpu_max` candidates,
    verdicts (accepted, reason) compared on those. `batched=False`: the reference alone.
    `procs` > 1: the batched path in that many processes sharing the device (`batched_processes`),
    with the default config."""

    brick = load_part(get_reader(), "3001")
    rows = []
    for n in sizes:
        s = grown(n)
        for batch in batches:
            poses = candidates(s, batch)
            row = {"bricks": n, "batch": batch}
            got = answers = gpu_s = None
            if batched and procs > 1:
                answers, gpu_s, on_mps = batched_processes("whole", n, batch, procs)
                row.update(procs=procs, mps=on_mps, gpu_per_s=round(batch / gpu_s, 1),
                           accepted=sum(ok for ok, _ in answers),
                           reasons=dict(Counter(r for _, r in answers if r)))
            elif batched:
                t = time.perf_counter()
                check(s, brick, poses, backend="jax", config=config, floor_y=24.0, explain=False)  # compiles
                first_s = time.perf_counter() - t
                # A process that has compiled with JAX holds many long-lived objects (a sampler
                # process: 661K, a full collection 0.29 s); moved out of the collector's view.
                gc.collect()
                gc.freeze()
                _ALONE.clear()  # the warm-up's clutch answers: the timed call finds its own
                before = check_mod.STAGE_SECONDS.copy()
                t = time.perf_counter()
                got = check(s, brick, poses, backend="jax", config=config, floor_y=24.0, explain=False)
                gpu_s = time.perf_counter() - t
                stages = check_mod.STAGE_SECONDS - before
                row.update(gpu_per_s=round(batch / gpu_s, 1), first_call_s=round(first_s, 2),
                           stage_s={k: round(v, 3) for k, v in sorted(stages.items())},
                           accepted=sum(v.ok for v in got),
                           reasons=dict(Counter(v.reason for v in got if v.reason)))
            if cpu_max:
                if got is not None:
                    answers = [(v.ok, v.reason) for v in got]
                _with_reference(row, "whole", n, batch, cpu_max, cpu_workers, (gpu_s, answers) if batched else None)
            _emit(rows, log, row)
    return rows


def measure_sweep(sizes=(30, 60, 90), batches=(1024, 2048, 4096, 8192, 16384), cpu_max: int = 512, log=None,
                  cpu_workers: int = 1, batched: bool = True, procs: int = 1) -> list[dict]:
    """Sweep candidates per second, the batched path (`sweep_jax`, default JAX device) and the CPU
    reference (`sweep.sweep`, in `cpu_workers` processes), on the same candidates: `sweep_pool`,
    drawn with replacement to fill each batch. The reference runs on the first `cpu_max` of them
    (its cost is per candidate), where the verdicts are compared too. Both are timed from the
    connections found (as `check_units` has them), the reference from its own `approach`.
    `batched=False`: the reference alone. `procs` > 1: the batched path in that many processes
    sharing the device (`batched_processes`)."""
    brick = load_part(get_reader(), "3001")
    rows = []
    for n in sizes:
        s = grown(n)
        scene = CollisionScene(s, [(brick, Pose.identity())], 1e6)
        pool = sweep_pool(s, scene)
        for batch in batches:
            rng = np.random.default_rng(0)
            cases = [pool[i] for i in rng.integers(0, len(pool), batch)]
            if not batched:
                ref, cpu_s = cpu_reference("sweep", n, batch, min(cpu_max, batch), cpu_workers)
                row = {"bricks": n, "batch": batch, "distinct_candidates": len(pool), "cpu_workers": cpu_workers,
                       "cpu_per_s": round(len(ref) / cpu_s, 1), "cpu_compared": len(ref)}
                _emit(rows, log, row)
                continue
            if procs > 1:
                row = {"bricks": n, "batch": batch, "distinct_candidates": len(pool)}
                _emit(rows, log, _shared_row("sweep", row, procs, cpu_max, cpu_workers,
                                             lambda got: {"blocked": sum(a is False for a in got)}))
                continue
            args = ([c[0] for c in cases], [c[1] for c in cases])
            compiles = len(sweep_jax.COMPILES)
            t = time.perf_counter()
            sweep_jax.sweep_many(scene, s, *args, directions=[c[2] for c in cases])  # compiles this batch's shapes
            first_s = time.perf_counter() - t
            before = sweep_jax.COUNTS.copy()
            t = time.perf_counter()
            got = sweep_jax.sweep_many(scene, s, *args, directions=[c[2] for c in cases])
            jax_s = time.perf_counter() - t
            counts = sweep_jax.COUNTS - before
            row = {"bricks": n, "batch": batch, "distinct_candidates": len(pool),
                   "jax_per_s": round(batch / jax_s, 1),
                   "first_call_s": round(first_s, 2), "new_compiles": len(sweep_jax.COMPILES) - compiles,
                   "referred": counts["referred"], "blocked": sum(r.buildable is False for r in got)}
            if cpu_max:
                ref, cpu_s = cpu_reference("sweep", n, batch, min(cpu_max, batch), cpu_workers)
                row.update(cpu_workers=cpu_workers, cpu_per_s=round(len(ref) / cpu_s, 1),
                           speedup=round(batch / jax_s / (len(ref) / cpu_s), 2), cpu_compared=len(ref),
                           agree=sum(a == b.buildable for a, b in zip(ref, got)))
            _emit(rows, log, row)
    return rows


def measure_growth(backend: str, batches, steps: int, objects: int, log=None, procs: int = 1,
                   judge_first: int | None = None, check_batch: int | None = None) -> list[dict]:
    """Lockstep growth: objects 0..objects-1 of the default sampler config with exactly `steps`
    parts each, grown `batch` at a time, for each batch: steps per second over the whole growth
    (the same objects whatever the batch, so rows compare on the same inputs). `WARM_OBJECTS` other
    objects are grown first, untimed (parts loaded, first kernels compiled); the compiles of
    shapes they did not meet fall in the rows, and each row starts without the answers cached by
    geometry (`_forget_answers`). Seconds per check stage from `check.STAGE_SECONDS`.

    With `procs` > 1 the objects are split into `procs` contiguous slices, each grown in its own
    process at `batch // procs` objects a round (so `batch` objects grow at once in all), the
    processes sharing the default device as the factory's grower workers do; every process is
    warmed and waits at a barrier before the clock starts, and the rate is all steps over the time
    from the first start to the last end. Stage seconds are summed over the processes.
    `judge_first`, `check_batch`: the sampler's (None: its defaults); the rows record the values used."""
    rows = []
    backend = backend_name(backend)
    # The value the sampler takes (its default when None), recorded in every row.
    knobs = {"judge_first": judge_first, "check_batch": check_batch}
    config = SamplerConfig(backend=backend, **knobs)
    used = {"judge_first": config.judge_first, "check_batch": config.check_batch}
    if procs > 1:
        spans = _spans(objects, procs)
        fill = _fill_compile_cache(backend, steps, objects, knobs) if backend == "jax" else None
        if fill is not None:
            _say(f"compile cache filled by one process in {fill[0]:.1f} s ({fill[1]} kernels compiled)")
        for batch in batches:
            per = max(1, batch // len(spans))
            # New processes for every row, so that no row finds the answers an earlier one cached.
            done, wall, shared = _together(spans, _growth_init, (backend, steps, objects, knobs), _growth_run,
                                           per, gpu=backend == "jax")
            infos = [info for *_, info in done]
            stages, jit = Counter(), Counter()
            for info in infos:
                stages.update(info["stages"])
                jit.update(info["jit"])
            row = _growth_row(backend, per * len(spans), objects, sum(i["placed"] for i in infos), steps, wall, stages,
                              procs=len(spans), jit=jit, warm_s=max(i["warm_s"] for i in infos), used=used,
                              cpu_s=sum(i["cpu_s"] for i in infos))
            row["mps"] = shared.mps
            if fill is not None:
                row.update(cache_fill_seconds=round(fill[0], 2), cache_fill_misses=fill[1],
                           warm_cache_misses=sum(i["warm_misses"] for i in infos))
            _emit(rows, log, row)
        return rows
    t0 = time.perf_counter()
    sampler = _warm_sampler(backend, steps, objects, knobs)
    warm_s = time.perf_counter() - t0
    _say(f"warm-up: {WARM_OBJECTS} objects in {warm_s:.1f} s")
    for batch in batches:
        _forget_answers()
        STAGE_SECONDS.clear()
        _JIT.clear()
        t0, c0 = time.perf_counter(), time.process_time()
        placed = sum(len(a.steps) for a in sampler.grow(range(objects), batch=batch))
        wall = time.perf_counter() - t0
        _emit(rows, log, _growth_row(backend, batch, objects, placed, steps, wall, STAGE_SECONDS, jit=_JIT,
                                     warm_s=warm_s, used=used, cpu_s=time.process_time() - c0))
        warm_s = None  # the warm-up came before the first row only
    return rows


_JIT: Counter = Counter()
"""This process's JAX compiles since the last clear (`_count_compiles`): `compiles` (each a backend
compile or a load from the persistent cache), `cache_misses` (compiled here), `compile_s`."""


def _count_compiles() -> None:
    """Count this process's JAX compiles into `_JIT` from now on."""
    _listen()
    _JIT.clear()


@functools.cache
def _listen() -> None:
    """JAX's compile events to `_JIT`, once per process (JAX has no way to remove a listener)."""
    import jax.monitoring  # optional: the [jax] extra

    jax.monitoring.register_event_duration_secs_listener(_on_duration)
    jax.monitoring.register_event_listener(_on_event)


def _on_duration(event: str, duration: float, **_) -> None:
    if event == "/jax/core/compile/backend_compile_duration":
        _JIT["compiles"] += 1
        _JIT["compile_s"] += duration


def _on_event(event: str, **_) -> None:
    if event == "/jax/compilation_cache/cache_misses":
        _JIT["cache_misses"] += 1


def _forget_answers() -> None:
    """Drop the checker's answers cached by geometry (stud probes, clutch cases), so that a row
    growing the same objects as an earlier row finds only what the warm-up object left."""
    collide_mod._CROSSED.clear()
    _ALONE.clear()


def _growth_row(backend, batch, objects, placed, steps, wall, stages, procs=1, jit=None, warm_s=None,
                used=None, cpu_s=None) -> dict:
    """A growth row; with the batched path, the JAX compiles inside the timed window (`_JIT`, summed
    over the processes) and the warm-up's seconds (the slowest process's; None after the first row
    of one process), where compiles of the shapes the warm-up objects met fall. `cpu_s`: the
    processes' CPU seconds in the window (all their threads), against `procs` x seconds: how much
    of the growth is host work and how much waiting on the device."""
    row = {"kind": "growth", "backend": backend, "batch": batch, "procs": procs, "objects": objects,
           "steps": placed, "target_steps": steps, **(used or {}), "seconds": round(wall, 2),
           "steps_per_s": round(placed / wall, 2),
           "stage_seconds": {k: round(v, 2) for k, v in sorted(stages.items())}}
    if cpu_s is not None:
        row.update(cpu_seconds=round(cpu_s, 2), cpu_share=round(cpu_s / (procs * wall), 3))
    if backend == "jax":
        jit = jit or {}
        row.update(warm_seconds=None if warm_s is None else round(warm_s, 2),
                   compiles=int(jit.get("compiles", 0)), compile_cache_misses=int(jit.get("cache_misses", 0)),
                   compile_seconds=round(jit.get("compile_s", 0.0), 2))
    return row


def _fill_compile_cache(backend: str, steps: int, objects: int, knobs: dict | None = None) -> tuple[float, int]:
    """(seconds, kernels compiled): one process grows the warm-up objects alone before the grower
    processes start, so the kernels they meet go into the persistent compilation cache
    (`jax_cache`) once and the grower processes load them, where each would otherwise compile
    every one of them at the same moment as the others (kernels that compile in under
    `jax_cache.MIN_COMPILE_SECONDS` are not written, and each process compiles those)."""
    t = time.perf_counter()
    misses = in_own_process(functools.partial(_fill_run, backend, steps, objects, knobs))
    return time.perf_counter() - t, misses


def _fill_run(backend: str, steps: int, objects: int, knobs: dict | None = None) -> int:
    _warm_sampler(backend, steps, objects, knobs, keep=False)
    return int(_JIT.get("cache_misses", 0))


def _growth_init(backend: str, steps: int, objects: int, knobs: dict | None = None) -> None:
    """A grower process of `measure_growth`: its sampler, warmed (`_warm_sampler`), and the seconds
    that took."""
    t = time.perf_counter()
    _CTX["sampler"] = _warm_sampler(backend, steps, objects, knobs)
    _CTX["warm_s"] = time.perf_counter() - t
    _CTX["warm_misses"] = int(_JIT.get("cache_misses", 0))
    _say(f"grower {os.getpid()}: warm-up in {_CTX['warm_s']:.1f} s, waiting for the others")


WARM_OBJECTS = 4
"""Objects grown untimed before `measure_growth`'s rows (indices after the timed ones): collision
scenes' meshes made, the first kernels compiled."""


def _warm_sampler(backend: str, steps: int, objects: int, knobs: dict | None = None,
                  keep: bool = True) -> Sampler | None:
    """A sampler (with `knobs`: `SamplerConfig` fields, None for their defaults) that has grown the
    `WARM_OBJECTS` warm-up objects (returned when `keep`)."""
    if backend == "jax":
        _count_compiles()
    sampler = Sampler(SamplerConfig(seed=0, min_steps=steps, max_steps=steps, backend=backend, **(knobs or {})),
                      None)
    for part in sampler.parts:  # found on a part's first use otherwise (0.1 s each), inside a row
        part.sockets
    list(sampler.grow(range(objects, objects + WARM_OBJECTS), batch=WARM_OBJECTS))
    _forget_answers()
    return sampler if keep else None


def _growth_run(span: tuple[int, int], batch: int, barrier) -> tuple[float, float, dict]:
    """Objects span[0]..span[1]-1 grown `batch` at a time once every process is ready: (start,
    end, {steps placed, stage seconds, JAX compiles meanwhile, warm-up seconds, kernels compiled in
    the warm-up})."""
    gc.collect()
    STAGE_SECONDS.clear()
    _JIT.clear()
    barrier.wait()
    t, c = time.time(), time.process_time()
    placed = done = 0
    said = t
    for a in _CTX["sampler"].grow(range(*span), batch=batch):
        placed, done = placed + len(a.steps), done + 1
        if time.time() - said >= SAY_EVERY_S or done == span[1] - span[0]:
            said = time.time()
            _say(f"grower {os.getpid()}: {done} of {span[1] - span[0]} objects, {placed} parts, {said - t:.1f} s")
    end, cpu = time.time(), time.process_time() - c
    return t, end, {"placed": placed, "stages": dict(STAGE_SECONDS), "jit": dict(_JIT), "cpu_s": cpu,
                            "warm_s": _CTX["warm_s"], "warm_misses": _CTX["warm_misses"]}


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
    global MPS_MODE
    MPS_MODE = args.mps
    sizes, batches = [int(x) for x in args.sizes.split(",")], [int(x) for x in args.batches.split(",")]
    log = lambda r: print(json.dumps(r), flush=True)
    if args.growth:
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
