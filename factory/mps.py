"""NVIDIA MPS for the factory's JAX processes that share a GPU (lockstep growers, bench processes).

Why: without MPS the CUDA contexts of different processes take turns on a GPU, one time slice each,
so 16 grower processes launching small batched checks wait on each other's slices. Under MPS their
kernels run side by side. Measured on one lent H100 (16 cores), 2026-11-26, 16 grower processes
of 256 objects of 30 parts (`pipelines.bench_physics --growth`): 138.7 steps/s without, 186.0 with
(docs/guides/gpus-and-clusters.md).

`shared_gpu(clients)` starts a control daemon of this job's own when it helps and nothing else
stands in the way (`plan`): in the foreground as a child of this process (so it ends with it), with
its pipes and logs in a new temporary folder (so two jobs never share one), and points this
process's environment there, so the worker processes started inside the block connect to it. It
checks that a server really starts (a CUDA context made through it, then the daemon's server
list); if not, it stops the daemon, says why and the job runs without MPS. A CUDA program that
cannot reach the daemon runs as it would without MPS (NVIDIA's documented behaviour), so a
daemon that dies mid-run costs speed, not the run.

`BRICK_FACTORY_MPS=off` (or a command's `--mps off`) never starts one; a user's own MPS
(`CUDA_MPS_PIPE_DIRECTORY` set, or a control daemon already running on the machine) is left as it
is and used.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from factory import gpus
from factory.environ import kept
from factory.parent_death import sigterm_on_parent_death

MODE_ENV = "BRICK_FACTORY_MPS"
"""'auto' (the default: start a daemon where `plan` finds it useful) or 'off'."""
MODES = ("auto", "off")
CONTROL = "nvidia-cuda-mps-control"
PIPE_ENV, LOG_ENV = "CUDA_MPS_PIPE_DIRECTORY", "CUDA_MPS_LOG_DIRECTORY"
MAX_CLIENTS = 48
"""Client CUDA contexts one MPS server takes per GPU (Volta and later); more processes than this
per GPU run without a daemon of the factory's."""
START_S = 20.0
"""Seconds the daemon, its first server and the probe context get to come up."""

_PROBE = ("import ctypes, sys\n"
          "cuda = ctypes.CDLL('libcuda.so.1')\n"
          "dev, ctx = ctypes.c_int(), ctypes.c_void_p()\n"
          "sys.exit(cuda.cuInit(0) or cuda.cuDeviceGet(ctypes.byref(dev), 0)\n"
          "         or cuda.cuCtxCreate_v2(ctypes.byref(ctx), 0, dev) or cuda.cuCtxDestroy_v2(ctx))\n")
"""A CUDA context made and destroyed through the driver alone (no JAX: quick), in a process of its
own, so that the daemon starts its server."""


@dataclass(frozen=True)
class Sharing:
    """How a job's GPU processes share each GPU."""

    mps: bool
    """Their CUDA contexts go through an MPS server (the factory's or the user's)."""
    why: str
    """In words, for the line a job prints."""


def mode_of(value: str | None = None) -> str:
    """The mode asked for: `value`, else `$BRICK_FACTORY_MPS`, else 'auto'."""
    mode = (value or os.environ.get(MODE_ENV) or "auto").strip().lower()
    if mode not in MODES:
        raise ValueError(f"MPS mode {mode!r} (from {'--mps' if value else MODE_ENV}): valid choices are "
                         f"{', '.join(MODES)}")
    return mode


def _daemon_running() -> bool:
    """Whether an MPS control daemon runs on this machine (any user's; read from /proc)."""
    for pid in os.listdir("/proc") if os.path.isdir("/proc") else ():
        if pid.isdigit():
            try:
                if Path(f"/proc/{pid}/comm").read_text().strip() == CONTROL[:15]:  # comm keeps 15 characters
                    return True
            except OSError:
                continue
    return False


def plan(clients: int, mode: str | None = None) -> Sharing | None:
    """None where the factory should start its own daemon for `clients` JAX processes spread over
    the machine's GPUs; else how they share the GPUs without one, and why."""
    if mode_of(mode) == "off":
        return Sharing(False, f"MPS off ({MODE_ENV}=off or --mps off)")
    if os.environ.get(PIPE_ENV):
        return Sharing(True, f"the user's MPS ({PIPE_ENV}={os.environ[PIPE_ENV]})")
    n = gpus.count()
    if n == 0:
        return Sharing(False, "no NVIDIA GPU")
    per_gpu = -(-clients // n)
    if per_gpu < 2:
        return Sharing(False, "one process per GPU: nothing to share")
    if per_gpu > MAX_CLIENTS:
        return Sharing(False, f"{per_gpu} processes per GPU, more than the {MAX_CLIENTS} one MPS server takes")
    if shutil.which(CONTROL) is None:
        return Sharing(False, f"{CONTROL} not found on PATH: GPU time slices between processes")
    if _daemon_running():
        return Sharing(True, "the MPS daemon already running on this machine")
    return None


def _control(env: dict, command: str, timeout: float = 10.0) -> str:
    """One command to the daemon (`get_server_list`, `quit`), its answer."""
    done = subprocess.run([CONTROL], input=command + "\n", env=env, capture_output=True, text=True, timeout=timeout)
    return done.stdout.strip()


def _stop(daemon: subprocess.Popen, env: dict, folder: str) -> None:
    try:
        _control(env, "quit")
        daemon.wait(timeout=10)
    except (OSError, subprocess.SubprocessError):
        daemon.kill()
        daemon.wait()
    shutil.rmtree(folder, ignore_errors=True)


def _start() -> tuple[subprocess.Popen, dict, str] | str:
    """(daemon, its environment, its folder) with a server up, or why not."""
    folder = tempfile.mkdtemp(prefix="brick-factory-mps-")
    env = {**os.environ, PIPE_ENV: os.path.join(folder, "pipe"), LOG_ENV: os.path.join(folder, "log")}
    os.makedirs(env[PIPE_ENV])
    os.makedirs(env[LOG_ENV])
    with open(os.path.join(folder, "daemon.out"), "wb") as out:
        daemon = subprocess.Popen([CONTROL, "-f"], env=env, stdin=subprocess.DEVNULL, stdout=out,
                                  stderr=subprocess.STDOUT, preexec_fn=sigterm_on_parent_death())
    why = None
    try:
        end = time.monotonic() + START_S
        while not os.path.exists(os.path.join(env[PIPE_ENV], "control")):
            if daemon.poll() is not None or time.monotonic() > end:
                why = f"{CONTROL} -f ended or made no control pipe (rc {daemon.poll()})"
                break
            time.sleep(0.05)
        if why is None:
            probe = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                                   timeout=max(1.0, end - time.monotonic()))
            servers = _control(env, "get_server_list")
            if probe.returncode != 0:
                why = f"a CUDA context through it failed (CUresult {probe.returncode})"
            elif not servers:
                why = "no MPS server started"
    except (OSError, subprocess.SubprocessError) as e:
        why = f"{type(e).__name__}: {e}"
    if why is not None:
        log = Path(env[LOG_ENV], "control.log")
        tail = log.read_text(errors="replace").strip().splitlines()[-1:] if log.exists() else []
        _stop(daemon, env, folder)
        return why + (f"; its log ends: {tail[0]}" if tail else "")
    return daemon, env, folder


@contextlib.contextmanager
def shared_gpu(clients: int, mode: str | None = None, say=None):
    """A block inside which the worker processes started here share the GPUs through MPS where
    `plan` finds it useful (see the module's docstring); yields the `Sharing`. `say(line)`: told
    how the GPUs are shared (stderr by default)."""
    say = say or (lambda line: print(line, file=sys.stderr, flush=True))
    sharing, started = plan(clients, mode), None
    if sharing is None:
        started = _start()
        if isinstance(started, str):
            sharing, started = Sharing(False, f"MPS not started: {started}"), None
        else:
            sharing = Sharing(True, f"MPS, a daemon of this job's own for {clients} processes ({started[2]})")
    say(f"gpu sharing: {sharing.why}")
    if started is None:
        yield sharing
        return
    daemon, env, folder = started
    try:
        with kept((PIPE_ENV, LOG_ENV)):
            os.environ[PIPE_ENV], os.environ[LOG_ENV] = env[PIPE_ENV], env[LOG_ENV]
            yield sharing
    finally:
        _stop(daemon, env, folder)
