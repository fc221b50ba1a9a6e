"""Evaluate: answer a dataset's test split with baselines and score them (`eval.predict`, `eval.score`).

Uses the tiny dataset of `build_dataset.py` (built first when OUT_DIR/synth is missing). The
oracle answers every step right (step success 1.0); the heuristic (the most common catalog
brick) and random baselines are the floor a model should beat. The same as
`python -m eval.predict --data OUT --model baseline:heuristic --out preds.jsonl` and
`python -m eval.score --data OUT --pred preds.jsonl`. Guide: docs/guides/evaluate.md.

    python examples/evaluate.py out/examples
"""

import argparse
from pathlib import Path

from build_dataset import build
from eval.predict import predict_file
from eval.score import format_table, score_file


def main(out_dir):
    data = build(out_dir)
    results = {}
    for model in ("baseline:oracle", "baseline:heuristic", "baseline:random"):
        preds = Path(out_dir) / f"preds-{model.split(':')[1]}.jsonl"
        predict_file(data, model, preds)  # one JSON line per answer: {"id", "task", "text"}
        results[model] = score_file(data, preds, mode="both")  # strict and paper mode
        print(f"{model}:\n{format_table(results[model])}\n")
    assert results["baseline:oracle"]["strict"]["overall"]["step_success"] == 1.0
    return results


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", nargs="?", default="out/examples", help="output folder (default out/examples)")
    main(ap.parse_args().out_dir)
