"""Sharded Parquet datasets of assembly steps for training and evaluating vision-language models.

    from pipelines.dataset import DatasetConfig, build, build_shard
    summary = build(config, "out/synth", runner="local", workers=2)

The row contract (tasks, prompts, answer formats, schema, meta/info.json) is `factory.dataset`;
the names below from it are re-exported. See docs/concepts/dataset-contract.md: rows, layout, determinism and
resume, the Ray runner, the designs source.
"""

from factory.dataset import POSE_IMAGES, SCHEMA_VERSION, SELECTION_IMAGES
from factory.dataset.prompts import (
    SYSTEM_TEXT,
    feedback_prompt,
    feedback_turn,
    pose_prompt,
    selection_prompt,
)
from pipelines.dataset.build import (
    RUNNERS,
    FolderBusyError,
    ShardFailedError,
    ShardInputError,
    build,
    finalize,
    prepare,
    summary_line,
)
from pipelines.dataset.config import ConfigMismatchError, DatasetConfig, split_of
from pipelines.dataset.shards import build_shard

__all__ = [
    "POSE_IMAGES",
    "RUNNERS",
    "SCHEMA_VERSION",
    "SELECTION_IMAGES",
    "SYSTEM_TEXT",
    "ConfigMismatchError",
    "DatasetConfig",
    "FolderBusyError",
    "ShardFailedError",
    "ShardInputError",
    "build",
    "build_shard",
    "feedback_prompt",
    "feedback_turn",
    "finalize",
    "pose_prompt",
    "prepare",
    "selection_prompt",
    "split_of",
    "summary_line",
]
