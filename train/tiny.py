"""A tiny Qwen2-VL-architecture model built locally: the stand-in base model when no hub is reachable.

There is no model hub on the machines we train on, so `python -m train` without `--model` builds
its base model here: a Qwen2-VL (`Qwen2VLForConditionalGeneration`) with a few million random
weights, a byte-level BPE tokenizer trained on the dataset's own prompt and answer text, and the
Qwen chat template. Everything downstream (processor, chat template, image tokens, M-RoPE,
generation, LoRA targets) is the real Qwen2-VL code path, so the trainer and evaluator exercise
what a real checkpoint would, in seconds on a CPU. The special tokens and their ids in the config
are the tokenizer's, so the model finds its image tokens.

The result is a plain `save_pretrained` folder: `AutoModelForImageTextToText.from_pretrained(dir)`
and `AutoProcessor.from_pretrained(dir)` load it. Built twice with the same texts and seed, the
files are identical.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable
from pathlib import Path

SPECIAL_TOKENS = (
    "<|endoftext|>", "<|im_start|>", "<|im_end|>",
    "<|object_ref_start|>", "<|object_ref_end|>", "<|box_start|>", "<|box_end|>",
    "<|quad_start|>", "<|quad_end|>",
    "<|vision_start|>", "<|vision_end|>", "<|vision_pad|>", "<|image_pad|>", "<|video_pad|>",
)
"""Qwen2-VL's special tokens, in its id order (ids 0.. here: the tiny vocabulary has no gap)."""

CHAT_TEMPLATE = (
    "{% set image_count = namespace(value=0) %}"
    "{% for message in messages %}"
    "{% if loop.first and message['role'] != 'system' %}"
    "<|im_start|>system\nYou are a helpful assistant.<|im_end|>\n"
    "{% endif %}"
    "<|im_start|>{{ message['role'] }}\n"
    "{% if message['content'] is string %}{{ message['content'] }}<|im_end|>\n"
    "{% else %}"
    "{% for content in message['content'] %}"
    "{% if content['type'] == 'image' or 'image' in content or 'image_url' in content %}"
    "{% set image_count.value = image_count.value + 1 %}"
    "<|vision_start|><|image_pad|><|vision_end|>"
    "{% elif content['type'] == 'video' or 'video' in content %}"
    "<|vision_start|><|video_pad|><|vision_end|>"
    "{% elif 'text' in content %}{{ content['text'] }}"
    "{% endif %}"
    "{% endfor %}<|im_end|>\n"
    "{% endif %}"
    "{% endfor %}"
    "{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)
"""Qwen2-VL's chat template (less the vision ids option): `<|im_start|>role\\n...<|im_end|>\\n`
per message, each image part `<|vision_start|><|image_pad|><|vision_end|>`."""

PATCH = 14
MERGE = 2
MIN_PIXELS = (PATCH * MERGE) ** 2 * 4
"""At least 4 merged image tokens per image."""
MAX_PIXELS = (PATCH * MERGE) ** 2 * 64
"""At most 64 merged image tokens per image (28 x 28 pixels each): 4 pose images cost <= 256."""


def train_tokenizer(texts: Iterable[str], vocab_size: int = 1024):
    """A byte-level BPE `tokenizers.Tokenizer` over `texts` with the Qwen2-VL special tokens first."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers

    tok = Tokenizer(models.BPE())
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=True)
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(vocab_size=vocab_size, min_frequency=2, special_tokens=list(SPECIAL_TOKENS),
                                  initial_alphabet=pre_tokenizers.ByteLevel.alphabet(), show_progress=False)
    tok.train_from_iterator(sorted(set(texts)), trainer=trainer)
    return tok


def make_processor(tokenizer, min_pixels: int = MIN_PIXELS, max_pixels: int = MAX_PIXELS):
    """A `Qwen2VLProcessor` around a `tokenizers.Tokenizer` trained by `train_tokenizer`."""
    from transformers import PreTrainedTokenizerFast, Qwen2VLImageProcessor

    from eval.processor import make_qwen2vl_processor

    fast = PreTrainedTokenizerFast(
        tokenizer_object=tokenizer, bos_token=None, eos_token="<|im_end|>", pad_token="<|endoftext|>",
        unk_token=None,
        additional_special_tokens=[t for t in SPECIAL_TOKENS if t not in ("<|im_end|>", "<|endoftext|>")],
        model_max_length=32768, padding_side="right", clean_up_tokenization_spaces=False)
    fast.chat_template = CHAT_TEMPLATE
    images = Qwen2VLImageProcessor(min_pixels=int(min_pixels), max_pixels=int(max_pixels), patch_size=PATCH,
                                   merge_size=MERGE, temporal_patch_size=2)
    return make_qwen2vl_processor(images, fast, CHAT_TEMPLATE)


def tiny_config(tokenizer, vocab_size: int, hidden: int = 128, layers: int = 2, heads: int = 4,
                vision_depth: int = 2, vision_dim: int = 64):
    """A `Qwen2VLConfig` of a few million parameters whose token ids are `tokenizer`'s."""
    from transformers import Qwen2VLConfig

    ids = {t: tokenizer.token_to_id(t) for t in SPECIAL_TOKENS}
    head_dim = hidden // heads
    half = head_dim // 2
    hw = half * 3 // 8
    mrope = [half - 2 * hw, hw, hw]  # rotary dims of temporal, height, width positions (Qwen: 16, 24, 24)
    text = dict(vocab_size=vocab_size, hidden_size=hidden, intermediate_size=hidden * 3,
                num_hidden_layers=layers, num_attention_heads=heads, num_key_value_heads=max(1, heads // 2),
                max_position_embeddings=8192, rms_norm_eps=1e-6, tie_word_embeddings=False,
                rope_parameters={"rope_type": "default", "rope_theta": 10000.0, "mrope_section": mrope},
                bos_token_id=ids["<|endoftext|>"], eos_token_id=ids["<|im_end|>"],
                pad_token_id=ids["<|endoftext|>"])
    vision = dict(depth=vision_depth, embed_dim=vision_dim, hidden_size=hidden, num_heads=max(1, vision_dim // 32),
                  mlp_ratio=2, in_channels=3, patch_size=PATCH, spatial_merge_size=MERGE, temporal_patch_size=2)
    cfg = Qwen2VLConfig(text_config=text, vision_config=vision, image_token_id=ids["<|image_pad|>"],
                        video_token_id=ids["<|video_pad|>"], vision_start_token_id=ids["<|vision_start|>"],
                        vision_end_token_id=ids["<|vision_end|>"], tie_word_embeddings=False)
    # generation and padding read these from the top-level config too
    cfg.bos_token_id = ids["<|endoftext|>"]
    cfg.eos_token_id = ids["<|im_end|>"]
    cfg.pad_token_id = ids["<|endoftext|>"]
    return cfg


SIZES = {
    "tiny": dict(hidden=128, layers=2, heads=4, vision_depth=2, vision_dim=64),
    "small": dict(hidden=512, layers=6, heads=8, vision_depth=4, vision_dim=256),
}
"""Configs a model can be built from: `tiny` (about 1M parameters, CPU tests) and `small` (about
25M, for a GPU run of the whole path); a real checkpoint is the user's own (`--model`)."""


def build_tiny_model(out_dir, texts: Iterable[str], vocab_size: int = 1024, seed: int = 0,
                     max_pixels: int = MAX_PIXELS, size: str = "tiny") -> Path:
    """Build the tiny model, its tokenizer (trained on `texts`) and processor into `out_dir`.

    Written to a temporary folder beside `out_dir` and renamed, so `out_dir` is complete or absent.
    Returns `out_dir`.
    """
    import torch
    from transformers import GenerationConfig, Qwen2VLForConditionalGeneration

    from eval.processor import save_processor

    out = Path(out_dir)
    tok = train_tokenizer(texts, vocab_size)
    processor = make_processor(tok, max_pixels=max_pixels)
    n_vocab = -(-tok.get_vocab_size() // 64) * 64
    if size not in SIZES:
        raise ValueError(f"unknown model size {size!r}; valid: {', '.join(SIZES)}")
    cfg = tiny_config(tok, n_vocab, **SIZES[size])
    state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    try:
        model = Qwen2VLForConditionalGeneration(cfg).to(torch.float32)
    finally:
        torch.random.set_rng_state(state)
    model.generation_config = GenerationConfig(
        bos_token_id=cfg.bos_token_id, eos_token_id=cfg.eos_token_id, pad_token_id=cfg.pad_token_id,
        do_sample=False)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    model.save_pretrained(tmp, safe_serialization=True)
    save_processor(processor, tmp)
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    return out


def dataset_texts(folders, split: str = "train") -> list[str]:
    """The distinct message texts (system, prompts, answers, feedback turns) of `split` of each
    dataset folder: what the tiny tokenizer is trained on. Reads no image column."""
    from eval.data import iter_rows, shard_files

    cols = ["selection_messages", "pose_messages"]
    seen: set[str] = set()
    for folder in folders:
        try:
            shard_files(folder, split)
        except ValueError:
            continue
        for row in iter_rows(folder, split, cols):
            for c in cols:
                for m in row[c] or []:
                    for p in m["content"]:
                        if p.get("text"):
                            seen.add(p["text"])
    return sorted(seen)
