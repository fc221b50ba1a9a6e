"""World-feedback rows as a source of the dataset builder (`pipelines.feedback`): one row per wrong
pose answer, shards, resume to the same bytes, a changed source refused, the command line, and
feedback folders written before the builder wrote them still read."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from factory.dataset.info import INFO_SOURCES
from ldraw_support import LDRAW as SHARED_LDRAW


@pytest.fixture(scope="module")
def random_preds(tiny_dataset, tmp_path_factory):
    """Random pose answers on the tiny dataset's train split (they parse and are mostly wrong)."""
    from eval.predict import RandomPredictor, write_predictions

    path = tmp_path_factory.mktemp("fbpred") / "preds.jsonl"
    write_predictions(tiny_dataset, RandomPredictor(0), path, split="train", tasks=("pose",))
    return path


def _wrong_answers(dataset, preds) -> set[str]:
    """Step ids whose pose answer parses and fails in paper mode (what gets feedback), found here
    from the predictions and the rows alone."""
    from eval.data import iter_rows
    from eval.feedback import pose_errors

    answers = {r["id"]: r["text"] for r in map(json.loads, preds.read_text().splitlines()) if r["task"] == "pose"}
    return {row["step_id"] for row in iter_rows(dataset, "train", ["step_id", "object_id", "bricks"])
            if pose_errors(row, answers.get(row["step_id"])) is not None}


def _data_bytes(out) -> dict:
    return {p.name: p.read_bytes() for p in sorted((out / "data").iterdir())}


def test_feedback_rows_are_built_by_the_builder_and_resume(tiny_dataset, random_preds, tmp_path):
    from eval.data import info, iter_rows
    from pipelines.dataset.build import ConfigMismatchError
    from pipelines.feedback import build_feedback

    out = tmp_path / "fb"
    meta = build_feedback(tiny_dataset, random_preds, out, objects_per_shard=1)
    wrong = _wrong_answers(tiny_dataset, random_preds)
    rows = list(iter_rows(out, "train"))
    assert wrong and sorted(r["step_id"] for r in rows) == sorted(wrong)
    assert all(r["split"] == "train" and r["pose_images"][-1] == "feedback" for r in rows)
    typed = info(out)
    assert typed.source == "feedback" and typed.tasks == ("pose",) and typed.extra_images == ("feedback",)
    assert typed.config["source"] == "feedback" and typed.config_hash and typed.num_shards == 2
    assert meta["reasons"]["built"] == len(rows) == meta["total"]["steps"]
    assert sum(meta["reasons"].get(k, 0) for k in ("built", "right", "unparseable", "missing", "failed")) == 6
    assert meta["source_dataset"] == str(tiny_dataset.resolve()) and meta["source_split"] == "train"
    assert (out / "README.md").is_file() and (out / "meta" / "shards" / "00001.json").is_file()
    # Each wrong prediction was executed: per brick its outcome and settled pose, said in the turn too.
    from factory.dataset.prompts import settle_sentence
    from factory.physics.settle import OUTCOMES

    for r in rows:
        assert len(r["settled"]) == len(r["bricks"])
        for k, s in enumerate(r["settled"], 1):
            assert s["outcome"] in OUTCOMES and len(s["T"]) == 3 and np.asarray(s["R"]).shape == (3, 3)
            turn = r["pose_messages"][-2]["content"][-1]["text"]
            assert f"Brick {k}: {settle_sentence(s)}." in turn
    before = _data_bytes(out)

    # a killed build: one shard's marker and file gone, a temporary file left; the re-run builds that shard again
    (out / "meta" / "shards" / "00000.json").unlink()
    next((out / "data").glob("train-00000-*")).unlink()
    (out / "data" / ".train-00000-of-00002.parquet.1.tmp").write_bytes(b"partial")
    assert build_feedback(tiny_dataset, random_preds, out, objects_per_shard=1) == meta
    assert _data_bytes(out) == before

    other = tmp_path / "other.jsonl"
    other.write_text(random_preds.read_text().replace('"text": "Brick 1', '"text": "Brick  1', 1))
    with pytest.raises(ConfigMismatchError, match="feedback.predictions_sha256"):
        build_feedback(tiny_dataset, other, out, objects_per_shard=1)


def test_static_feedback_rows_have_no_settled_column_and_its_config_hashes_as_before(tiny_dataset, random_preds,
                                                                                      tmp_path):
    import pyarrow.parquet as pq

    from pipelines.dataset.config import DatasetConfig
    from pipelines.feedback import build_feedback, feedback_config

    static = feedback_config(tiny_dataset, random_preds, physics=False)
    record = static.to_json()
    assert "physics" not in record["feedback"]  # as every feedback folder before the field recorded it
    assert DatasetConfig.from_json(record) == static and DatasetConfig.from_json(record).hash == static.hash
    executed = feedback_config(tiny_dataset, random_preds)
    assert executed.to_json()["feedback"]["physics"] is True and executed.hash != static.hash
    out = tmp_path / "static"
    build_feedback(tiny_dataset, random_preds, out, objects_per_shard=1, physics=False)
    names = pq.read_schema(next((out / "data").glob("train-*"))).names
    assert "feedback" in names and "settled" not in names


def test_the_command_and_its_errors(tiny_dataset, random_preds, tmp_path, capsys):
    from train.feedback import main

    out = tmp_path / "fb"
    assert main(["--data", str(tiny_dataset), "--pred", str(random_preds), "--out", str(out), "--no-progress"]) == 0
    line = capsys.readouterr().out
    assert f"{out}: " in line and "correction rows (built " in line
    assert main(["--data", str(tiny_dataset), "--pred", str(tmp_path / "none.jsonl"), "--out", str(tmp_path / "x"),
                 "--no-progress"]) == 2
    assert "no such predictions file" in capsys.readouterr().err
    assert main(["--data", str(tmp_path), "--pred", str(random_preds), "--out", str(tmp_path / "y"),
                 "--no-progress"]) == 2
    assert "not a dataset folder" in capsys.readouterr().err


def test_a_feedback_folder_written_before_the_builder_is_read(tiny_dataset, random_preds, tmp_path):
    """train.feedback used to write one file and an info.json of its own shape (no config hash, the
    source dataset's config, `kind`): such folders are still read as feedback datasets."""
    from eval.data import info, iter_rows
    from pipelines.feedback import build_feedback

    out = tmp_path / "fb"
    meta = build_feedback(tiny_dataset, random_preds, out, objects_per_shard=8)
    old = {k: meta[k] for k in ("dataset_id", "schema_extra_columns", "tasks", "source_dataset", "source_dataset_id",
                                "source_config_hash", "source_split", "predictions", "predictions_sha256", "reasons")}
    old.update(kind="feedback", config=info(tiny_dataset).config, splits_present=["train"],
               counts={"train": {k: meta["total"][k] for k in ("objects", "steps")}},
               total={k: meta["total"][k] for k in ("objects", "steps")})
    for name in ("meta", "README.md", "gallery"):
        shutil.rmtree(out / name) if (out / name).is_dir() else (out / name).unlink()
    (out / "meta").mkdir()
    (out / "meta" / "info.json").write_text(json.dumps(old))
    next((out / "data").glob("test-*")).unlink()
    (next((out / "data").glob("train-*"))).rename(out / "data" / "train-00000-of-00001.parquet")
    typed = info(out)
    assert "feedback" in INFO_SOURCES and typed.source == "feedback" and typed.schema_version == 1
    assert typed.available_tasks == ("pose",) and typed.extra_images == ("feedback",)
    assert len(list(iter_rows(out, "train"))) == meta["total"]["steps"]


def test_a_dataset_built_on_another_machine_names_its_library(tiny_dataset, random_preds, tmp_path, capsys):
    """A dataset records the LDraw folder it was built with; moved to a machine without that folder,
    the feedback rows (which render its parts again) stop with an error that names the folder and
    `--ldraw`, before anything is written; with `--ldraw` they are built from the library given."""
    from train.feedback import main

    moved = tmp_path / "moved"
    shutil.copytree(tiny_dataset, moved)
    meta = moved / "meta" / "info.json"
    doc = json.loads(meta.read_text())
    doc["config"]["ldraw"] = str(tmp_path / "nowhere" / "ldraw")
    meta.write_text(json.dumps(doc))
    out = tmp_path / "fb"
    assert main(["--data", str(moved), "--pred", str(random_preds), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"built with the LDraw library {tmp_path / 'nowhere' / 'ldraw'}, which is not a folder here" in err
    assert "--ldraw DIR" in err and not out.exists()
    if not (SHARED_LDRAW / "parts").is_dir():
        pytest.skip(f"the rest needs the LDraw subset in {SHARED_LDRAW} (the embedded library has no folder)")
    assert main(["--data", str(moved), "--pred", str(random_preds), "--out", str(out), "--no-progress",
                 "--ldraw", str(SHARED_LDRAW)]) == 0
    built = json.loads((out / "meta" / "info.json").read_text())
    assert built["config"]["ldraw"] == str(SHARED_LDRAW) and built["reasons"].get("built", 0) > 0
