"""BC-Bench metrics: pose errors, brick and step correctness, selection accuracy, aggregation.

Conventions (docs: bc-bench brief). Poses are LDraw: a part point p lands at ``R @ p + t`` (LDU, y
down). A symmetry S of a part acts in the part frame, so ``R_gt @ S`` is an equally right answer.

Brick correctness has two modes:

- ``strict``: translation error <= 0.5 LDU and rotation error <= 1 degree (the paper's text:
  "exact pose", allowing rounding of printed numbers);
- ``paper``: every axis |delta| <= 10 LDU (inclusive) and rotation error < 45 degrees (the paper's
  public evaluation code).

Thresholds get 1e-9 of numeric slack in the direction their text says (inclusive stays inclusive
for a difference like 30.000000000000004 - 20), nothing more.

Scoring rules of `score` (each chosen so that nothing a model emits is dropped):

- Each step expects two predictions, keyed ``(step id, "selection")`` and ``(step id, "pose")``.
  A key that is absent (or None) is *missing*; a text that yields nothing usable is *unparseable*.
  Both count as wrong and are counted; neither is dropped. Keys of unknown step ids are ignored.
- Selection accuracy of a step: predicted cells (duplicates removed: a cell can be taken once) are
  matched to target bricks as a set, each target and each cell used at most once, a cell matching
  a target when it is in the target's set of equivalent cells (maximum bipartite matching). The
  step's score is ``matched / max(#targets, #cells)``: extra picks count as wrong, so listing every
  cell does not pay. Missing or unparseable: 0.
- Pose answers are matched to target bricks by their number N (``Brick N`` is bricks[N-1]); a
  block for a number outside 1..n is ignored. A parsed matrix that is not a rotation (within 1e-3)
  is replaced by its nearest rotation and counted in ``projected_rotations``, unless it is
  *mirrored* (finite, determinant < 0: a reflection, the handedness slip of a y-down frame). A
  mirrored answer is wrong in every mode, whatever the part's symmetry: it places the mirror image
  of the part, and a reflection has no single nearest rotation (negating one column of a rotation
  leaves three rotations equally near, so an SVD would pick one arbitrarily and could score it 0
  degrees). Its rotation error is 180 degrees, the largest there is, and it is counted in
  ``failures.mirrored`` (not in the other failure kinds) and ``mirrored_rotations``.
- A matrix that is no rotation at all is *degenerate*, and wrong in every mode: non-finite, or
  with columns not orthonormal within `DEGENERATE_TOL` (some entry of ``M^T M - I`` beyond 0.05:
  a column's length off by about 2.5 %, or two columns off square by about 3 degrees; a singular,
  scaled or sheared matrix). Its nearest rotation would be a guess (a singular matrix has many),
  so, like a mirrored one, its rotation error is 180 degrees and it is counted in
  ``failures.degenerate`` and ``degenerate_rotations``. Between `PROJECTION_TOL` and
  `DEGENERATE_TOL` (a rotation printed with 1-2 decimals) the nearest rotation is scored.
- A translation error is capped at `TRANSLATION_CAP_LDU` (10,000 LDU, 4 m; far beyond every
  threshold, so a capped answer is wrong) and such answers are counted in
  ``capped_translations``: one answer of 1e308 cannot make a split's mean infinite or undefined.
- Translation and rotation error means use only the bricks whose pose parsed (an unparseable pose
  has no error to average, and any stand-in value would be arbitrary and swamp the mean); such
  bricks fail their step and are counted in ``unparseable_pose`` and ``failures.unparseable``.
  A step's error is the mean over its parsed bricks; a step with none has no error value.
- Step success: the pose answer has every target brick right in the mode, and, when a selection
  prediction for the step exists (present, parseable or not), its selection score is 1. A missing
  selection does not fail the step, as the paper's step success is on pose estimation (the brick's
  identity is given by the target); it still scores 0 in selection accuracy.
- ``failures`` counts target bricks whose pose is wrong: ``mirrored`` (a reflection given as its
  rotation, whatever its translation), ``degenerate`` (a matrix that is no rotation, whatever its
  translation), ``translation_only``, ``rotation_only``, ``both``, or
  ``unparseable`` (missing or unparseable pose for that brick).
- ``overall`` is the mean over objects of per-object means (per-object: mean over its steps; for
  errors, over its steps that have a value). A metric with no value anywhere is None.
- ``best_object`` is the one object with the highest step success (ties: lower mean translation
  error, then object id), reported with that object's own other metrics. Taking each metric's
  best over objects separately would build a row no single object achieved, mixing objects per
  column, and would favour noise (the maximum of many small-sample means); one object's row is a
  real, consistent data point and is what the paper's "best object" names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from eval.parse import PoseAnswer, parse_pose, parse_selection
from factory.pose import nearest_rotation_matrix
from factory.symmetry import Symmetry

MODES = ("strict", "paper")
PROJECTION_TOL = 1e-3
"""Max entry difference between a parsed matrix and its nearest rotation before it counts as projected."""
DEGENERATE_TOL = 0.05
"""Max entry of ``|M^T M - I|`` of a matrix still scored as a (projected) rotation; beyond it the
matrix is degenerate: wrong, 180 degrees."""
TRANSLATION_CAP_LDU = 10_000.0
"""The largest translation error a brick contributes to the means (LDU); larger or non-finite ones
are capped here and counted in ``capped_translations``."""
_EPS = 1e-9


# -- targets ----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class BrickTarget:
    """One brick to place: identity, the catalog cells equivalent to it, its pose and symmetry."""

    part: str
    colour: int
    cells: frozenset
    """(row, col) cells, 1-indexed, holding a brick of the same geometry and colour."""
    R: np.ndarray
    t: np.ndarray
    symmetry: Symmetry | None = None
    """The part's symmetry (`load_part(...).symmetry`); None: no symmetry."""

    def __post_init__(self):
        object.__setattr__(self, "cells", frozenset((int(r), int(c)) for r, c in self.cells))
        object.__setattr__(self, "R", np.array(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.array(self.t, dtype=np.float64).reshape(3))


@dataclass(frozen=True)
class StepTarget:
    """One assembly step of one object: the bricks added in it, in answer order."""

    id: str
    object_id: str
    bricks: tuple = field(default_factory=tuple)

    def __post_init__(self):
        object.__setattr__(self, "bricks", tuple(self.bricks))


# -- geometry ---------------------------------------------------------------------------------


def project_to_rotation(M) -> tuple[np.ndarray, bool]:
    """(nearest proper rotation in the Frobenius norm, whether M was not a rotation within 1e-3).

    SVD ``M = U S V^T``; the nearest rotation is ``U diag(1, 1, det(U V^T)) V^T``. Rounded printed
    rotations (0.7071) are not flagged; scaled, sheared, reflected or non-finite ones are (a
    non-finite matrix maps to the identity). Scoring first asks `rotation_kind`: a degenerate or
    mirrored matrix is never projected.
    """
    m = np.asarray(M, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(m)):
        return np.eye(3), True
    r = nearest_rotation_matrix(m)
    return r, bool(np.max(np.abs(m - r)) > PROJECTION_TOL)


def is_degenerate(M) -> bool:
    """Whether a predicted matrix is no rotation at all: non-finite, or its columns not orthonormal
    within `DEGENERATE_TOL` (singular, scaled, sheared). Wrong in every mode."""
    m = np.asarray(M, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(m)) or np.max(np.abs(m)) > 1e6:  # larger entries: far off, and m.T @ m overflows
        return True
    return bool(np.max(np.abs(m.T @ m - np.eye(3))) > DEGENERATE_TOL)


def is_mirrored(M) -> bool:
    """Whether a predicted matrix is a reflection (finite, determinant < 0, not degenerate): wrong
    in every mode."""
    m = np.asarray(M, dtype=np.float64).reshape(3, 3)
    return bool(not is_degenerate(m) and np.linalg.det(m) < 0.0)


def rotation_kind(M) -> str:
    """'degenerate', 'mirrored', 'projected' (scored as its nearest rotation) or 'rotation'."""
    if is_degenerate(M):
        return "degenerate"
    if is_mirrored(M):
        return "mirrored"
    return "projected" if project_to_rotation(M)[1] else "rotation"


MIRRORED_ERROR_DEG = 180.0
"""The rotation error of a mirrored or degenerate answer: the largest angle, so it never passes a
threshold."""


def translation_error(t_gt, t_pred) -> float:
    """Euclidean distance in LDU, capped at `TRANSLATION_CAP_LDU` (also for non-finite answers,
    without overflow warnings)."""
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.asarray(t_pred, dtype=np.float64) - np.asarray(t_gt, dtype=np.float64)
        if not np.all(np.isfinite(d)) or np.max(np.abs(d)) > TRANSLATION_CAP_LDU:
            return TRANSLATION_CAP_LDU
        return float(min(np.linalg.norm(d), TRANSLATION_CAP_LDU))


def translation_capped(t_gt, t_pred) -> bool:
    """Whether a translation's error is beyond `TRANSLATION_CAP_LDU` (or not finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.asarray(t_pred, dtype=np.float64) - np.asarray(t_gt, dtype=np.float64)
        return bool(not np.all(np.isfinite(d)) or np.linalg.norm(d) > TRANSLATION_CAP_LDU)


def _angle_deg(e: np.ndarray) -> float:
    """Rotation angle of e, as ``atan2(sin, cos)``: equal to ``acos((tr e - 1) / 2)`` for a rotation,
    but accurate near 0 and 180 degrees, and never out of domain."""
    s = 0.5 * math.hypot(e[2, 1] - e[1, 2], e[0, 2] - e[2, 0], e[1, 0] - e[0, 1])
    c = 0.5 * (e[0, 0] + e[1, 1] + e[2, 2] - 1.0)
    return math.degrees(math.atan2(s, c))


def _about(axis: np.ndarray, radians: float) -> np.ndarray:
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(radians) * k + (1.0 - math.cos(radians)) * (k @ k)


def rotation_error_deg(R_gt, R_pred, symmetry=None) -> float:
    """Geodesic angle between R_gt and R_pred in degrees, minimised over the part's symmetries.

    Discrete: min over S of angle(R_gt @ S, R_pred). Continuous axis a (part frame): also min over
    all turns about a, in closed form. With ``D = (R_gt S)^T R_pred``, ``tr(Rot(a, p) D) =
    a^T D a + cos p (tr D - a^T D a) + sin p tr(K_a D)``, maximal at ``p = atan2(tr(K_a D),
    tr D - a^T D a)``; the error is the angle of the residual ``Rot(a, p) D``. R_pred is first
    replaced by its nearest rotation (`project_to_rotation`); a mirrored R_pred (`is_mirrored`)
    or degenerate R_pred (`rotation_kind`) has error `MIRRORED_ERROR_DEG`.
    """
    if rotation_kind(R_pred) in ("mirrored", "degenerate"):
        return MIRRORED_ERROR_DEG
    r_gt = np.asarray(R_gt, dtype=np.float64).reshape(3, 3)
    r_pred, _ = project_to_rotation(R_pred)
    rotations = list(getattr(symmetry, "rotations", ()) or ()) or [np.eye(3)]
    axis = getattr(symmetry, "continuous_axis", None)
    if axis is not None:
        axis = np.asarray(axis, dtype=np.float64)
        axis = axis / np.linalg.norm(axis)
        k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    best = 180.0
    for s in rotations:
        d = (r_gt @ np.asarray(s, dtype=np.float64)).T @ r_pred
        if axis is not None:
            along = axis @ d @ axis
            p = math.atan2(float(np.trace(k @ d)), float(np.trace(d) - along))
            d = _about(axis, p) @ d
        best = min(best, _angle_deg(d))
    return best


@dataclass(frozen=True)
class BrickResult:
    """One predicted brick against its target, in one mode."""

    translation_error: float
    rotation_error: float
    translation_ok: bool
    rotation_ok: bool
    projected: bool
    mirrored: bool = False
    """The answer's matrix was a reflection (`is_mirrored`): wrong, rotation error 180 degrees."""
    degenerate: bool = False
    """The answer's matrix was no rotation (`is_degenerate`): wrong, rotation error 180 degrees."""
    capped: bool = False
    """The translation error was beyond `TRANSLATION_CAP_LDU` and is given as that."""

    @property
    def ok(self) -> bool:
        return self.translation_ok and self.rotation_ok


def judge_rotation(R_gt, R_pred, symmetry=None) -> tuple[float, str]:
    """(rotation error in degrees, `rotation_kind` of R_pred): the one place where a predicted
    matrix is classified before it is scored."""
    kind = rotation_kind(R_pred)
    if kind in ("mirrored", "degenerate"):
        return MIRRORED_ERROR_DEG, kind
    return rotation_error_deg(R_gt, R_pred, symmetry), kind


def evaluate_brick(target: BrickTarget, answer: PoseAnswer, mode: str = "paper") -> BrickResult:
    """Errors and correctness of one predicted pose (the brick's identity is the target's)."""
    _check_mode(mode)
    t_pred = np.asarray(answer.t, dtype=np.float64).reshape(3)
    t_err, capped = translation_error(target.t, t_pred), translation_capped(target.t, t_pred)
    r_err, kind = judge_rotation(target.R, answer.R, target.symmetry)
    wrong_matrix = kind in ("mirrored", "degenerate")
    if mode == "strict":
        t_ok = t_err <= 0.5 + _EPS
        r_ok = r_err <= 1.0 + _EPS
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            t_ok = bool(np.all(np.abs(t_pred - target.t) <= 10.0 + _EPS))
        r_ok = r_err < 45.0 - _EPS
    return BrickResult(t_err, r_err, bool(t_ok and not capped), bool(r_ok and not wrong_matrix), kind == "projected",
                       kind == "mirrored", kind == "degenerate", capped)


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")


# -- selection --------------------------------------------------------------------------------


def match_cells(targets: list[frozenset], cells: list[tuple[int, int]]) -> list[int | None]:
    """A maximum matching of cells to targets: for each target, the index of its cell or None.

    Each target and each cell is used once; a cell fits a target when it is in the target's set.
    Kuhn's augmenting paths: steps hold a few bricks, so this is instant.
    """
    owner: dict[int, int] = {}  # cell index -> target index

    def augment(ti: int, seen: set[int]) -> bool:
        # Free cells first, so the result is greedy (in cell order) wherever greedy suffices.
        order = sorted(range(len(cells)), key=lambda ci: ci in owner)
        for ci in order:
            if cells[ci] in targets[ti] and ci not in seen:
                seen.add(ci)
                if ci not in owner or augment(owner[ci], seen):
                    owner[ci] = ti
                    return True
        return False

    for ti in range(len(targets)):
        augment(ti, set())
    out: list[int | None] = [None] * len(targets)
    for ci, ti in owner.items():
        out[ti] = ci
    return out


def selection_score(step: StepTarget, picks) -> float:
    """``matched / max(#targets, #distinct picked cells)``; 0 for no picks (see module docstring)."""
    cells = list(dict.fromkeys((int(p.row), int(p.col)) if hasattr(p, "row") else tuple(p) for p in picks))
    if not cells or not step.bricks:
        return 0.0
    matched = sum(m is not None for m in match_cells([b.cells for b in step.bricks], cells))
    return matched / max(len(step.bricks), len(cells))


# -- one step ---------------------------------------------------------------------------------


@dataclass
class StepResult:
    step: StepTarget
    selection: float = 0.0
    selection_status: str = "missing"  # "ok", "missing", "unparseable"
    pose_status: str = "missing"  # "ok", "missing", "unparseable" (some brick has no pose)
    bricks: list = field(default_factory=list)  # BrickResult or None per target brick
    success: bool = False

    @property
    def translation_error(self) -> float | None:
        vals = [b.translation_error for b in self.bricks if b is not None]
        return float(np.mean(vals)) if vals else None

    @property
    def rotation_error(self) -> float | None:
        vals = [b.rotation_error for b in self.bricks if b is not None]
        return float(np.mean(vals)) if vals else None


def score_step(step: StepTarget, selection_text, pose_text, mode: str = "paper") -> StepResult:
    """Score one step's two answers (None: missing). See the module docstring for the rules."""
    _check_mode(mode)
    res = StepResult(step)
    if selection_text is not None:
        picks = parse_selection(selection_text)
        res.selection_status = "ok" if picks else "unparseable"
        res.selection = selection_score(step, picks)
    blocks = parse_pose(pose_text) if pose_text is not None else {}
    res.bricks = [
        evaluate_brick(b, blocks[i + 1], mode) if (i + 1) in blocks else None for i, b in enumerate(step.bricks)
    ]
    if pose_text is not None:
        res.pose_status = "ok" if all(b is not None for b in res.bricks) else "unparseable"
    pose_ok = pose_text is not None and all(b is not None and b.ok for b in res.bricks)
    selection_ok = selection_text is None or res.selection >= 1.0 - _EPS
    res.success = bool(pose_ok and selection_ok and step.bricks)
    return res


# -- aggregation ------------------------------------------------------------------------------


def _mean(vals) -> float | None:
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) if vals else None


def _object_metrics(results: list[StepResult]) -> dict:
    return {
        "selection_accuracy": _mean(r.selection for r in results),
        "translation_error_ldu": _mean(r.translation_error for r in results),
        "rotation_error_deg": _mean(r.rotation_error for r in results),
        "step_success": _mean(float(r.success) for r in results),
    }


def answer_text(predictions: dict, key):
    """The answer under `key`: None when missing, "" (unparseable) when not a string."""
    value = predictions.get(key)
    if value is None:
        return None
    return value if isinstance(value, str) else ""  # a non-string answer is unparseable


def new_counts(steps: list) -> dict:
    """The ``counts`` of a score over `steps`, every count at 0 (`objects` set at the end)."""
    return {
        "steps": len(steps),
        "objects": 0,
        "unparseable": 0,
        "unparseable_selection": 0,
        "unparseable_pose": 0,
        "projected_rotations": 0,
        "mirrored_rotations": 0,
        "degenerate_rotations": 0,
        "capped_translations": 0,
        "missing_predictions": 0,
        "failures": {"mirrored": 0, "degenerate": 0, "translation_only": 0, "rotation_only": 0, "both": 0,
                     "unparseable": 0},
    }


def count_bricks(counts: dict, bricks) -> None:
    """Add one step's bricks (results with `projected`, `mirrored`, `degenerate`, `capped`,
    `translation_ok`, `rotation_ok`; None for no pose) to `counts`: projections, mirrors,
    degenerate matrices, capped translations and the failure kinds."""
    fails = counts["failures"]
    for b in bricks:
        if b is None:
            fails["unparseable"] += 1
            continue
        counts["projected_rotations"] += b.projected
        counts["mirrored_rotations"] += b.mirrored
        counts["degenerate_rotations"] += b.degenerate
        counts["capped_translations"] += b.capped
        if b.mirrored:
            fails["mirrored"] += 1
        elif b.degenerate:
            fails["degenerate"] += 1
        elif not b.translation_ok and not b.rotation_ok:
            fails["both"] += 1
        elif not b.translation_ok:
            fails["translation_only"] += 1
        elif not b.rotation_ok:
            fails["rotation_only"] += 1


def score(steps: list[StepTarget], predictions: dict, mode: str = "paper") -> dict:
    """Score predictions ``{(step id, "selection" | "pose"): text}`` against the steps.

    Returns ``{"overall", "best_object", "counts", "mode"}`` as described in the module docstring.
    """
    _check_mode(mode)
    ids = [s.id for s in steps]
    if len(set(ids)) != len(ids):
        raise ValueError("step ids must be unique")
    counts = new_counts(steps)
    by_object: dict[str, list[StepResult]] = {}
    for step in steps:
        sel = answer_text(predictions, (step.id, "selection"))
        pose = answer_text(predictions, (step.id, "pose"))
        res = score_step(step, sel, pose, mode)
        by_object.setdefault(step.object_id, []).append(res)
        counts["missing_predictions"] += (sel is None) + (pose is None)
        counts["unparseable_selection"] += res.selection_status == "unparseable"
        counts["unparseable_pose"] += res.pose_status == "unparseable"
        count_bricks(counts, res.bricks)
    counts["unparseable"] = counts["unparseable_selection"] + counts["unparseable_pose"]
    counts["objects"] = len(by_object)

    per_object = {obj: _object_metrics(results) for obj, results in by_object.items()}
    keys = ("selection_accuracy", "translation_error_ldu", "rotation_error_deg", "step_success")
    overall = {k: _mean(m[k] for m in per_object.values()) for k in keys}
    if per_object:
        def rank(obj):
            m = per_object[obj]
            t = m["translation_error_ldu"]
            return (-m["step_success"], math.inf if t is None else t, obj)

        best = min(per_object, key=rank)
        best_object = {**per_object[best], "object": best}
    else:
        best_object = {**{k: None for k in keys}, "object": None}
    return {"overall": overall, "best_object": best_object, "counts": counts, "mode": mode}
