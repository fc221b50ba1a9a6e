"""`torchrun --nproc_per_node 2 -m train` on the CPU (two gloo processes, the tiny Qwen2-VL, a few
steps): rank 0 alone writes the run folder; two processes at batch 1 train as one process at
batch 2 (the same examples per step, the same losses and weights up to float rounding), full
fine-tuning and LoRA with gradient checkpointing and gradient accumulation; an interrupted
two-process run resumes to the same result; another process count is refused."""

from __future__ import annotations

import json

import pytest
from process_support import torchrun
from training_support import assert_resumed_run_is_the_same, interrupted_copy, run_weights, train_argv, train_log

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")
pytest.importorskip("peft")


def _one_process(argv, capsys):
    from train.__main__ import main

    assert main(argv) == 0
    capsys.readouterr()


def _two_processes(argv):
    done = torchrun("train", *argv)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def _assert_same_training(one, two, base, atol=1e-5):
    """The same steps and losses in the two logs, the same final weights within `atol`, which is
    far below what training moved them from `base` (the untrained model's folder)."""
    from safetensors.torch import load_file

    a, b = train_log(one), train_log(two)
    assert [r["step"] for r in a] == [r["step"] for r in b]
    assert [r["examples"] for r in a] == [r["examples"] for r in b]
    for ra, rb in zip(a, b):
        assert ra["loss"] == pytest.approx(rb["loss"], abs=1e-4)
    wa, wb, w0 = run_weights(one), run_weights(two), load_file(str(base / "model.safetensors"))
    assert wa.keys() == wb.keys()
    for k in wa:
        torch.testing.assert_close(wb[k], wa[k], atol=atol, rtol=0, msg=k)
    assert max(float((wa[k] - w0[k]).abs().max()) for k in wa) > 100 * atol


@pytest.fixture(scope="module")
def full_runs(tiny_dataset, tiny_model, tmp_path_factory):
    """Full fine-tuning, 3 steps of 2 examples: one process at batch 2 and two at batch 1 (the
    latter evaluated by rank 0 on one test step); (one, two, the torchrun result)."""
    from train.__main__ import main

    root = tmp_path_factory.mktemp("ddp")
    one, two = root / "one", root / "two"
    assert main(train_argv(tiny_dataset, tiny_model, one, "--lora", "0", "--batch-size", "2", "--no-eval")) == 0
    done = _two_processes(train_argv(tiny_dataset, tiny_model, two, "--lora", "0", "--batch-size", "1",
                                "--eval-limit", "1", "--max-new-tokens", "8"))
    return one, two, done


@pytest.mark.slow
def test_rank_0_alone_writes_the_run_folder(full_runs):
    from train import checkpoint as ckpt

    _, two, done = full_runs
    assert [s for s, _ in ckpt.checkpoints(two)] == [2, 3]
    for name in ("final/model.safetensors", "train_summary.json", "metrics.json", "preds_after.jsonl", "loss.png"):
        assert (two / name).is_file(), name
    assert not [p.name for p in two.iterdir() if p.name.startswith(".")]  # no temporary folder left
    assert [r["step"] for r in train_log(two)] == [1, 2, 3]  # one line per step: one writer
    assert done.stdout.count("final model:") == 1  # rank 0 reports; the other rank ended quietly
    summary = json.loads((two / "train_summary.json").read_text())
    assert summary["processes"] == 2 and summary["examples_per_step"] == 2 and summary["examples"] == 6
    state = ckpt.load_state(two / "checkpoint-000003")
    assert state["processes"] == 2 and len(state["rng_ranks"]) == 2
    assert not torch.equal(state["rng_ranks"][0]["torch"], state["rng_ranks"][1]["torch"])  # own dropout masks


def test_two_processes_train_as_one_with_their_global_batch(full_runs, tiny_model):
    """Two processes' answer tokens differ per example (so a plain mean of their losses would
    differ from one process's on both examples: 6.553 against 6.596 in the first step, tried)."""
    one, two, _ = full_runs
    _assert_same_training(one, two, tiny_model)


@pytest.mark.slow
def test_an_interrupted_two_process_run_resumes_to_the_same_result(full_runs, tmp_path):
    _, two, _ = full_runs
    run, config, log_before, weights_before = interrupted_copy(two, tmp_path)
    _two_processes(train_argv(config["data"][0], config["model"], run, "--lora", "0", "--batch-size", "1", "--no-eval"))
    assert_resumed_run_is_the_same(run, log_before, weights_before)


def test_another_process_count_is_refused(full_runs, tiny_dataset, tiny_model, capsys):
    from train.__main__ import main
    from train.config import ConfigError, TrainConfig
    from train.loop import check_processes

    _, two, _ = full_runs
    capsys.readouterr()
    assert main(train_argv(tiny_dataset, tiny_model, two, "--lora", "0", "--batch-size", "1", "--no-eval")) == 2
    err = capsys.readouterr().err
    assert "checkpoint-000003 was trained by 2 process(es)" in err and "this run has 1" in err
    assert "torchrun --nproc_per_node 2" in err
    # a one-process checkpoint (no count saved before this) under two processes
    with pytest.raises(ConfigError, match=r"trained by 1 process\(es\).*this run has 2.*python -m train"):
        check_processes({}, two / "checkpoint-000002", 2, TrainConfig.load(two))


@pytest.mark.slow
def test_lora_with_gradient_checkpointing_and_accumulation(tiny_dataset, tiny_model, tmp_path, capsys):
    """LoRA (no dropout, so both runs draw nothing), gradient checkpointing, 2 passes per step: two
    processes at batch 1 train as one at batch 2."""
    more = ["--lora", "1", "--lora-dropout", "0", "--gradient-checkpointing", "--grad-accum", "2", "--no-eval",
            "--steps", "2"]
    _one_process(train_argv(tiny_dataset, tiny_model, tmp_path / "one", *more, "--batch-size", "2"), capsys)
    _two_processes(train_argv(tiny_dataset, tiny_model, tmp_path / "two", *more, "--batch-size", "1"))
    assert [r["examples"] for r in train_log(tmp_path / "two")] == [4, 8]
    _assert_same_training(tmp_path / "one", tmp_path / "two", tiny_model)


def test_the_staged_recipe_refuses_torchrun(monkeypatch, capsys, tmp_path):
    from train.recipe import main

    monkeypatch.setenv("WORLD_SIZE", "2")
    assert main(["--designs", str(tmp_path), "--synthetic", str(tmp_path), "--outdir", str(tmp_path / "run")]) == 2
    assert "runs in one process (this is one of 2 under torchrun)" in capsys.readouterr().err
