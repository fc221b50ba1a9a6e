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

Several processes (`torchrun --nproc_per_node N -m train`, one per GPU, `train.distributed`): the
model is in DistributedDataParallel; every process reads the one example stream and a step's
`batch_size * grad_accum * N` examples are the next ones of it, each forward pass's `batch_size * N`
examples split by rank (rank r the r-th `batch_size`), each loss weighted by its share of the pass's
answer tokens, so the averaged gradient is that of one process with `batch_size * N` (dropout
masks aside: each rank draws its own). Rank 0 alone writes the run folder (checkpoints, log,
`final/`, summary) while the others wait at a barrier; the logged loss is the pass's over every
rank (all-reduced). A checkpoint records N and every rank's RNG state; it resumes with N processes
only (another count is refused, naming both).

`config.shard` fsdp (full fine-tuning): the model is sharded by FSDP2 instead
(`train.distributed.shard_model`), each process holding 1/N of the weights, gradients and AdamW
states; the examples, loss weighting, clipping and updates are as above. Its checkpoints and
`final/` hold the whole model, gathered to rank 0, and the optimizer state as the processes hold it
(`train.checkpoint`).
"""

from __future__ import annotations

import gc
import json
import math
import queue
import shutil
import threading
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from eval.data import shard_files
from eval.processor import load_processor, pad_token_id, save_processor
from train import checkpoint as ckpt
from train.config import CONFIG_FILE, ConfigError, TrainConfig, resume_conflicts
from train.data import IGNORE, ExampleStream, collate
from train.distributed import Group, end, is_sharded, parallel, start
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


TORCH_DTYPES = {"bf16": torch.bfloat16, "fp32": torch.float32}
"""The torch dtype of each weight precision named in settings (`TrainConfig.weight_dtype`, `train.speed`)."""


def weight_dtype(config: TrainConfig, device: torch.device) -> torch.dtype:
    """`config.weight_dtype`; auto: the frozen base weights of a LoRA run on CUDA in bf16 (half the
    memory), trained weights fp32."""
    if config.weight_dtype != "auto":
        return TORCH_DTYPES[config.weight_dtype]
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
               amp: torch.dtype | None, step: int | None = None, group: Group = Group()) -> dict:
    """One optimizer step (number `step`, named in the error a non-finite loss raises) over
    `config.grad_accum` batches from `batches` (a `Batches`): forward and backward, gradient
    clipping, AdamW and scheduler steps. Returns the mean loss, grad norm, the
    learning rate used, examples, tokens (non-padding, image tokens included) and answer tokens
    (labels) seen, the stream's position and skip count after the last batch, and the seconds spent
    waiting for batches (data loading the model's step did not hide).

    `group`: the processes sharing each forward pass's examples (`batches` made with its rank and
    count, `model` in DistributedDataParallel or sharded by FSDP): each rank's mean loss is
    weighted by its share of the pass's answer tokens, so the averaged gradient is one process's on
    the whole pass, and the loss and counts returned are the whole pass's (see the module
    docstring). DDP averages the gradients at a step's last backward pass only; FSDP
    reduce-scatters them after every pass (each process then keeps 1/N of them, summed over the
    passes: an unsharded gradient held over the passes would be the memory FSDP saves)."""
    optimizer.zero_grad(set_to_none=True)
    losses, n_ex, n_tok, n_label, wait = [], 0, 0, 0, 0.0
    for i in range(config.grad_accum):
        t = time.perf_counter()
        batch, counts, position, skipped = next(batches)
        wait += time.perf_counter() - t
        n_ex += counts["examples"]
        n_tok += counts["tokens"]
        n_label += counts["label_tokens"]
        if group.processes == 1:
            losses.append(forward_backward(model, batch, device, amp, 1.0 / config.grad_accum))
            continue
        share = _loss_tokens(batch["labels"]) / counts["loss_tokens"]
        # DDP: gradients averaged over the processes at the step's last backward only
        last = i == config.grad_accum - 1
        sync = model.no_sync() if isinstance(model, DistributedDataParallel) and not last else nullcontext()
        with sync:
            mean = forward_backward(model, batch, device, amp, group.processes * share / config.grad_accum)
        losses.append(mean * share)
    if group.processes > 1:
        losses = group.reduce(losses)  # each pass's loss over every rank's answer tokens
    loss = sum(losses) / len(losses)
    if not math.isfinite(loss):
        at = f" at step {step}" if step is not None else ""
        raise FloatingPointError(f"loss is {loss}{at}; lower --lr, or use --dtype fp32")
    params = [p for p in model.parameters() if p.requires_grad]
    norm = torch.nn.utils.clip_grad_norm_(params, config.max_grad_norm if config.max_grad_norm > 0 else float("inf"))
    if hasattr(norm, "full_tensor"):  # FSDP: a DTensor (the norm of every process's slices, replicated)
        norm = norm.full_tensor()
    lr = scheduler.get_last_lr()[0]
    optimizer.step()
    scheduler.step()
    return {"loss": loss, "grad_norm": float(norm), "lr": lr, "examples": n_ex, "tokens": n_tok,
            "label_tokens": n_label, "position": position, "skipped": skipped, "data_wait": wait}


# -- batches ---------------------------------------------------------------------------------------
def _loss_tokens(labels: torch.Tensor) -> int:
    """Tokens a causal LM's loss averages over: labels after the first position (shifted)."""
    return int((labels[..., 1:] != IGNORE).sum())


def pass_counts(examples: list[dict]) -> dict:
    """A forward pass's examples, tokens (non-padding, image tokens included), answer tokens
    (labels) and the tokens its loss averages over, over every rank's examples."""
    tokens = sum(int(e["attention_mask"].sum()) if "attention_mask" in e else int(e["input_ids"].numel())
                 for e in examples)
    return {"examples": len(examples), "tokens": tokens,
            "label_tokens": sum(int((e["labels"] != IGNORE).sum()) for e in examples),
            "loss_tokens": sum(_loss_tokens(e["labels"]) for e in examples)}


class Batches:
    """Collated batches from an `ExampleStream`, prepared one step ahead in a thread (decoding
    PNGs and processing images overlaps the model's step). Each item is (batch, `pass_counts`,
    the stream's position and skip count after it, which is what a checkpoint records).

    `processes` > 1: each forward pass takes `batch_size * processes` examples from the stream and
    this process (`rank`) collates the rank-th `batch_size` of them; the counts are the whole
    pass's. Every process reads (and encodes) every example, so all know the position and which
    examples were skipped."""

    def __init__(self, stream: ExampleStream, batch_size: int, pad_id: int, ahead: int = 2, rank: int = 0,
                 processes: int = 1):
        self.stream, self.batch_size, self.pad_id = stream, batch_size, pad_id
        self.rank, self.processes = rank, processes
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
                examples = [next(it) for _ in range(self.batch_size * self.processes)]
                mine = examples[self.rank * self.batch_size:(self.rank + 1) * self.batch_size]
                self._put((collate(mine, self.pad_id), pass_counts(examples), self.stream.position,
                           self.stream.skipped))
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


def build(config: TrainConfig, device: torch.device, resume_from: Path | None, progress: bool = False,
          move: bool = True):
    """(model, processor, base path) for a fresh run or a checkpoint to resume; on `device` unless
    not `move` (a model FSDP will shard stays on the CPU: it moves each unit as it shards it)."""
    base = base_model_path(config, progress)
    processor = load_processor(base, config.max_pixels)
    torch.manual_seed(config.seed)
    wdtype = weight_dtype(config, device)
    # A LoRA checkpoint holds the adapters only (loaded onto the base below); a full one, every weight.
    full_checkpoint = resume_from if resume_from is not None and not config.lora else None
    model = trainable_model(load_base(full_checkpoint or base, wdtype), config)
    if config.lora and resume_from is not None:
        load_adapter_weights(model, resume_from)
    if move:
        model.to(device)
    model.train()
    return model, processor, base


def check_processes(saved: dict, resume_from: Path, processes: int, config: TrainConfig) -> None:
    """Refuse to resume a checkpoint trained by another number of processes: its steps took
    `batch_size * grad_accum * N` examples, and each rank's RNG state is saved."""
    done = int(saved.get("processes", 1))
    if done == processes:
        return
    how = "python -m train (one process)" if done == 1 else f"torchrun --nproc_per_node {done} -m train"
    raise ConfigError(f"{resume_from} was trained by {done} process(es), {done * config.examples_per_step} examples "
                      f"per step; this run has {processes} ({processes * config.examples_per_step} per step). Resume "
                      f"it with {how} and the same settings, or use another --outdir.")


def rank_seed(seed: int, rank: int) -> int:
    """The torch seed of rank `rank` > 0 after the model is built (its own dropout masks)."""
    return int(np.random.SeedSequence([int(seed), int(rank)]).generate_state(1)[0])


def train(config: TrainConfig, progress: bool = True) -> dict:
    """Train (or resume) the run of `config`; returns the training summary (see the module
    docstring). Under torchrun, every process calls it; rank 0 returns the summary, the others
    {"rank": r, "steps": n}."""
    run = Path(config.outdir)
    check_data(config)
    check_run_folder(config)
    group, device = start(resolve_device(config))
    progress = progress and group.main
    amp = autocast_dtype(config, device)
    resume_from = ckpt.latest(run)
    saved = ckpt.load_state(resume_from) if resume_from is not None else None
    sharded = config.shard == "fsdp" and group.processes > 1
    if saved is not None:
        check_processes(saved, resume_from, group.processes, config)
        if (saved.get("shard") == "fsdp") != sharded:  # the config check refuses this first
            raise ConfigError(f"{resume_from} was written by {'an unsharded' if sharded else 'an FSDP'} run; this run "
                              f"is {'sharded by FSDP' if sharded else 'not sharded'}: use the settings it was "
                              "trained with, or another --outdir")
    if group.main:
        run.mkdir(parents=True, exist_ok=True)
        ckpt.remove_stale(run)
        base_model_path(config, progress)  # a base built from a config: by rank 0, before the others load it
    group.barrier()
    model, processor, base = build(config, device, resume_from, progress, move=not sharded)
    if group.rank:
        torch.manual_seed(rank_seed(config.seed, group.rank))
    if group.main:
        # recorded once the settings are known to work, so a failed start leaves the folder reusable
        ckpt.write_atomic_text(run / CONFIG_FILE, config.to_json() + "\n")
    wrapped = parallel(model, group, find_unused_parameters=not config.lora, shard=config.shard,
                       keep_gathered=config.fsdp_keep_gathered)
    optimizer = make_optimizer(model, config)
    scheduler = make_scheduler(optimizer, config)
    state = {"step": 0, "position": (0, 0), "skipped": 0, "examples": 0, "tokens": 0, "train_seconds": 0.0}
    if saved is not None:
        if sharded:
            ckpt.load_optimizer_shards(model, optimizer, resume_from / ckpt.OPTIMIZER_DIR)
        else:
            optimizer.load_state_dict(saved["optimizer"])
        scheduler.load_state_dict(saved["scheduler"])
        ckpt.set_rng_state(saved["rng_ranks"][group.rank] if "rng_ranks" in saved else saved["rng"])
        state.update({k: saved[k] for k in state})
        state["position"] = tuple(state["position"])
        del saved
        if progress:
            print(f"resuming {run} from {resume_from.name} (step {state['step']})", flush=True)
    log_path = run / LOG_FILE
    if group.main:
        _truncate_log(log_path, state["step"])
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    n_train, n_all = trainable(model)
    stream = ExampleStream(config.data, processor, config.tasks, config.seed, config.shuffle_window,
                           config.max_length, state["position"], workers=config.resolved_workers(group.processes),
                           processor_path=base, max_pixels=config.max_pixels, weights=config.weights)
    batches = (Batches(stream, config.batch_size, pad_token_id(processor.tokenizer), rank=group.rank, processes=group.processes)
               if state["step"] < config.steps else None)
    bar = tqdm(total=config.steps, initial=state["step"], unit="step", desc="train", disable=not progress,
               dynamic_ncols=True)
    log = log_path.open("a", encoding="utf-8") if group.main else None
    try:
        while state["step"] < config.steps:
            t0 = time.perf_counter()
            out = train_step(wrapped, optimizer, scheduler, batches, config, device, amp, state["step"] + 1, group)
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
            if log is not None and (step % config.log_every == 0 or step == config.steps):
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
                save_checkpoint(run, step, model, optimizer, scheduler, processor, config, state, group)
    finally:
        bar.close()
        if log is not None:
            log.close()
        if batches is not None:
            batches.close()
    peak = _gpu_mem_gb(device)
    if peak is not None:
        peak = group.reduce([peak], op="max")[0]  # the fullest GPU
    # a sharded model is gathered whole to rank 0 by every process
    weights = ckpt.full_model_state(model) if sharded and not final_is_current(config) else None
    # Every process lets go of the model, its optimizer and scheduler before leaving the group: FSDP's
    # parameters hold the group (through their mesh), and a gloo group last freed at interpreter
    # exit aborted a CPU rank once ("terminate called without an active exception").
    wrapped = optimizer = scheduler = out = norm = None  # (out and norm: unset when no step was left)
    if not group.main:
        del model
        gc.collect()
        end()  # its barrier waits for rank 0 to write final/ and the summary
        return {"rank": group.rank, "steps": state["step"]}
    final = save_final(config, model, processor, base, weights)
    summary = write_summary(run, config, state, device, trainable=n_train, parameters=n_all,
                            peak_gpu_gb=peak, final=final, processes=group.processes,
                            epochs=state["position"][0] + state["position"][1] / stream.examples_per_epoch)
    model = weights = None
    gc.collect()
    end()
    return summary


def save_checkpoint(run: Path, step: int, model, optimizer, scheduler, processor, config: TrainConfig, state: dict,
                    group: Group = Group()) -> None:
    """Checkpoint `step` (`train.checkpoint`), called by every process: rank 0 writes it, the
    others give their RNG states (and, sharded by FSDP, their slices of the weights and their
    optimizer files) and wait until it is whole."""
    rngs = group.gather(ckpt.rng_state())
    record = {**state, "scheduler": scheduler.state_dict(), "rng": rngs[0], "processes": group.processes,
              **({"rng_ranks": rngs} if group.processes > 1 else {})}
    if not is_sharded(model):
        if group.main:
            ckpt.save(run, step, model, processor, config, {**record, "optimizer": optimizer.state_dict()},
                      keep=config.keep_checkpoints)
        group.barrier()  # no process goes on (or ends) before the checkpoint is whole
        return
    weights = ckpt.full_model_state(model)  # rank 0's; {} on the others
    tmp = Path(group.gather(str(ckpt.tmp_dir(run, ckpt.checkpoint_name(step))))[0])  # rank 0's folder for all
    if group.main:
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
    group.barrier()
    ckpt.save_optimizer_shards(model, optimizer, tmp / ckpt.OPTIMIZER_DIR)
    group.barrier()
    if group.main:
        ckpt.save(run, step, model, processor, config, {**record, "shard": "fsdp"}, keep=config.keep_checkpoints,
                  tmp=tmp, weights=weights)
    del weights
    group.barrier()


def final_is_current(config: TrainConfig) -> bool:
    """Whether `RUN/final/` already holds this run's model trained to `config.steps`."""
    final = Path(config.outdir) / FINAL
    if (final / "config.json").is_file() and (final / CONFIG_FILE).is_file():
        done = json.loads((final / CONFIG_FILE).read_text()).get("steps")
        return done == config.steps and final_step(final) == config.steps
    return False


def save_final(config: TrainConfig, model, processor, base: Path, weights: dict | None = None) -> Path:
    """`RUN/final/`: the trained model as plain transformers weights (LoRA merged), processor, config.
    `weights`: a model sharded by FSDP gathered whole (`train.checkpoint.full_model_state`)."""
    run = Path(config.outdir)
    final = run / FINAL
    if final_is_current(config):
        return final
    full = merged(model)
    tmp = ckpt.fresh_tmp(run, FINAL)
    ckpt.save_model(full, tmp, weights)
    save_processor(processor, tmp)
    config.save(tmp)
    (tmp / "final.json").write_text(json.dumps({"step": config.steps, "base": str(base), "lora_merged": config.lora},
                                               indent=1) + "\n")
    return ckpt.publish(tmp, final)


def final_step(final: Path) -> int | None:
    """The step a `final/` folder was trained to (its final.json), None if it has none or the file
    does not hold one (a damaged file: the stage is trained again)."""
    try:
        return int(json.loads((final / "final.json").read_text())["step"])
    except (OSError, ValueError, KeyError, TypeError):  # TypeError: not an object, or a null step
        return None
