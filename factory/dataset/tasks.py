"""The tasks a dataset row poses, its splits, and the image columns each task shows, in prompt order."""

from __future__ import annotations

TASKS = ("selection", "pose")
"""Brick selection (which catalog cells hold the step's bricks) and pose estimation (where they go)."""

SPLITS = ("train", "test")

SELECTION_IMAGES = ("before", "after", "catalog")
"""Image columns of the brick selection conversation, in prompt order."""
POSE_IMAGES = ("before", "after", "part", "axes")
"""Image columns of the pose estimation conversation, in prompt order."""
FEEDBACK_IMAGES = ("feedback",)
"""The image of a world-feedback turn (`factory.render.render_feedback` of the prediction)."""


def check_task(task: str) -> str:
    """`task` when it is one of `TASKS`, else a ValueError listing them."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; valid: {', '.join(TASKS)}")
    return task


def image_columns(task: str) -> tuple[str, ...]:
    """The image columns of `task`'s conversation, in prompt order."""
    return SELECTION_IMAGES if check_task(task) == "selection" else POSE_IMAGES
