"""The verbs at the top of `factory`: grow objects, verify a design (a typed result with
`to_json`), build a dataset; the command lines call the same functions."""

from __future__ import annotations

import json
import pydoc
import subprocess
import sys
from pathlib import Path

import pytest

import factory
from factory.replay import summarize, verify_model

ROOT = Path(__file__).resolve().parents[1]
SMALL = factory.SamplerConfig(seed=7, min_steps=6, max_steps=8)
DESIGN = """0 FILE held.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
0 STEP
1 4 100 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
1 4 100 0 0 1 0 0 0 1 0 0 0 1 3001.dat
0 STEP
1 1 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat
1 1 10 -48 0 1 0 0 0 1 0 0 0 1 3001.dat
"""


def test_help_shows_the_verbs():
    text = pydoc.render_doc(factory)
    assert "factory.grow(8, factory.SamplerConfig(seed=7))" in text and "factory.verify(" in text
    assert "factory.build_dataset(" in text
    assert {"grow", "verify", "Verification", "build_dataset", "DatasetConfig"} <= set(factory.__all__)


def test_grow_gives_the_samplers_objects_in_index_order():
    objects = factory.grow(3, SMALL, start=2)
    sampler = factory.Sampler(SMALL)
    assert [a.index for a in objects] == [2, 3, 4]
    assert [a.to_json(steps=True) for a in objects] == [sampler.sample(i).to_json(steps=True) for i in (2, 3, 4)]
    assert [a.to_json(steps=True) for a in factory.grow(3, SMALL, start=2, batch=3)] == \
        [a.to_json(steps=True) for a in objects]
    assert factory.grow(0, SMALL) == []
    with pytest.raises(ValueError, match="n must be an integer >= 0"):
        factory.grow(-1)


def test_verify_gives_a_typed_result_and_the_command_prints_its_records(tmp_path):
    path = tmp_path / "held.ldr"
    path.write_text(DESIGN)
    seen = []
    found = factory.verify(path, faults=True, on_record=seen.append)
    assert isinstance(found, factory.Verification) and found.model == str(path)
    assert list(found.records) == seen == list(verify_model(path, None, faults=True))
    assert found.summary == {**summarize(seen), "finished_stands": found.finished_stands}
    # the brick half off the one below it (10 LDU across) is the only placement rejected
    assert [(r["part"], r["reason"]) for r in found.rejected] == [("3001.dat", found.rejected[0]["reason"])]
    assert found.rejected[0]["reason"] in ("collision", "no-connection", "unstable")
    assert len(found.placements) == 5 and found.summary["placements"] == 5
    assert json.loads(json.dumps(found.to_json())) == {"model": str(path), "summary": found.summary,
                                                      "records": list(found.records)}
    out = subprocess.run([sys.executable, "-m", "pipelines.verify", str(path), "--faults"], capture_output=True,
                         text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines()]
    assert lines == [*found.records, {"summary": found.summary}]


def test_build_dataset_is_the_builders_and_builds(tmp_path):
    from dataset_support import tiny_dataset_config
    from pipelines.dataset import DatasetConfig, build

    assert factory.build_dataset is build and factory.DatasetConfig is DatasetConfig
    summary = factory.build_dataset(tiny_dataset_config(n_objects=1), tmp_path / "synth", progress=False)
    assert summary["shards_built"] == 1 and (tmp_path / "synth" / "meta" / "info.json").is_file()
    with pytest.raises(AttributeError, match="no attribute 'build'"):
        factory.build
