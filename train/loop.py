"""The training loop: AdamW with linear warmup and decay, gradient clipping, bf16 autocast on CUDA,
checkpoints that resume to the same trajectory, per-step logs.

`train(config)` runs or resumes the run in `config.outdir`:

1. `RUN/train_config.json` is compared with `config`: a run folder made under other settings is
   refused (`ConfigError`, listing the differences), except for the settings in
   `config.RESUME_FREE`;
2. the base model is `config.model`, or a tiny model of `config.base_family` built into
   `RUN/base/` from the train split's texts (kept, so the untrained model can be evaluated as `hf:RUN/base`);
3. with a checkpoint in the folder, weights, optimizer, scheduler, RNG and the data position are
   restored and training continues at the saved step: the examples, dropout masks and updates are
   those the uninterrupted run would have had;
4. each step appends to `RUN/log.jsonl`; checkpoints every `save_every` steps and at the end;
5. `RUN/final/` gets the trained model as plain transformers weights (LoRA merged in), the
   processor and the config, so `hf:RUN/final` and `AutoModelForImageTextToText` load it alone.
"""

from __future__ import annotations

import json
import math
import queue
import shutil
import threading
import time
from contextlib import nullcontext
from pathlib import Path

import torch
from tqdm import tqdm

from eval.data import shard_files
from eval.processor import load_processor, save_processor
from train import checkpoint as ckpt
from train.config import CONFIG_FILE, ConfigError, TrainConfig, resume_conflicts
from train.data import IGNORE, ExampleStream, collate
from train.model import ModelError, add_lora, load_adapter_weights, load_base, merged, trainable
from train.report import write_summary
from train.tiny import build_tiny_model, dataset_texts

LOG_FILE = "log.jsonl"
FINAL = "final"
BASE = "base"


# -- setup -----------------------------------------------------------------------------------------
def resolve_device(config: TrainConfig) -> torch.device:
    if config.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device=cuda but torch sees no CUDA device; valid here: cpu, auto")
    if config.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(config.device)


def autocast_dtype(config: TrainConfig, device: torch.device) -> torch.dtype | None:
    """bf16 autocast on CUDA (auto, bf16); none on CPU or with fp32."""
    if device.type == "cuda" and config.dtype in ("auto", "bf16"):
        return torch.bfloat16
    if device.type == "cpu" and config.dtype == "bf16":
        return torch.bfloat16
    return None


def weight_dtype(config: TrainConfig, device: torch.device) -> torch.dtype:
    """Frozen base weights of a LoRA run on CUDA in bf16 (half the memory); trained weights fp32."""
    if config.lora and autocast_dtype(config, device) is torch.bfloat16 and device.type == "cuda":
        return torch.bfloat16
    return torch.float32


def check_data(config: TrainConfig) -> None:
    """Every --data folder is a dataset with a train split (before anything is built)."""
    for folder in config.data:
        shard_files(folder, "train")


def check_run_folder(config: TrainConfig) -> None:
    """Refuse a run folder made under another config (see the module docstring)."""
    run = Path(config.outdir)
    path = run / CONFIG_FILE
    if not path.is_file():
        return
    saved = TrainConfig.load(run)
    conflicts = resume_conflicts(saved, config)
    if conflicts:
        hint = ("Use the same settings, or another --outdir." if ckpt.latest(run) is not None else
                "It has no checkpoint yet: delete the folder to start over with these, or use another --outdir.")
        raise ConfigError(f"{run} holds a run made with other settings, which cannot be resumed with these: "
                          + "; ".join(conflicts) + ". " + hint)


def base_model_path(config: TrainConfig, progress: bool = False) -> Path:
    """The base model folder: `config.model`, or `RUN/base` (built on first use)."""
    if config.model:
        if not (Path(config.model) / "config.json").is_file():
            raise ModelError(f"{config.model}: not a model folder (no config.json); give a local folder saved "
                             "with save_pretrained, or leave out --model for a tiny model built from a config")
        return Path(config.model)
    base = Path(config.outdir) / BASE
    if not (base / "config.json").is_file():
        if progress:
            print(f"building the {config.base_size} {config.base_family} base model into {base}", flush=True)
        build_tiny_model(base, dataset_texts(config.data), seed=config.seed, max_pixels=config.max_pixels,
                         size=config.base_size, family_name=config.base_family)
    return base


def make_optimizer(model, config: TrainConfig) -> torch.optim.Optimizer:
    """AdamW; no weight decay on biases and norm weights (1-D tensors)."""
    decay, no_decay = [], []
    for _, p in model.named_parameters():
        if p.requires_grad:
            (no_decay if p.dim() < 2 else decay).append(p)
    groups = [{"params": decay, "weight_decay": config.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    return torch.optim.AdamW([g for g in groups if g["params"]], lr=config.lr, betas=(0.9, 0.999), eps=1e-8)


def lr_lambda(config: TrainConfig):
    warm, total = min(config.warmup, config.steps), config.steps

    def f(step: int) -> float:
        if step < warm:
            return (step + 1) / warm
        return max(0.0, (total - step) / max(1, total - warm))

    return f


def make_scheduler(optimizer, config: TrainConfig):
    return torch.optim.lr_scheduler.LambdaLR(optimizer, lr_lambda(config))


def forward_backward(model, batch: dict, device: torch.device, amp: torch.dtype | None, scale: float = 1.0) -> float:
    """One forward and backward pass; returns the batch's mean answer-token loss."""
    batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
    ctx = torch.autocast(device_type=device.type, dtype=amp) if amp is not None else nullcontext()
    with ctx:
        loss = model(**batch).loss
    (loss * scale).backward()
    return float(loss.detach())


def trainable_model(model, config: TrainConfig):
    """`model` ready to train under `config`: LoRA adapters on its language model (`config.lora`,
    initialised from the current torch RNG) or every weight trainable, and gradient checkpointing
    when asked (with LoRA the inputs must require grad, or the checkpointed blocks get none)."""
    if config.lora:
        model = add_lora(model, config)
    else:
        model.requires_grad_(True)
    if config.gradient_checkpointing:
        model.gradient_checkpointing_enable(gradient_checkpointing_kwargs={"use_reentrant": False})
        if config.lora and hasattr(model, "enable_input_require_grads"):
            model.enable_input_require_grads()
    return model


def train_step(model, optimizer, scheduler, batches, config: TrainConfig, device: torch.device,
               amp: torch.dtype | None, step: int | None = None) -> dict:
    """One optimizer step (number `step`, named in the error a non-finite loss raises) over
    `config.grad_accum` batches from `batches` (a `Batches`): forward and backward, gradient
    clipping, AdamW and scheduler steps. Returns the mean loss, grad norm, the
    learning rate used, examples, tokens (non-padding, image tokens included) and answer tokens
    (labels) seen, the stream's position and skip count after the last batch, and the seconds spent
    waiting for batches (data loading the model's step did not hide)."""
    optimizer.zero_grad(set_to_none=True)
    losses, n_ex, n_tok, n_label, wait = [], 0, 0, 0, 0.0
    for _ in range(config.grad_accum):
        t = time.perf_counter()
        batch, position, skipped = next(batches)
        wait += time.perf_counter() - t
        n_ex += int(batch["input_ids"].shape[0])
        mask = batch.get("attention_mask")
        n_tok += int(mask.sum()) if mask is not None else batch["input_ids"].numel()
        n_label += int((batch["labels"] != IGNORE).sum())
        losses.append(forward_backward(model, batch, device, amp, 1.0 / config.grad_accum))
    loss = sum(losses) / len(losses)
    if not math.isfinite(loss):
        at = f" at step {step}" if step is not None else ""
        raise FloatingPointError(f"loss is {loss}{at}; lower --lr, or use --dtype fp32")
    params = [p for p in model.parameters() if p.requires_grad]
    norm = torch.nn.utils.clip_grad_norm_(params, config.max_grad_norm if config.max_grad_norm > 0 else float("inf"))
    lr = scheduler.get_last_lr()[0]
    optimizer.step()
    scheduler.step()
    return {"loss": loss, "grad_norm": float(norm), "lr": lr, "examples": n_ex, "tokens": n_tok,
            "label_tokens": n_label, "position": position, "skipped": skipped, "data_wait": wait}


# -- batches ---------------------------------------------------------------------------------------
class Batches:
    """Collated batches from an `ExampleStream`, prepared one step ahead in a thread (decoding
    PNGs and processing images overlaps the model's step). Each item carries the stream's
    position and skip count after it, which is what a checkpoint records."""

    def __init__(self, stream: ExampleStream, batch_size: int, pad_id: int, ahead: int = 2):
        self.stream, self.batch_size, self.pad_id = stream, batch_size, pad_id
        self.q: queue.Queue = queue.Queue(maxsize=ahead)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _put(self, item) -> None:
        """Queue `item`, waiting while the queue is full, unless the consumer stops first."""
        while not self.stop.is_set():
            try:
                self.q.put(item, timeout=0.2)
                return
            except queue.Full:
                continue

    def _run(self):
        it = iter(self.stream)
        try:
            while not self.stop.is_set():
                examples = [next(it) for _ in range(self.batch_size)]
                self._put((collate(examples, self.pad_id), self.stream.position, self.stream.skipped))
        except BaseException as exc:  # handed to the consumer
            self._put(exc)
        finally:
            it.close()  # ends the stream's worker processes

    def __next__(self):
        item = self.q.get()
        if isinstance(item, BaseException):
            raise item
        return item

    def close(self):
        self.stop.set()
        self.thread.join(timeout=30)


# -- the run ---------------------------------------------------------------------------------------
def _truncate_log(path: Path, step: int) -> None:
    """Drop log lines after `step` (a run killed after its last checkpoint logged them)."""
    if not path.is_file():
        return
    keep = [line for line in path.read_text().splitlines() if line.strip() and json.loads(line)["step"] <= step]
    ckpt.write_atomic_text(path, "".join(line + "\n" for line in keep))


def _gpu_mem_gb(device: torch.device) -> float | None:
    if device.type != "cuda":
        return None
    return round(torch.cuda.max_memory_allocated(device) / 2**30, 3)


def build(config: TrainConfig, device: torch.device, resume_from: Path | None, progress: bool = False):
    """(model, processor, base path) for a fresh run or a checkpoint to resume."""
    base = base_model_path(config, progress)
    processor = load_processor(base, config.max_pixels)
    torch.manual_seed(config.seed)
    wdtype = weight_dtype(config, device)
    if config.lora:
        model = trainable_model(load_base(base, wdtype), config)
        if resume_from is not None:
            load_adapter_weights(model, resume_from)
    else:
        model = trainable_model(load_base(resume_from if resume_from is not None else base, wdtype), config)
    model.to(device)
    model.train()
    return model, processor, base


def train(config: TrainConfig, progress: bool = True) -> dict:
    """Train (or resume) the run of `config`; returns the training summary (see the module docstring)."""
    run = Path(config.outdir)
    check_data(config)
    run.mkdir(parents=True, exist_ok=True)
    ckpt.remove_stale(run)
    check_run_folder(config)
    device = resolve_device(config)
    amp = autocast_dtype(config, device)
    resume_from = ckpt.latest(run)
    model, processor, base = build(config, device, resume_from, progress)
    # recorded once the settings are known to work, so a failed start leaves the folder reusable
    ckpt.write_atomic_text(run / CONFIG_FILE, config.to_json() + "\n")
    optimizer = make_optimizer(model, config)
    scheduler = make_scheduler(optimizer, config)
    state = {"step": 0, "position": (0, 0), "skipped": 0, "examples": 0, "tokens": 0, "train_seconds": 0.0}
    if resume_from is not None:
        saved = ckpt.load_state(resume_from)
        optimizer.load_state_dict(saved["optimizer"])
        scheduler.load_state_dict(saved["scheduler"])
        ckpt.set_rng_state(saved["rng"])
        state.update({k: saved[k] for k in state})
        state["position"] = tuple(state["position"])
        if progress:
            print(f"resuming {run} from {resume_from.name} (step {state['step']})", flush=True)
    log_path = run / LOG_FILE
    _truncate_log(log_path, state["step"])
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    n_train, n_all = trainable(model)
    stream = ExampleStream(config.data, processor, config.tasks, config.seed, config.shuffle_window,
                           config.max_length, state["position"], workers=config.resolved_workers(),
                           processor_path=base, max_pixels=config.max_pixels, weights=config.weights)
    pad_id = processor.tokenizer.pad_token_id
    if pad_id is None:
        pad_id = processor.tokenizer.eos_token_id
    batches = Batches(stream, config.batch_size, pad_id) if state["step"] < config.steps else None
    bar = tqdm(total=config.steps, initial=state["step"], unit="step", desc="train", disable=not progress,
               dynamic_ncols=True)
    last_loss = None
    try:
        with log_path.open("a", encoding="utf-8") as log:
            while state["step"] < config.steps:
                t0 = time.perf_counter()
                out = train_step(model, optimizer, scheduler, batches, config, device, amp, state["step"] + 1)
                last_loss, norm, lr = out["loss"], out["grad_norm"], out["lr"]
                n_ex, n_tok, position, skipped = out["examples"], out["tokens"], out["position"], out["skipped"]
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                dt = time.perf_counter() - t0
                state["step"] += 1
                state["position"], state["skipped"] = position, skipped
                state["examples"] += n_ex
                state["tokens"] += n_tok
                state["train_seconds"] += dt
                step = state["step"]
                if step % config.log_every == 0 or step == config.steps:
                    rec = {"step": step, "loss": round(last_loss, 6), "lr": lr, "grad_norm": round(float(norm), 6),
                           "samples_per_s": round(n_ex / dt, 3), "tokens_per_s": round(n_tok / dt, 1),
                           "epoch": position[0], "examples": state["examples"], "skipped": skipped,
                           "seconds": round(dt, 4)}
                    mem = _gpu_mem_gb(device)
                    if mem is not None:
                        rec["gpu_mem_gb"] = mem
                    log.write(json.dumps(rec) + "\n")
                    log.flush()
                bar.update(1)
                bar.set_postfix(loss=f"{last_loss:.4f}", lr=f"{lr:.2e}")
                if step == config.steps or (config.save_every and step % config.save_every == 0):
                    ckpt.save(run, step, model, processor, config,
                              {**state, "optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict(),
                               "rng": ckpt.rng_state()}, keep=config.keep_checkpoints)
    finally:
        bar.close()
        if batches is not None:
            batches.close()
    final = save_final(config, model, processor, base)
    summary = write_summary(run, config, state, device, trainable=n_train, parameters=n_all,
                            peak_gpu_gb=_gpu_mem_gb(device), final=final,
                            epochs=state["position"][0] + state["position"][1] / stream.examples_per_epoch)
    del model, optimizer
    return summary


def save_final(config: TrainConfig, model, processor, base: Path) -> Path:
    """`RUN/final/`: the trained model as plain transformers weights (LoRA merged), processor, config."""
    run = Path(config.outdir)
    final = run / FINAL
    if (final / "config.json").is_file() and (final / CONFIG_FILE).is_file():
        done = json.loads((final / CONFIG_FILE).read_text()).get("steps")
        if done == config.steps and _final_step(final) == config.steps:
            return final
    full = merged(model)
    tmp = ckpt.tmp_dir(run, FINAL)
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    full.save_pretrained(str(tmp), safe_serialization=True)
    save_processor(processor, tmp)
    config.save(tmp)
    (tmp / "final.json").write_text(json.dumps({"step": config.steps, "base": str(base), "lora_merged": config.lora},
                                               indent=1) + "\n")
    return ckpt.publish(tmp, final)


def _final_step(final: Path) -> int | None:
    try:
        return int(json.loads((final / "final.json").read_text())["step"])
    except (OSError, ValueError, KeyError):
        return None
