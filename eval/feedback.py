"""World feedback (the paper's revision turn): a wrong pose answer is executed in the simulator, the
model is shown the result and its errors, and asked again.

One builder, `feedback_example`, serves both sides: the predictor (`eval.predict --feedback`) asks
the model with it, and the trainer turns wrong predictions into correction examples with it (append
``{"role": "assistant", ...row["pose_answer"]}``), so a model is trained on exactly the revision
prompt it is evaluated with.

The prediction is executed (`settle_answer`, `factory.physics.settle`): each predicted brick is
released on the before-assembly (fixed, as the checks hold it) over a table at the finished
assembly's lowest point, and settles: it snaps onto a valid connection it landed on, falls, slides,
is pushed out of an overlap, or is found too deep inside another part. The render shows the
predicted placement as a red outline and where the brick ended up in solid red, and the feedback
turn says what happened in one sentence per brick; each brick's errors carry the outcome, the
settled pose and the distance moved. `physics=False` gives the static feedback (the prediction
drawn in red where it was put, errors only).

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
from factory.parts import load_part
from factory.physics.linked import linked
from factory.physics.settle import SettleConfig, settle_all
from factory.physics.structure import Placed, Structure
from factory.pose import Pose, nearest_rotation_matrix

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
    "R": the predicted matrix as written (3x3 list)}; with physics also "outcome" (one of
    `factory.physics.settle.OUTCOMES`), "moved_ldu", "connections", "settled_R" and "settled_T"
    (the settled pose, LDraw frame)."""


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


def settle_answer(row: dict, predicted_text, before: list[dict], reader, scene: list[dict] | None = None,
                  config: SettleConfig = SettleConfig()) -> list:
    """Each predicted brick of a pose answer released on the before-assembly and settled
    (`factory.physics.settle.Settled` per target brick, in order). The table lies at the lowest
    point of `scene` (the whole assembly; default: before and this row); a predicted matrix that
    is not a rotation is taken as its nearest rotation."""
    blocks = parse_pose(predicted_text)
    # With the joints its parts make as links: a part held by a pin carries what is put on it.
    structure = linked(Placed(load_part(reader, p.part), p.colour, p.pose) for p in placed_parts(before))
    everything = Structure([Placed(load_part(reader, p.part), p.colour, p.pose)
                            for p in placed_parts(scene if scene is not None else [*before, row])])
    floor_y = everything.floor_y()
    cases = [(structure, load_part(reader, b["part"]),
              Pose(nearest_rotation_matrix(blocks[i + 1].R), np.asarray(blocks[i + 1].t, float)), floor_y)
             for i, b in enumerate(row["bricks"])]
    return settle_all(cases, config)


def feedback_render(row: dict, predicted_text, before: list[dict], renderer, size: int,
                    scene: list[dict] | None = None, settled: list | None = None):
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
    ended = None
    if settled is not None:
        ended = [PlacedPart(b["part"], int(b["colour"]), st.pose, "settled") for b, st in zip(row["bricks"], settled)]
    return render_feedback(renderer, placed_parts(before), predicted, size, bounds=bounds,
                           scene_parts=scene_parts or None, settled=ended)


def revision_messages(row: dict, predicted_text: str, errors: list[dict]) -> list[dict]:
    """The row's pose prompt (Parquet message format), the wrong answer and the feedback turn that
    asks for a revision: what a model is asked at evaluation, and a correction row's prompt."""
    prompt = list(row["pose_messages"])
    if prompt and prompt[-1]["role"] == "assistant":
        prompt = prompt[:-1]
    return [*prompt, {"role": "assistant", "content": [text_part(predicted_text)]},
            feedback_turn(errors, image_index=len(row["pose_images"]))]


def feedback_example(row: dict, predicted_text, before: list[dict], renderer, size: int, *,
                     scene: list[dict] | None = None, physics: bool = True) -> Feedback | None:
    """The revision conversation for a pose answer, or None when it gets no feedback.

    `row`: a dataset row with `feedback_columns()`; `before`: the rows of its before-assembly
    (`before_rows`); `renderer`: a `factory.render.Renderer` of the dataset's library
    (`get_reader(info["config"]["ldraw"])`), one per object as the builder renders; `size`: the
    dataset's view size (`info["config"]["size"]`); `scene`: the rows of the whole assembly
    (`assembly_rows`) to frame the render like the row's own images (default: before and row);
    `physics`: execute the prediction (`settle_answer`; False: the static feedback).
    """
    errors = pose_errors(row, predicted_text)
    if errors is None:
        return None
    settled = None
    if physics:
        settled = settle_answer(row, predicted_text, before, renderer.reader, scene)
        for e, st in zip(errors, settled):
            e.update(outcome=st.outcome, moved_ldu=round(float(st.moved_ldu), 3), connections=int(st.connections),
                     settled_R=np.round(st.pose.R, 6).tolist(), settled_T=np.round(st.pose.t, 3).tolist())
    _, images, _ = task_chat(row, "pose")
    image = feedback_render(row, predicted_text, before, renderer, size, scene, settled)
    return Feedback(clean_messages(revision_messages(row, predicted_text, errors)), [*images, image], errors)

