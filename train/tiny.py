"""Tiny models of each supported family built locally: the stand-in base models when no hub is
reachable, and the test checkpoints of every family the trainer supports.

There is no model hub on the machines we train on, so `python -m train` without `--model` builds
its base model here, and the family tests build a checkpoint folder of each family here and hand
it to `--model`. A family (`FAMILIES`) is a transformers architecture with a few million random
weights, a byte-level BPE tokenizer trained on the dataset's own prompt and answer text whose
special tokens are the family's (image placeholders, turn markers, think tags), the family's chat
template as its checkpoints ship it (`train.templates`), and its own processor and image
processor classes. Everything downstream (processor, chat template, image tokens, position ids,
generation, LoRA targets) is the real code path of that family, so the trainer and evaluator
exercise what a real checkpoint would, in seconds on a CPU. The special tokens' ids in the config
are the tokenizer's, so the model finds its image tokens.

The result is a plain `save_pretrained` folder: `AutoModelForImageTextToText.from_pretrained(dir)`
and `AutoProcessor.from_pretrained(dir)` (or `eval.processor.load_processor` without torchvision)
load it. Built twice with the same texts, family and seed, the files are identical. transformers,
tokenizers and torch (the `train` extra) are imported inside the functions that build, so the
families, sizes and settings here read without them.

    python -m train.tiny --family gemma3 --data OUT --out MODEL_DIR   # then: make train MODEL=MODEL_DIR
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from factory.cli import ArgumentParser
from eval.data import iter_rows, shard_files
from eval.processor import make_processor as processor_of
from train import templates

QWEN_SPECIAL = (
    "<|endoftext|>", "<|im_start|>", "<|im_end|>",
    "<|object_ref_start|>", "<|object_ref_end|>", "<|box_start|>", "<|box_end|>",
    "<|quad_start|>", "<|quad_end|>",
    "<|vision_start|>", "<|vision_end|>", "<|vision_pad|>", "<|image_pad|>", "<|video_pad|>",
)
"""Qwen2-VL's special tokens, in its id order (ids 0.. here: the tiny vocabulary has no gap)."""

PATCH = 14
MERGE = 2
MAX_PIXELS = (PATCH * MERGE) ** 2 * 64
"""At most 64 merged image tokens per image (28 x 28 pixels each): 4 pose images cost <= 256."""


@dataclass(frozen=True)
class Family:
    """What a tiny checkpoint of one model family is made of (see the module docstring)."""

    name: str
    special: tuple[str, ...]
    """Special tokens, first in the vocabulary in this order."""
    tokens: dict[str, str | None]
    """The tokenizer's bos, eos, pad and unk tokens."""
    template: str
    """The chat template as the family's checkpoints ship it (`train.templates`)."""
    processor: str
    """The transformers processor class."""
    config: Callable
    """(token ids, vocabulary size, size settings) -> the model config."""
    image_processor: Callable
    """(max_pixels) -> the image processor."""
    stop: tuple[str, ...]
    """Tokens that end generation (the generation config's eos ids)."""
    named: dict[str, str] = field(default_factory=dict)
    """Named special tokens the processor reads off the tokenizer (`tokenizer.boi_token`, ...)."""
    added: tuple[str, ...] = ()
    """Added tokens that are not special (kept when decoding), e.g. think tags."""
    add_bos: bool = False
    """The tokenizer puts bos before every text it encodes with special tokens (Gemma)."""
    processor_kwargs: dict = field(default_factory=dict)


# -- configs ---------------------------------------------------------------------------------------
def _mrope(head_dim: int) -> list[int]:
    """Rotary dims of the temporal, height and width positions (Qwen2-VL at head_dim 128: 16, 24, 24)."""
    half = head_dim // 2
    hw = half * 3 // 8
    return [half - 2 * hw, hw, hw]


def _qwen_text(ids, vocab, s, **extra) -> dict:
    heads = s["heads"]
    return dict(vocab_size=vocab, hidden_size=s["hidden"], intermediate_size=s["hidden"] * 3,
                num_hidden_layers=s["layers"], num_attention_heads=heads, num_key_value_heads=max(1, heads // 2),
                max_position_embeddings=8192, rms_norm_eps=1e-6, tie_word_embeddings=False,
                bos_token_id=ids["<|endoftext|>"], eos_token_id=ids["<|im_end|>"], pad_token_id=ids["<|endoftext|>"],
                **extra)


def _qwen_vision_ids(ids) -> dict:
    return dict(image_token_id=ids["<|image_pad|>"], video_token_id=ids["<|video_pad|>"],
                vision_start_token_id=ids["<|vision_start|>"], vision_end_token_id=ids["<|vision_end|>"])


def _qwen2_vl_config(ids, vocab, s):
    from transformers import Qwen2VLConfig

    head_dim = s["hidden"] // s["heads"]
    text = _qwen_text(ids, vocab, s, rope_parameters={"rope_type": "default", "rope_theta": 10000.0,
                                                      "mrope_section": _mrope(head_dim)})
    vision = dict(depth=s["vision_depth"], embed_dim=s["vision_dim"], hidden_size=s["hidden"],
                  num_heads=max(1, s["vision_dim"] // 32), mlp_ratio=2, in_channels=3, patch_size=PATCH,
                  spatial_merge_size=MERGE, temporal_patch_size=2)
    return Qwen2VLConfig(text_config=text, vision_config=vision, tie_word_embeddings=False, **_qwen_vision_ids(ids))


def _qwen2_5_vl_config(ids, vocab, s):
    from transformers import Qwen2_5_VLConfig

    head_dim = s["hidden"] // s["heads"]
    text = _qwen_text(ids, vocab, s, rope_parameters={"rope_type": "default", "rope_theta": 10000.0,
                                                      "mrope_section": _mrope(head_dim)})
    # window attention in every block but the last (Qwen2.5-VL: full attention in 4 of 32)
    vision = dict(depth=s["vision_depth"], hidden_size=s["vision_dim"], intermediate_size=s["vision_dim"] * 2,
                  num_heads=max(1, s["vision_dim"] // 32), out_hidden_size=s["hidden"], in_channels=3,
                  patch_size=PATCH, spatial_merge_size=MERGE, temporal_patch_size=2, window_size=112,
                  fullatt_block_indexes=[s["vision_depth"] - 1])
    return Qwen2_5_VLConfig(text_config=text, vision_config=vision, tie_word_embeddings=False,
                            **_qwen_vision_ids(ids))


def _qwen3_vl_config(ids, vocab, s):
    from transformers import Qwen3VLConfig

    head_dim = s["hidden"] // s["heads"]
    half = head_dim // 2
    hw = half * 5 // 16  # Qwen3-VL at head_dim 128: 24, 20, 20, interleaved
    text = _qwen_text(ids, vocab, s, head_dim=head_dim,
                      rope_parameters={"rope_type": "default", "rope_theta": 5000000.0,
                                       "mrope_section": [half - 2 * hw, hw, hw], "mrope_interleaved": True})
    # DeepStack: features of the first vision block are added to the language model's early layers too
    vision = dict(depth=s["vision_depth"], hidden_size=s["vision_dim"], intermediate_size=s["vision_dim"] * 2,
                  num_heads=max(1, s["vision_dim"] // 32), out_hidden_size=s["hidden"], in_channels=3,
                  patch_size=16, spatial_merge_size=MERGE, temporal_patch_size=2, num_position_embeddings=256,
                  deepstack_visual_indexes=[0])
    return Qwen3VLConfig(text_config=text, vision_config=vision, tie_word_embeddings=False, **_qwen_vision_ids(ids))


GEMMA_IMAGE = 112
GEMMA_PATCH = 14
GEMMA_IMAGE_TOKENS = 16
"""Gemma 3 pools the 8 x 8 patches of its 112-pixel image to 4 x 4 tokens (the real model: 64 x 64
patches of an 896-pixel image to 256)."""


def _gemma3_config(ids, vocab, s):
    from transformers import Gemma3Config

    head_dim = s["hidden"] // s["heads"]
    text = dict(vocab_size=vocab, hidden_size=s["hidden"], intermediate_size=s["hidden"] * 3,
                num_hidden_layers=s["layers"], num_attention_heads=s["heads"],
                num_key_value_heads=max(1, s["heads"] // 2), head_dim=head_dim, query_pre_attn_scalar=head_dim,
                sliding_window=256, layer_types=["sliding_attention"] * (s["layers"] - 1) + ["full_attention"],
                max_position_embeddings=8192, bos_token_id=ids["<bos>"], eos_token_id=ids["<eos>"],
                pad_token_id=ids["<pad>"])
    vision = dict(hidden_size=s["vision_dim"], intermediate_size=s["vision_dim"] * 2,
                  num_hidden_layers=s["vision_depth"], num_attention_heads=max(1, s["vision_dim"] // 32),
                  image_size=GEMMA_IMAGE, patch_size=GEMMA_PATCH, vision_use_head=False)
    return Gemma3Config(text_config=text, vision_config=vision, mm_tokens_per_image=GEMMA_IMAGE_TOKENS,
                        boi_token_index=ids["<start_of_image>"], eoi_token_index=ids["<end_of_image>"],
                        image_token_index=ids["<image_soft_token>"])


INTERNVL_IMAGE = 56
INTERNVL_PATCH = 14
INTERNVL_IMAGE_TOKENS = 4
"""InternVL's 56-pixel tiles are 4 x 4 patches, pixel-shuffled by 0.5 to 2 x 2 tokens (the real
model: 448-pixel tiles, 256 tokens)."""


def _internvl_config(ids, vocab, s):
    from transformers import InternVLConfig

    text = _qwen_text(ids, vocab, s, model_type="qwen2",
                      rope_parameters={"rope_type": "default", "rope_theta": 1000000.0})
    vision = dict(hidden_size=s["vision_dim"], intermediate_size=s["vision_dim"] * 2,
                  num_hidden_layers=s["vision_depth"], num_attention_heads=max(1, s["vision_dim"] // 32),
                  image_size=[INTERNVL_IMAGE, INTERNVL_IMAGE], patch_size=[INTERNVL_PATCH, INTERNVL_PATCH])
    return InternVLConfig(vision_config=vision, text_config=text, image_token_id=ids["<IMG_CONTEXT>"],
                          image_seq_length=INTERNVL_IMAGE_TOKENS, downsample_ratio=0.5, tie_word_embeddings=False)


# -- image processors ------------------------------------------------------------------------------
def _qwen_images(patch: int, mean=None, std=None):
    def make(max_pixels: int):
        from transformers import Qwen2VLImageProcessor

        unit = (patch * MERGE) ** 2  # pixels of one merged image token; at least 4 per image
        kw = {} if mean is None else {"image_mean": mean, "image_std": std}
        return Qwen2VLImageProcessor(min_pixels=min(unit * 4, int(max_pixels)), max_pixels=int(max_pixels),
                                     patch_size=patch, merge_size=MERGE, temporal_patch_size=2, **kw)

    return make


def _gemma3_images(max_pixels: int):
    from transformers import Gemma3ImageProcessor

    return Gemma3ImageProcessor(size={"height": GEMMA_IMAGE, "width": GEMMA_IMAGE}, do_pan_and_scan=False,
                                image_mean=[0.5] * 3, image_std=[0.5] * 3)


def _internvl_images(max_pixels: int):
    from transformers import GotOcr2ImageProcessor

    # InternVL cuts an image into tiles of its input size plus a thumbnail (the real model: up to 12)
    return GotOcr2ImageProcessor(size={"height": INTERNVL_IMAGE, "width": INTERNVL_IMAGE}, crop_to_patches=True,
                                 min_patches=1, max_patches=4, image_mean=[0.485, 0.456, 0.406],
                                 image_std=[0.229, 0.224, 0.225])


_QWEN_TOKENS = {"bos": None, "eos": "<|im_end|>", "pad": "<|endoftext|>", "unk": None}

FAMILIES: dict[str, Family] = {f.name: f for f in (
    Family("qwen2-vl", QWEN_SPECIAL, _QWEN_TOKENS, templates.QWEN2_VL, "Qwen2VLProcessor", _qwen2_vl_config,
           _qwen_images(PATCH), stop=("<|im_end|>", "<|endoftext|>")),
    Family("qwen2.5-vl", QWEN_SPECIAL, _QWEN_TOKENS, templates.QWEN2_VL, "Qwen2_5_VLProcessor",
           _qwen2_5_vl_config, _qwen_images(PATCH), stop=("<|im_end|>", "<|endoftext|>")),
    Family("qwen3-vl", QWEN_SPECIAL, _QWEN_TOKENS, templates.QWEN3_VL_THINKING, "Qwen3VLProcessor",
           _qwen3_vl_config, _qwen_images(16, [0.5] * 3, [0.5] * 3), stop=("<|im_end|>", "<|endoftext|>"),
           added=("<think>", "</think>")),
    Family("gemma3", ("<pad>", "<eos>", "<bos>", "<unk>", "<mask>", "<start_of_turn>", "<end_of_turn>",
                      "<start_of_image>", "<end_of_image>", "<image_soft_token>"),
           {"bos": "<bos>", "eos": "<eos>", "pad": "<pad>", "unk": "<unk>"}, templates.GEMMA3, "Gemma3Processor",
           _gemma3_config, _gemma3_images, stop=("<eos>", "<end_of_turn>"),
           named={"boi_token": "<start_of_image>", "eoi_token": "<end_of_image>", "image_token": "<image_soft_token>"},
           add_bos=True, processor_kwargs={"image_seq_length": GEMMA_IMAGE_TOKENS}),
    Family("internvl3", (*QWEN_SPECIAL, "<img>", "</img>", "<IMG_CONTEXT>", "<video>", "<quad>", "</quad>",
                         "<ref>", "</ref>", "<box>", "</box>"),
           _QWEN_TOKENS, templates.INTERNVL, "InternVLProcessor", _internvl_config, _internvl_images,
           stop=("<|im_end|>", "<|endoftext|>"),
           named={"start_image_token": "<img>", "end_image_token": "</img>", "context_image_token": "<IMG_CONTEXT>",
                  "video_token": "<video>"},
           processor_kwargs={"image_seq_length": INTERNVL_IMAGE_TOKENS}),
)}
"""The families a tiny checkpoint can be built of, by name. Qwen2.5-VL ships Qwen2-VL's template;
Qwen3-VL is the Thinking variant's template (think tags); InternVL3 has a Qwen2 language model."""

SIZES = {
    "tiny": dict(hidden=128, layers=2, heads=4, vision_depth=2, vision_dim=64),
    "small": dict(hidden=512, layers=6, heads=8, vision_depth=4, vision_dim=256),
}
"""Configs a model can be built from: `tiny` (about 1M parameters, CPU tests) and `small` (about
25M, for a GPU run of the whole path); a real checkpoint is the user's own (`--model`)."""


def family(name: str) -> Family:
    """The family `name`; a clear error listing the valid ones."""
    if name not in FAMILIES:
        raise ValueError(f"unknown model family {name!r}; valid: {', '.join(FAMILIES)}")
    return FAMILIES[name]


# -- tokenizer and processor -----------------------------------------------------------------------
def train_tokenizer(texts: Iterable[str], vocab_size: int = 1024, fam: str | Family = "qwen2-vl"):
    """A byte-level BPE `tokenizers.Tokenizer` over `texts` with the family's special tokens first."""
    from tokenizers import AddedToken, Tokenizer, decoders, models, pre_tokenizers, processors, trainers

    fam = family(fam) if isinstance(fam, str) else fam
    tok = Tokenizer(models.BPE())
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=True)
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(vocab_size=vocab_size, min_frequency=2, special_tokens=list(fam.special),
                                  initial_alphabet=pre_tokenizers.ByteLevel.alphabet(), show_progress=False)
    tok.train_from_iterator(sorted(set(texts)), trainer=trainer)
    if fam.added:
        tok.add_tokens([AddedToken(t, special=False, normalized=False) for t in fam.added])
    if fam.add_bos:
        bos = fam.tokens["bos"]
        tok.post_processor = processors.TemplateProcessing(single=f"{bos} $A", pair=f"{bos} $A {bos} $B",
                                                          special_tokens=[(bos, tok.token_to_id(bos))])
    return tok


def make_processor(tokenizer, max_pixels: int = MAX_PIXELS, fam: str | Family = "qwen2-vl", image_processor=None,
                   processor_kwargs: dict | None = None):
    """The family's processor around a `tokenizers.Tokenizer` trained by `train_tokenizer`; the
    tiny image processor and processor settings unless given (`train.speed` gives a real
    checkpoint's, so image token counts are the real model's)."""
    import transformers
    from transformers import PreTrainedTokenizerFast

    fam = family(fam) if isinstance(fam, str) else fam
    named = set(fam.tokens.values()) | set(fam.named.values())
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tokenizer, bos_token=fam.tokens["bos"], eos_token=fam.tokens["eos"],
        pad_token=fam.tokens["pad"], unk_token=fam.tokens["unk"],
        additional_special_tokens=[t for t in fam.special if t not in named], extra_special_tokens=dict(fam.named),
        model_max_length=32768, padding_side="right", clean_up_tokenization_spaces=False)
    fast.chat_template = fam.template
    images = image_processor if image_processor is not None else fam.image_processor(max_pixels)
    kwargs = {**fam.processor_kwargs, **(processor_kwargs or {})}
    return processor_of(getattr(transformers, fam.processor), images, fast, fam.template, **kwargs)


def tiny_config(tokenizer, vocab_size: int, fam: str | Family = "qwen2-vl", size: str = "tiny"):
    """The family's config at `size` whose token ids are `tokenizer`'s; bos, eos and pad at the top
    level too (generation and padding read them there)."""
    fam = family(fam) if isinstance(fam, str) else fam
    if size not in SIZES:
        raise ValueError(f"unknown model size {size!r}; valid: {', '.join(SIZES)}")
    ids = {t: tokenizer.token_to_id(t) for t in (*fam.special, *fam.added)}
    cfg = fam.config(ids, vocab_size, SIZES[size])
    for key in ("bos", "eos", "pad"):
        tok = fam.tokens[key] or fam.tokens["pad"]
        setattr(cfg, f"{key}_token_id", ids[tok])
    return cfg


def build_tiny_model(out_dir, texts: Iterable[str], vocab_size: int = 1024, seed: int = 0,
                     max_pixels: int = MAX_PIXELS, size: str = "tiny", family_name: str = "qwen2-vl") -> Path:
    """Build the tiny model of a family, its tokenizer (trained on `texts`) and processor into `out_dir`.

    Written to a temporary folder beside `out_dir` and renamed, so `out_dir` is complete or absent.
    Returns `out_dir`.
    """
    import torch
    from transformers import AutoModelForImageTextToText, GenerationConfig

    from train.checkpoint import write_model_folder  # imports torch (the [train] extra), as the lines above

    fam = family(family_name)
    if size not in SIZES:
        raise ValueError(f"unknown model size {size!r}; valid: {', '.join(SIZES)}")
    out = Path(out_dir)
    tok = train_tokenizer(texts, vocab_size, fam)
    processor = make_processor(tok, max_pixels=max_pixels, fam=fam)
    n_vocab = -(-tok.get_vocab_size() // 64) * 64
    cfg = tiny_config(tok, n_vocab, fam, size)
    state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    try:
        model = AutoModelForImageTextToText.from_config(cfg).to(torch.float32)
    finally:
        torch.random.set_rng_state(state)
    model.generation_config = GenerationConfig(
        bos_token_id=cfg.bos_token_id, eos_token_id=[tok.token_to_id(t) for t in fam.stop],
        pad_token_id=cfg.pad_token_id, do_sample=False)
    return write_model_folder(model, processor, out)


def dataset_texts(folders, split: str = "train") -> list[str]:
    """The distinct message texts (system, prompts, answers, feedback turns) of `split` of each
    dataset folder: what the tiny tokenizer is trained on. Reads no image column."""
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


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m train.tiny",
                                 description="Build a tiny checkpoint folder of a model family.")
    ap.add_argument("--family", required=True, help=f"one of: {', '.join(FAMILIES)}")
    ap.add_argument("--data", action="append", required=True, help="dataset folder whose texts train the tokenizer")
    ap.add_argument("--out", required=True, help="the checkpoint folder to write")
    ap.add_argument("--size", default="tiny", help=f"one of: {', '.join(SIZES)}")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    for name, valid in (("family", FAMILIES), ("size", SIZES)):
        if getattr(args, name) not in valid:
            print(f"error: --{name} {getattr(args, name)!r} is not valid; valid: {', '.join(valid)}", file=sys.stderr)
            return 2
    texts = dataset_texts(args.data)
    if not texts:
        print(f"error: no train split texts in {', '.join(args.data)}", file=sys.stderr)
        return 2
    print(build_tiny_model(args.out, texts, seed=args.seed, size=args.size, family_name=args.family))
    return 0


if __name__ == "__main__":
    sys.exit(main())
