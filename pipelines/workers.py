"""Worker processes of the factory's jobs (`pipelines.synth`'s local build, `pipelines.sample
--workers`): one numeric thread each, numbered in start order so that they spread over the
machine's GPUs (`factory.gpus`), and ended with the process that started them."""

from __future__ import annotations

import multiprocessing
import os
import signal
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

from factory import gpus
from factory.environ import kept
from factory.parent_death import sigterm_on_parent_death

ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""Numeric libraries' threads per worker process, unless the user set them: the workers fill the
cores, and a pool per process oversubscribes them (16 samplers on 16 cores of an H200 machine:
980 steps in 58.7 s with the libraries' default threads, 45.4 s with one each)."""


def one_thread_each() -> None:
    """Worker processes started from now on use one numeric thread each (`ONE_THREAD`)."""
    for k, v in ONE_THREAD.items():
        os.environ.setdefault(k, v)


@contextmanager
def one_thread_each_meanwhile():
    """`one_thread_each` for the processes started inside the block; this process's environment
    as it was after it (a sampler that prepares its parts first keeps its own threads)."""
    with kept(ONE_THREAD):
        one_thread_each()
        yield


def numbering(ctx) -> tuple:
    """The initializer arguments of `start_worker` for a pool of context `ctx`."""
    return ctx.Value("i", 0), os.getpid()


def start_worker(counter, parent: int) -> None:
    """A worker's set-up: its number (`gpus.SLOT_ENV`), and on Linux a SIGTERM when its parent
    dies (a killed build used to leave its workers running: they finished their shards and then
    waited forever, holding memory and, on a GPU machine, GPU memory)."""
    with counter.get_lock():
        number = counter.value
        counter.value += 1
    os.environ[gpus.SLOT_ENV] = str(number)
    gpus.pin_worker()  # its GPU, before anything in it starts CUDA
    gpus.budget_worker_memory()
    # Ctrl-C reaches the whole process group: a worker ends at once and quietly (its parent says
    # what happened once), instead of each printing a KeyboardInterrupt traceback. Where SIGINT is
    # ignored (a background job: so is it in the parent), the worker keeps ignoring it.
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        signal.signal(signal.SIGINT, lambda *_: os._exit(130))
    sigterm_on_parent_death()()
    if os.getppid() != parent:  # the parent died before the line above took effect
        os._exit(1)


def pool(workers: int) -> ProcessPoolExecutor:
    """Spawned worker processes (a fresh interpreter each: no GL, MuJoCo or JAX state copied from
    this process), set up by `start_worker`."""
    one_thread_each()
    os.environ[gpus.WORKERS_ENV] = str(workers)  # read by each worker's memory budget
    ctx = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=start_worker,
                               initargs=numbering(ctx))
