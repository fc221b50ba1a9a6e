"""What a build ran on and used: the host (CPU model, logical CPUs, GPU models), the CPU seconds of
the build's processes, and each NVIDIA GPU's utilisation and memory while it ran.

Build times differ by host more than by most code changes: `make synth N=700` with the reference
checks took 446 s on one lent 16-core H200 machine and 571 s on another, whose CPUs went unrecorded
(docs/guides/build-a-dataset.md). So every build records them itself, in `meta/timings.json` and its summary line.

The GPU figures come from `nvidia-smi` run beside the build (`GpuWatch`), one sample a second:
utilisation is the share of each second in which a kernel ran (the driver's own figure, as
`nvidia-smi` prints it), memory the device memory in use by every process. Without `nvidia-smi`
or a GPU nothing is sampled and the report says so.
"""

from __future__ import annotations

import os
import platform
import resource
import shutil
import subprocess
import threading
from pathlib import Path

from factory.gpus import models as gpu_models
from factory.parent_death import sigterm_on_parent_death

QUERY = "index,utilization.gpu,memory.used"
"""The `nvidia-smi --query-gpu` fields sampled, in this order."""


def cpu_model(cpuinfo: str = "/proc/cpuinfo") -> str:
    """The processor's model name as the kernel reports it (the first CPU's), else the machine type."""
    try:
        for line in Path(cpuinfo).read_text(errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() in ("model name", "Model Name") and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def host() -> dict:
    """{"cpu_model", "logical_cpus", "gpus": [model, ...]} of this machine."""
    return {"cpu_model": cpu_model(), "logical_cpus": os.cpu_count() or 1, "gpus": gpu_models()}


def cpu_seconds() -> dict:
    """User and system CPU seconds of this process and of its children that have ended (a build's
    pool workers end with the pool; Ray's workers are not its children and are not counted)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"user": own.ru_utime + kids.ru_utime, "system": own.ru_stime + kids.ru_stime}


def peak_rss_mb() -> dict:
    """Peak resident memory of this process and of its largest ended child (MB; Linux reports KB):
    a build's main process and its largest worker. Ray workers are not its children."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {"main": round(own, 1), "largest_worker": round(child, 1)}


def parse_sample(line: str) -> tuple[int, float, float] | None:
    """(GPU index, utilisation %, memory used MiB) from one line of `nvidia-smi --query-gpu=QUERY
    --format=csv,noheader,nounits`, or None for a line that is not one (a field '[N/A]', say)."""
    parts = [p.strip() for p in line.split(",")]
    if len(parts) != 3:
        return None
    try:
        return int(parts[0]), float(parts[1]), float(parts[2])
    except ValueError:
        return None


class GpuWatch:
    """Samples every NVIDIA GPU once a second while the block runs:

        with GpuWatch() as watch:
            ...
        watch.report()  # [{"index", "busy_mean_pct", "memory_max_mib", "samples"}, ...] or None

    `command`: the sampler to run (default `nvidia-smi`, found on PATH); nothing is started where
    it is missing or the driver lists no GPU (`gpus`, default `factory.gpus.models()`)."""

    def __init__(self, interval_ms: int = 1000, command: str | None = None, gpus: list[str] | None = None):
        self.interval_ms = int(interval_ms)
        self.command = command if command is not None else shutil.which("nvidia-smi")
        self.gpus = gpu_models() if gpus is None else gpus
        self._proc: subprocess.Popen | None = None
        self._thread: threading.Thread | None = None
        self._samples: dict[int, list[tuple[float, float]]] = {}
        self.why_not: str | None = None
        """Why nothing was sampled (no GPU, no `nvidia-smi`, it failed), else None."""

    def __enter__(self) -> GpuWatch:
        if not self.gpus:
            self.why_not = "no NVIDIA GPU"
        elif not self.command:
            self.why_not = "nvidia-smi not found"
        else:
            try:
                self._proc = subprocess.Popen(
                    [self.command, f"--query-gpu={QUERY}", "--format=csv,noheader,nounits", f"-lms={self.interval_ms}"],
                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, text=True,
                    preexec_fn=sigterm_on_parent_death())  # a killed build leaves no sampler running
            except OSError as exc:
                self.why_not = f"nvidia-smi did not start ({exc})"
            else:
                self._thread = threading.Thread(target=self._read, name="gpu-watch", daemon=True)
                self._thread.start()
        return self

    def _read(self) -> None:
        for line in self._proc.stdout:  # type: ignore[union-attr]
            sample = parse_sample(line)
            if sample is not None:
                self._samples.setdefault(sample[0], []).append(sample[1:])

    def __exit__(self, *exc) -> None:
        if self._proc is not None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
            if self._thread is not None:
                self._thread.join(timeout=5)
            if not self._samples:
                self.why_not = "nvidia-smi gave no samples"

    def report(self) -> list[dict] | None:
        """Per GPU sampled: mean utilisation (%), peak memory in use (MiB) and the samples taken;
        None when nothing was sampled (`why_not` says why)."""
        if not self._samples:
            return None
        return [{"index": i, "busy_mean_pct": round(sum(u for u, _ in s) / len(s), 1),
                 "memory_max_mib": round(max(m for _, m in s)), "samples": len(s)}
                for i, s in sorted(self._samples.items())]


def describe(used: dict) -> str:
    """The part of a build's summary line about what it used (`used`: a build summary's "usage")."""
    h = used["host"]
    text = (f"CPU {used['cpu_seconds']['user'] + used['cpu_seconds']['system']:.0f} s "
            f"(system {used['cpu_seconds']['system']:.0f}) on {h['logical_cpus']} x {h['cpu_model']}")
    gpus = used.get("gpus")
    if gpus:
        text += "; " + ", ".join(f"GPU {g['index']} busy {g['busy_mean_pct']:.0f} % (mean), "
                                 f"{g['memory_max_mib']} MiB peak" for g in gpus)
    elif h["gpus"]:
        text += f"; GPUs not sampled ({used.get('gpus_not_sampled') or 'unknown'})"
    return text
