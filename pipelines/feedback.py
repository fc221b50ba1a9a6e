"""World-feedback correction rows from a model's wrong pose answers: a source of the dataset builder.

    python -m pipelines.feedback --data OUT --pred preds.jsonl --out OUT_FB [--split train]
    python -m train.feedback ...            (the same command)

For each pose answer in `preds.jsonl` (`eval.predict` output on `--split` of OUT) that parses and
fails its step in paper mode, `eval.feedback.feedback_example` executes it in the simulator, renders
the predicted placement (red outline) and where each brick ended up (solid red) and writes the
revision prompt (`--static-feedback`: the placement drawn in red where it was put, errors only); the row goes to OUT_FB with `pose_messages` = the pose prompt,
the wrong answer (assistant), the feedback turn (user, with the `feedback` image) and the right
answer (assistant), and `pose_images` = the pose images then `feedback`. The trainer learns the
last turn only, so the model is taught to revise a wrong pose given what the simulator showed.

OUT_FB is written by the dataset builder (`pipelines.dataset.build`) like every other dataset:
a `DatasetConfig` of source `feedback` (its `FeedbackSpec` names the dataset, the split, the
predictions file and its sha256, and the split's objects), one shard per `objects_per_shard`
objects of the split (each object one row group of its wrong answers), temporary files renamed
into place, completion markers, resume of a killed run, `meta/info.json` (a `DatasetInfo` of
source `feedback`, tasks `["pose"]`, the `feedback` image column, where the rows came from and
the count of pose answers by reason: built, right, unparseable, missing, failed), the dataset card
and gallery. Every row is in the train split (`python -m train --data OUT --data OUT_FB` mixes
them into training, pose only). Other predictions make another config: the folder is refused.

The source reads the answers and the rows through `eval` (the parser, the metrics, the feedback
renderer), which the builder does not import, so this module makes the source and hands it to
`build` (`FeedbackSource`; picklable, for worker processes).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import pyarrow.parquet as pq

from eval.data import DatasetError, info, library, shard_files
from eval.feedback import assembly_rows, before_rows, feedback_example, revision_messages
from eval.parse import parse_pose
from eval.score import PredictionsError, read_predictions
from factory.cli import ArgumentParser, add_progress_flag
from factory.dataset.info import read_info
from factory.dataset.prompts import text_part
from factory.dataset.schema import arrow_schema
from factory.dataset.tasks import FEEDBACK_IMAGES, SPLITS
from factory.ldraw import get_reader
from factory.render import Renderer
from pipelines.dataset.build import build
from pipelines.dataset.config import DatasetConfig, FeedbackSpec
from pipelines.dataset.png import png_bytes
from pipelines.dataset.sources import ObjectSpec, file_sha256
from pipelines.synth import guarded

(FEEDBACK_COLUMN,) = FEEDBACK_IMAGES


def feedback_schema(physics: bool = True):
    """The dataset's Arrow schema plus the `feedback` image column (HF `Image` in the metadata) and,
    when the predictions are executed, the `settled` column (`factory.dataset.schema.EXTRA_FIELDS`)."""
    return arrow_schema(FEEDBACK_IMAGES, ("settled",) if physics else ())


def correction_messages(row: dict, predicted: str, errors: list[dict]) -> list[dict]:
    """The row's pose conversation (Parquet format) with the wrong answer, the feedback turn and the
    right answer appended: what `eval.feedback.feedback_example` asks, then its target."""
    return [*revision_messages(row, predicted, errors),
            {"role": "assistant", "content": [text_part(row["pose_answer"])]}]


def split_objects(data, split: str, step_ids: list | None = None) -> dict[str, list[tuple[str, int]]]:
    """{object id: [(shard file, row group), ...]} of `split` of dataset `data`, in dataset order
    (Parquet metadata and the `object_id` column only). `step_ids`, when given, gets the split's
    step ids appended in dataset order, read in the same pass."""
    columns = ["object_id"] if step_ids is None else ["object_id", "step_id"]
    where: dict[str, list[tuple[str, int]]] = {}
    for f in shard_files(data, split):
        pf = pq.ParquetFile(f)
        for g in range(pf.num_row_groups):
            table = pf.read_row_group(g, columns=columns)
            for oid in dict.fromkeys(table.column("object_id").to_pylist()):
                where.setdefault(oid, []).append((str(f), g))
            if step_ids is not None:
                step_ids.extend(table.column("step_id").to_pylist())
    return where


def feedback_config(data, pred, split: str = "train", objects_per_shard: int = 4, ldraw=None,
                    physics: bool = True) -> DatasetConfig:
    """The `DatasetConfig` of the correction rows of predictions `pred` on `split` of `data`: the
    source dataset's view size, library (or `ldraw`: the same library in another folder,
    `eval.data.library`) and PNG level, its objects in order; `physics` False: static feedback."""
    data, pred = Path(data), Path(pred)
    if split not in SPLITS:
        raise DatasetError(f"unknown split {split!r}; valid: {', '.join(SPLITS)}")
    src = info(data)
    if not pred.is_file():
        raise PredictionsError(f"{pred}: no such predictions file")
    objects = tuple(split_objects(data, split))
    if not objects:
        raise DatasetError(f"{data}: the {split} split has no rows")
    config = src.config
    if "size" not in config:
        raise DatasetError(f"{data}: meta/info.json's config has no view size (size): the feedback renders need it")
    spec = FeedbackSpec(dataset=str(data.resolve()), dataset_id=src.dataset_id, config_hash=src.config_hash,
                        split=split, predictions=str(pred.resolve()), predictions_sha256=file_sha256(pred),
                        objects=objects, physics=physics)
    seed = src.seed if src.seed is not None else int(config.get("seed", 0))
    ldraw = library(data, ldraw, src)
    return DatasetConfig("feedback", len(objects), seed=seed, dataset_id=f"{src.dataset_id}-feedback",
                         size=int(config["size"]), tile=int(config.get("tile", 128)),
                         objects_per_shard=objects_per_shard, png_compress_level=int(config.get("png_compress_level", 6)),
                         ldraw=ldraw, feedback=spec)


class FeedbackSource:
    """The builder's object source of a feedback `DatasetConfig`: object i is object i of the
    answered split, its rows the correction rows of its wrong pose answers (`ObjectSpec.rows`)."""

    def __init__(self, config: DatasetConfig):
        spec = config.feedback
        self.physics = spec.physics
        self.dataset_id, self.ldraw, self.size, self.level = (config.dataset_id, config.ldraw, config.size,
                                                              config.png_compress_level)
        ids: list[str] = []
        self.where = split_objects(spec.dataset, spec.split, ids)
        missing = [o for o in spec.objects if o not in self.where]
        if missing:
            raise DatasetError(f"{spec.dataset}: object {missing[0]!r} of the feedback config is not in its "
                               f"{spec.split} split any more; build the feedback dataset again into a new folder")
        self.answers, _ = read_predictions(spec.predictions, ids)

    def object(self, index: int, object_id: str) -> ObjectSpec:
        rows = [r for f, g in self.where[object_id] for r in pq.ParquetFile(f).read_row_group(g).to_pylist()]
        counts: Counter = Counter()
        built, seconds = [], {"render": 0.0, "encode": 0.0}
        # One renderer per object (its feedback renders share scenes), freed before the next object.
        with Renderer(get_reader(self.ldraw)) as renderer:
            for row in rows:
                text = self.answers.get((row["step_id"], "pose"))
                if text is None:
                    counts["missing"] += 1
                    continue
                blocks = parse_pose(text)
                if any((i + 1) not in blocks for i in range(len(row["bricks"]))):
                    counts["unparseable"] += 1
                    continue
                t = time.perf_counter()
                try:
                    fb = feedback_example(row, text, before_rows(rows, row), renderer, self.size,
                                          scene=assembly_rows(rows, row), physics=self.physics)
                except Exception as exc:  # a pose the renderer cannot draw: count it, go on
                    counts["failed"] += 1
                    counts[f"failed:{type(exc).__name__}"] += 1
                    continue
                finally:
                    seconds["render"] += time.perf_counter() - t
                if fb is None:
                    counts["right"] += 1
                    continue
                t = time.perf_counter()
                new = dict(row)
                new["dataset_id"] = self.dataset_id
                new["split"] = "train"
                new["pose_messages"] = correction_messages(row, text, fb.errors)
                new["pose_images"] = [*row["pose_images"], FEEDBACK_COLUMN]
                new[FEEDBACK_COLUMN] = {"bytes": png_bytes(fb.images[-1], self.level), "path": None}
                if self.physics:
                    new["settled"] = [{"outcome": e["outcome"], "moved_ldu": e["moved_ldu"],
                                       "connections": e["connections"], "R": e["settled_R"], "T": e["settled_T"]}
                                      for e in fb.errors]
                built.append(new)
                counts["built"] += 1
                seconds["encode"] += time.perf_counter() - t
        reasons = {k: int(v) for k, v in sorted(counts.items())}
        return ObjectSpec(object_id, "feedback", [], {"source_steps": len(rows), "reasons": reasons},
                          {"feedback": reasons}, seconds, rows=built)


def build_feedback(data, pred, out, split: str = "train", progress: bool = False, workers: int = 1,
                   objects_per_shard: int = 4, ldraw=None, physics: bool = True) -> dict:
    """Build (or resume) the correction dataset `out` from predictions `pred` on `split` of
    `data` with the dataset builder; returns its `meta/info.json` as a dict (`reasons` counts the
    pose answers by what became of them)."""
    config = feedback_config(data, pred, split, objects_per_shard, ldraw, physics)
    build(config, out, workers=workers, progress=progress, desc="feedback", source=FeedbackSource(config))
    return read_info(out).to_dict()


def summary_text(out, meta: dict) -> str:
    """The command's one line: rows, objects with rows, and the pose answers by reason."""
    reasons = ", ".join(f"{k} {v}" for k, v in meta["reasons"].items()) or "no pose answers"
    return f"{out}: {meta['total']['steps']} correction rows ({reasons})"


def parser(prog: str = "python -m pipelines.feedback") -> argparse.ArgumentParser:
    ap = ArgumentParser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="dataset folder the predictions answer")
    ap.add_argument("--pred", required=True, help="predictions file (eval.predict output)")
    ap.add_argument("--out", required=True, help="folder for the correction dataset")
    ap.add_argument("--split", default="train", choices=SPLITS, help="split of the predictions (default: train)")
    ap.add_argument("--workers", type=int, default=1, help="parallel shards (default 1: this process)")
    ap.add_argument("--objects-per-shard", type=int, default=4, help="objects of the split per shard (default 4)")
    ap.add_argument("--ldraw", help="the LDraw library the feedback renders draw parts from (default: the one "
                    "the dataset was built with)")
    ap.add_argument("--static-feedback", action="store_true",
                    help="draw each prediction where it was put, without executing it in the simulator")
    add_progress_flag(ap)
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m pipelines.feedback") -> int:
    args = parser(prog).parse_args(argv)

    def run() -> int:
        meta = build_feedback(args.data, args.pred, args.out, args.split, progress=not args.no_progress,
                              workers=args.workers, objects_per_shard=args.objects_per_shard, ldraw=args.ldraw,
                              physics=not args.static_feedback)
        print(summary_text(args.out, meta), flush=True)
        return 0

    return guarded(run)


if __name__ == "__main__":
    sys.exit(main())
