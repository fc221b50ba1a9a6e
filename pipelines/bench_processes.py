"""How the physics benchmarks run (`pipelines.bench_physics`): measurements in processes of their
own that start together (`_together`: a barrier, then the clocks; on a GPU through MPS where
`factory.mps` finds it useful), a call in a fresh process (`in_own_process`), and their output
(rows as they come, `_emit`; progress on stderr, `_say`).
"""

from __future__ import annotations

import contextlib
import functools
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor

from factory import mps

_CTX: dict = {}
"""This process's inputs, set by its pool's initializer (`bench_checks._ctx_init`,
`bench_growth._growth_init`)."""


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


def _say(message: str) -> None:
    """Progress of a long measurement on stderr (the rows go to stdout): a run cut short by a
    time limit still shows how far it got."""
    print(f"bench_physics: {message}", file=sys.stderr, flush=True)


def _emit(rows: list, log, row: dict) -> None:
    """Keep `row`, and log it as it comes."""
    rows.append(row)
    if log is not None:
        log(row)
