"""Checkpoints of a run folder: written whole or not at all, found again on resume.

`RUN/checkpoint-{step:06d}/` holds the model (`save_pretrained(safe_serialization=True)`: the LoRA
adapter, or the full model, in safetensors files of at most `SHARD_SIZE`), the processor,
`train_config.json` and `trainer_state.pt` (optimizer, scheduler, RNG states, data position,
counters). It is written into a hidden temporary folder and
renamed into place, so a folder with that name is complete; `RUN/last` then names it. A killed run
leaves at worst a temporary folder, removed by the next run.

A run sharded by FSDP (`TrainConfig.shard` fsdp under torchrun) writes the same folder, the model
gathered whole to rank 0 (`full_model_state`) and saved in safetensors files of at most
`SHARD_SIZE`, except the optimizer: its AdamW states stay split as the processes hold them, in
`optimizer/` (torch.distributed.checkpoint, one file per process, `save_optimizer_shards`), and
every process reads its own slice back on resume (`load_optimizer_shards`): no process ever holds
the whole optimizer state (Gemma-3-12B's is 97 GB in fp32), and the restored states are the
saved ones bit for bit. The processes write into rank 0's temporary folder, renamed once whole.
"""

from __future__ import annotations

import os
import random
import re
import shutil
from pathlib import Path

import torch

from eval.processor import save_processor
from factory.atomic import write_atomic

STATE_FILE = "trainer_state.pt"
OPTIMIZER_DIR = "optimizer"
"""A sharded run's optimizer state (torch.distributed.checkpoint) inside its checkpoint folder."""
SHARD_SIZE = "5GB"
"""Largest safetensors file of a checkpoint's or final model's weights."""
LAST_FILE = "last"
_NAME = re.compile(r"^checkpoint-(\d{6,})$")


def checkpoint_name(step: int) -> str:
    return f"checkpoint-{int(step):06d}"


def tmp_dir(run: Path, name: str) -> Path:
    return Path(run) / f".tmp-{name}-{os.getpid()}"


def fresh_tmp(run: Path, name: str) -> Path:
    """This process's temporary folder for `run/name` (`tmp_dir`), made empty."""
    tmp = tmp_dir(run, name)
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    return tmp


def write_atomic_text(path: Path, text: str) -> None:
    """`factory.atomic.write_atomic` for text (UTF-8)."""
    write_atomic(path, text.encode())


def publish(tmp: Path, final: Path) -> Path:
    """Rename the finished folder `tmp` to `final` (replacing an older one of that name)."""
    if final.exists():
        old = final.with_name(f".old-{final.name}-{os.getpid()}")
        os.replace(final, old)
        os.replace(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, final)
    return final


def remove_stale(run: Path) -> None:
    """Temporary folders and files left by a killed run."""
    run = Path(run)
    if not run.is_dir():
        return
    for p in run.iterdir():
        if p.name.startswith((".tmp-", ".old-")) or (p.name.startswith(".") and p.name.endswith(".tmp")):
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)


def checkpoints(run) -> list[tuple[int, Path]]:
    """Complete checkpoints of the run folder as (step, path), by step."""
    run = Path(run)
    out = []
    if run.is_dir():
        for p in run.iterdir():
            m = _NAME.match(p.name)
            if m and p.is_dir() and (p / STATE_FILE).is_file():
                out.append((int(m.group(1)), p))
    return sorted(out)


def latest(run) -> Path | None:
    """The checkpoint `RUN/last` names, else the highest complete one, else None."""
    run = Path(run)
    last = run / LAST_FILE
    if last.is_file():
        p = run / last.read_text().strip()
        if _NAME.match(p.name) and (p / STATE_FILE).is_file():
            return p
    found = checkpoints(run)
    return found[-1][1] if found else None


def save(run, step: int, model, processor, config, state: dict, keep: int = 0, tmp: Path | None = None,
         weights: dict | None = None) -> Path:
    """Write checkpoint `step` (see the module docstring); keep the newest `keep` (0: all).
    `tmp`: the temporary folder, already made and holding the other processes' files (a sharded
    run), else a new one; `weights`: the model's state dict to save (a sharded model's, gathered
    by `full_model_state`), in files of at most `SHARD_SIZE`, else the model's own."""
    run = Path(run)
    name = checkpoint_name(step)
    if tmp is None:
        tmp = fresh_tmp(run, name)
    save_model(model, tmp, weights)
    save_processor(processor, tmp)
    config.save(tmp)
    torch.save(state, tmp / STATE_FILE)
    final = publish(tmp, run / name)
    write_atomic_text(run / LAST_FILE, name + "\n")
    if keep:
        for _, p in checkpoints(run)[:-keep]:
            if p != final:
                shutil.rmtree(p, ignore_errors=True)
    return final


def save_model(model, folder, weights: dict | None = None) -> None:
    """`model.save_pretrained(folder)` in safetensors files of at most `SHARD_SIZE` (with an index
    when there are several: transformers' default, 50GB, would put an 8B model's fp32 weights in
    one 35 GB file); with `weights` (a sharded model's state dict, `full_model_state`), those."""
    extra = {} if weights is None else {"state_dict": weights}
    model.save_pretrained(str(folder), safe_serialization=True, max_shard_size=SHARD_SIZE, **extra)


def write_model_folder(model, processor, out) -> Path:
    """`model` (`save_model`) and `processor` as the checkpoint folder `out`, whole or not at all
    (written beside it and renamed into place, replacing an older one: `publish`)."""
    out = Path(out)
    tmp = fresh_tmp(out.parent, out.name)
    save_model(model, tmp)
    save_processor(processor, tmp)
    return publish(tmp, out)


def full_model_state(model) -> dict:
    """A model sharded by FSDP gathered whole: its state dict in CPU tensors on rank 0, {} on the
    others. A collective: every process calls it (each weight is gathered in turn). Tied weights
    (Gemma 3's LM head and embeddings: one parameter, two names) are one tensor under both names,
    as in the model's own state dict, so `save_pretrained` writes them once (gathered, each name
    got its own copy: Gemma-3-12B's 4 GB in fp32 twice)."""
    from torch.distributed.checkpoint.state_dict import StateDictOptions, get_model_state_dict

    state = get_model_state_dict(model, options=StateDictOptions(full_state_dict=True, cpu_offload=True))
    if state:
        names: dict[int, list[str]] = {}
        for name, p in model.named_parameters(remove_duplicate=False):
            names.setdefault(id(p), []).append(name)
        for tied in names.values():
            kept = [n for n in tied if n in state]
            for n in tied[1:] if kept else ():
                state[n] = state[kept[0]]
    return state


def save_optimizer_shards(model, optimizer, folder) -> None:
    """Every process writes its slice of the optimizer state of a model sharded by FSDP into
    `folder` (torch.distributed.checkpoint: a file per process, the layout in `.metadata`). A
    collective: every process calls it with the same folder."""
    import torch.distributed.checkpoint as dcp
    from torch.distributed.checkpoint.state_dict import get_optimizer_state_dict

    dcp.save({"optimizer": get_optimizer_state_dict(model, optimizer)}, checkpoint_id=str(folder))


def load_optimizer_shards(model, optimizer, folder) -> None:
    """`save_optimizer_shards`' inverse: every process reads its slice into `optimizer` (made for
    `model` sharded as when it was saved: the same processes). A collective."""
    import torch.distributed.checkpoint as dcp
    from torch.distributed.checkpoint.state_dict import get_optimizer_state_dict, set_optimizer_state_dict

    state = {"optimizer": get_optimizer_state_dict(model, optimizer)}  # the layout, filled in place
    dcp.load(state, checkpoint_id=str(folder))
    set_optimizer_state_dict(model, optimizer, state["optimizer"])


def load_state(path) -> dict:
    return torch.load(Path(path) / STATE_FILE, map_location="cpu", weights_only=True)


def rng_state() -> dict:
    state = {"torch": torch.random.get_rng_state(), "python": list(random.getstate()[1])}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    torch.random.set_rng_state(state["torch"])
    if "python" in state:
        random.setstate((3, tuple(state["python"]), None))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
