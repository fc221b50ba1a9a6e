"""Correction examples from a model's wrong pose answers: the paper's world feedback as training data.

    python -m train.feedback --data OUT --pred preds.jsonl --out OUT_FB [--split train]

For each pose answer in `preds.jsonl` (`eval.predict` output on `--split` of OUT) that parses and
fails its step in paper mode, `eval.feedback.feedback_example` renders the predicted placement in
red and writes the revision prompt; the row is written to OUT_FB with `pose_messages` = the pose
prompt, the wrong answer (assistant), the feedback turn (user, with the `feedback` image) and the
right answer (assistant), and `pose_images` = the pose images then `feedback`. The trainer learns
the last turn only, so the model is taught to revise a wrong pose given what the simulator showed.

OUT_FB is a dataset folder in the row format of `factory.dataset.schema` plus one image column,
`feedback`: `data/train-00000-of-00001.parquet` (one row group per object, written to a temporary
file and renamed) and `meta/info.json` (a `factory.dataset.DatasetInfo`, written last) with
``"source": "feedback"``, ``"tasks": ["pose"]`` (so `python -m train --data OUT --data OUT_FB`
trains only pose on it) and where the predictions and the dataset came from. Answers that get no example are counted by reason
(right, unparseable, missing, failed to render) and reported.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from eval.data import DatasetError, info, iter_objects, iter_rows, load_targets
from eval.feedback import assembly_rows, before_rows, feedback_example, revision_messages
from eval.parse import parse_pose
from eval.score import PredictionsError, read_predictions
from factory.cli import add_progress_flag, run_guarded
from factory.dataset.info import Counts, DatasetInfo, write_info
from factory.dataset.prompts import text_part
from factory.dataset.schema import arrow_schema
from factory.dataset.tasks import FEEDBACK_IMAGES
from factory.ldraw import get_reader
from factory.render import Renderer
from pipelines.dataset.png import png_bytes
from pipelines.dataset.shards import WRITER_OPTIONS
from pipelines.dataset.sources import file_sha256

(FEEDBACK_COLUMN,) = FEEDBACK_IMAGES
OUT_FILE = "train-00000-of-00001.parquet"


def feedback_schema() -> pa.Schema:
    """The dataset's Arrow schema plus the `feedback` image column (HF `Image` in the metadata)."""
    return arrow_schema(FEEDBACK_IMAGES)


def correction_messages(row: dict, predicted: str, errors: list[dict]) -> list[dict]:
    """The row's pose conversation (Parquet format) with the wrong answer, the feedback turn and the
    right answer appended: what `eval.feedback.feedback_example` asks, then its target."""
    return [*revision_messages(row, predicted, errors),
            {"role": "assistant", "content": [text_part(row["pose_answer"])]}]


def build_feedback(data, pred, out, split: str = "train", progress: bool = False) -> dict:
    """Write the correction dataset OUT from predictions `pred` on `split` of `data`; returns the counts."""
    data, pred, out = Path(data), Path(pred), Path(out)
    src = info(data)
    answers, _ = read_predictions(pred, [s.id for s in load_targets(data, split)])
    config = src.config
    reader, size = get_reader(config.get("ldraw")), int(config["size"])
    level = int(config.get("png_compress_level", 6))
    schema = feedback_schema()
    counts: Counter = Counter()
    objects = 0
    (out / "data").mkdir(parents=True, exist_ok=True)
    (out / "meta").mkdir(parents=True, exist_ok=True)
    final = out / "data" / OUT_FILE
    tmp = final.with_name(f".{final.name}.{os.getpid()}.tmp")
    writer = pq.ParquetWriter(str(tmp), schema, **WRITER_OPTIONS)
    bar = tqdm(unit="step", desc="feedback", disable=not progress, file=sys.stderr)
    try:
        for rows in iter_objects(iter_rows(data, split)):
            built = []
            # One renderer per object (its feedback renders share scenes), freed before the next object.
            with Renderer(reader) as renderer:
                for row in rows:
                    bar.update(1)
                    text = answers.get((row["step_id"], "pose"))
                    if text is None:
                        counts["missing"] += 1
                        continue
                    blocks = parse_pose(text)
                    if any((i + 1) not in blocks for i in range(len(row["bricks"]))):
                        counts["unparseable"] += 1
                        continue
                    try:
                        fb = feedback_example(row, text, before_rows(rows, row), renderer, size,
                                              scene=assembly_rows(rows, row))
                    except Exception as exc:  # a pose the renderer cannot draw: count it, go on
                        counts["failed"] += 1
                        counts[f"failed:{type(exc).__name__}"] += 1
                        continue
                    if fb is None:
                        counts["right"] += 1
                        continue
                    new = dict(row)
                    new["dataset_id"] = f"{row['dataset_id']}-feedback"
                    new["pose_messages"] = correction_messages(row, text, fb.errors)
                    new["pose_images"] = [*row["pose_images"], FEEDBACK_COLUMN]
                    new[FEEDBACK_COLUMN] = {"bytes": png_bytes(fb.images[-1], level), "path": None}
                    built.append({f.name: new.get(f.name) for f in schema})
                    counts["built"] += 1
            if built:
                writer.write_table(pa.Table.from_pylist(built, schema=schema))
                objects += 1
        writer.close()
        os.replace(tmp, final)
    except BaseException:
        writer.close()
        tmp.unlink(missing_ok=True)
        raise
    finally:
        bar.close()
    written = Counts(objects, counts["built"])
    meta = DatasetInfo(
        dataset_id=f"{src.dataset_id}-feedback",
        source="feedback",
        config=config,
        counts={"train": written},
        total=written,
        splits_present=("train",),
        tasks=("pose",),
        extra_images=FEEDBACK_IMAGES,
        details={
            "source_dataset": str(data.resolve()),
            "source_dataset_id": src.dataset_id,
            "source_config_hash": src.config_hash,
            "source_split": split,
            "predictions": str(pred.resolve()),
            "predictions_sha256": file_sha256(pred),
            "reasons": dict(sorted(counts.items())),
        },
    )
    write_info(out, meta)
    return meta.to_dict()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m train.feedback", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="dataset folder the predictions answer")
    ap.add_argument("--pred", required=True, help="predictions file (eval.predict output)")
    ap.add_argument("--out", required=True, help="folder for the correction dataset")
    ap.add_argument("--split", default="train", choices=("train", "test"), help="split of the predictions")
    add_progress_flag(ap)
    args = ap.parse_args(argv)

    def run() -> int:
        s = build_feedback(args.data, args.pred, args.out, args.split, progress=not args.no_progress)
        reasons = ", ".join(f"{k} {v}" for k, v in s["reasons"].items())
        print(f"{args.out}: {s['total']['steps']} correction rows from {s['total']['objects']} objects ({reasons})")
        return 0

    return run_guarded(run, {DatasetError: 2, PredictionsError: 2})


if __name__ == "__main__":
    sys.exit(main())
