"""The session's tiny synthetic dataset: `tiny_dataset_config` (3 sampled objects of 2-3 steps,
128 px views, one object per shard; tests build variants of it with other fields) and the
`tiny_dataset` fixture, the real dataset folder built from it once per session on the embedded
library, read-only to the tests. `conftest` imports the fixture so that every test finds it by
name."""

from __future__ import annotations

from pathlib import Path

import pytest


def tiny_dataset_config(n_objects: int = 3, min_steps: int = 2, max_steps: int = 3, **fields):
    """The config of the session's tiny synthetic dataset: 3 sampled objects of 2-3 steps, 128 px
    views, one object per shard (`fields` override further `DatasetConfig` fields). The same
    build as `test_dataset.CLI_ARGS` on the command line."""
    from factory.sampler import SamplerConfig
    from pipelines.dataset import DatasetConfig

    sampler = SamplerConfig(min_steps=min_steps, max_steps=max_steps, candidates_per_step=16)
    return DatasetConfig.synthetic(n_objects, seed=0, sampler=sampler,
                                   **{"size": 128, "tile": 64, "objects_per_shard": 1, **fields})


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """A real dataset folder built once per session (embedded library): 3 objects, 2-3 steps each,
    train and test splits. Read-only: tests that change a dataset copy it first."""
    from pipelines.dataset import build

    out = tmp_path_factory.mktemp("ds") / "synth"
    summary = build(tiny_dataset_config(), out, progress=False)
    assert summary["shards_built"] == 3
    return out
