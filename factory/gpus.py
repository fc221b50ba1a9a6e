"""Which GPU a worker process uses (the factory's worker processes spread over every GPU), and
whether the batched checks run on one (`checks_backend`).

A build's pool numbers its workers (`SLOT_ENV`, set by `pipelines.dataset.build`). On a machine
with several NVIDIA GPUs, worker k renders on EGL device k mod G (`MUJOCO_EGL_DEVICE_ID`, read by
MuJoCo's EGL backend when the process's context is made) and runs its JAX kernels on JAX's GPU
k mod G, the only GPU JAX opens in that process (`jax_cuda_visible_devices`); with one GPU, none
or no slot, nothing is chosen. A user's own `MUJOCO_EGL_DEVICE_ID` wins. `CUDA_VISIBLE_DEVICES`
is not set: NVIDIA's EGL remaps its devices by it (google-deepmind/mujoco#3245), so setting it for
JAX could move the renders too.
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


def choose_egl_device() -> int | None:
    """Set `MUJOCO_EGL_DEVICE_ID` for this worker (before its GL context exists) unless the user
    did; returns the device chosen, or None."""
    k, gpus = slot(), count()
    if k is None or gpus < 2 or "MUJOCO_EGL_DEVICE_ID" in os.environ:
        return None
    os.environ["MUJOCO_EGL_DEVICE_ID"] = str(k % gpus)
    return k % gpus


class CudaStartError(RuntimeError):
    """JAX's CUDA backend did not start in a process on a machine with NVIDIA GPUs and JAX's CUDA
    build: JAX would have run the batched checks on the CPU, slowly, without saying so."""


def choose_jax_device(jax) -> object | None:
    """Make this worker's JAX default device its share of the GPUs; returns it, or None.

    Worker k of a pool on a machine with G >= 2 NVIDIA GPUs lets JAX open GPU k mod G only
    (`jax_cuda_visible_devices`, set before JAX starts its CUDA backend; unlike
    `CUDA_VISIBLE_DEVICES` it leaves EGL's devices alone). A process that opened every GPU held a
    CUDA context, and an MPS client, on each: 64 workers of a 4-GPU machine asked the MPS daemons
    for 256 clients and a quarter of them failed to start CUDA. Where JAX's CUDA build is installed
    and GPUs are there but JAX starts without one, `CudaStartError` says so."""
    k, gpus = slot(), count()
    if k is not None and gpus >= 2:
        jax.config.update("jax_cuda_visible_devices", str(k % gpus))
    if gpus and cuda_jax() is not None and jax.default_backend() != "gpu":
        raise CudaStartError(
            f"JAX did not start CUDA in this process (worker {k if k is not None else '-'}; {gpus} NVIDIA GPU(s), "
            f"{cuda_jax()} installed; JAX's backend is {jax.default_backend()!r}): the batched checks would run "
            "on the CPU. JAX's log above says why (out of memory, MPS clients); use fewer workers, or "
            "--check-backend cpu")
    devices = [d for d in jax.devices() if d.platform == "gpu"]
    if k is None or gpus < 2 or not devices:
        return None
    jax.config.update("jax_default_device", devices[0])
    return devices[0]


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
