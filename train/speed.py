"""`python -m train.speed`: training speed and GPU memory of a real-size model on the dataset.

    python -m train.speed --family qwen3-vl-8b --mode lora --batch-size 4 --data OUT [--steps 20]
        [--warmup-steps 3] [--max-pixels P] [--weight-dtype bf16|fp32] [--no-gradient-checkpointing] [--out FILE]
    torchrun --nproc_per_node 2 -m train.speed ... [--shard ddp|fsdp [--fsdp-keep-gathered]] [--profile DIR]
    python -m train.speed --family qwen3-vl-8b --data OUT --save-model DIR [--weight-dtype bf16|fp32]

Speed and memory do not depend on the weights' values, so no checkpoint is needed: the model is
built from the exact config of a published checkpoint (`REAL`: every dimension, the vocabulary
size included, so embedding and logit memory are real) with random weights, directly on the device,
in bf16, as `python -m train --weight-dtype bf16` holds them (`--weight-dtype fp32` gives
`python -m train`'s default for full fine-tuning: fp32 weights under bf16 autocast). The tokenizer
is trained on the dataset's texts as `train.tiny` does, with the family's special tokens and real
chat template, and the processor is the family's class with the checkpoint's own image processor
settings (Qwen3-VL-8B: 16-pixel patches merged 2 x 2, 65,536 to 16,777,216 pixels per image; Gemma
3: 896 x 896 pixels, 256 image tokens), so an example has the real checkpoint's image and text
token counts up to the tokenizer's text splits.
The special tokens' ids in the config are the local tokenizer's (all below the real vocabulary
size); nothing else differs from the checkpoint's config.

The examples come from the dataset through the trainer's own example stream and collator
(`train.data`, answer-only labels, images at their stored size unless `--max-pixels` caps them,
data worker processes as `python -m train` has them), and each step is the trainer's own
(`train.loop.train_step`: AdamW, gradient clipping, bf16 autocast), with LoRA adapters
(`train.model`, needs peft) or every weight trained, and gradient checkpointing by default.

One JSON line on stdout per run: parameters (all, trainable), samples/s, tokens/s (every input
token, image tokens included), answer tokens/s, peak GPU memory (allocated and reserved by torch's
allocator), the attention implementation (`flash_attention_2` where flash-attn imports, else
`sdpa`), and `epoch_hours_40k`: hours for 40,000 examples at the measured rate. One synthetic
step gives one example per task, so 40,000 dataset steps trained on both tasks are 80,000
examples: `hours_40k_steps` is that (both tasks, as `python -m train` trains by default). A run that
runs out of GPU memory prints a row with `"fits": false`, the stage it failed in and the peak
memory, and exits 0. `--out FILE` appends the row to FILE (the whole file rewritten atomically).

Several GPUs: `torchrun --nproc_per_node N -m train.speed ...` runs one process per GPU, each on
its own examples (the stream's seed plus its rank), the model in DistributedDataParallel; the one
row (printed by rank 0) has `processes`, every process's examples and tokens over the slowest
process's timed seconds, and the largest peak memory (`--batch-size` is per process). `step_seconds_median`
is rank 0's. `--shard fsdp` (full fine-tuning only) shards the model with FSDP2 instead
(`train.distributed.shard_model`: weights, gradients and AdamW states split over the GPUs); the row
records `shard` (ddp or fsdp; none with one process), and its peak memory is per GPU (the fullest),
counted from after sharding (the random model is built whole on each GPU first, which `python -m
train` does not do: it loads the weights on the CPU and FSDP moves one block at a time).

`--profile DIR` runs `--profile-steps` more steps after the timed ones under torch.profiler and
writes each process's trace and operator tables to DIR (`train.profile`); the row gets `profile`:
their wall seconds, device kernel seconds, NCCL's share, and the seconds the GPU ran no kernel.

`--save-model DIR` times nothing: it writes the random-weight model and its processor to DIR, a
local checkpoint folder for `python -m train --model DIR` (the trainer itself at a real size).

torch and transformers (the `train` extra, seconds to import) are imported inside the functions that
build and run, so `--help` and the checks of the arguments need neither.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import itertools
import json
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from factory.cli import ArgumentParser
from eval.processor import pad_token_id, save_processor
from factory.atomic import write_atomic
from train.config import DEVICES, SHARD_MODES, ConfigError, TrainConfig
from train.tiny import (FAMILIES, MAX_PIXELS, SIZES, dataset_texts, family, make_processor, tiny_config,
                        train_tokenizer)

EXAMPLES_PROJECTED = 40_000


@dataclass(frozen=True)
class Real:
    """A published checkpoint's architecture: config.json as a dict, its processor settings, and
    the total parameter count published for it."""

    family: str
    """The `train.tiny` family whose tokenizer specials, chat template and processor class it uses."""
    config: dict
    image_processor: dict
    """Keyword arguments of the family's image processor class, as the checkpoint's preprocessor_config.json."""
    params: int
    """Published total parameters (the count the tests compare the config's with)."""
    token_ids: dict = field(default_factory=dict)
    """Config keys (top level, and `text.` in text_config) holding a special token's id -> that token."""
    processor_kwargs: dict = field(default_factory=dict)


REAL = {
    # Qwen/Qwen3-VL-8B-Instruct config.json (transformers 4.57): the same values in
    # NVIDIA/TensorRT-LLM's Qwen3-VL-8B-Instruct test config (36 layers there noted as the full
    # model's), HiDream-O1's and Cosmos-Reason2-8B's copies of it, and ollama's
    # qwen3-vl:8b-instruct metadata (block_count 36, 4096 wide, 27 vision blocks, deepstack 8/16/24).
    "qwen3-vl-8b": Real(
        family="qwen3-vl",
        config={
            "model_type": "qwen3_vl", "architectures": ["Qwen3VLForConditionalGeneration"],
            "image_token_id": 151655, "video_token_id": 151656, "vision_start_token_id": 151652,
            "vision_end_token_id": 151653, "tie_word_embeddings": False,
            "text_config": {
                "model_type": "qwen3_vl_text", "attention_bias": False, "attention_dropout": 0.0,
                "bos_token_id": 151643, "eos_token_id": 151645, "head_dim": 128, "hidden_act": "silu",
                "hidden_size": 4096, "initializer_range": 0.02, "intermediate_size": 12288,
                "max_position_embeddings": 262144, "num_attention_heads": 32, "num_hidden_layers": 36,
                "num_key_value_heads": 8, "rms_norm_eps": 1e-06,
                "rope_scaling": {"mrope_interleaved": True, "mrope_section": [24, 20, 20], "rope_type": "default"},
                "rope_theta": 5000000, "tie_word_embeddings": False, "use_cache": True, "vocab_size": 151936,
            },
            "vision_config": {
                "model_type": "qwen3_vl", "deepstack_visual_indexes": [8, 16, 24], "depth": 27,
                "hidden_act": "gelu_pytorch_tanh", "hidden_size": 1152, "in_channels": 3, "initializer_range": 0.02,
                "intermediate_size": 4304, "num_heads": 16, "num_position_embeddings": 2304, "out_hidden_size": 4096,
                "patch_size": 16, "spatial_merge_size": 2, "temporal_patch_size": 2,
            },
        },
        # preprocessor_config.json: ollama's qwen3-vl:8b metadata (patch 16, merge 2, temporal 2,
        # shortest_edge 65536, longest_edge 16777216 pixels, mean and std 0.5)
        image_processor={"patch_size": 16, "merge_size": 2, "temporal_patch_size": 2, "min_pixels": 65536,
                         "max_pixels": 16777216, "image_mean": [0.5] * 3, "image_std": [0.5] * 3},
        # 8.767B: OpenExplorer/Qwen3-VL-8B-Instruct's card, counted from the upstream checkpoint's
        # tensors (576.4M vision, 8.191B language model); the hub page rounds it to 8.77B
        params=8_767_000_000,
        token_ids={"image_token_id": "<|image_pad|>", "video_token_id": "<|video_pad|>",
                   "vision_start_token_id": "<|vision_start|>", "vision_end_token_id": "<|vision_end|>",
                   "text.bos_token_id": "<|endoftext|>", "text.eos_token_id": "<|im_end|>"},
    ),
    # google/gemma-3-12b-it config.json (transformers 4.50) names only what differs from
    # transformers' defaults; written out here with the defaults it relies on (vocab 262208, head_dim
    # 256, query_pre_attn_scalar 256, rope 1e6 global / 1e4 local, sliding window 1024 in 5 of 6
    # layers) as an LTX-2 trainer's Gemma 3 12B text encoder config spells them out in full; the
    # same values in TensorStack/TextEncoder's Gemma-3-12B-IT/config.json (hub commit 5ae4186),
    # cornball-ai/diffuseR's Gemma 3 text encoder (48 layers, 3840 wide, 16 / 8 heads) and an MLX
    # Gemma 3 12B config (head_dim 256, MLP 15360, vocab 262208).
    "gemma3-12b": Real(
        family="gemma3",
        config={
            "model_type": "gemma3", "architectures": ["Gemma3ForConditionalGeneration"],
            "boi_token_index": 255999, "eoi_token_index": 256000, "eos_token_id": [1, 106],
            "image_token_index": 262144, "initializer_range": 0.02, "mm_tokens_per_image": 256,
            "text_config": {
                "model_type": "gemma3_text", "attention_bias": False, "attention_dropout": 0.0,
                "attn_logit_softcapping": None, "final_logit_softcapping": None, "head_dim": 256,
                "hidden_activation": "gelu_pytorch_tanh", "hidden_size": 3840, "initializer_range": 0.02,
                "intermediate_size": 15360, "max_position_embeddings": 131072, "num_attention_heads": 16,
                "num_hidden_layers": 48, "num_key_value_heads": 8, "query_pre_attn_scalar": 256,
                "rms_norm_eps": 1e-06, "rope_local_base_freq": 10000,
                "rope_scaling": {"factor": 8.0, "rope_type": "linear"}, "rope_theta": 1000000,
                "sliding_window": 1024, "sliding_window_pattern": 6, "use_cache": True, "vocab_size": 262208,
            },
            "vision_config": {
                "model_type": "siglip_vision_model", "attention_dropout": 0.0, "hidden_act": "gelu_pytorch_tanh",
                "hidden_size": 1152, "image_size": 896, "intermediate_size": 4304, "layer_norm_eps": 1e-06,
                "num_attention_heads": 16, "num_channels": 3, "num_hidden_layers": 27, "patch_size": 14,
                "vision_use_head": False,
            },
        },
        # preprocessor_config.json: 896 x 896, no pan and scan, mean and std 0.5; 256 tokens per image
        image_processor={"size": {"height": 896, "width": 896}, "do_pan_and_scan": False,
                         "image_mean": [0.5] * 3, "image_std": [0.5] * 3},
        processor_kwargs={"image_seq_length": 256},
        # 12B: the size the model cards give (no page with an exact count was found); the config
        # above counts 12,187,325,040, 1.6% above it
        params=12_000_000_000,
        token_ids={"boi_token_index": "<start_of_image>", "eoi_token_index": "<end_of_image>",
                   "image_token_index": "<image_soft_token>", "bos_token_id": "<bos>", "eos_token_id": "<eos>",
                   "pad_token_id": "<pad>", "text.bos_token_id": "<bos>", "text.eos_token_id": "<eos>",
                   "text.pad_token_id": "<pad>"},
    ),
}
"""The real-size models, by `--family` name."""

CHOICES = (*REAL, *FAMILIES)
MODES = ("lora", "full")
WEIGHT_DTYPES = ("bf16", "fp32")


class SpeedError(ValueError):
    """A setting the speed run cannot use (named with the valid choices)."""


# -- the model -------------------------------------------------------------------------------------
def real_config(name: str, tokenizer=None):
    """The transformers config of `REAL[name]`; with `tokenizer`, its special tokens' ids in place
    of the checkpoint's (the tokenizer is smaller than the vocabulary, which stays real)."""
    from transformers import AutoConfig

    real = REAL[name]
    d = copy.deepcopy(real.config)
    d.pop("architectures", None)
    if tokenizer is not None:
        for key, token in real.token_ids.items():
            where, k = (d["text_config"], key[5:]) if key.startswith("text.") else (d, key)
            tid = tokenizer.token_to_id(token)
            if tid is None:
                raise SpeedError(f"the {real.family} tokenizer has no {token} (for {key})")
            where[k] = tid
    return AutoConfig.for_model(d.pop("model_type"), **d)


def count_parameters(config) -> int:
    """Parameters of the model of `config`, built on the meta device (nothing allocated)."""
    import torch
    from transformers import AutoModelForImageTextToText

    with torch.device("meta"):
        model = AutoModelForImageTextToText.from_config(config)
    return sum(p.numel() for p in model.parameters())


def attention_implementation(device) -> str:
    """`flash_attention_2` on CUDA where flash-attn imports, else `sdpa`."""
    from transformers.utils import is_flash_attn_2_available

    return "flash_attention_2" if device.type == "cuda" and is_flash_attn_2_available() else "sdpa"


def build(name: str, texts: list[str], max_pixels: int | None, size: str = "tiny"):
    """(config, processor) of `--family name`: a `REAL` model with its checkpoint's image processor,
    or a `train.tiny` family at `size` with the tiny one."""
    import transformers

    fam = family(REAL[name].family if name in REAL else name)
    tok = train_tokenizer(texts, 1024, fam)
    if name not in REAL:
        processor = make_processor(tok, max_pixels=max_pixels or MAX_PIXELS, fam=fam)
        return tiny_config(tok, -(-tok.get_vocab_size() // 64) * 64, fam, size), processor
    real = REAL[name]
    settings = dict(real.image_processor)
    if max_pixels and "max_pixels" in settings:
        settings["max_pixels"] = int(max_pixels)
        settings["min_pixels"] = min(settings["min_pixels"], int(max_pixels))
    cls = {"qwen3-vl": transformers.Qwen2VLImageProcessor, "gemma3": transformers.Gemma3ImageProcessor}[fam.name]
    processor = make_processor(tok, fam=fam, image_processor=cls(**settings), processor_kwargs=real.processor_kwargs)
    return real_config(name, tok), processor


def instantiate(config, device, dtype, attn: str):
    """The model of `config` with random weights, made directly on `device` in `dtype`."""
    import torch
    from transformers import AutoModelForImageTextToText

    with torch.device(device):
        model = AutoModelForImageTextToText.from_config(config, dtype=dtype, attn_implementation=attn)
    return model


# -- the run ---------------------------------------------------------------------------------------
def _gib(n: int) -> float:
    return round(n / 2**30, 3)


def _memory(device) -> dict:
    import torch

    if device.type != "cuda":
        return {"peak_allocated_gib": None, "peak_reserved_gib": None}
    return {"peak_allocated_gib": _gib(torch.cuda.max_memory_allocated(device)),
            "peak_reserved_gib": _gib(torch.cuda.max_memory_reserved(device))}


def measure(args, progress=print) -> dict:
    """Build the model and run `args.warmup_steps + args.steps` training steps; the JSON row."""
    import torch
    import transformers

    # torch at import (the [train] extra): loaded when a run starts, so `--help` and refusals need none
    from train.data import ExampleStream
    from train.distributed import parallel, start
    from train.loop import Batches, autocast_dtype, check_data, make_optimizer, make_scheduler, resolve_device
    from train.loop import TORCH_DTYPES, train_step, trainable_model
    from train.model import trainable
    from train.profile import profile_steps

    config = TrainConfig(data=(str(Path(args.data).resolve()),), outdir=str(Path(tempfile.gettempdir()) / "speed"),
                         steps=args.warmup_steps + args.steps + (args.profile_steps if args.profile else 0),
                         batch_size=args.batch_size, lora=args.mode == "lora",
                         gradient_checkpointing=args.gradient_checkpointing, max_length=args.max_length,
                         max_pixels=args.max_pixels or MAX_PIXELS, workers=args.workers, seed=args.seed,
                         dtype="bf16", device=args.device, eval=False, shard=args.shard,
                         fsdp_keep_gathered=args.fsdp_keep_gathered)
    check_data(config)
    # One process per GPU (torchrun): each its own device, its own examples (the stream's seed plus
    # the rank), gradients averaged by DistributedDataParallel.
    group, device = start(resolve_device(config))
    rank, world = group.rank, group.processes
    amp = autocast_dtype(config, device)
    wdtype = TORCH_DTYPES[args.weight_dtype]
    attn = attention_implementation(device)
    gpu = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    row = {"family": args.family, "mode": args.mode, "batch_size": args.batch_size, "gpu": gpu,
           "attn_implementation": attn, "weight_dtype": args.weight_dtype, "autocast": str(amp).replace("torch.", ""),
           "gradient_checkpointing": args.gradient_checkpointing, "max_pixels": args.max_pixels,
           "torch": torch.__version__, "transformers": transformers.__version__, "processes": world,
           "shard": args.shard if world > 1 else "none", "fsdp_keep_gathered": args.fsdp_keep_gathered}
    progress(f"{args.family}: {args.mode}, batch {args.batch_size}, {args.weight_dtype} weights, attention {attn}, "
             f"on {gpu}" + (f", {world} processes ({args.shard})" if world > 1 else ""))
    cfg, processor = build(args.family, dataset_texts(config.data), args.max_pixels, args.size)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    stage, batches = "model", None
    try:
        torch.manual_seed(config.seed)
        t = time.perf_counter()
        model = trainable_model(instantiate(cfg, device, wdtype, attn), config)
        model.train()
        n_train, n_all = trainable(model)
        sharded = args.shard == "fsdp" and world > 1
        stage = "shard" if sharded else stage
        model = parallel(model, group, find_unused_parameters=args.mode == "full", shard=args.shard,
                         keep_gathered=args.fsdp_keep_gathered)
        if sharded and device.type == "cuda":
            # built whole on each GPU, then sharded: the peak counts from here (python -m train loads
            # the model on the CPU and never holds it whole on a GPU)
            torch.cuda.empty_cache()
            torch.cuda.reset_peak_memory_stats(device)
        row.update(params_total=n_all, params_trainable=n_train)
        progress(f"built {n_all:,} parameters ({n_train:,} trainable) in {time.perf_counter() - t:.1f} s")
        stage = "optimizer"
        optimizer = make_optimizer(model, config)
        scheduler = make_scheduler(optimizer, config)
        with tempfile.TemporaryDirectory() as tmp:
            save_processor(processor, tmp)  # the data workers load it from here
            stream = ExampleStream(config.data, processor, config.tasks, config.seed + rank, config.shuffle_window,
                                   config.max_length, workers=config.resolved_workers(world), processor_path=tmp,
                                   max_pixels=args.max_pixels)
            batches = Batches(stream, config.batch_size, pad_token_id(processor.tokenizer))
            totals = {"examples": 0, "tokens": 0, "label_tokens": 0, "data_wait": 0.0}
            times = []
            measured = args.warmup_steps + args.steps
            for i in range(measured):
                stage = "warmup step" if i < args.warmup_steps else "timed step"
                if world > 1 and i == args.warmup_steps:
                    group.barrier()  # every process starts its timed steps together
                t = time.perf_counter()
                out = train_step(model, optimizer, scheduler, batches, config, device, amp, i + 1)
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                dt = time.perf_counter() - t
                if i >= args.warmup_steps:
                    times.append(dt)
                    for k in totals:
                        totals[k] += out[k]
                progress(f"{stage} {i + 1}/{measured}: {dt:.2f} s, loss {out['loss']:.3f}, "
                         f"{out['tokens']} tokens, data wait {out['data_wait']:.2f} s")
            skipped = out["skipped"]
            if args.profile:
                stage = "profiled step"
                numbers = itertools.count(measured + 1)  # the scheduler's step numbers go on
                step = lambda: train_step(model, optimizer, scheduler, batches, config, device, amp, next(numbers))
                row["profile"] = profile_steps(step, args.profile_steps, args.profile, rank, device)
                progress(f"profiled {args.profile_steps} steps: {row['profile']}")
    except torch.OutOfMemoryError as exc:
        row.update(fits=False, oom_stage=stage, error=str(exc).splitlines()[0][:300], **_memory(device))
        row.setdefault("params_total", count_parameters(cfg))  # out of memory before the model was whole
        return row
    finally:
        if batches is not None:
            batches.close()
    seconds = sum(times)
    memory = _memory(device)
    if world > 1:
        # All processes' examples and tokens over the slowest process's seconds; the largest peak.
        totals, seconds, memory = _gather(group, totals, seconds, memory)
    sps = totals["examples"] / seconds
    n_tasks = len(config.tasks)
    row.update(fits=True, steps=args.steps, warmup_steps=args.warmup_steps, seconds=round(seconds, 3),
               step_seconds_median=round(statistics.median(times), 4), examples=totals["examples"],
               samples_per_s=round(sps, 4), tokens_per_s=round(totals["tokens"] / seconds, 1),
               label_tokens_per_s=round(totals["label_tokens"] / seconds, 1),
               tokens_per_example=round(totals["tokens"] / totals["examples"], 1),
               data_wait_s=round(totals["data_wait"], 3), skipped_over_max_length=skipped, tasks=list(config.tasks),
               epoch_hours_40k=round(EXAMPLES_PROJECTED / sps / 3600, 3),
               hours_40k_steps=round(EXAMPLES_PROJECTED * n_tasks / sps / 3600, 3), **memory)
    return row


def _gather(group, totals: dict, seconds: float, memory: dict) -> tuple[dict, float, dict]:
    """Totals summed over the processes, seconds and memory peaks their largest."""
    keys = sorted(totals)
    summed = group.reduce([totals[k] for k in keys])
    mem_keys = sorted(k for k, v in memory.items() if v is not None)
    top = group.reduce([seconds] + [memory[k] for k in mem_keys], op="max")
    out = {k: (int(v) if isinstance(totals[k], int) else float(v)) for k, v in zip(keys, summed)}
    return out, top[0], {**memory, **dict(zip(mem_keys, top[1:]))}


def append_row(path, row: dict) -> None:
    """Append `row` as a JSON line to `path`, rewriting the whole file atomically."""
    path = Path(path)
    old = path.read_bytes() if path.is_file() else b""
    if old and not old.endswith(b"\n"):
        old += b"\n"
    write_atomic(path, old + (json.dumps(row) + "\n").encode())


def parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="python -m train.speed", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--family", required=True, help=f"one of: {', '.join(CHOICES)} (the last ones: tiny test models)")
    ap.add_argument("--size", default="tiny", help=f"size of a tiny family's model: {', '.join(SIZES)}")
    ap.add_argument("--mode", default="lora", help="lora or full (default: lora)")
    ap.add_argument("--shard", default="ddp",
                    help="under torchrun: ddp (DistributedDataParallel, the whole model on every GPU; default) or "
                         "fsdp (FSDP2: weights, gradients and AdamW states split over the GPUs; --mode full only)")
    ap.add_argument("--fsdp-keep-gathered", action="store_true",
                    help="with --shard fsdp: keep each block's gathered weights from its forward to its backward "
                         "(one all-gather per block and step less, more memory; TrainConfig.fsdp_keep_gathered)")
    ap.add_argument("--data", required=True, help="dataset folder (python -m pipelines.synth output)")
    ap.add_argument("--batch-size", type=int, default=4)
    ap.add_argument("--steps", type=int, default=10, help="timed steps (default: 10)")
    ap.add_argument("--warmup-steps", type=int, default=3, help="untimed steps first (default: 3)")
    ap.add_argument("--gradient-checkpointing", action=argparse.BooleanOptionalAction, default=True,
                    help="recompute activations in the backward pass (default: on)")
    ap.add_argument("--max-pixels", type=int, default=None,
                    help="most pixels per image, as python -m train's --max-pixels (default: the checkpoint's own "
                         "limit, so images keep their stored size)")
    ap.add_argument("--max-length", type=int, default=16384,
                    help="longer examples are skipped and counted, as in python -m train (default: 16384)")
    ap.add_argument("--weight-dtype", default="bf16",
                    help="bf16 (default; python -m train --weight-dtype bf16) or fp32 (python -m train's default "
                         "for full fine-tuning)")
    ap.add_argument("--workers", type=int, default=None, help="data worker processes (default: as python -m train)")
    ap.add_argument("--device", default="auto", help=f"one of: {', '.join(DEVICES)}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="append the JSON row to this file too")
    ap.add_argument("--profile", default=None, metavar="DIR",
                    help="after the timed steps, run --profile-steps more under torch.profiler and write each "
                         "process's trace and operator tables to DIR (train.profile); the row gets a summary")
    ap.add_argument("--profile-steps", type=int, default=3, help="steps profiled with --profile (default: 3)")
    ap.add_argument("--save-model", default=None, metavar="DIR",
                    help="instead of timing steps, write the random-weight model (in --weight-dtype) and its "
                         "processor to DIR as a local checkpoint folder that `python -m train --model DIR` takes "
                         "(safetensors files of at most 5 GB); nothing is trained")
    return ap


def check(args) -> None:
    """Every choice valid before anything is built."""
    for name, valid in (("family", CHOICES), ("mode", MODES), ("shard", SHARD_MODES), ("weight_dtype", WEIGHT_DTYPES),
                        ("size", SIZES), ("device", DEVICES)):
        if getattr(args, name) not in valid:
            flag = "--" + name.replace("_", "-")
            raise SpeedError(f"{flag} {getattr(args, name)!r} is not valid; valid: {', '.join(valid)}")
    for name in ("batch_size", "steps", "max_length", "profile_steps"):
        if getattr(args, name) < 1:
            raise SpeedError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    if args.warmup_steps < 0:
        raise SpeedError(f"--warmup-steps must be 0 or more, got {args.warmup_steps}")
    if args.shard == "fsdp" and args.mode != "full":
        raise SpeedError("--shard fsdp shards full fine-tuning only; give --mode full (LoRA: --shard ddp)")
    if args.mode == "lora" and importlib.util.find_spec("peft") is None:
        raise SpeedError("--mode lora needs peft (pip install peft), which is not installed; "
                         "--mode full runs without it")


def save_model(args, progress=print) -> dict:
    """`--save-model DIR`: the model of `--family` with random weights (seeded by `--seed`) in
    `--weight-dtype`, and its processor, written to DIR as a checkpoint folder (a temporary folder
    renamed into place: `train.checkpoint.write_model_folder`); a JSON row of what was written."""
    import torch

    # torch at import (the [train] extra): loaded when a run starts, so `--help` and refusals need none
    from train.checkpoint import write_model_folder
    from train.loop import TORCH_DTYPES, check_data, resolve_device

    out = Path(args.save_model)
    if out.exists():
        raise SpeedError(f"--save-model {out}: exists already; give a new folder")
    config = TrainConfig(data=(str(Path(args.data).resolve()),), outdir=str(out), device=args.device)
    check_data(config)
    device = resolve_device(config)
    cfg, processor = build(args.family, dataset_texts(config.data), args.max_pixels, args.size)
    wdtype = TORCH_DTYPES[args.weight_dtype]
    torch.manual_seed(args.seed)
    t = time.perf_counter()
    model = instantiate(cfg, device, wdtype, "sdpa")
    built = time.perf_counter() - t
    n = sum(p.numel() for p in model.parameters())
    progress(f"{args.family}: {n:,} parameters built in {built:.1f} s; writing {out}")
    t = time.perf_counter()
    write_model_folder(model, processor, out)
    files = sorted(out.glob("*.safetensors"))
    return {"family": args.family, "saved": str(out), "weight_dtype": args.weight_dtype,
            "parameters": n, "build_seconds": round(built, 2),
            "save_seconds": round(time.perf_counter() - t, 2), "files": len(files),
            "bytes": sum(f.stat().st_size for f in files)}


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        check(args)
        run = save_model if args.save_model else measure
        row = run(args, progress=lambda m: print(m, file=sys.stderr, flush=True))
    except (SpeedError, ConfigError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finally:
        # torch at import (the [train] extra): `--help` and the refusals above need none
        from train.distributed import end, launched_rank

        end()
    if launched_rank() == 0:  # under torchrun, one row for all processes
        print(json.dumps(row), flush=True)
        if args.out:
            append_row(args.out, row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
