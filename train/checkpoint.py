"""Checkpoints of a run folder: written whole or not at all, found again on resume.

`RUN/checkpoint-{step:06d}/` holds the model (`save_pretrained(safe_serialization=True)`: the LoRA
adapter, or the full model), the processor, `train_config.json` and `trainer_state.pt` (optimizer,
scheduler, RNG states, data position, counters). It is written into a hidden temporary folder and
renamed into place, so a folder with that name is complete; `RUN/last` then names it. A killed run
leaves at worst a temporary folder, removed by the next run.
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
LAST_FILE = "last"
_NAME = re.compile(r"^checkpoint-(\d{6,})$")


def checkpoint_name(step: int) -> str:
    return f"checkpoint-{int(step):06d}"


def tmp_dir(run: Path, name: str) -> Path:
    return Path(run) / f".tmp-{name}-{os.getpid()}"


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


def save(run, step: int, model, processor, config, state: dict, keep: int = 0) -> Path:
    """Write checkpoint `step` (see the module docstring); keep the newest `keep` (0: all)."""
    run = Path(run)
    name = checkpoint_name(step)
    tmp = tmp_dir(run, name)
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    model.save_pretrained(str(tmp), safe_serialization=True)
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
