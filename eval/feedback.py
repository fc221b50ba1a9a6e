"""World feedback (the paper's revision turn): a wrong pose answer is executed in the simulator, the
model is shown the result and its errors, and asked again.

One builder, `feedback_example`, serves both sides: the predictor (`eval.predict --feedback`) asks
the model with it, and the trainer turns wrong predictions into correction examples with it (append
``{"role": "assistant", ...row["pose_answer"]}``), so a model is trained on exactly the revision
prompt it is evaluated with.

Which answers get feedback: those that parse a pose for every target brick and fail the step in
``paper`` mode (the paper's public thresholds). An answer that does not parse has nothing to draw
or to measure, so it gets none; a right answer needs none.

The "before" assembly of a row is the bricks of the earlier rows of the same object and the same
`assembly` (every row's bricks are in its assembly's frame, and a module step's row lists the
sub-assembly's bricks in the parent's frame), see `before_rows`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from eval.chat import clean_messages, columns_for, task_chat
from eval.data import TARGET_COLUMNS, step_target
from eval.metrics import evaluate_brick
from eval.parse import parse_pose
from factory.dataset.prompts import feedback_turn, text_part
from factory.ldraw import PlacedPart
from factory.pose import Pose

FEEDBACK_MODE = "paper"
"""The mode whose step failure triggers feedback."""


class Feedback(NamedTuple):
    """A revision conversation: unpacks as ``messages, images, errors``."""

    messages: list[dict]
    """Pose prompt, the model's answer (assistant), the feedback turn (user); ends where the model
    answers again. Clean parts as `eval.chat.task_chat` gives them."""
    images: list
    """The pose images then the feedback render (PIL, RGB), in the order the image parts appear."""
    errors: list[dict]
    """Per target brick: {"translation_error": LDU, "rotation_error": degrees (symmetry-aware),
    "R": the predicted matrix as written (3x3 list)}."""


def feedback_columns() -> list[str]:
    """The Parquet columns `feedback_example` reads from a row (and from before/scene rows)."""
    return list(dict.fromkeys([*TARGET_COLUMNS, *columns_for("pose")]))


def assembly_rows(object_rows: list[dict], row: dict) -> list[dict]:
    """Every row of `row`'s object and assembly: the finished assembly frames every step of it alike."""
    return [r for r in object_rows if r["object_id"] == row["object_id"] and r["assembly"] == row["assembly"]]


def before_rows(object_rows: list[dict], row: dict) -> list[dict]:
    """The rows whose bricks stand before `row` is built: earlier steps of its object and assembly."""
    return [r for r in assembly_rows(object_rows, row) if r["step_index"] < row["step_index"]]


def placed_parts(rows: list[dict]) -> list:
    """The bricks of `rows` as `PlacedPart`s (poses in the assembly's frame)."""
    return [PlacedPart(b["part"], int(b["colour"]), Pose(np.asarray(b["R"], float), np.asarray(b["T"], float)),
                       r["step_id"]) for r in rows for b in r["bricks"]]


def pose_errors(row: dict, predicted_text) -> list[dict] | None:
    """Per-brick errors of a pose answer when it gets feedback (see the module docstring), else None."""
    target = step_target(row)
    blocks = parse_pose(predicted_text) if isinstance(predicted_text, str) else {}
    answers = [blocks.get(i + 1) for i in range(len(target.bricks))]
    if not target.bricks or any(a is None for a in answers):
        return None
    results = [evaluate_brick(b, a, FEEDBACK_MODE) for b, a in zip(target.bricks, answers)]
    if all(r.ok for r in results):
        return None
    return [{"translation_error": r.translation_error, "rotation_error": r.rotation_error,
             "R": np.asarray(a.R, dtype=np.float64).tolist()} for r, a in zip(results, answers)]


def feedback_render(row: dict, predicted_text, before: list[dict], renderer, size: int,
                    scene: list[dict] | None = None):
    """The answer's bricks in red on the before-assembly (`render_feedback`), framed on the bounds
    of `scene` rows (default: before and this row), as the dataset framed the row's own views."""
    # Importing factory.render picks and loads a GL backend (an error where there is none): only
    # this render needs it, so scoring and text-only prediction run on machines without GL.
    from factory.render import bounds_of, render_feedback

    blocks = parse_pose(predicted_text)
    predicted = [PlacedPart(b["part"], int(b["colour"]), Pose(blocks[i + 1].R, blocks[i + 1].t), "prediction")
                 for i, b in enumerate(row["bricks"]) if (i + 1) in blocks]
    scene_parts = placed_parts(scene if scene is not None else [*before, row])
    bounds = bounds_of(scene_parts, renderer.reader) if scene_parts else None
    return render_feedback(renderer, placed_parts(before), predicted, size, bounds=bounds,
                           scene_parts=scene_parts or None)


def revision_messages(row: dict, predicted_text: str, errors: list[dict]) -> list[dict]:
    """The row's pose prompt (Parquet message format), the wrong answer and the feedback turn that
    asks for a revision: what a model is asked at evaluation, and a correction row's prompt."""
    prompt = list(row["pose_messages"])
    if prompt and prompt[-1]["role"] == "assistant":
        prompt = prompt[:-1]
    return [*prompt, {"role": "assistant", "content": [text_part(predicted_text)]},
            feedback_turn(errors, image_index=len(row["pose_images"]))]


def feedback_example(row: dict, predicted_text, before: list[dict], renderer, size: int, *,
                     scene: list[dict] | None = None) -> Feedback | None:
    """The revision conversation for a pose answer, or None when it gets no feedback.

    `row`: a dataset row with `feedback_columns()`; `before`: the rows of its before-assembly
    (`before_rows`); `renderer`: a `factory.render.Renderer` of the dataset's library
    (`get_reader(info["config"]["ldraw"])`), one per object as the builder renders; `size`: the
    dataset's view size (`info["config"]["size"]`); `scene`: the rows of the whole assembly
    (`assembly_rows`) to frame the render like the row's own images (default: before and row).
    """
    errors = pose_errors(row, predicted_text)
    if errors is None:
        return None
    _, images, _ = task_chat(row, "pose")
    image = feedback_render(row, predicted_text, before, renderer, size, scene)
    return Feedback(clean_messages(revision_messages(row, predicted_text, errors)), [*images, image], errors)

