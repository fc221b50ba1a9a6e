"""One process per GPU under torchrun: the process group that `python -m train` and `python -m
train.speed` start, and the few collectives they use.

`torchrun --nproc_per_node N -m train ...` starts N processes with RANK, LOCAL_RANK and WORLD_SIZE
in their environment; `start` then joins them in one process group (NCCL on GPUs, gloo on the
CPU) and gives each process its own GPU (cuda:LOCAL_RANK). Without torchrun (WORLD_SIZE unset or
1) nothing is started and `Group()` is the one process: every collective is the identity.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel

TIMEOUT = timedelta(hours=1)
"""How long a collective waits for the other processes: rank 0 writes checkpoints and the final
model while the others wait at a barrier (minutes for a model of several GB)."""


@dataclass(frozen=True)
class Group:
    """This process's place among the processes of one run."""

    rank: int = 0
    processes: int = 1
    device: torch.device = torch.device("cpu")
    """Where the collectives' tensors live (NCCL needs them on this process's GPU)."""

    @property
    def main(self) -> bool:
        """Rank 0: the process that writes the run folder and evaluates."""
        return self.rank == 0

    def barrier(self) -> None:
        if self.processes > 1:
            dist.barrier()

    def reduce(self, values, op: str = "sum") -> list[float]:
        """`values` (floats) summed (op "sum") or their largest (op "max") over the processes."""
        values = [float(v) for v in values]
        if self.processes == 1:
            return values
        t = torch.tensor(values, dtype=torch.float64, device=self.device)
        dist.all_reduce(t, op={"sum": dist.ReduceOp.SUM, "max": dist.ReduceOp.MAX}[op])
        return t.tolist()

    def gather(self, obj) -> list:
        """Every process's `obj` (picklable), by rank."""
        if self.processes == 1:
            return [obj]
        out = [None] * self.processes
        dist.all_gather_object(out, obj)
        return out


def launched_processes() -> int:
    """Processes torchrun started for this run (WORLD_SIZE), 1 without torchrun."""
    return int(os.environ.get("WORLD_SIZE", "1"))


def launched_rank() -> int:
    """This process's rank under torchrun (RANK), 0 without it."""
    return int(os.environ.get("RANK", "0"))


def start(device: torch.device) -> tuple[Group, torch.device]:
    """(group, this process's device): under torchrun the process group is started here (NCCL for
    cuda, gloo for cpu) and a cuda device becomes cuda:LOCAL_RANK; else (Group(), device)."""
    if launched_processes() <= 1:
        return Group(device=device), device
    if device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", launched_rank())))
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo", timeout=TIMEOUT)
    return Group(dist.get_rank(), dist.get_world_size(), device), device


def parallel(model, group: Group, find_unused_parameters: bool):
    """`model` in DistributedDataParallel (its weights broadcast from rank 0, gradients averaged
    over the processes in the backward pass) when there are several processes; else `model`.
    `find_unused_parameters`: for full fine-tuning, where an architecture may have weights that a
    step does not use (LoRA's adapters are all used)."""
    if group.processes == 1:
        return model
    ids = [group.device.index] if group.device.type == "cuda" else None
    return DistributedDataParallel(model, device_ids=ids, find_unused_parameters=find_unused_parameters)


def end() -> None:
    """Leave the process group once every process got here (after a run that ended well)."""
    if dist.is_available() and dist.is_initialized():
        # Every process reaches this point before any tears its group down: a process that left
        # while another was still inside a collective aborted it (gloo: "terminate called without
        # an active exception", seen once in a CPU test run of train.speed without this barrier).
        dist.barrier()
        dist.destroy_process_group()
