"""Which GPU a worker process uses (the factory's worker processes spread over every GPU), and
whether the batched checks run on one (`checks_backend`).

A build's pool numbers its workers (`SLOT_ENV`, set by `pipelines.workers.start_worker`). On a
machine with several NVIDIA GPUs, worker k is given GPU k mod G when it starts, before anything in
it starts CUDA (`pin_worker`): `CUDA_VISIBLE_DEVICES` = k mod G, so JAX (and Warp) see that GPU
alone, as device 0. Its renders go to EGL device k mod G (`choose_egl_device`, when its GL context
is made): NVIDIA's EGL listed every GPU whatever `CUDA_VISIBLE_DEVICES` said on a 2-GPU H200
machine (with EGL device 0 for all, GPU 0 was 64% busy and GPU 1 9%); where EGL lists only the
visible GPU, `factory.render.gl` falls back to its default device. EGL may number GPUs in another
order than CUDA (google-deepmind/mujoco#3245): a worker's renders can land on another GPU than its
kernels, spread evenly either way. A user's own `CUDA_VISIBLE_DEVICES` or `MUJOCO_EGL_DEVICE_ID`
wins. With one GPU, none or no slot, nothing is chosen.

Why not JAX's own `jax_cuda_visible_devices`: a process shown GPU 1 alone that way keeps calling it
device id 1, and its kernels failed to run ("Device id 1 is out of range [0, 1)": 37 and then 64 of
80 shards of a 2-GPU H200 build, 2026-11-29, GPU 1 idle).
"""

from __future__ import annotations

import os
from functools import cache
from importlib import metadata

SLOT_ENV = "BRICK_FACTORY_WORKER"
"""The worker's number in its pool (0, 1, ...), set by the pool's initializer."""

_NVIDIA_GPUS = "/proc/driver/nvidia/gpus"


def count() -> int:
    """NVIDIA GPUs of this machine, as the driver lists them (0 without the driver)."""
    try:
        return len(os.listdir(_NVIDIA_GPUS))
    except OSError:
        return 0


def models(folder: str = _NVIDIA_GPUS) -> list[str]:
    """The NVIDIA GPUs' model names, in the driver's order (empty without the driver): the `Model`
    line of each GPU's `information` file."""
    try:
        entries = sorted(os.listdir(folder))
    except OSError:
        return []
    out = []
    for entry in entries:
        try:
            text = open(os.path.join(folder, entry, "information"), errors="replace").read()
        except OSError:
            continue
        model = next((v.strip() for k, _, v in (line.partition(":") for line in text.splitlines())
                      if k.strip() == "Model"), "")
        out.append(model or "NVIDIA GPU")
    return out


def slot() -> int | None:
    """This process's worker number, or None outside a numbered pool."""
    value = os.environ.get(SLOT_ENV, "")
    return int(value) if value.isdigit() else None


def pin_worker() -> int | None:
    """Give this numbered worker GPU k mod G (module docstring), unless the user chose
    `CUDA_VISIBLE_DEVICES`; call before anything in the process starts CUDA. Returns the GPU, or
    None."""
    k, gpus = slot(), count()
    if k is None or gpus < 2 or "CUDA_VISIBLE_DEVICES" in os.environ:
        return None
    os.environ["CUDA_VISIBLE_DEVICES"] = str(k % gpus)
    return k % gpus


WORKERS_ENV = "BRICK_FACTORY_WORKERS"
"""The size of a worker's pool (set by `pipelines.workers.pool` for its workers)."""

GPU_MEMORY_SHARE = 0.85
"""Of each GPU's memory, the share that the pool's workers on it split evenly for JAX; the rest is
for their EGL renders, MPS and CUDA contexts."""


def budget_worker_memory() -> float | None:
    """Cap this numbered worker's JAX memory at its share of its GPU (`GPU_MEMORY_SHARE` over the
    pool's workers per GPU), through `XLA_PYTHON_CLIENT_MEM_FRACTION` (JAX's allocator grows up to
    it, preallocating nothing: `factory.physics`), unless the user set it; returns the fraction, or
    None. Without it each worker's allocator kept what it had once needed and a GPU's 16 workers
    filled its 143 GB (2-GPU H200, 32 workers: 5 of 80 shards out of memory, 2026-11-29)."""
    k, gpus, n = slot(), count(), os.environ.get(WORKERS_ENV, "")
    if k is None or not gpus or not n.isdigit() or int(n) < 1 or "XLA_PYTHON_CLIENT_MEM_FRACTION" in os.environ:
        return None
    share = GPU_MEMORY_SHARE / -(-int(n) // gpus)
    os.environ["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{share:.4f}"
    return share


def choose_egl_device() -> int | None:
    """Set `MUJOCO_EGL_DEVICE_ID` for this worker (before its GL context exists) unless the user
    did; returns the device chosen, or None: EGL device k mod G (module docstring)."""
    k, gpus = slot(), count()
    if k is None or gpus < 2 or "MUJOCO_EGL_DEVICE_ID" in os.environ:
        return None
    os.environ["MUJOCO_EGL_DEVICE_ID"] = str(k % gpus)
    return k % gpus


class CudaStartError(RuntimeError):
    """JAX's CUDA backend did not start in a process on a machine with NVIDIA GPUs and JAX's CUDA
    build: JAX would have run the batched checks on the CPU, slowly, without saying so."""


def choose_jax_device(jax) -> object | None:
    """This worker's JAX GPU; returns it, or None.

    A pinned worker (`pin_worker`) sees its GPU alone: JAX opens that one only. A process that
    opened every GPU held a CUDA context, and an MPS client, on each: 64 workers of a 4-GPU machine
    asked the MPS daemons for 256 clients and a quarter of them failed to start CUDA. A numbered
    worker that was not pinned (the user set `CUDA_VISIBLE_DEVICES` to several GPUs) gets GPU k mod
    G of those as its default device. Where JAX's CUDA build is installed and GPUs are there but
    JAX starts without one, `CudaStartError` says so."""
    k, gpus = slot(), count()
    if gpus and cuda_jax() is not None and jax.default_backend() != "gpu":
        raise CudaStartError(
            f"JAX did not start CUDA in this process (worker {k if k is not None else '-'}; {gpus} NVIDIA GPU(s), "
            f"{cuda_jax()} installed; JAX's backend is {jax.default_backend()!r}): the batched checks would run "
            "on the CPU. JAX's log above says why (out of memory, MPS clients); use fewer workers, or "
            "--check-backend cpu")
    devices = [d for d in jax.devices() if d.platform == "gpu"]
    if k is None or gpus < 2 or not devices:
        return None
    device = devices[k % len(devices)]
    jax.config.update("jax_default_device", device)
    return device


def render_path() -> str:
    """Where a job's worker renders run, in words (for the line a job prints at its start)."""
    n = count()
    if n and os.environ.get("MUJOCO_GL", "egl").lower() == "egl":
        return f"EGL on {n} NVIDIA GPU(s), worker k on GPU k mod {n}"
    return f"on the CPU ({os.environ.get('MUJOCO_GL') or 'EGL or OSMesa, whichever is installed'})"


@cache
def cuda_jax() -> str | None:
    """The installed distribution of JAX's CUDA build (what the `gpu` extra brings), or None. Read
    from the installed packages' metadata: importing JAX here would start CUDA in the process that
    then starts the workers. Read once a process: it walks every installed package."""
    for dist in metadata.distributions():
        name = (dist.metadata["Name"] or "").lower().replace("_", "-")
        if name.startswith("jax-cuda") and name.endswith("-plugin"):
            return name
    return None


def checks_backend() -> tuple[str, str]:
    """The physics checks' backend for `--check-backend auto` on this machine, and why: 'jax' (the
    batched JAX kernels, on the GPU) where an NVIDIA GPU and JAX's CUDA build are, else 'cpu' (the
    reference, on the CPU). Both write the same files; their build times are in docs/results.md."""
    n = count()
    if not n:
        return "cpu", "no NVIDIA GPU here"
    cuda = cuda_jax()
    if cuda is None:
        return "cpu", f"{n} NVIDIA GPU(s) but no CUDA build of JAX (pip install -e '.[gpu]')"
    return "jax", f"{n} NVIDIA GPU(s) and JAX's CUDA build ({cuda})"
