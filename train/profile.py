"""Where a training step's time goes: a few steps under `torch.profiler`, summarised.

`python -m train.speed --profile DIR` runs `--profile-steps` more steps after its timed ones (so
the profiler's own cost never enters the timed figures) and, per process, writes

- `DIR/trace-rank{R}.json.gz`: the Chrome/Perfetto trace (CPU ops, and CUDA kernels and memory
  copies on a GPU), to open in https://ui.perfetto.dev or chrome://tracing;
- `DIR/ops-rank{R}.txt`: the operators and kernels, most device time first, then most CPU time;

and returns a summary for the speed row: the profiled steps' wall seconds, the device kernels'
seconds summed (every stream: kernels that overlap count twice), of which NCCL's (the
collectives of DDP and FSDP), and the seconds the device ran no kernel at all (the union of the
kernels' intervals against the wall time: what the GPU waited for the host or for nothing).
"""

from __future__ import annotations

import time
from pathlib import Path

TABLE_ROWS = 40
"""Rows of each table in `ops-rank{R}.txt`."""


NOT_KERNELS = ("Command Buffer Full",)
"""Device-side records that are no kernel: CUPTI's span of a launch queue that was full (the host
ahead of the GPU), which overlaps the kernels it waited for."""


def kernel_events(events) -> list:
    """The kernels (and memory copies) among profiler `events`: device-side events of nonzero
    length. Each kernel once: the operator tables also credit a kernel's time to the CPU operator
    that launched it (`aten::mm` and its `nvjet_...` kernel; `nccl:_all_gather_base` and its
    `ncclDevKernel_...`), so summing their device columns counts it twice."""
    from torch.autograd import DeviceType

    return [ev for ev in events if getattr(ev, "device_type", None) == DeviceType.CUDA
            and ev.time_range.elapsed_us() > 0 and ev.name not in NOT_KERNELS]


def kernel_totals(kernels) -> tuple[float, float]:
    """(all, NCCL's) summed length in microseconds of `kernels` (`kernel_events`)."""
    total = sum(ev.time_range.elapsed_us() for ev in kernels)
    nccl = sum(ev.time_range.elapsed_us() for ev in kernels if "nccl" in ev.name.lower())
    return float(total), float(nccl)


def idle_seconds(intervals: list[tuple[float, float]], wall_s: float) -> float:
    """Wall seconds not covered by any of `intervals` (microseconds), never below 0."""
    busy, end = 0.0, None
    for a, b in sorted(intervals):
        if end is None or a > end:
            busy += b - a
            end = b
        elif b > end:
            busy += b - end
            end = b
    return max(0.0, wall_s - busy / 1e6)


def profile_steps(step, steps: int, outdir, rank: int, device) -> dict:
    """Run `step()` `steps` times under the profiler; write this process's trace and operator
    tables into `outdir`; the summary (see the module docstring)."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=activities) as prof:
        t = time.perf_counter()
        for _ in range(steps):
            step()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        wall = time.perf_counter() - t
    trace = out / f"trace-rank{rank}.json.gz"
    prof.export_chrome_trace(str(trace))
    averages = prof.key_averages()
    by_device = averages.table(sort_by="self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total",
                               row_limit=TABLE_ROWS)
    by_cpu = averages.table(sort_by="self_cpu_time_total", row_limit=TABLE_ROWS)
    (out / f"ops-rank{rank}.txt").write_text(f"most device time:\n{by_device}\n\nmost CPU time:\n{by_cpu}\n")
    kernels = kernel_events(prof.events())
    kernel_us, nccl_us = kernel_totals(kernels)
    summary = {"steps": steps, "seconds": round(wall, 3), "device_kernel_s": round(kernel_us / 1e6, 3),
               "nccl_kernel_s": round(nccl_us / 1e6, 3), "trace": str(trace)}
    if device.type == "cuda":
        summary["device_idle_s"] = round(idle_seconds([(ev.time_range.start, ev.time_range.end) for ev in kernels], wall), 3)
    return summary
