"""Every supported model family end to end on the session's tiny dataset: a tiny checkpoint folder
of each (`train.tiny`) loads through the transformers auto classes with its own chat template and
processor, its answer-only labels are right token by token, and `python -m train --model FOLDER`
trains 4 steps, resumes from a checkpoint and evaluates the base and trained models."""

from __future__ import annotations

import json
import shutil

import pytest
from training_support import assert_resumed_run_is_the_same, train_log

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")
pytest.importorskip("peft")

EXPECTED = {
    # family: (model class, processor class, template, end of turn, image placeholder in the
    # rendered chat, image token the processor expands it into)
    "qwen2-vl": ("Qwen2VLForConditionalGeneration", "Qwen2VLProcessor", "QWEN2_VL", "<|im_end|>",
                 "<|vision_start|><|image_pad|><|vision_end|>", "<|image_pad|>"),
    "qwen2.5-vl": ("Qwen2_5_VLForConditionalGeneration", "Qwen2_5_VLProcessor", "QWEN2_VL", "<|im_end|>",
                   "<|vision_start|><|image_pad|><|vision_end|>", "<|image_pad|>"),
    "qwen3-vl": ("Qwen3VLForConditionalGeneration", "Qwen3VLProcessor", "QWEN3_VL_THINKING", "<|im_end|>",
                 "<|vision_start|><|image_pad|><|vision_end|>", "<|image_pad|>"),
    "gemma3": ("Gemma3ForConditionalGeneration", "Gemma3Processor", "GEMMA3", "<end_of_turn>",
               "<start_of_image>", "<image_soft_token>"),
    "internvl3": ("InternVLForConditionalGeneration", "InternVLProcessor", "INTERNVL", "<|im_end|>",
                  "<IMG_CONTEXT>\n", "<IMG_CONTEXT>"),
}
FAMILIES = list(EXPECTED)


@pytest.fixture(scope="module")
def texts(tiny_dataset):
    from train.tiny import dataset_texts

    return dataset_texts([tiny_dataset])


@pytest.fixture(scope="module")
def folders(texts, tmp_path_factory):
    """Each family's tiny checkpoint folder, built on first use."""
    from train.tiny import build_tiny_model

    root = tmp_path_factory.mktemp("families")
    built = {}

    def get(name):
        if name not in built:
            built[name] = build_tiny_model(root / name, texts, seed=0, family_name=name)
        return built[name]

    return get


def _first_row(dataset, split="train"):
    from eval.data import iter_rows

    return next(iter_rows(dataset, split))


def test_family_names_and_refusals(tiny_dataset):
    from train.config import FAMILY_NAMES, ConfigError, TrainConfig
    from train.tiny import FAMILIES as BUILT
    from train.tiny import family

    assert tuple(BUILT) == FAMILY_NAMES == tuple(FAMILIES)
    with pytest.raises(ValueError, match="unknown model family 'llava'; valid: qwen2-vl, qwen2.5-vl, qwen3-vl, "
                                         "gemma3, internvl3"):
        family("llava")
    with pytest.raises(ConfigError, match=r"base_family='llava' is not valid; valid: qwen2-vl, .*internvl3"):
        TrainConfig(data=(str(tiny_dataset),), outdir="x", base_family="llava")


def test_command_line_builds_a_family_folder(folders, tiny_dataset, tmp_path, capsys):
    from train.tiny import main

    assert main(["--family", "llava", "--data", str(tiny_dataset), "--out", str(tmp_path / "x")]) == 2
    assert "--family 'llava' is not valid; valid: qwen2-vl, qwen2.5-vl, qwen3-vl, gemma3, internvl3" in \
        capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert main(["--family", "gemma3", "--data", str(tiny_dataset), "--out", str(tmp_path / "g")]) == 0
    for file in ("model.safetensors", "tokenizer.json", "chat_template.jinja", "processor_config.json"):
        assert (tmp_path / "g" / file).read_bytes() == (folders("gemma3") / file).read_bytes(), file


@pytest.mark.parametrize("name", FAMILIES)
def test_folder_loads_through_the_auto_classes(name, folders, texts, tmp_path):
    from transformers import AutoConfig, AutoModelForImageTextToText

    from train import templates
    from eval.processor import load_processor
    from train.tiny import build_tiny_model

    model_cls, processor_cls, template, end, _, image_token = EXPECTED[name]
    folder = folders(name)
    model = AutoModelForImageTextToText.from_pretrained(str(folder))
    assert type(model).__name__ == model_cls
    processor = load_processor(folder)
    assert type(processor).__name__ == processor_cls
    assert processor.chat_template == getattr(templates, template)
    tok = processor.tokenizer
    image_id = tok.convert_tokens_to_ids(image_token)
    cfg = AutoConfig.from_pretrained(str(folder))
    assert getattr(cfg, "image_token_id", getattr(cfg, "image_token_index", None)) == image_id
    assert tok.convert_tokens_to_ids(end) in model.generation_config.eos_token_id
    assert 0.2e6 < sum(p.numel() for p in model.parameters()) < 20e6
    again = build_tiny_model(tmp_path / "again", texts, seed=0, family_name=name)
    for file in ("model.safetensors", "tokenizer.json", "config.json", "processor_config.json"):
        assert (again / file).read_bytes() == (folder / file).read_bytes(), file


@pytest.mark.parametrize("name", FAMILIES)
@pytest.mark.parametrize("task", ["selection", "pose"])
def test_labels_are_the_answer_and_end_of_turn_token_by_token(name, task, folders, tiny_dataset):
    from eval.chat import task_chat
    from train.data import encode
    from eval.processor import load_processor

    *_, end, placeholder, image_token = EXPECTED[name]
    processor = load_processor(folders(name))
    tok = processor.tokenizer
    messages, images, answer = task_chat(_first_row(tiny_dataset), task, with_answer=True)
    ex = encode(processor, messages, images, max_length=4096)
    ids, labels = ex["input_ids"], ex["labels"]
    trained = (labels != -100).nonzero().flatten().tolist()
    assert trained == list(range(trained[0], trained[-1] + 1))  # one span
    # token by token: the answer's own tokens, then the end-of-turn token, and nothing else
    want = tok(answer, add_special_tokens=False)["input_ids"] + [tok.convert_tokens_to_ids(end)]
    assert ids[trained].tolist() == want
    assert labels[trained].tolist() == want
    assert tok.decode(ids[trained]) == answer + end
    assert ids[trained[-1] + 1:].tolist() == tok("\n", add_special_tokens=False)["input_ids"]  # not trained
    # every image token is context, and each image expanded to several of them
    rendered = processor.apply_chat_template(messages, tokenize=False)
    assert rendered.count(placeholder) == len(images)
    is_image = ids == tok.convert_tokens_to_ids(image_token)
    assert int(is_image.sum()) >= 4 * len(images) and not bool((labels[is_image] != -100).any())
    before = tok.decode(ids[:trained[0]])
    if name == "qwen3-vl":  # the template's empty think block sits between prompt and answer, untrained
        assert before.endswith("<|im_start|>assistant\n<think>\n\n</think>\n\n")
    if name == "gemma3":  # the template renders <bos>; nothing adds a second
        assert before.startswith("<bos><start_of_turn>user\n") and before.count("<bos>") == 1
        assert before.endswith("<end_of_turn>\n<start_of_turn>model\n")


@pytest.mark.parametrize("name", FAMILIES)
def test_only_the_final_answer_of_a_feedback_chat_is_trained(name, folders, tiny_dataset):
    from eval.chat import task_chat
    from train.data import encode
    from eval.processor import load_processor

    end = EXPECTED[name][3]
    processor = load_processor(folders(name))
    messages, images, answer = task_chat(_first_row(tiny_dataset), "pose", with_answer=True)
    wrong = {"role": "assistant", "content": [{"type": "text", "text": "Brick 1:\nTranslation:\nx=1.0, y=2.0, z=3.0"}]}
    again = {"role": "user", "content": [{"type": "text", "text": "The placement is not right. Try again."}]}
    ex = encode(processor, [*messages[:-1], wrong, again, messages[-1]], images)
    assert processor.tokenizer.decode(ex["input_ids"][ex["labels"] != -100]) == answer + end


@pytest.mark.slow
@pytest.mark.parametrize("name", FAMILIES)
def test_trains_resumes_and_evaluates_from_a_local_folder(name, folders, tiny_dataset, tmp_path):
    from safetensors.torch import load_file
    from transformers import AutoModelForImageTextToText

    from train import checkpoint as ckpt
    from train.__main__ import main
    from eval.processor import load_processor

    folder = folders(name)
    run = tmp_path / "run"
    argv = ["--data", str(tiny_dataset), "--outdir", str(run), "--model", str(folder), "--steps", "4",
            "--batch-size", "2", "--lr", "1e-3", "--warmup", "1", "--save-every", "2", "--keep-checkpoints", "0",
            "--workers", "0", "--no-progress"]
    assert main([*argv, "--no-eval"]) == 0  # LoRA (the default for a --model checkpoint)
    assert [s for s, _ in ckpt.checkpoints(run)] == [2, 4]
    first = train_log(run)
    assert [r["step"] for r in first] == [1, 2, 3, 4] and all(r["loss"] > 0 for r in first)
    uninterrupted = load_file(str(run / "final" / "model.safetensors"))

    # killed after step 4 was logged, before its checkpoint: the re-run resumes at step 2
    shutil.rmtree(run / "checkpoint-000004")
    shutil.rmtree(run / "final")
    (run / "last").write_text("checkpoint-000002\n")
    assert main([*argv, "--eval-limit", "1", "--max-new-tokens", "8"]) == 0
    assert_resumed_run_is_the_same(run, first, uninterrupted)

    # the before/after evaluation: the local folder, then the trained model
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["before_model"] == str(folder) and metrics["after_model"] == str(run / "final")
    for which in ("before", "after"):
        assert metrics[which]["paper"]["counts"]["steps"] == 1
        assert (run / f"preds_{which}.jsonl").read_text().strip()
    final = AutoModelForImageTextToText.from_pretrained(str(run / "final"))
    assert type(final).__name__ == EXPECTED[name][0]
    assert type(load_processor(run / "final")).__name__ == EXPECTED[name][1]
