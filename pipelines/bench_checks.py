"""Physics checks per second (`pipelines.bench_physics`), on the grown structures of
`bench_structures`: full checks and the load stage by backend (`measure`), whole checks
(`measure_whole`), load checks (`measure_lp`) and sweeps (`measure_sweep`), the batched path
against the CPU reference on the same candidates (the reference in `cpu_workers` processes,
`cpu_reference`; the batched path in `procs` processes sharing the device, `batched_processes`).
"""

from __future__ import annotations

import gc
import multiprocessing
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from factory import Pose, get_reader, load_part
from factory.physics import Checker, pair_kernels, sweep_jax
from factory.physics.check import CheckConfig, _unit_connections, backend_name, check
from factory.physics.collide import CollisionScene
from factory.physics.load_model import LoadBase
from factory.physics.statics import judge_many, judge_on_base
from factory.physics.structure import Placed, Structure
from factory.physics.sweep import seating_from_connections, sweep
from pipelines.bench_processes import _CTX, _emit, _spans, _together
from pipelines.bench_structures import candidates, grown, load_models


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
                    from factory.physics.loads_jax import solve_loads  # optional: JAX (the [jax] extra)
                    from factory.physics.lp_jax import COMPILES

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
    `check_units` runs it: the CPU reference builds each model (`load_model.LoadBase.model`) and
    solves its program with HiGHS (`judge_many`); the batched path (`batched`) judges them all on
    the structure's shared columns (`judge_on_base` with `loads_jax.solve_on_base`). Failing
    connections are not sought (`explain=False`, as the sampler asks)."""

    brick = load_part(get_reader(), "3001")
    if conns is None:
        conns = [_unit_connections(s, [(brick, p)]) for p in poses]
    base = LoadBase(s.placed, s.connections, 24.0, s.links, config.loads)
    units = [[Placed(brick, 4, p)] for p in poses]
    if batched:
        from factory.physics.loads_jax import solve_on_base  # optional: JAX (the [jax] extra)

        return judge_on_base(base, units, conns, config.loads, solve_on_base, explain=False)
    return judge_many([base.model(u, c) for u, c in zip(units, conns)], config.loads, explain=False)


# The CPU reference in worker processes (`cpu_workers`): each builds its inputs once, from the
# same seeds as the parent, so both time the same candidates (`bench_processes._CTX`).
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
    Checker.shared().clear(["alone"])  # the warm-up's clutch answers: the timed call finds its own
    barrier.wait()
    t = time.time()
    got = _batched_answers(a, b)
    return t, time.time(), got


def batched_processes(kind: str, n: int, batch: int, procs: int) -> tuple[list, float, bool]:
    """(answers, seconds, mps): the batch on the batched path ('whole', 'loads' or 'sweep') in
    `procs` processes that share the default JAX device, each on a contiguous slice, so that one
    process's host work overlaps another's device work, as the factory's workers do. Seconds from
    the first start to the last end, every process compiled and waiting at a barrier before the
    clock starts; `mps`: whether they shared the GPU through MPS (`factory.mps`,
    `bench_processes.MPS_MODE`)."""

    done, seconds, sharing = _together(_spans(batch, procs), _ctx_init, (kind, n, batch), _shared_run, gpu=True)
    return [x for *_, got in done for x in got], seconds, sharing.mps


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
                checker = Checker(config, "jax")
                t = time.perf_counter()
                checker.check(s, brick, poses, floor_y=24.0, explain=False)  # compiles
                first_s = time.perf_counter() - t
                # A process that has compiled with JAX holds many long-lived objects (a sampler
                # process: 661K, a full collection 0.29 s); moved out of the collector's view.
                gc.collect()
                gc.freeze()
                checker.clear(["alone"])  # the warm-up's clutch answers: the timed call finds its own
                checker.reset_counters()
                t = time.perf_counter()
                got = checker.check(s, brick, poses, floor_y=24.0, explain=False)
                gpu_s = time.perf_counter() - t
                stages = checker.counters()["stage_seconds"]
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
            compiles = len(pair_kernels.COMPILES)
            t = time.perf_counter()
            sweep_jax.sweep_many(scene, s, *args, directions=[c[2] for c in cases])  # compiles this batch's shapes
            first_s = time.perf_counter() - t
            # sweep_many asked without a checker counts on the process's default one (`Checker.shared`).
            before = Counter(Checker.shared().counters()["sweep_counts"])
            t = time.perf_counter()
            got = sweep_jax.sweep_many(scene, s, *args, directions=[c[2] for c in cases])
            jax_s = time.perf_counter() - t
            counts = Counter(Checker.shared().counters()["sweep_counts"]) - before
            row = {"bricks": n, "batch": batch, "distinct_candidates": len(pool),
                   "jax_per_s": round(batch / jax_s, 1),
                   "first_call_s": round(first_s, 2), "new_compiles": len(pair_kernels.COMPILES) - compiles,
                   "referred": counts["referred"], "blocked": sum(r.buildable is False for r in got)}
            if cpu_max:
                ref, cpu_s = cpu_reference("sweep", n, batch, min(cpu_max, batch), cpu_workers)
                row.update(cpu_workers=cpu_workers, cpu_per_s=round(len(ref) / cpu_s, 1),
                           speedup=round(batch / jax_s / (len(ref) / cpu_s), 2), cpu_compared=len(ref),
                           agree=sum(a == b.buildable for a, b in zip(ref, got)))
            _emit(rows, log, row)
    return rows
