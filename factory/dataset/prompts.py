"""The prompts of the two tasks and of world feedback, and the chat conversations built from them.

Conversations use TRL's vision `messages` format: a list of {"role", "content"} where content is a
list of parts, {"type": "image"} (the images come separately, in order) or {"type": "text",
"text": ...}. In the Parquet rows every content part has the same three keys (`type`, `text`,
`index`; the unused ones are null), as Arrow needs one struct type; `index` is the position of
the image in the task's image list (`factory.dataset.tasks.image_columns`). No key is named
`image`, so chat templates that test `'image' in part` treat text parts as text.

Answers are written by `factory.dataset.answers.format_selection` / `format_pose`, the formatters
the evaluator's parser is tested against, so what a model is trained on is what the scorer reads.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from factory.dataset.answers import format_pose, format_selection

SYSTEM_TEXT = (
    "You are an expert LEGO builder reading step-by-step building instructions rendered from LDraw "
    "models. Each step adds one or more bricks to an object. All coordinates use LDraw conventions: "
    "units are LDU (1 LDU = 0.4 mm; stud pitch 20 LDU, brick height 24 LDU, plate height 8 LDU), "
    "+X points right, +Y points DOWN (up is -Y), and +Z points away from the viewer in the Front "
    "view. Answer exactly in the requested format, with no other text."
)

VIEWS_TEXT = "six orthographic views (top row: Top, Front, Right; bottom row: Bottom, Back, Left)"

POSE_CONVENTION = (
    "Pose convention: R is the rotation matrix of the LDraw type-1 line "
    "`1 <colour> x y z a b c d e f g h i <part>`, written as three rows [a, b, c], [d, e, f], "
    "[g, h, i]; a point p of the part, in the part's own frame, lands at R p + T in the object's "
    "frame, where T = (x, y, z). Units are LDU; y points down."
)

SELECTION_FORMAT = "3023.dat, row 6, col 3"
POSE_FORMAT = format_pose([((-10.0, -8.0, -20.0), ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0)))])


def _bricks(n: int) -> str:
    return "1 brick" if n == 1 else f"{n} bricks"


def _context(kind: str, assembly: str, n: int) -> str:
    """One sentence on what the step does, for sub-assembly and module steps of human designs."""
    if kind == "module":
        name = assembly.rsplit("/", 1)[-1].split("#")[0] if "/" in assembly else "the model"
        return (f"This step attaches a sub-assembly built in earlier steps ({_bricks(n)}) to {name}; "
                "poses are in the frame of the assembly it is attached to.\n")
    if assembly not in ("", "main"):
        name = assembly.rsplit("/", 1)[-1].split("#")[0]
        return f"This step builds the sub-assembly {name} on its own; poses are in its own frame.\n"
    return ""


def selection_prompt(n_bricks: int, first_step: bool = False, kind: str = "part", assembly: str = "main") -> str:
    """The user text of the brick selection task (images: before, after, catalog)."""
    empty = " (empty: this is the first step)" if first_step else ""
    return (
        "Task: brick selection.\n"
        f"Image 1: the assembly before this step{empty}, {VIEWS_TEXT}.\n"
        "Image 2: the same six views after this step; each brick added in this step is marked "
        "with a red dashed box.\n"
        "Image 3: the catalog of bricks still to place, 6 columns; rows and columns are numbered "
        "from 1 starting at the top-left, and the part file name is written above each tile.\n"
        + _context(kind, assembly, n_bricks)
        + f"This step adds {_bricks(n_bricks)}. For each added brick, give the catalog cell that "
        "holds it, one line per brick, in the format:\n"
        f"{SELECTION_FORMAT}"
    )


def pose_prompt(bricks: Sequence[dict], first_step: bool = False, kind: str = "part",
                assembly: str = "main") -> str:
    """The user text of the pose estimation task (images: before, after, part, axes).

    `bricks`: per added brick, {"part", "colour", "colour_name", "size_cm": (x, y, z)}.
    """
    empty = " (empty: this is the first step)" if first_step else ""
    n = len(bricks)
    lines = [
        "Task: pose estimation.",
        f"Image 1: the assembly before this step{empty}, {VIEWS_TEXT}.",
        "Image 2: the same six views after this step; each brick added in this step is marked with "
        "a red dashed box.",
        ("Image 3: the added brick alone" if n == 1 else "Image 3: each added brick alone, labelled Brick 1, "
         "Brick 2, ...") + " in its own LDraw frame (isometric view), with axes drawn from the part's "
        "origin: red +X, green +Y (down), blue +Z (pointing away from the viewer, drawn up and to the "
        "right).",
        "Image 4: the assembly before this step in seven views (six orthographic and one isometric) "
        "with LDU tick labels on the axes.",
    ]
    ctx = _context(kind, assembly, n)
    if ctx:
        lines.append(ctx.rstrip("\n"))
    lines.append(f"This step adds {_bricks(n)}:")
    for k, b in enumerate(bricks, 1):
        sx, sy, sz = (float(v) for v in b["size_cm"])
        lines.append(f"Brick {k}: {b['part']}, colour {b['colour_name']} (LDraw code {b['colour']}), "
                     f"size {sx:.2f} x {sy:.2f} x {sz:.2f} cm along its own x, y, z axes.")
    lines.append("Give the pose of each added brick in the object's LDraw frame.")
    lines.append(POSE_CONVENTION)
    lines.append("Answer one block per brick, numbered as above, in the format:")
    lines.append(POSE_FORMAT)
    return "\n".join(lines)


def selection_answer(picks) -> str:
    """`picks`: (part, row, col) per brick."""
    return format_selection(picks)


def pose_answer(poses) -> str:
    """`poses`: (T, R) per brick."""
    return format_pose(poses)


# -- conversations ---------------------------------------------------------------------------------
def text_part(text: str) -> dict:
    return {"type": "text", "text": text, "index": None}


def image_part(index: int) -> dict:
    return {"type": "image", "text": None, "index": int(index)}


def conversation(system: str, n_images: int, user_text: str, answer: str | None) -> list[dict]:
    """[system, user (n images then the text), assistant] in TRL's vision format."""
    msgs = [
        {"role": "system", "content": [text_part(system)]},
        {"role": "user", "content": [image_part(i) for i in range(n_images)] + [text_part(user_text)]},
    ]
    if answer is not None:
        msgs.append({"role": "assistant", "content": [text_part(answer)]})
    return msgs


# -- world feedback --------------------------------------------------------------------------------
def _row(v) -> str:
    return "[" + ", ".join(repr(round(float(x), 4) + 0.0) for x in v) + "]"


def settle_sentence(e: dict) -> str:
    """What physics did with a predicted brick, in one sentence without its full stop, from the
    feedback errors' "outcome", "moved_ldu" and "connections" (`eval.feedback.feedback_example`)."""
    moved, n = float(e["moved_ldu"]), int(e["connections"])
    studs = f"{n} stud{'s' if n != 1 else ''}"
    outcome = e["outcome"]
    if outcome == "rests-connected":
        if moved < 0.5:
            return f"It stays where you put it, connected on {studs}"
        return f"It snapped {moved:.0f} LDU onto a connection on {studs} and stays there"
    if outcome == "rests-unconnected":
        return f"It moved {moved:.0f} LDU and rests without a stud connection"
    if outcome == "fell-off":
        return f"It fell off the assembly: it moved {moved:.0f} LDU and lies on the table"
    if outcome == "pushed-out":
        return f"It overlapped another part and was pushed {moved:.0f} LDU out of it; it rests without a connection"
    if outcome == "collides":
        return "It lies deep inside another part: the overlap is too deep to push it out"
    raise ValueError(f"unknown settle outcome {outcome!r}")


def feedback_prompt(errors: Sequence[dict]) -> str:
    """The revision prompt after a wrong pose was executed in the simulator (the paper's world
    feedback): per brick its translation error (LDU), geodesic rotation error (degrees) and the
    rotation matrix it was drawn with; never the per-axis offsets.

    `errors`: per brick, {"translation_error": float, "rotation_error": float, "R": 3x3}, and when
    the prediction was executed "outcome", "moved_ldu" and "connections" (`settle_sentence`).
    The image to show with it (`factory.dataset.tasks.FEEDBACK_IMAGES`) is `render_feedback` of the prediction.
    """
    physics = any("outcome" in e for e in errors)
    lines = [
        "Your previous answer was executed in the simulator. The image shows the assembly in muted "
        "colours and your predicted placement in bright red, in seven views (six orthographic and "
        "one isometric)." if not physics else
        "Your previous answer was executed in the simulator: each brick was released where you put it "
        "and physics moved it. The image shows the assembly in muted colours, your predicted placement "
        "as a red outline and where the brick ended up in solid red, in seven views (six orthographic "
        "and one isometric).",
    ]
    for k, e in enumerate(errors, 1):
        r = np.asarray(e["R"], dtype=np.float64).reshape(3, 3)
        head = f"Brick {k}: {settle_sentence(e)}. Translation error" if "outcome" in e else f"Brick {k}: translation error"
        lines.append(f"{head} {float(e['translation_error']):.1f} LDU, rotation error "
                     f"{float(e['rotation_error']):.1f} degrees; your rotation matrix was "
                     + " ".join(_row(x) for x in r) + ".")
    lines.append("The placement is not right. Look at the images again and give the pose of every added "
                 "brick once more.")
    lines.append(POSE_CONVENTION)
    lines.append("Answer in the same format as before, one block per brick.")
    return "\n".join(lines)


def feedback_turn(errors: Sequence[dict], image_index: int) -> dict:
    """A user message with the feedback render (image `image_index`) and `feedback_prompt`."""
    return {"role": "user", "content": [image_part(image_index), text_part(feedback_prompt(errors))]}
