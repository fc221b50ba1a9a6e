"""Lockstep growth (`pipelines.bench_physics --growth`): the same objects grown at each batch, steps
per second, in one process or in several sharing the device as the factory's grower workers do
(`measure_growth`), with the JAX compiles inside the timed window (`_JIT`).
"""

from __future__ import annotations

import functools
import gc
import os
import time
from collections import Counter

from factory.physics import Checker
from factory.physics.check import backend_name
from factory.sampler import Sampler, SamplerConfig
from pipelines.bench_processes import _CTX, _emit, _say, _spans, _together, in_own_process


def measure_growth(backend: str, batches, steps: int, objects: int, log=None, procs: int = 1,
                   judge_first: int | None = None, check_batch: int | None = None) -> list[dict]:
    """Lockstep growth: objects 0..objects-1 of the default sampler config with exactly `steps`
    parts each, grown `batch` at a time, for each batch: steps per second over the whole growth
    (the same objects whatever the batch, so rows compare on the same inputs). `WARM_OBJECTS` other
    objects are grown first, untimed (parts loaded, first kernels compiled); the compiles of
    shapes they did not meet fall in the rows, and each row starts without the answers cached by
    geometry (`_forget_answers`). Seconds per check stage from the sampler's checker (`Checker.counters`).

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
        _forget_answers(sampler)
        sampler.checker.reset_counters()
        _JIT.clear()
        t0, c0 = time.perf_counter(), time.process_time()
        placed = sum(len(a.steps) for a in sampler.grow(range(objects), batch=batch))
        wall = time.perf_counter() - t0
        _emit(rows, log, _growth_row(backend, batch, objects, placed, steps, wall,
                                     sampler.checker.counters()["stage_seconds"], jit=_JIT,
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


def _forget_answers(sampler: Sampler) -> None:
    """Drop the sampler's checker's answers cached by geometry (stud probes, clutch cases), so that
    a row growing the same objects as an earlier row finds only what the warm-up object left."""
    sampler.checker.clear(("crossed", "alone"))


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
    config = SamplerConfig(seed=0, min_steps=steps, max_steps=steps, backend=backend, **(knobs or {}))
    sampler = Sampler(config, None, Checker(config.check, config.backend))
    for part in sampler.parts:  # found on a part's first use otherwise (0.1 s each), inside a row
        part.sockets
    list(sampler.grow(range(objects, objects + WARM_OBJECTS), batch=WARM_OBJECTS))
    _forget_answers(sampler)
    return sampler if keep else None


SAY_EVERY_S = 10.0
"""Seconds between a grower process's progress lines."""


def _growth_run(span: tuple[int, int], batch: int, barrier) -> tuple[float, float, dict]:
    """Objects span[0]..span[1]-1 grown `batch` at a time once every process is ready: (start,
    end, {steps placed, stage seconds, JAX compiles meanwhile, warm-up seconds, kernels compiled in
    the warm-up})."""
    gc.collect()
    _CTX["sampler"].checker.reset_counters()
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
    stages = _CTX["sampler"].checker.counters()["stage_seconds"]
    return t, end, {"placed": placed, "stages": stages, "jit": dict(_JIT), "cpu_s": cpu,
                            "warm_s": _CTX["warm_s"], "warm_misses": _CTX["warm_misses"]}
