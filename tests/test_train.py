"""The trainer on the session's tiny dataset with the tiny Qwen2-VL: answer-only labels, learning,
exact resume, refusal of a changed config, world-feedback rows, and the command end to end."""

from __future__ import annotations

import json
import shutil

import pytest
from training_support import assert_resumed_run_is_the_same, run_weights, train_log

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")
pytest.importorskip("peft")

END = "<|im_end|>"


@pytest.fixture(scope="module")
def processor(tiny_model):
    from eval.processor import load_processor

    return load_processor(tiny_model)


def _first_row(dataset, split="train"):
    from eval.data import iter_rows

    return next(iter_rows(dataset, split))


def _labelled(processor, ex) -> str:
    return processor.tokenizer.decode(ex["input_ids"][ex["labels"] != -100])


def _base_cfg(dataset, outdir, **kw):
    from train.config import TrainConfig

    args = dict(data=(str(dataset),), outdir=str(outdir), steps=4, batch_size=2, save_every=2, keep_checkpoints=0,
                lr=1e-3, warmup=1, eval=False, seed=0, workers=0)
    args.update(kw)
    return TrainConfig(**args)


def test_tiny_model_loads_back_and_is_deterministic(tiny_dataset, tiny_model, tmp_path):
    from transformers import AutoModelForImageTextToText

    from train.tiny import QWEN_SPECIAL, build_tiny_model, dataset_texts

    again = build_tiny_model(tmp_path / "again", dataset_texts([tiny_dataset]), seed=0)
    for name in ("model.safetensors", "tokenizer.json", "config.json"):
        assert (again / name).read_bytes() == (tiny_model / name).read_bytes(), name
    model = AutoModelForImageTextToText.from_pretrained(str(tiny_model))
    from eval.processor import load_processor

    tok = load_processor(tiny_model).tokenizer
    ids = {t: tok.convert_tokens_to_ids(t) for t in QWEN_SPECIAL}
    assert model.config.image_token_id == ids["<|image_pad|>"]
    assert model.config.vision_start_token_id == ids["<|vision_start|>"]
    assert tok.eos_token == END and model.config.text_config.eos_token_id == ids[END]
    assert 0.2e6 < sum(p.numel() for p in model.parameters()) < 20e6


@pytest.mark.parametrize("task", ["selection", "pose"])
def test_labels_cover_exactly_the_answer(tiny_dataset, processor, task):
    from eval.chat import task_chat
    from train.data import encode

    messages, images, answer = task_chat(_first_row(tiny_dataset), task, with_answer=True)
    ex = encode(processor, messages, images, max_length=4096)
    assert _labelled(processor, ex) == answer + END
    mask = (ex["labels"] != -100).nonzero().flatten().tolist()
    assert mask == list(range(mask[0], mask[-1] + 1))  # one contiguous span
    assert mask[-1] == len(ex["input_ids"]) - 2  # the trailing newline after <|im_end|> is not trained
    image_id = processor.tokenizer.convert_tokens_to_ids("<|image_pad|>")
    assert (ex["input_ids"] == image_id).sum() > len(images)  # images expanded to several tokens each
    assert ex["image_grid_thw"].shape[0] == len(images)


def test_only_the_final_answer_of_a_multi_turn_chat_is_trained(tiny_dataset, processor):
    from eval.chat import task_chat
    from train.data import encode

    messages, images, answer = task_chat(_first_row(tiny_dataset), "pose", with_answer=True)
    wrong = {"role": "assistant", "content": [{"type": "text", "text": "Brick 1:\nTranslation:\nx=1.0, y=2.0, z=3.0"}]}
    again = {"role": "user", "content": [{"type": "text", "text": "The placement is not right. Try again."}]}
    ex = encode(processor, [*messages[:-1], wrong, again, messages[-1]], images)
    assert _labelled(processor, ex) == answer + END


def test_too_long_examples_are_skipped_and_counted(tiny_dataset, processor):
    from train.config import ConfigError
    from train.data import ExampleStream, epoch_order

    stream = ExampleStream([tiny_dataset], processor, max_length=600)  # selection fits, pose does not
    it = iter(stream)
    got = [next(it) for _ in range(6)]  # the six selection examples of the first epoch
    assert all(len(e["input_ids"]) <= 600 for e in got)
    read = epoch_order(stream.groups, 0, 0, stream.window)[:stream.position[1]]
    assert stream.position[0] == 0 and stream.skipped == sum(t == "pose" for _, _, t, _ in read) >= 5
    with pytest.raises(ConfigError, match="max_length"):
        next(iter(ExampleStream([tiny_dataset], processor, max_length=50)))


def test_data_order_is_a_function_of_seed_and_position(tiny_dataset, processor):
    from train.data import ExampleStream

    def ids(position, n, seed=0):
        s = ExampleStream([tiny_dataset], processor, seed=seed, position=position)
        it = s.raw()
        return [w for *_, w in (next(it) for _ in range(n))], s.position

    full, end = ids((0, 0), 20)
    later, _ = ids((0, 7), 13)
    assert later == full[7:] and end == (1, 8)
    assert sorted(full[:12]) == sorted(full[12:] + ids((1, 8), 4)[0])  # every epoch is all examples
    assert ids((0, 0), 12, seed=1)[0] != full[:12]


def test_weighted_folders_mix_by_weight_and_resume(tiny_dataset, tmp_path):
    """Each example's folder is drawn by weight (measured over the stream), each folder gives its
    own examples once per pass in its own order, and a stream started at a saved position continues
    the uninterrupted one."""
    from train.config import ConfigError, TrainConfig
    from train.data import MIX_BLOCK, ExampleStream

    other = tmp_path / "copy"
    shutil.copytree(tiny_dataset, other)

    def take(weights, n, position=(0, 0)):
        s = ExampleStream([tiny_dataset, other], None, weights=weights, position=position)
        out = []
        for row, task, after, where in s.rows(position):
            out.append((s.groups[where[0]].folder, row["step_id"], task, after))
            if len(out) == n:
                return s, out

    s, first = take((3, 1), 800)
    share = sum(f == 0 for f, *_ in first) / len(first)
    assert 0.70 < share < 0.80, share  # expected 0.75
    assert 0.20 < sum(f == 0 for f, *_ in take((1, 3), 800)[1]) / 800 < 0.30
    per_folder = s.examples_per_epoch // 2  # 12 examples each (6 train steps, 2 tasks)
    mine = [(sid, t) for f, sid, t, _ in first if f == 1][:per_folder]
    assert len(set(mine)) == per_folder  # the lighter folder's first 12 are each of its examples once
    assert first[-1][3] == divmod(800, s.examples_per_epoch)  # position: examples / one pass of both folders
    _, later = take((3, 1), 300, position=first[499][3])
    assert later == first[500:800]
    # a resume past a block of draws
    _, far = take((3, 1), MIX_BLOCK + 10)
    assert take((3, 1), 5, position=far[MIX_BLOCK + 2][3])[1] == far[MIX_BLOCK + 3:MIX_BLOCK + 8]
    with pytest.raises(ConfigError, match="one per data folder"):
        TrainConfig(data=(str(tiny_dataset),), outdir="x", weights=(1.0, 2.0))
    with pytest.raises(ConfigError, match="must be > 0"):
        TrainConfig(data=(str(tiny_dataset), str(other)), outdir="x", weights=(1.0, 0.0))


@pytest.mark.slow
def test_worker_processes_give_the_same_examples(tiny_dataset, tiny_model, processor):
    from train.data import ExampleStream

    def take(workers):
        s = ExampleStream([tiny_dataset], processor, position=(0, 5), workers=workers, processor_path=tiny_model)
        it = iter(s)
        out = [(next(it), s.position) for _ in range(4)]
        it.close()
        return out

    for (a, pa), (b, pb) in zip(take(0), take(1)):
        assert pa == pb and a.keys() == b.keys()
        assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.slow
def test_overfits_a_fixed_batch(tiny_dataset, tiny_model, processor):
    from train.data import ExampleStream, collate
    from train.loop import forward_backward, make_optimizer, make_scheduler
    from train.model import load_base

    it = iter(ExampleStream([tiny_dataset], processor))
    batch = collate([next(it) for _ in range(2)], processor.tokenizer.pad_token_id)
    torch.manual_seed(0)
    model = load_base(tiny_model)
    model.train()
    cfg = _base_cfg(tiny_dataset, "unused", lora=False, lr=2e-3, steps=30, warmup=0)
    opt = make_optimizer(model, cfg)
    sched = make_scheduler(opt, cfg)
    losses = []
    for _ in range(cfg.steps):
        opt.zero_grad()
        losses.append(forward_backward(model, batch, torch.device("cpu"), None))
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
    assert losses[-1] < 0.5 * losses[0], losses


def test_resume_continues_the_same_run_and_refuses_other_settings(tiny_dataset, tmp_path):
    from safetensors.torch import load_file

    from train import checkpoint as ckpt
    from train.config import ConfigError
    from train.loop import train

    run = tmp_path / "run"
    cfg = _base_cfg(tiny_dataset, run)  # LoRA with dropout: the RNG state must be restored too
    summary = train(cfg, progress=False)
    assert summary["steps"] == 4 and (run / "final" / "model.safetensors").is_file()
    assert [s for s, _ in ckpt.checkpoints(run)] == [2, 4]
    uninterrupted = load_file(str(run / "final" / "model.safetensors"))
    log_before = train_log(run)
    assert [r["step"] for r in log_before] == [1, 2, 3, 4]

    # killed after step 4 was logged but before its checkpoint: only checkpoint 2 is complete
    shutil.rmtree(run / "checkpoint-000004")
    shutil.rmtree(run / "final")
    (run / "last").write_text("checkpoint-000004\n")
    (run / ".tmp-checkpoint-000004-1").mkdir()
    assert ckpt.latest(run).name == "checkpoint-000002"
    train(cfg, progress=False)
    assert_resumed_run_is_the_same(run, log_before, uninterrupted)
    assert not (run / ".tmp-checkpoint-000004-1").exists()

    with pytest.raises(ConfigError, match=r"lr: 0.001 -> 0.0005"):
        train(_base_cfg(tiny_dataset, run, lr=5e-4), progress=False)
    with pytest.raises(ConfigError, match="steps"):
        train(_base_cfg(tiny_dataset, run, steps=6), progress=False)
    # settings that do not change the training may change
    assert train(_base_cfg(tiny_dataset, run, save_every=1, eval_limit=1), progress=False)["steps"] == 4


def test_feedback_rows_train_the_revision(tiny_dataset, tmp_path, processor):
    from eval.chat import clean_messages, task_chat
    from eval.data import info, iter_rows
    from eval.feedback import assembly_rows, before_rows, feedback_example
    from eval.predict import RandomPredictor, write_predictions
    from factory.ldraw import get_reader
    from factory.render import Renderer
    from train.data import ExampleStream, encode
    from train.feedback import build_feedback

    preds = tmp_path / "preds.jsonl"
    write_predictions(tiny_dataset, RandomPredictor(0), preds, split="train", tasks=("pose",))
    out = tmp_path / "fb"
    summary = build_feedback(tiny_dataset, preds, out)
    meta = info(out)
    assert meta.source == "feedback" and meta.tasks == ("pose",) and meta.extra_images == ("feedback",)
    assert summary["total"]["steps"] >= 1
    assert sum(summary["reasons"].get(k, 0) for k in ("built", "right", "unparseable", "missing", "failed")) == 6

    rows = list(iter_rows(out, "train"))
    assert len(rows) == summary["total"]["steps"]
    row = rows[0]
    assert row["pose_images"] == ["before", "after", "part", "axes", "feedback"]
    assert [m["role"] for m in row["pose_messages"]] == ["system", "user", "assistant", "user", "assistant"]
    # the prompt is exactly what the evaluator asks after a wrong answer
    src_rows = [r for r in iter_rows(tiny_dataset, "train") if r["object_id"] == row["object_id"]]
    src = next(r for r in src_rows if r["step_id"] == row["step_id"])
    predicted = row["pose_messages"][2]["content"][0]["text"]
    with Renderer(get_reader(None)) as renderer:
        fb = feedback_example(src, predicted, before_rows(src_rows, src), renderer, int(meta.config["size"]),
                              scene=assembly_rows(src_rows, src))
    assert clean_messages(row["pose_messages"][:-1]) == fb.messages

    messages, images, answer = task_chat(row, "pose", with_answer=True)
    ex = encode(processor, messages, images)
    assert len(images) == 5 and answer == src["pose_answer"]
    assert _labelled(processor, ex) == answer + END

    stream = ExampleStream([tiny_dataset, out], processor, tasks=("selection", "pose"))
    assert stream.examples_per_epoch == 12 + len(rows)  # feedback rows give pose examples only
    it = iter(stream)
    for _ in range(stream.examples_per_epoch):
        next(it)


def test_command_line_trains_evaluates_and_leaves_a_loadable_model(tiny_dataset, tmp_path, capsys):
    from transformers import AutoModelForImageTextToText

    from train.__main__ import main

    run = tmp_path / "cli"
    argv = ["--data", str(tiny_dataset), "--outdir", str(run), "--steps", "3", "--batch-size", "2", "--lora", "0",
            "--lr", "1e-3", "--save-every", "2", "--workers", "0", "--eval-limit", "1", "--max-new-tokens", "8",
            "--no-progress"]
    assert main(argv) == 0
    for name in ("base/config.json", "checkpoint-000002/model.safetensors", "checkpoint-000003/trainer_state.pt",
                 "final/model.safetensors", "final/train_config.json", "log.jsonl", "loss.png",
                 "train_summary.json", "metrics.json", "preds_before.jsonl", "preds_after.jsonl"):
        assert (run / name).is_file(), name
    summary = json.loads((run / "train_summary.json").read_text())
    assert summary["steps"] == 3 and summary["examples"] == 6 and summary["samples_per_s"] > 0
    metrics = json.loads((run / "metrics.json").read_text())
    for name in ("before", "after"):
        assert set(metrics[name]) >= {"strict", "paper"}
        # --eval-limit 1: the one answered step of the 3-step test split is scored, not the other two
        assert metrics[name]["paper"]["counts"]["steps"] == 1 and metrics[name]["split_steps"] == 3
    assert len((run / "preds_after.jsonl").read_text().splitlines()) == 2
    AutoModelForImageTextToText.from_pretrained(str(run / "final"))
    from eval.hf import HFPredictor
    from eval.processor import load_processor

    HFPredictor(AutoModelForImageTextToText.from_pretrained(str(run / "final")), load_processor(run / "final"))
    # a changed setting is refused with a clear one-line error, exit status 2
    capsys.readouterr()
    assert main([*argv[:-1], "--lr", "5e-4", "--no-progress"]) == 2
    assert "lr: 0.001 -> 0.0005" in capsys.readouterr().err


def test_large_weights_are_saved_in_shards_and_a_run_resumes_from_them(tiny_dataset, tmp_path, monkeypatch):
    """Checkpoints and `final/` write the weights in safetensors files of at most `SHARD_SIZE`
    with an index (transformers' default, 50GB, puts an 8B model's fp32 weights in one file); a run
    resumed from such a checkpoint ends with the uninterrupted run's weights. Here `SHARD_SIZE` is
    cut to 1 MB so that the tiny model (3.6 MB in fp32) takes several files."""
    import torch

    from train import checkpoint as ckpt
    from train.loop import train

    monkeypatch.setattr(ckpt, "SHARD_SIZE", "1MB")
    run = tmp_path / "run"
    cfg = _base_cfg(tiny_dataset, run, lora=False)
    train(cfg, progress=False)
    for folder in (run / "checkpoint-000002", run / "final"):
        files = sorted(p.name for p in folder.glob("model*.safetensors"))
        assert len(files) >= 3 and "model.safetensors.index.json" in {p.name for p in folder.iterdir()}, files
        assert max(p.stat().st_size for p in folder.glob("model*.safetensors")) <= 1_100_000
        index = json.loads((folder / "model.safetensors.index.json").read_text())
        assert set(index["weight_map"].values()) == set(files)
    uninterrupted, log_before = run_weights(run), train_log(run)

    shutil.rmtree(run / "checkpoint-000004")
    shutil.rmtree(run / "final")
    train(cfg, progress=False)
    assert [r["loss"] for r in train_log(run)] == pytest.approx([r["loss"] for r in log_before], abs=1e-5)
    resumed = run_weights(run)
    assert resumed.keys() == uninterrupted.keys()
    for k in resumed:
        torch.testing.assert_close(resumed[k], uninterrupted[k], atol=1e-6, rtol=1e-5)


@pytest.mark.slow
def test_bf16_weights_train_and_resume_in_bf16(tiny_dataset, tmp_path):
    """weight_dtype=bf16 holds every weight of a full fine-tuning in bf16, and with them the AdamW
    states (what lets full fine-tuning of an 8B model fit one GPU); its checkpoints and `final/` are
    bf16, a resume continues to the same losses and weights, and resuming with another
    weight_dtype is refused."""
    import torch

    from train.config import ConfigError
    from train.loop import train

    run = tmp_path / "run"
    cfg = _base_cfg(tiny_dataset, run, lora=False, weight_dtype="bf16")
    train(cfg, progress=False)
    weights, log_before = run_weights(run), train_log(run)
    assert {v.dtype for v in weights.values()} == {torch.bfloat16}
    state = torch.load(run / "checkpoint-000004" / "trainer_state.pt", weights_only=True)
    moments = [s["exp_avg"] for s in state["optimizer"]["state"].values()]
    assert moments and {m.dtype for m in moments} == {torch.bfloat16}
    assert all(abs(r["loss"]) < float("inf") for r in log_before)
    # the weights moved: bf16 did not round the updates away (lr 1e-3, 4 AdamW steps)
    from safetensors.torch import load_file

    base = {k: v.to(torch.bfloat16) for f in (run / "base").glob("*.safetensors") for k, v in load_file(str(f)).items()}
    changed = sum(int((weights[k] != base[k]).sum()) for k in weights if k in base)
    assert changed > 0.5 * sum(v.numel() for k, v in weights.items() if k in base)

    shutil.rmtree(run / "checkpoint-000004")
    shutil.rmtree(run / "final")
    train(cfg, progress=False)
    assert [r["loss"] for r in train_log(run)] == pytest.approx([r["loss"] for r in log_before], abs=1e-5)
    resumed = run_weights(run)
    for k in resumed:
        torch.testing.assert_close(resumed[k], weights[k], atol=0, rtol=0)
    with pytest.raises(ConfigError, match=r"weight_dtype: 'bf16' -> 'fp32'"):
        train(_base_cfg(tiny_dataset, run, lora=False, weight_dtype="fp32"), progress=False)
