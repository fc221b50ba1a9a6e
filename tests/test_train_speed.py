"""`python -m train.speed`: a real JSON row from timed training steps of a tiny family on the
session's tiny dataset, the real-size configs' parameter counts against the published ones, and
the real checkpoints' image token counts on the dataset's images."""

from __future__ import annotations

import gzip
import json
import math
import re

import pytest
from process_support import torchrun

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")


def _run(capsys, *argv):
    from train.speed import main

    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _row(capsys, *argv):
    code, out, err = _run(capsys, *argv)
    assert code == 0, err
    lines = [line for line in out.splitlines() if line.strip()]
    assert len(lines) == 1, out
    return json.loads(lines[0])


def _check_rates(row, steps=2, batch=2):
    assert row["fits"] is True
    assert row["steps"] == steps and row["batch_size"] == batch
    assert row["examples"] == steps * batch * row.get("processes", 1)
    # The rate is examples over the unrounded seconds: the row's seconds (3 decimals) and rate (4)
    # agree up to their rounding (a 0.43 s run missed a relative 1e-3 once).
    assert row["seconds"] > 0 and row["samples_per_s"] > 0
    rounding = 5e-4 + row["examples"] / row["samples_per_s"] ** 2 * 5e-5
    assert abs(row["examples"] / row["samples_per_s"] - row["seconds"]) <= rounding + 1e-9
    assert row["tokens_per_s"] > row["label_tokens_per_s"] > 0
    # image tokens are in the input: an example is far longer than its answer
    assert row["tokens_per_example"] > 4 * row["label_tokens_per_s"] / row["samples_per_s"]
    assert row["epoch_hours_40k"] == pytest.approx(40_000 / row["samples_per_s"] / 3600, rel=1e-2)
    assert row["hours_40k_steps"] == pytest.approx(row["epoch_hours_40k"] * len(row["tasks"]), rel=1e-2)
    assert row["attn_implementation"] == "sdpa" and row["gpu"] == "cpu"
    assert row["peak_allocated_gib"] is None  # no GPU here


@pytest.mark.slow
@pytest.mark.parametrize("family", ["qwen3-vl", "gemma3"])
def test_lora_run_writes_a_row(family, tiny_dataset, tmp_path, capsys):
    pytest.importorskip("peft")
    out = tmp_path / "rows.jsonl"
    argv = ["--family", family, "--mode", "lora", "--data", str(tiny_dataset), "--batch-size", "2", "--steps", "2",
            "--warmup-steps", "1", "--device", "cpu", "--workers", "0", "--out", str(out)]
    row = _row(capsys, *argv)
    _check_rates(row)
    assert row["family"] == family and row["mode"] == "lora"
    assert 0 < row["params_trainable"] < row["params_total"] / 2
    assert json.loads(out.read_text()) == row
    again = _row(capsys, *argv)  # appended, the first row kept
    assert [json.loads(line) for line in out.read_text().splitlines()] == [row, again]


@pytest.mark.slow
def test_full_run_trains_every_weight(tiny_dataset, capsys):
    row = _row(capsys, "--family", "qwen3-vl", "--mode", "full", "--data", str(tiny_dataset), "--batch-size", "2",
               "--steps", "2", "--warmup-steps", "0", "--device", "cpu", "--workers", "0", "--weight-dtype", "fp32")
    _check_rates(row)
    assert row["params_trainable"] == row["params_total"] > 0
    assert row["weight_dtype"] == "fp32" and row["processes"] == 1 and row["shard"] == "none"


def test_saved_model_trains_with_python_m_train(tiny_dataset, tmp_path, capsys):
    """`--save-model DIR` writes the family's model with random weights and its processor as a
    checkpoint folder (nothing timed) that `python -m train --model DIR` fine-tunes; the same seed
    writes the same weights; an existing folder is refused."""
    from safetensors.torch import load_file

    from train.config import TrainConfig
    from train.loop import train

    base = tmp_path / "base"
    argv = ["--family", "qwen3-vl", "--data", str(tiny_dataset), "--device", "cpu", "--weight-dtype", "fp32"]
    row = _row(capsys, *argv, "--save-model", str(base))
    assert row["saved"] == str(base) and row["files"] == 1 and row["parameters"] > 0
    assert not list(tmp_path.glob(".*"))  # the temporary folder was renamed
    again = _row(capsys, *argv, "--save-model", str(tmp_path / "again"))
    first, second = load_file(str(base / "model.safetensors")), load_file(str(tmp_path / "again" / "model.safetensors"))
    assert sum(p.numel() for p in first.values()) == row["parameters"] == again["parameters"]
    assert all(torch.equal(first[k], second[k]) for k in first)
    code, _, err = _run(capsys, *argv, "--save-model", str(base))
    assert code == 2 and "exists already" in err

    summary = train(TrainConfig(data=(str(tiny_dataset),), outdir=str(tmp_path / "run"), model=str(base), lora=False,
                                steps=2, batch_size=2, save_every=2, eval=False, workers=0, device="cpu"),
                    progress=False)
    assert summary["steps"] == 2 and (tmp_path / "run" / "final" / "model.safetensors").is_file()


@pytest.mark.slow
def test_profile_writes_each_process_trace_and_tables_outside_the_timed_steps(tiny_dataset, tmp_path, capsys):
    prof = tmp_path / "prof"
    row = _row(capsys, "--family", "qwen3-vl", "--mode", "full", "--data", str(tiny_dataset), "--batch-size", "2",
               "--steps", "1", "--warmup-steps", "0", "--device", "cpu", "--workers", "0", "--profile", str(prof),
               "--profile-steps", "2")
    _check_rates(row, steps=1)  # the profiled steps are not among the timed ones
    summary = row["profile"]
    assert summary["steps"] == 2 and summary["seconds"] > 0
    assert summary["device_kernel_s"] == 0 and summary["nccl_kernel_s"] == 0  # no GPU here
    with gzip.open(summary["trace"], "rt") as f:
        events = json.load(f)["traceEvents"]
    names = {e.get("name", "") for e in events}
    assert any("aten::mm" in n or "aten::addmm" in n for n in names)  # the model's matmuls were recorded
    tables = (prof / "ops-rank0.txt").read_text()
    assert "most CPU time" in tables and "aten::" in tables


def test_idle_seconds_count_the_union_of_kernel_intervals():
    from train.profile import idle_seconds

    # two overlapping kernels (0-4 and 2-6 us) and one apart (10-11 us): busy 7 us of a 20 us wall
    assert idle_seconds([(10, 11), (0, 4), (2, 6)], 20e-6) == pytest.approx(13e-6)
    assert idle_seconds([(0, 5), (1, 2)], 5e-6) == pytest.approx(0.0)
    assert idle_seconds([], 1.0) == 1.0


def test_kernel_totals_count_each_kernel_once():
    """The device totals come from the kernels themselves: the CPU operators that launched them
    (which the operator tables credit with the same device time) and CUPTI's full-launch-queue
    spans are not added again."""
    from torch.autograd import DeviceType
    from torch.autograd.profiler_util import FunctionEvent

    from train.profile import kernel_events, kernel_totals

    def ev(i, name, a, b, device):
        return FunctionEvent(i, name, thread=0, start_us=a, end_us=b, device_type=device)

    events = [ev(0, "aten::mm", 0, 50, DeviceType.CPU), ev(1, "nvjet_sm90_tst_128x256", 10, 40, DeviceType.CUDA),
              ev(2, "nccl:_all_gather_base", 40, 60, DeviceType.CPU),
              ev(3, "ncclDevKernel_AllGather_RING_LL", 45, 70, DeviceType.CUDA),
              ev(4, "Command Buffer Full", 0, 100, DeviceType.CUDA), ev(5, "empty", 80, 80, DeviceType.CUDA)]
    kernels = kernel_events(events)
    assert [k.name for k in kernels] == ["nvjet_sm90_tst_128x256", "ncclDevKernel_AllGather_RING_LL"]
    assert kernel_totals(kernels) == (55.0, 25.0)


@pytest.mark.parametrize("argv, named", [
    (["--family", "qwen3-vl-9b"], "qwen3-vl-8b, gemma3-12b, qwen2-vl"),
    (["--family", "qwen3-vl", "--mode", "half"], "lora, full"),
    (["--family", "qwen3-vl", "--weight-dtype", "fp16"], "bf16, fp32"),
    (["--family", "qwen3-vl", "--steps", "0"], "at least 1"),
    (["--family", "qwen3-vl", "--profile", "p", "--profile-steps", "0"], "--profile-steps must be at least 1"),
    (["--family", "qwen3-vl", "--mode", "full", "--shard", "zero"], "ddp, fsdp"),
    (["--family", "qwen3-vl", "--mode", "lora", "--shard", "fsdp"], "full fine-tuning only; give --mode full"),
    (["--family", "qwen3-vl", "--mode", "full", "--fsdp-keep-gathered"], "applies with shard=fsdp only"),
])
def test_bad_choices_are_refused_with_the_valid_ones(argv, named, tiny_dataset, capsys):
    code, out, err = _run(capsys, *argv, "--data", str(tiny_dataset), "--device", "cpu")
    assert code == 2 and out == ""
    assert named in err


@pytest.mark.parametrize("name", ["qwen3-vl-8b", "gemma3-12b"])
def test_real_configs_have_the_published_parameter_count(name):
    from train.speed import REAL, count_parameters, real_config

    n = count_parameters(real_config(name))
    assert abs(n - REAL[name].params) / REAL[name].params < 0.02, (n, REAL[name].params)


def test_real_processors_give_the_checkpoints_image_tokens(tiny_dataset):
    """Gemma 3: 256 tokens per image whatever its size; Qwen3-VL-8B: one token per 32 x 32 pixels
    of the image resized to multiples of 32 (at least 65,536 pixels); the config's token ids are
    the local tokenizer's, the vocabulary the checkpoint's."""
    from eval.chat import task_chat
    from eval.data import iter_rows
    from train.data import encode
    from train.speed import REAL, build
    from train.tiny import dataset_texts

    texts = dataset_texts([tiny_dataset])
    row = next(iter_rows(tiny_dataset, "train"))
    messages, images, _ = task_chat(row, "pose", with_answer=True)
    assert images
    for name in REAL:
        cfg, processor = build(name, texts, None)
        tok = processor.tokenizer
        assert cfg.text_config.vocab_size == REAL[name].config["text_config"]["vocab_size"] > len(tok)
        ex = encode(processor, messages, images)
        if name == "gemma3-12b":
            image_id = cfg.image_token_index
            assert image_id == tok.convert_tokens_to_ids("<image_soft_token>")
            assert int((ex["input_ids"] == image_id).sum()) == 256 * len(images)
            assert tuple(ex["pixel_values"].shape[-2:]) == (896, 896)
        else:
            image_id = cfg.image_token_id
            assert image_id == tok.convert_tokens_to_ids("<|image_pad|>")
            expected = 0
            for im in images:
                w, h = im.size
                hh, ww = max(32, round(h / 32) * 32), max(32, round(w / 32) * 32)
                if hh * ww < 65536:  # upscaled to the checkpoint's minimum
                    scale = math.sqrt(65536 / (h * w))
                    hh, ww = math.ceil(h * scale / 32) * 32, math.ceil(w * scale / 32) * 32
                expected += hh * ww // (32 * 32)
            assert int((ex["input_ids"] == image_id).sum()) == expected
            assert int(ex["image_grid_thw"].prod(-1).sum()) == 4 * expected


@pytest.mark.slow
def test_two_processes_under_torchrun_write_one_row_for_both(tiny_dataset, tmp_path):
    """torchrun with two CPU processes (gloo): one row, both processes' examples over the slowest's
    seconds, and the processes trained different examples (their own seeds) on one model."""
    pytest.importorskip("peft")
    out = tmp_path / "rows.jsonl"
    done = torchrun("train.speed", "--family", "qwen3-vl", "--mode", "lora", "--data", str(tiny_dataset),
                    "--batch-size", "2", "--steps", "2", "--warmup-steps", "1", "--device", "cpu", "--workers", "0",
                    "--out", str(out))
    assert done.returncode == 0, done.stderr[-3000:]
    rows = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    assert len(rows) == 1 and json.loads(out.read_text()) == rows[0]
    row = rows[0]
    assert row["processes"] == 2 and row["shard"] == "ddp"
    _check_rates(row, steps=2, batch=2)  # per process
    assert row["examples"] == 2 * 2 * 2
    # The two processes' progress lines may interleave on stderr: found anywhere in it.
    last = re.findall(r"timed step 3/3: [\d.]+ s, loss ([\d.]+), (\d+) tokens", done.stderr)
    assert len(last) == 2 and last[0] != last[1]  # each process its own examples


@pytest.mark.slow
def test_two_sharded_processes_write_one_fsdp_row(tiny_dataset):
    """torchrun with two CPU processes and --shard fsdp: one row that records the mode, both
    processes' examples, every weight trained."""
    done = torchrun("train.speed", "--family", "qwen3-vl", "--mode", "full", "--shard", "fsdp", "--data",
                    str(tiny_dataset), "--batch-size", "2", "--steps", "2", "--warmup-steps", "1", "--device", "cpu",
                    "--workers", "0", "--weight-dtype", "fp32")
    assert done.returncode == 0, done.stderr[-3000:]
    rows = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    assert len(rows) == 1
    row = rows[0]
    assert row["processes"] == 2 and row["shard"] == "fsdp" and row["mode"] == "full"
    _check_rates(row, steps=2, batch=2)
    assert row["examples"] == 2 * 2 * 2
    assert row["params_trainable"] == row["params_total"] > 0  # counted whole, not one process's slice
    assert "2 processes (fsdp)" in done.stderr
