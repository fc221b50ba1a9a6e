"""One process per GPU under torchrun: the process group that `python -m train` and `python -m
train.speed` start, and the few collectives they use.

`torchrun --nproc_per_node N -m train ...` starts N processes with RANK, LOCAL_RANK and WORLD_SIZE
in their environment; `start` then joins them in one process group (NCCL on GPUs, gloo on the
CPU) and gives each process its own GPU (cuda:LOCAL_RANK). Without torchrun (WORLD_SIZE unset or
1) nothing is started and `Group()` is the one process: every collective is the identity.

`parallel` puts the model in DistributedDataParallel (shard "ddp": a whole copy on every GPU) or
shards it with FSDP2 (shard "fsdp", `shard_model`: each transformer block of the language model and
of the vision tower is one `fully_shard` unit, the rest, embeddings, LM head, projector, norms, the
root's).
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


def parallel(model, group: Group, find_unused_parameters: bool, shard: str = "ddp", keep_gathered: bool = False):
    """With several processes: `model` in DistributedDataParallel (shard "ddp": its weights
    broadcast from rank 0, gradients averaged over the processes in the backward pass) or sharded
    in place by FSDP2 (shard "fsdp", `shard_model`); with one, `model` as it is.
    `find_unused_parameters` (DDP): for full fine-tuning, where an architecture may have weights
    that a step does not use (LoRA's adapters are all used). `keep_gathered` (FSDP): see
    `shard_model`."""
    if group.processes == 1:
        return model
    if shard == "fsdp":
        return shard_model(model, group, keep_gathered)
    if shard != "ddp":
        raise ValueError(f"shard={shard!r} is not valid; valid: ddp, fsdp")
    ids = [group.device.index] if group.device.type == "cuda" else None
    # gradient_as_bucket_view: the gradients live in DDP's all-reduce buckets instead of beside
    # them, one gradient-sized copy less per GPU (16 GB at 8B parameters in bf16).
    return DistributedDataParallel(model, device_ids=ids, find_unused_parameters=find_unused_parameters,
                                   gradient_as_bucket_view=True)


def shard_units(model) -> list[str]:
    """Names of the modules FSDP shards one by one: the transformer blocks, i.e. the members of
    the model's ModuleLists whose class is in its `_no_split_modules` (transformers names there the
    blocks that must stay whole on one device: the language model's decoder layers and the vision
    tower's blocks, e.g. Qwen2VLDecoderLayer and Qwen2VLVisionBlock); a model that names none:
    the members of every ModuleList of two or more modules of one class. Deepest first (each
    unit's `fully_shard` before any module holding it)."""
    blocks = set(getattr(model, "_no_split_modules", None) or ())
    out = []
    for name, mod in model.named_modules():
        if not isinstance(mod, torch.nn.ModuleList) or not len(mod):
            continue
        kinds = {type(m).__name__ for m in mod}
        for i, m in enumerate(mod):
            block = type(m).__name__ in blocks if blocks else len(mod) > 1 and len(kinds) == 1
            if block:
                out.append(f"{name}.{i}" if name else str(i))
    if not out:
        raise ValueError(f"{type(model).__name__}: no transformer blocks to shard (no ModuleList member of a class in "
                         f"_no_split_modules {sorted(blocks)})")
    return sorted(out, key=lambda n: -n.count("."))


def shard_model(model, group: Group, keep_gathered: bool = False):
    """`model` sharded in place by FSDP2 over the processes of `group`: `fully_shard` on each of
    `shard_units` (its weights split over the processes, gathered for its forward and again for
    its backward, freed after each), then on the model (the remaining weights; the root's
    forward starts every step). Weights stay in their dtype (no mixed-precision policy: autocast
    computes as under DDP) and on the CPU they may be: FSDP moves each unit's weights to this
    process's device as it shards them, so a GPU never holds more than one unit unsharded while
    the model is sharded. Every process must hold the same weights (FSDP keeps each process's own
    slice, it broadcasts nothing). Gradients are reduce-scattered (averaged over the processes)
    after each unit's backward; the optimizer must be made after this (the parameters become
    DTensors). `keep_gathered` keeps each unit's gathered weights from its forward to its backward
    (`reshard_after_forward=False`: one all-gather per unit and step less, the whole model's
    weights held gathered by the forward's end; `TrainConfig.fsdp_keep_gathered`)."""
    from torch.distributed.device_mesh import init_device_mesh
    from torch.distributed.fsdp import fully_shard

    mesh = init_device_mesh(group.device.type, (group.processes,))
    for name in shard_units(model):
        fully_shard(model.get_submodule(name), mesh=mesh, reshard_after_forward=not keep_gathered)
    fully_shard(model, mesh=mesh, reshard_after_forward=not keep_gathered)
    return model


def is_sharded(model) -> bool:
    """Whether `model` is sharded by FSDP2 (`shard_model`)."""
    from torch.distributed.fsdp import FSDPModule

    return isinstance(model, FSDPModule)


def end() -> None:
    """Leave the process group once every process got here (after a run that ended well)."""
    if dist.is_available() and dist.is_initialized():
        # Every process reaches this point before any tears its group down: a process that left
        # while another was still inside a collective aborted it (gloo: "terminate called without
        # an active exception", seen once in a CPU test run of train.speed without this barrier).
        dist.barrier()
        dist.destroy_process_group()
