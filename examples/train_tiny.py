"""Train: fine-tune a tiny vision-language model on the dataset for a few steps on the CPU (`train`).

Uses the tiny dataset of `build_dataset.py` (built first when OUT_DIR/synth is missing). Without
a `model` the trainer builds a tiny Qwen2-VL from a config (random weights, a tokenizer trained
on the dataset's text) into RUN/base, trains every weight for 3 steps, and writes checkpoints and
RUN/final (a plain transformers folder). The trained model then answers one test step through
`eval.predict` as `hf:RUN/final`. A tiny model learns nothing in 3 steps: this shows the
plumbing; `make train` runs 200 steps, and MODEL= a real checkpoint. Guide: docs/guides/train.md.

    python examples/train_tiny.py out/examples
"""

import argparse
from pathlib import Path

from transformers.utils import logging

from build_dataset import build
from eval.predict import predict_file
from eval.score import score_file
from train.config import TrainConfig
from train.loop import train


def main(out_dir):
    logging.disable_progress_bar()  # transformers' bars for loading and saving weights
    data = build(out_dir)
    run = Path(out_dir) / "run"
    config = TrainConfig(data=(str(data),), outdir=str(run), steps=3, lora=False, workers=0, device="cpu",
                         eval=False)  # the command line's `--no-eval`: no before/after scoring here
    summary = train(config, progress=False)  # re-running resumes (here: finds the run done)
    print(f"{summary['steps']} steps, final loss {summary['final_loss']:.3f}, {summary['samples_per_s']:.1f} samples/s")
    preds = run / "preds.jsonl"
    predict_file(data, f"hf:{run / 'final'}", preds, limit=1, max_new_tokens=16, device="cpu")
    print(preds.read_text())
    scores = score_file(data, preds, only_predicted=True)
    print("paper step success:", scores["paper"]["overall"]["step_success"])
    return summary


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", nargs="?", default="out/examples", help="output folder (default out/examples)")
    main(ap.parse_args().out_dir)
