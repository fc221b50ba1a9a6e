"""`python -m train.feedback`: world-feedback correction rows from a model's wrong pose answers.

    python -m train.feedback --data OUT --pred preds.jsonl --out OUT_FB [--split train]

The command of `pipelines.feedback` under the trainer's name: the rows are a source of the
dataset builder (`pipelines.feedback.FeedbackSource`), written with its shards, atomic files,
resume and `meta/info.json`; `python -m train --data OUT --data OUT_FB` mixes them into training.
"""

from __future__ import annotations

import sys

from pipelines.feedback import build_feedback, correction_messages, feedback_schema
from pipelines.feedback import main as _main

__all__ = ["build_feedback", "correction_messages", "feedback_schema", "main"]


def main(argv: list[str] | None = None) -> int:
    return _main(argv, prog="python -m train.feedback")


if __name__ == "__main__":
    sys.exit(main())
