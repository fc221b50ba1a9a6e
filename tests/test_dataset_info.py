"""`factory.dataset.DatasetInfo`: meta/info.json files as the writers have written them load, round-trip
byte for byte, and a wrong one is refused naming the key and the file."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from eval.data import DatasetError, info
from factory.dataset import TASKS
from factory.dataset.info import Counts, DatasetInfo, InfoError, json_bytes, read_info, write_info
from pipelines.dataset.config import DatasetConfig, record_hash, started_hash

INFOS = Path(__file__).parent / "data" / "info"
WRITTEN = ("synthetic.json", "design.json", "bcbench.json")
"""info.json files as written before `DatasetInfo` existed: by the builder (`make synth` at N=2,
seed 0, 3-5 steps; `pipelines.designs` on a hostile MPD) and by the BC-Bench import."""


@pytest.mark.parametrize("name", WRITTEN)
def test_written_files_load_and_round_trip_byte_for_byte(name):
    text = (INFOS / name).read_bytes()
    meta = DatasetInfo.from_dict(json.loads(text), name)
    assert meta.schema_version == 1 and meta.source == name.split(".")[0]
    assert meta.total.steps == sum(c.steps for c in meta.counts.values()) > 0
    assert json_bytes(meta.to_dict()) == text


def test_builder_file_is_typed():
    meta = DatasetInfo.from_dict(json.loads((INFOS / "synthetic.json").read_text()))
    assert meta.dataset_id == "brick-factory-synth" and meta.seed == 0 and meta.num_shards == 1
    assert meta.counts["train"] == Counts(objects=1, steps=5, bytes=meta.counts["train"].bytes)
    assert meta.splits_present == ("train", "test") and meta.available_tasks == TASKS
    # A version-1 record (its sampler names the backend 'mujoco'): read, and its folder resumed under
    # its own hash by a config with the same settings (`started_hash`, the version-1 rule).
    assert meta.config["schema_version"] == 1 and meta.config["sampler"]["backend"] == "mujoco"
    config = DatasetConfig.from_json(meta.config)
    assert config.hash != meta.config_hash and record_hash(meta.config) == meta.config_hash
    assert started_hash(config, {"config_hash": meta.config_hash, "config": meta.config}) == meta.config_hash
    assert meta.statistics["rejections"]["collision"] == 15
    with pytest.raises(dataclasses.FrozenInstanceError):
        meta.dataset_id = "other"  # type: ignore[misc]


def test_bcbench_facts_are_kept_as_details():
    meta = DatasetInfo.from_dict(json.loads((INFOS / "bcbench.json").read_text()))
    assert meta.tasks == ("selection", "pose") and meta.details["blank_steps_skipped"] == 1
    assert meta.details["bcbench_import"]["steps"] == {"test": 3, "train": 2}


def test_feedback_file_written_before_source_loads_as_feedback():
    """train.feedback wrote `"kind": "feedback"`, no source and no schema version: it loads as source
    feedback, layout 1, pose only, with the feedback image column; written again it says so."""
    old = json.loads((INFOS / "feedback_before_source.json").read_text())
    meta = DatasetInfo.from_dict(old)
    assert (meta.source, meta.schema_version, meta.tasks, meta.extra_images) == ("feedback", 1, ("pose",), ("feedback",))
    assert meta.details["reasons"] == {"built": 3, "right": 1, "unparseable": 1}
    again = meta.to_dict()
    assert "kind" not in again and again["source"] == "feedback" and again["schema_version"] == 1
    assert {k: v for k, v in old.items() if k != "kind"} == {k: v for k, v in again.items()
                                                            if k not in ("source", "schema_version")}
    assert DatasetInfo.from_dict(again) == meta


def _synthetic() -> dict:
    return json.loads((INFOS / "synthetic.json").read_text())


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(colour_mode="x"), "unknown key 'colour_mode' for source 'synthetic'; valid: config, "),
    (lambda d: d.update(bcbench_import={}), "unknown key 'bcbench_import' for source 'synthetic'"),
    (lambda d: d.pop("counts"), "missing 'counts'"),
    (lambda d: d.update(source="scraped"), "source must be one of synthetic, design, bcbench, feedback, got 'scraped'"),
    (lambda d: d.update(schema_version=3), "schema_version must be an integer in 1..2"),
    (lambda d: d["total"].update(steps=10), "total.steps is 10 but the splits' counts sum to 9"),
    (lambda d: d["counts"].update(validation={"objects": 1, "steps": 1}), "counts: unknown split 'validation'; valid: train, test"),
    (lambda d: d["counts"]["train"].update(steps=-1), "counts.train.steps must be an integer >= 0, got -1"),
    (lambda d: d.update(tasks=["captions"]), "tasks: unknown task 'captions'; valid: selection, pose"),
    (lambda d: d.update(splits_present="train"), "splits_present must be a list of names"),
    (lambda d: d.update(seed="0"), "seed must be an integer or absent, got '0'"),
])
def test_a_wrong_file_is_refused_naming_the_key_and_file(change, message):
    data = _synthetic()
    change(data)
    with pytest.raises(InfoError) as err:
        DatasetInfo.from_dict(data, "OUT/meta/info.json")
    assert str(err.value).startswith("OUT/meta/info.json: ") and message in str(err.value)


def test_read_and_write_a_folder(tmp_path):
    meta = DatasetInfo.from_dict(_synthetic())
    path = write_info(tmp_path / "ds", meta)
    assert path == tmp_path / "ds" / "meta" / "info.json"
    assert path.read_bytes() == (INFOS / "synthetic.json").read_bytes()
    assert read_info(tmp_path / "ds") == meta and info(tmp_path / "ds") == meta
    path.write_text("{not json")
    with pytest.raises(InfoError, match=r"meta/info.json: not valid JSON"):
        read_info(tmp_path / "ds")
    with pytest.raises(DatasetError, match=r"meta/info.json: not valid JSON"):
        info(tmp_path / "ds")
    with pytest.raises(DatasetError, match="not a dataset folder"):
        info(tmp_path / "empty")


def test_counts_must_add_up_when_built_in_code():
    with pytest.raises(InfoError, match="total.objects is 3 but the splits' counts sum to 2"):
        DatasetInfo("d", "design", {}, {"train": Counts(1, 4), "test": Counts(1, 2)}, Counts(3, 6), ("train", "test"))
