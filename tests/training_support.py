"""Helpers of the training tests: the `tiny_model` fixture (the tiny Qwen2-VL of `train.tiny`
built from the tiny dataset's texts once per session), a run folder's log and final weights
(`train_log`, `run_weights`), the `python -m train` arguments of the several-process tests
(`train_argv`), and the interrupt-and-resume check: `interrupted_copy` makes a run look killed
before its last checkpoint, `assert_resumed_run_is_the_same` compares the resumed run with the
uninterrupted one. `conftest` imports the fixture so that every test finds it by name."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def tiny_model(tiny_dataset, tmp_path_factory) -> Path:
    """The tiny Qwen2-VL (`train.tiny`, seed 0) built from the tiny dataset's texts, once per session."""
    from train.tiny import build_tiny_model, dataset_texts

    return build_tiny_model(tmp_path_factory.mktemp("tiny") / "base", dataset_texts([tiny_dataset]), seed=0)


def train_log(run: Path) -> list[dict]:
    """The trainer's per-step log of run folder `run`."""
    return [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]


def run_weights(run: Path) -> dict:
    """The weights of run folder `run`'s `final/`, from all its safetensors files."""
    from safetensors.torch import load_file

    return {k: v for f in sorted((run / "final").glob("*.safetensors")) for k, v in load_file(str(f)).items()}


def train_argv(dataset, model, outdir, *more) -> list[str]:
    """`python -m train` arguments of the several-process tests: 3 steps on the CPU from `model`,
    a checkpoint every 2, no data workers, then `more`."""
    return ["--data", str(dataset), "--model", str(model), "--outdir", str(outdir), "--steps", "3", "--lr", "1e-3",
            "--warmup", "1", "--save-every", "2", "--keep-checkpoints", "0", "--workers", "0", "--device", "cpu",
            "--no-progress", *map(str, more)]


def interrupted_copy(run: Path, into: Path) -> tuple[Path, dict, list[dict], dict]:
    """A copy of the finished 3-step run `run` (a checkpoint every 2) in `into`, as if killed
    after step 3 was logged but before its checkpoint (checkpoint 2 the last whole one), its config
    pointing at the copy: (copy, its config, the run's log, the run's final weights)."""
    copy = into / run.name
    shutil.copytree(run, copy)
    log_before, weights_before = train_log(copy), run_weights(copy)
    shutil.rmtree(copy / "checkpoint-000003")
    shutil.rmtree(copy / "final")
    (copy / "last").write_text("checkpoint-000003\n")
    config = json.loads((copy / "train_config.json").read_text())
    config["outdir"] = str(copy)  # the copy is another run folder
    (copy / "train_config.json").write_text(json.dumps(config))
    return copy, config, log_before, weights_before


def assert_resumed_run_is_the_same(run: Path, log_before: list[dict], weights_before: dict) -> None:
    """A run resumed from a checkpoint logged the same losses step for step and ended with the
    same final weights as the uninterrupted run (`log_before`, `weights_before`)."""
    import torch
    from safetensors.torch import load_file

    log_after = train_log(run)
    assert [r["step"] for r in log_after] == [r["step"] for r in log_before]
    for a, b in zip(log_before, log_after):
        assert a["loss"] == pytest.approx(b["loss"], abs=1e-5)
    resumed = load_file(str(run / "final" / "model.safetensors"))
    assert resumed.keys() == weights_before.keys()
    for k in resumed:
        torch.testing.assert_close(resumed[k], weights_before[k], atol=1e-6, rtol=1e-5)
