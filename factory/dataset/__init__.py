"""The dataset contract: what a row of our Parquet datasets holds, and what `meta/info.json` says.

One home for what the writers (`pipelines`) and the readers (`eval`, `train`) must agree on:

- `tasks`: the tasks (`TASKS`), the splits, and the image columns of each task's conversation;
- `answers`: the two answer formats (the one writer of both, which `eval.parse` is tested against);
- `prompts`: the task prompts and the chat-message layout of the rows;
- `schema`: the Arrow row schema and its Hugging Face features, with `SCHEMA_VERSION`;
- `info`: `DatasetInfo`, the typed `meta/info.json`.

It sits at the top of `factory` and imports only from `factory`; nothing else in `factory` imports
it (`tests/test_imports.py`).
"""

from factory.dataset.answers import format_pose, format_selection, normalise_part
from factory.dataset.info import Counts, DatasetInfo, InfoError, json_bytes, read_info, write_info
from factory.dataset.schema import IMAGE_COLUMNS, SCHEMA, SCHEMA_VERSION, arrow_schema
from factory.dataset.tasks import (
    FEEDBACK_IMAGES,
    POSE_IMAGES,
    SELECTION_IMAGES,
    SPLITS,
    TASKS,
    check_task,
    image_columns,
)

__all__ = [
    "FEEDBACK_IMAGES",
    "IMAGE_COLUMNS",
    "POSE_IMAGES",
    "SCHEMA",
    "SCHEMA_VERSION",
    "SELECTION_IMAGES",
    "SPLITS",
    "TASKS",
    "Counts",
    "DatasetInfo",
    "InfoError",
    "arrow_schema",
    "check_task",
    "format_pose",
    "format_selection",
    "image_columns",
    "json_bytes",
    "normalise_part",
    "read_info",
    "write_info",
]
