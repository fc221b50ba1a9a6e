"""BC-Bench's layout, found and checked: `read_bcbench` finds the pose files, tasks.json files and
split lists under a folder, checks every field it reads (a `BCBenchError` names the file, the JSON
path and what was expected) and joins them by (object folder, step number) into `Step`s, each with
its `PoseBrick`s and catalog cells (`BCBenchData`: the steps and the counts). The released absolute
image paths are found again under the folder by their trailing components, so they need no
rewriting.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from factory.dataset.answers import normalise_part
from factory.dataset.tasks import SPLITS
from pipelines.bcbench.layout import EXTENSION, POSE_FILE, TASKS_FILE, BCBenchError, _fail

MAX_DEPTH = 5
"""How deep under SRC `read_bcbench` looks for tasks.json, split lists and pose files."""


@dataclass
class PoseBrick:
    part: str
    colour: int
    T: tuple[float, float, float]
    R: tuple[tuple[float, ...], ...]


@dataclass
class Step:
    """One step found in both files (or in the pose file alone when SRC has no tasks.json)."""
    object: str
    step_k: int
    split: str
    pose_file: Path
    pose_index: int
    images: list[Path]
    """Resolved: before, after, part render(s)..., axes."""
    human: str
    system: str | None
    answer: str | None
    bricks: list[PoseBrick]
    task: dict | None = None
    task_file: Path | None = None
    task_index: int | None = None
    catalog: Path | None = None
    cells: list[list[tuple[int, int]]] = field(default_factory=list)
    """Per pose brick, its candidate cells (1-based); empty lists without a task."""
    pooled_cells: bool = False


@dataclass
class BCBenchData:
    """What `read_bcbench` found under SRC: the steps to import, in (object, step) order, and the counts."""
    src: Path
    steps: list[Step]
    blank: int
    skipped: dict[str, int]
    tasks: tuple[str, ...]
    pose_files: list[Path]
    ignored_files: list[Path]
    """JSON files under SRC that are none of the layout's (not a pose set, tasks.json or split list)."""
    task_files: list[Path]
    split_lists: list[Path]
    split_from: dict[str, int]
    num_steps: dict[str, int]
    """Per object: 1 + the largest step number seen (blank and skipped steps included)."""


_STEP_DIR = re.compile(r"step_(\d+)(?:_.*)?")
_KEY = re.compile(r"(.+)/step_(\d+)(?:_[^/]*)?")


def _resolve(raw, src: Path, base: Path, file, where: str) -> Path:
    """A path from a file of the layout: as written when it exists (relative: to `base`, then to
    `src`), else the longest run of its trailing components (at least 3: object, step, file) that
    exists under `src`, so absolute paths of another machine need no rewriting."""
    if not isinstance(raw, str) or not raw:
        raise _fail(file, where, "an image path (a string)", raw)
    p = Path(raw)
    if p.is_absolute():
        if p.is_file():
            return p
    else:
        for root in (base, src):
            if (root / p).is_file():
                return root / p
    parts = p.parts[1:] if p.is_absolute() else p.parts
    for i in range(len(parts) - 2):
        cand = src.joinpath(*parts[i:])
        if cand.is_file():
            return cand
    raise BCBenchError(f"{file}: {where}: expected an existing image, got {raw!r} (not found as written, nor by "
                       f"its trailing folders under {src})")


def _load_json(path: Path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise BCBenchError(f"{path}: not UTF-8 text ({exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise BCBenchError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None


def _int(value, file, where: str, what: str = "an integer", minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or (minimum is not None and value < minimum):
        raise _fail(file, where, what, value)
    return value


def _number(value, file, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _fail(file, where, "a finite number", value)
    return float(value)


def _walk(src: Path):
    """(pose candidates, tasks.json files, split lists) under `src`, at most MAX_DEPTH folders down;
    step folders (images) are not entered."""
    pose, tasks, lists = [], [], []
    for dirpath, dirnames, filenames in os.walk(src):
        d = Path(dirpath)
        depth = len(d.relative_to(src).parts)
        dirnames[:] = sorted(n for n in dirnames if not n.startswith(".") and not _STEP_DIR.fullmatch(n)
                             and depth < MAX_DEPTH)
        for name in sorted(filenames):
            if not name.endswith(".json") or name.startswith("."):
                continue
            if name == TASKS_FILE:
                tasks.append(d / name)
            elif name in ("train.json", "test.json"):
                lists.append(d / name)
            elif name not in (POSE_FILE, "dataset_info.json"):
                pose.append(d / name)
    return pose, tasks, lists


def _is_pose_file(data) -> bool:
    """A ShareGPT list whose first record has at least 4 images, the first in a `step_<k>` folder
    (other LLaMA-Factory files of a release, selection sets say, are ignored and listed)."""
    if not (isinstance(data, list) and data and isinstance(data[0], dict) and "conversations" in data[0]):
        return False
    images = data[0].get("images")
    return (isinstance(images, list) and len(images) >= 4 and isinstance(images[0], str)
            and _STEP_DIR.fullmatch(Path(images[0]).parent.name) is not None)


def _read_bricks(path: Path) -> tuple[bool, list[PoseBrick]]:
    data = _load_json(path)
    if not isinstance(data, dict):
        raise _fail(path, "", "a JSON object with is_blank and bricks", data)
    blank = data.get("is_blank", False)
    if not isinstance(blank, bool):
        raise _fail(path, "is_blank", "true or false", blank)
    bricks = data.get("bricks", [])
    if not isinstance(bricks, list):
        raise _fail(path, "bricks", "a list of bricks", bricks)
    out = []
    for i, b in enumerate(bricks):
        at = f"bricks[{i}]"
        if not isinstance(b, dict):
            raise _fail(path, at, "an object with brick_name, ldraw_color, x, y, z, transform", b)
        name = b.get("brick_name")
        if not isinstance(name, str) or not name.strip():
            raise _fail(path, f"{at}.brick_name", "a part file name such as 3023.dat", name)
        colour = b.get("ldraw_color")
        colour = -1 if colour is None else _int(colour, path, f"{at}.ldraw_color", "an LDraw colour code (integer)")
        t = tuple(_number(b.get(k), path, f"{at}.{k}") for k in ("x", "y", "z"))
        m = b.get("transform")
        if not (isinstance(m, list) and len(m) == 3 and all(isinstance(r, list) and len(r) == 3 for r in m)):
            raise _fail(path, f"{at}.transform", "a 3x3 rotation matrix as three rows of three numbers", m)
        R = tuple(tuple(_number(v, path, f"{at}.transform[{r}][{c}]") for c, v in enumerate(row))
                  for r, row in enumerate(m))
        out.append(PoseBrick(normalise_part(name), colour, t, R))
    return blank, out


def _read_pose_record(rec, i: int, path: Path, src: Path):
    """(object, step_k, images, human, system, answer) of one ShareGPT record; images[0] is
    resolved (it locates the step folder), the others are resolved once the step is imported."""
    at = f"[{i}]"
    if not isinstance(rec, dict):
        raise _fail(path, at, "a record with system, conversations and images", rec)
    images = rec.get("images")
    if not isinstance(images, list) or len(images) < 4:
        raise _fail(path, f"{at}.images", "a list of at least 4 image paths (before views, after views, part "
                    "render(s), axes composite)", images)
    conv = rec.get("conversations")
    if not isinstance(conv, list) or not conv or not isinstance(conv[0], dict):
        raise _fail(path, f"{at}.conversations", "a list of turns, the first {\"from\": \"human\", \"value\": ...}",
                    conv)
    turns = []
    for j, turn in enumerate(conv[:2]):
        value = turn.get("value", turn.get("content")) if isinstance(turn, dict) else None
        if not isinstance(value, str):
            raise _fail(path, f"{at}.conversations[{j}].value", "a string", value)
        turns.append(value)
    human = turns[0]
    if human.count("<image>") != len(images):
        raise _fail(path, f"{at}.conversations[0].value", f"one <image> per image ({len(images)})",
                    f"{human.count('<image>')} <image> placeholders", has_got=True)
    system = rec.get("system")
    if system is not None and not isinstance(system, str):
        raise _fail(path, f"{at}.system", "a string", system)
    resolved = [_resolve(images[0], src, path.parent, path, f"{at}.images[0]"), *images[1:]]
    step_dir = resolved[0].parent
    m = _STEP_DIR.fullmatch(step_dir.name)
    if not m:
        raise _fail(path, f"{at}.images[0]", "an image in a step folder named step_<k> (k: the step number), "
                    "inside the object's folder", images[0])
    return step_dir.parent.name, int(m.group(1)), resolved, human, system, (turns[1] if len(turns) > 1 else None)


def _read_task(task, i: int, path: Path, src: Path) -> tuple[int, bool, dict]:
    at = f"tasks[{i}]"
    if not isinstance(task, dict):
        raise _fail(path, at, "a task object", task)
    k = _int(task.get("step_k"), path, f"{at}.step_k", "the step number, an integer >= 0", 0)
    blank = task.get("is_blank", False)
    if not isinstance(blank, bool):
        raise _fail(path, f"{at}.is_blank", "true or false", blank)
    if blank:
        return k, True, task
    gt = task.get("gt_bricks")
    if not isinstance(gt, list) or not all(isinstance(b, str) for b in gt):
        raise _fail(path, f"{at}.gt_bricks", "a list of part file names", gt)
    positions = task.get("gt_position") or []
    if not isinstance(positions, list):
        raise _fail(path, f"{at}.gt_position", "a list of {\"candidate_positions\": [{\"row\", \"col\"}]}", positions)
    for j, entry in enumerate(positions):
        cands = entry.get("candidate_positions") if isinstance(entry, dict) else None
        if not isinstance(cands, list):
            raise _fail(path, f"{at}.gt_position[{j}].candidate_positions", "a list of {\"row\": r, \"col\": c}",
                        cands)
        for c_i, c in enumerate(cands):
            w = f"{at}.gt_position[{j}].candidate_positions[{c_i}]"
            if not isinstance(c, dict):
                raise _fail(path, w, "{\"row\": r, \"col\": c} (1-based)", c)
            _int(c.get("row"), path, f"{w}.row", "a 1-based row (integer >= 1)", 1)
            _int(c.get("col"), path, f"{w}.col", "a 1-based column (integer >= 1)", 1)
    count = task.get("catalog_brick_count")
    if count is not None:
        _int(count, path, f"{at}.catalog_brick_count", "the number of catalog cells (integer >= 0)", 0)
    imgs = task.get("input_images")
    if not isinstance(imgs, dict):
        raise _fail(path, f"{at}.input_images", "an object with catalog_remaining", imgs)
    key = "catalog_remaining" if imgs.get("catalog_remaining") else "catalog_remaining_no_caption"
    task = dict(task)
    task["_catalog"] = _resolve(imgs.get(key), src, path.parent, path, f"{at}.input_images.{key}")
    ext = task.get(EXTENSION)
    if ext is not None and not isinstance(ext, dict):
        raise _fail(path, f"{at}.{EXTENSION}", "an object", ext)
    return k, False, task


def _split_lists(paths: list[Path]) -> dict[str, set]:
    found: dict[str, set] = {}
    for path in paths:
        data = _load_json(path)
        if not isinstance(data, list) or not all(isinstance(k, str) for k in data):
            raise _fail(path, "", "a list of step keys \"<object>/step_<k:04d>_<view>\"", data)
        split = path.stem
        for i, key in enumerate(data):
            m = _KEY.fullmatch(key)
            if not m:
                raise _fail(path, f"[{i}]", "a step key \"<object>/step_<k:04d>_<view>\"", key)
            found.setdefault(split, set()).add((m.group(1).rsplit("/", 1)[-1], int(m.group(2))))
    return found


def _cells_per_brick(step: Step, task: dict, task_file: Path, i: int) -> None:
    """Join a task to the pose bricks: check the parts, give each brick its candidate cells."""
    gt = [normalise_part(b) for b in task["gt_bricks"]]
    pose = [b.part for b in step.bricks]
    if Counter(gt) != Counter(pose):
        raise BCBenchError(f"{task_file}: tasks[{i}].gt_bricks: expected the parts of "
                           f"{step.images[0].parent / POSE_FILE} {pose}, got {gt}")
    positions = task.get("gt_position") or []
    cands = [sorted({(int(c["row"]), int(c["col"])) for c in e["candidate_positions"]}) for e in positions]
    if len(cands) == len(gt):
        # entry j belongs to gt_bricks[j]; pose bricks take the entries of their part in order
        free: dict[str, list[int]] = {}
        for j, name in enumerate(gt):
            free.setdefault(name, []).append(j)
        step.cells = [cands[free[b.part].pop(0)] for b in step.bricks]
    else:
        # not one entry per brick: BC-Bench's scorer accepts any candidate for any brick; so do we
        pooled = sorted({c for cs in cands for c in cs})
        step.cells = [list(pooled) for _ in step.bricks]
        step.pooled_cells = bool(step.bricks)


def read_bcbench(src, default_split: str = "test") -> BCBenchData:
    """Find BC-Bench's files under `src` and join them by (object folder, step number).

    Pose records come from every ShareGPT JSON file (a list of records with `conversations`) found
    under `src` (at most MAX_DEPTH folders down), tasks from every `tasks.json`, splits from
    `test.json` / `train.json` step-key lists. A step is imported when its brick_pose.json has
    bricks and is not blank and, if `src` has any tasks.json, when it also has a non-blank task
    (the imported folder then provides both tasks; else pose only). Split of a step: its key in a
    split list (a step missing from a lone test.json is train), else the pose file's name
    (`test`/`testing` or `train`/`training` in it), else `default_split`.
    """
    if default_split not in SPLITS:
        raise BCBenchError(f"default split must be one of {', '.join(SPLITS)}, got {default_split!r}")
    src = Path(src)
    if not src.is_dir():
        raise BCBenchError(f"{src}: not a folder")
    candidates, task_files, list_files = _walk(src)
    skipped = Counter()
    blank_keys: set = set()
    seen: dict[str, int] = {}

    def saw(obj: str, k: int) -> None:
        seen[obj] = max(seen.get(obj, 0), k + 1)

    # -- pose records
    pose_files, ignored, steps, where = [], [], {}, {}
    for path in candidates:
        data = _load_json(path)
        if not _is_pose_file(data):
            ignored.append(path)
            continue
        pose_files.append(path)
        name = path.stem.lower()
        file_split = "test" if "test" in name else "train" if "train" in name else None
        for i, rec in enumerate(data):
            obj, k, images, human, system, answer = _read_pose_record(rec, i, path, src)
            saw(obj, k)
            key = (obj, k)
            if key in where:
                raise BCBenchError(f"{path}: [{i}]: step {k} of {obj} is also record {where[key]}")
            where[key] = f"[{i}] of {path}"
            bp = images[0].parent / POSE_FILE
            if not bp.is_file():
                skipped["no_brick_pose"] += 1  # BC-Bench's pose script skips these too
                continue
            blank, bricks = _read_bricks(bp)
            if blank:
                blank_keys.add(key)
                continue
            if not bricks:
                skipped["no_bricks"] += 1
                continue
            images[1:] = [_resolve(p, src, path.parent, path, f"[{i}].images[{k}]")
                          for k, p in enumerate(images[1:], 1)]
            steps[key] = Step(obj, k, file_split or "", path, i, images, human, system, answer, bricks)
    if not pose_files:
        raise BCBenchError(f"{src}: no pose file found (a ShareGPT JSON list of records with system, conversations "
                           f"and at least 4 images, the first in a step_<k> folder holding {POSE_FILE}), at most "
                           f"{MAX_DEPTH} folders down" + (f"; ignored: {', '.join(str(p) for p in ignored[:5])}"
                                                          if ignored else ""))

    # -- selection tasks
    tasks: dict = {}
    for path in task_files:
        data = _load_json(path)
        if not isinstance(data, dict) or not isinstance(data.get("tasks"), list):
            raise _fail(path, "", "{\"tasks\": [...]}", data)
        obj = path.parent.name
        for i, task in enumerate(data["tasks"]):
            k, blank, task = _read_task(task, i, path, src)
            saw(obj, k)
            if (obj, k) in tasks:
                raise BCBenchError(f"{path}: tasks[{i}]: step {k} of {obj} appears twice")
            if blank:
                blank_keys.add((obj, k))
                tasks[(obj, k)] = None
            else:
                tasks[(obj, k)] = (path, i, task)
    with_selection = bool(task_files)
    joined = []
    for key in sorted(steps):
        if key in blank_keys:  # blank in tasks.json though brick_pose.json has bricks
            continue
        step = steps[key]
        hit = tasks.get(key)
        if with_selection and hit is None:
            skipped["pose_only"] += 1
            continue
        if hit is not None:
            path, i, task = hit
            step.task, step.task_file, step.task_index, step.catalog = task, path, i, task["_catalog"]
            _cells_per_brick(step, task, path, i)
            skipped["gt_position_pooled"] += step.pooled_cells
        else:
            step.cells = [[] for _ in step.bricks]
        joined.append(step)
    skipped["selection_only"] = sum(1 for key, hit in tasks.items() if hit is not None and key not in steps
                                    and key not in blank_keys)

    # -- splits
    lists = _split_lists(list_files)
    split_from = Counter()
    for step in joined:
        key = (step.object, step.step_k)
        listed = [s for s in ("test", "train") if key in lists.get(s, ())]
        if listed:
            step.split, how = listed[0], "split list"
        elif "test" in lists and "train" not in lists:
            step.split, how = "train", "not in test.json"
        elif "train" in lists and "test" not in lists:
            step.split, how = "test", "not in train.json"
        elif step.split:
            how = "pose file name"
        else:
            step.split, how = default_split, "default"
        split_from[how] += 1
    return BCBenchData(
        src=src, steps=joined, blank=len(blank_keys),
        skipped={k: int(skipped[k]) for k in sorted({"pose_only", "selection_only", *skipped})
                 if skipped[k] or k in ("pose_only", "selection_only")},
        tasks=("selection", "pose") if with_selection else ("pose",),
        pose_files=pose_files, ignored_files=ignored, task_files=task_files, split_lists=list_files,
        split_from=dict(sorted(split_from.items())), num_steps=seen,
    )
