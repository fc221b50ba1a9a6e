"""What a run leaves to read: `RUN/loss.png` (the loss curve from `RUN/log.jsonl`) and
`RUN/train_summary.json` (steps, time, throughput, memory, final loss)."""

from __future__ import annotations

import json
from pathlib import Path

from factory.atomic import write_atomic, write_figure

SUMMARY_FILE = "train_summary.json"
PLOT_FILE = "loss.png"


def read_log(run) -> list[dict]:
    path = Path(run) / "log.jsonl"
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def plot_loss(run, records: list[dict]) -> Path | None:
    """The loss per step (and its running mean over 10% of the steps) as `RUN/loss.png`."""
    if not records:
        return None
    import matplotlib  # optional: the [train] extra

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [r["step"] for r in records]
    loss = [r["loss"] for r in records]
    k = max(1, len(loss) // 10)
    smooth = [sum(loss[max(0, i - k + 1):i + 1]) / len(loss[max(0, i - k + 1):i + 1]) for i in range(len(loss))]
    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    ax.plot(steps, loss, lw=0.8, alpha=0.5, label="loss")
    if k > 1:
        ax.plot(steps, smooth, lw=1.8, label=f"mean of {k} steps")
    ax.set_xlabel("step")
    ax.set_ylabel("answer-token cross-entropy")
    ax.set_title(f"training loss ({Path(run).name})")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    out = Path(run) / PLOT_FILE
    write_figure(fig, out)
    plt.close(fig)
    return out


def write_summary(run, config, state: dict, device, trainable: int, parameters: int, peak_gpu_gb, final,
                  epochs: float, processes: int = 1) -> dict:
    """Write `RUN/train_summary.json` and `RUN/loss.png`; returns the summary."""
    records = read_log(run)
    secs = float(state["train_seconds"])
    summary = {
        "steps": int(state["step"]),
        "examples": int(state["examples"]),
        "tokens": int(state["tokens"]),
        "skipped_too_long": int(state["skipped"]),
        "epochs": round(float(epochs), 3),
        "train_seconds": round(secs, 3),
        "samples_per_s": round(state["examples"] / secs, 3) if secs else None,
        "tokens_per_s": round(state["tokens"] / secs, 1) if secs else None,
        "peak_gpu_mem_gb": peak_gpu_gb,
        "final_loss": records[-1]["loss"] if records else None,
        "first_loss": records[0]["loss"] if records else None,
        "device": str(device),
        "processes": int(processes),
        "examples_per_step": int(config.examples_per_step * processes),
        "lora": bool(config.lora),
        "trainable_parameters": int(trainable),
        "parameters": int(parameters),
        "final_model": str(final),
    }
    write_atomic(Path(run) / SUMMARY_FILE, (json.dumps(summary, indent=1) + "\n").encode())
    plot_loss(run, records)
    return summary
