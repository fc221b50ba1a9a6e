"""BC-Bench's released data layout, out and in.

    python -m pipelines.export OUT --format bcbench DEST      # ours -> their layout (`write_bcbench`)
    python -m pipelines.bcbench import SRC OUT [--ldraw DIR]   # their layout -> ours (`import_bcbench`)

The layout is the one BC-Bench's evaluation scripts read (Brick-Composer, `reasoning/`; docs:
docs/reference/bcbench-layout.md, "BC-Bench layout: export and import"):

- pose estimation: a LLaMA-Factory ShareGPT JSON file, a list of records {"system", "conversations":
  [{"from": "human", "value": text with one `<image>` per image}, {"from": "gpt", "value": answer}],
  "images": [before views, after views, part render(s), 7-view axes composite]}. The folder of the
  first image is the step folder, named `step_<k>` (the scripts read k as the integer after the first
  `_`) inside the object folder; it holds `brick_pose.json`: {"is_blank": bool, "bricks":
  [{"brick_name", "ldraw_color", "x", "y", "z", "transform"}]}, translation in LDU and `transform` the
  3x3 rotation as rows, compared as `R_gt @ g` with the part's symmetries g (so it maps the part's
  frame into the model's: the LDraw type-1 matrix).
- brick selection: one `tasks.json` per object folder, {"tasks": [{"step_k", "view_folder", "is_blank",
  "ground_truth" ('module "..."' for a multi-brick step), "gt_bricks" (part file names),
  "gt_position" ([{"candidate_positions": [{"row", "col"}]}], 1-based catalog cells),
  "catalog_brick_count", "input_images": {"original": [6 view images], "target": [6 view images],
  "catalog_remaining", "catalog_remaining_no_caption"}, "task_dir"}]}, step folders
  `step_<k:04d>_<view_folder>` beside it, and a `test.json` listing the test steps as
  "<object folder>/step_<k:04d>_<view_folder>".

`write_bcbench` puts both in one tree under DEST (the pose step folder is the selection step folder),
with every path relative to DEST, and streams one object at a time. `read_bcbench` finds these files
under a folder (the released absolute paths are found again under it by their trailing components,
so they need no rewriting) and `import_bcbench` writes our dataset format from them. Fields of ours
that the layout has no place for travel in a `brick_factory` key of each task (ignored by BC-Bench's
scripts), so our data comes back unchanged.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import re
import shutil
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from PIL import Image, ImageDraw, ImageFont

from factory.atomic import umask
from factory.cli import ArgumentParser, run_guarded
from factory.dataset import prompts
from factory.dataset.answers import format_pose, format_selection, normalise_part
from factory.dataset.info import Counts, DatasetInfo, read_info, write_info
from factory.dataset.schema import SCHEMA
from factory.dataset.tasks import POSE_IMAGES, SELECTION_IMAGES, SPLITS
from factory.errors import LDrawError
from factory.ldraw import Library, Reader, get_reader
from factory.parts import LDU_CM, load_part
from pipelines.dataset.config import check_name
from pipelines.dataset.png import SIGNATURE, png_bytes
from pipelines.dataset.shards import WRITER_OPTIONS

VIEW_FOLDER = "0"
"""`view_folder` of the steps we write (BC-Bench's name a camera setting, e.g. "340"; ours have one)."""
TASKS_ROOT = "tasks"
"""DEST/tasks: object folders (tasks.json and step folders) and the split lists."""
FILES = {
    "before": "original_orthogonal_views.png",
    "after": "target_orthogonal_views.png",
    "part": "part_render.png",
    "axes": "current_state_axes.png",
    "catalog": "catalog_remaining.png",
}
"""Our image columns -> file names in a step folder (the first two and the axes are the names
BC-Bench's pose script documents; ours have no caption-free catalog, so both catalog keys name one)."""
VIEW_NAMES = {"Top": "Up", "Front": "front", "Right": "Right", "Bottom": "Bottom", "Back": "Back", "Left": "Left"}
"""Our six views (in our composite's order) -> the names of BC-Bench's per-view files
(`original_<name>.png`, `target_<name>.png`, read by its selection script `run.py`)."""
POSE_FILE = "brick_pose.json"
TASKS_FILE = "tasks.json"
EXTENSION = "brick_factory"
"""Key of a task holding what the layout has no field for (step id, assembly, step kind, catalog)."""
CATALOG_COLUMNS = 6
UNKNOWN_PART = ""
"""Part (with colour -1) of a catalog cell an imported task does not name (only the target cells and
the cell count are in BC-Bench's tasks)."""
GRID_GAP = 2
GRID_RGB = (200, 200, 200)
MAX_DEPTH = 5
"""How deep under SRC `read_bcbench` looks for tasks.json, split lists and pose files."""
FEEDBACK_SIZE = 256
"""`config.size` of an imported folder: the view size of world-feedback renders (eval.predict --feedback)."""


class BCBenchError(ValueError):
    """Input that is not in BC-Bench's layout: the message names the file, the JSON path and what was expected."""


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _fail(file, where: str, expected: str, got=None, has_got: bool = True) -> BCBenchError:
    at = f"{file}: {where}: " if where else f"{file}: "
    return BCBenchError(at + f"expected {expected}" + (f", got {_short(got)}" if has_got else ""))


def _dir_mode(path: Path) -> None:
    os.chmod(path, 0o777 & ~umask())  # mkdtemp makes 0700; a plain mkdir would give this


class _Staging:
    """A temporary folder beside `final`, renamed to it at the end (or removed on failure), so
    `final` holds a whole result or nothing. `final` must be absent or an empty folder."""
    def __init__(self, final, what: str):
        self.final = Path(final)
        if self.final.exists() and (not self.final.is_dir() or any(self.final.iterdir())):
            raise BCBenchError(f"{self.final}: the {what} folder exists and is not empty; give a new folder")
        self.final.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.", suffix=".tmp", dir=self.final.parent))
        _dir_mode(self.tmp)

    def __enter__(self) -> Path:
        return self.tmp

    def __exit__(self, kind, exc, tb) -> None:
        if kind is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        if self.final.is_dir():
            self.final.rmdir()  # empty (checked at the start)
        os.replace(self.tmp, self.final)


# ============================================================================================
# ours -> BC-Bench
# ============================================================================================
def six_views(png: bytes) -> dict[str, np.ndarray] | None:
    """Our six-view composite (`factory.render.images.six_view_composite`: 3 x 2 labelled square
    tiles, 2 px grey gaps) cut into its views without their label strips, by our view name; None
    when the image is not laid out so (then no per-view files are written)."""
    with Image.open(io.BytesIO(png)) as im:
        a = np.asarray(im.convert("RGB"))
    H, W = a.shape[:2]
    if (W - 2 * GRID_GAP) % 3 or (H - GRID_GAP) % 2:
        return None
    w, h = (W - 2 * GRID_GAP) // 3, (H - GRID_GAP) // 2
    strip = h - w
    if w < 8 or not 0 <= strip < w:
        return None
    grey = np.asarray(GRID_RGB, dtype=np.uint8)
    gaps = [a[:, w:w + GRID_GAP], a[:, 2 * w + GRID_GAP:2 * w + 2 * GRID_GAP], a[h:h + GRID_GAP, :]]
    if not all(np.all(g == grey) for g in gaps):
        return None
    out = {}
    for i, name in enumerate(VIEW_NAMES):
        r, c = divmod(i, 3)
        x0, y0 = c * (w + GRID_GAP), r * (h + GRID_GAP)
        out[name] = np.ascontiguousarray(a[y0 + strip:y0 + h, x0:x0 + w])
    return out


def _system_of(messages, default: str) -> str:
    for m in messages or []:
        if m["role"] == "system":
            return "\n".join(p["text"] or "" for p in m["content"] if p["type"] == "text")
    return default


def _human_value(messages) -> str:
    """The user turn as one ShareGPT string: each image part as `<image>`, in place."""
    for m in messages:
        if m["role"] == "user":
            out = ""
            for p in m["content"]:
                if p["type"] == "image":
                    out += "<image>"
                else:
                    text = p["text"] or ""
                    out += ("\n" if out.endswith("<image>") and not text.startswith("\n") else "") + text
            return out
    raise ValueError("conversation has no user message")


def _task_of(row: dict, rel: str, views: dict, images: dict) -> dict:
    """The tasks.json entry of one row (see the module docstring), paths relative to DEST."""
    bricks = row["bricks"]
    n = len(bricks)
    if row["step_kind"] == "module" or n > 1:
        assembly = row["assembly"]
        name = assembly.rsplit("/", 1)[-1].split("#")[0] if "/" in assembly else f"step_{row['step_index']}"
        ground_truth = f'module "{name}"'  # BC-Bench's selection scorer takes a multi-brick step by this prefix
    else:
        ground_truth = bricks[0]["part"] if bricks else ""
    return {
        "step_k": int(row["step_index"]),
        "view_folder": VIEW_FOLDER,
        "is_blank": False,
        "ground_truth": ground_truth,
        "gt_bricks": [b["part"] for b in bricks],
        "gt_position": [{"brick_name": b["part"], "ldraw_color": int(b["colour"]),
                         "candidate_positions": [{"row": int(r), "col": int(c)} for r, c in b["cells"]]}
                        for b in bricks],
        "catalog_brick_count": len(row["catalog_parts"]),
        "input_images": {
            "original": views.get("before", [images["before"]]),
            "target": views.get("after", [images["after"]]),
            "catalog_remaining": images["catalog"],
            "catalog_remaining_no_caption": images["catalog"],
        },
        "task_dir": rel,
        EXTENSION: {
            "step_id": row["step_id"],
            "assembly": row["assembly"],
            "step_kind": row["step_kind"],
            "catalog": [{"part": e["part"], "colour": int(e["colour"]), "row": int(e["row"]), "col": int(e["col"])}
                        for e in row["catalog_parts"]],
        },
    }


def _brick_pose(row: dict) -> dict:
    return {"is_blank": False, "bricks": [
        {"brick_name": b["part"], "ldraw_color": int(b["colour"]),
         "x": float(b["T"][0]), "y": float(b["T"][1]), "z": float(b["T"][2]),
         "transform": [[float(v) for v in r] for r in b["R"]]} for b in row["bricks"]]}


READ_COLUMNS = ("object_id", "step_id", "step_index", "split", "assembly", "step_kind", "before", "after", "part",
                "axes", "catalog", "bricks", "catalog_parts", "system", "selection_messages", "pose_messages",
                "pose_images", "pose_answer")


def write_bcbench(out, dest, splits=("train", "test"), png_level: int = 6) -> dict:
    """Write the built dataset `out` in BC-Bench's layout under `dest` (absent or empty); returns a
    summary {"dest", "splits": {split: {"objects", "steps", "pose_file"}}, "view_files"}.

    DEST/{dataset_id}_pose_{split}.json: the pose records (ShareGPT, our pose prompt and answer);
    DEST/dataset_info.json: them registered for LLaMA-Factory; DEST/tasks/<object>/tasks.json and
    DEST/tasks/<object>/step_<k:04d>_0/: images, per-view images and brick_pose.json;
    DEST/tasks/{split}.json: the split's step keys. Every path in a file is relative to DEST.
    One object's rows are in memory at a time; everything is written to a temporary folder renamed
    to `dest` at the end.
    """
    bad = [s for s in splits if s not in SPLITS]
    if bad:
        raise BCBenchError(f"unknown split {bad[0]!r}; valid: {', '.join(SPLITS)}")
    out, dest = Path(out), Path(dest)
    info_path = out / "meta" / "info.json"
    if not info_path.is_file():
        raise BCBenchError(f"{out}: not a dataset folder (no meta/info.json)")
    did = check_name(read_info(out).dataset_id, "dataset_id", f"{info_path}: ")
    summary = {"dest": str(dest), "splits": {}, "view_files": 0}
    registry = {}
    with _Staging(dest, "destination") as tmp:
        for split in splits:
            files = sorted((out / "data").glob(f"{split}-*-of-*.parquet"))
            if not files:
                continue
            pose_name = f"{did}_pose_{split}"
            keys: list[str] = []
            objects: set[str] = set()
            with open(tmp / f"{pose_name}.json", "w", encoding="utf-8") as pose_out:
                pose_out.write("[\n")
                first = True
                for f in files:
                    pf = pq.ParquetFile(f)
                    for g in range(pf.num_row_groups):
                        tasks: dict[str, list] = {}
                        for row in pf.read_row_group(g, columns=list(READ_COLUMNS)).to_pylist():
                            obj = check_name(row["object_id"], "object_id", f"{f}: ")  # paths stay under dest
                            rel = f"{TASKS_ROOT}/{obj}/step_{int(row['step_index']):04d}_{VIEW_FOLDER}"
                            folder = tmp / rel
                            folder.mkdir(parents=True, exist_ok=True)
                            images = {}
                            for col, name in FILES.items():
                                if row[col] is not None:
                                    (folder / name).write_bytes(row[col]["bytes"])
                                    images[col] = f"{rel}/{name}"
                            views = {}
                            for col, prefix in (("before", "original"), ("after", "target")):
                                cut = six_views(row[col]["bytes"]) if row[col] is not None else None
                                if cut is None:
                                    continue
                                views[col] = []
                                for ours, theirs in VIEW_NAMES.items():
                                    name = f"{prefix}_{theirs}.png"
                                    (folder / name).write_bytes(png_bytes(cut[ours], png_level))
                                    views[col].append(f"{rel}/{name}")
                                summary["view_files"] += len(cut)
                            (folder / POSE_FILE).write_text(json.dumps(_brick_pose(row), indent=1) + "\n")
                            record = {
                                "id": row["step_id"],
                                "system": _system_of(row["pose_messages"], row["system"]),
                                "conversations": [
                                    {"from": "human", "value": _human_value(row["pose_messages"])},
                                    {"from": "gpt", "value": row["pose_answer"]},
                                ],
                                "images": [images[c] for c in row["pose_images"]],
                            }
                            pose_out.write(("" if first else ",\n") + json.dumps(record, ensure_ascii=False))
                            first = False
                            if row["selection_messages"] and "catalog" in images:
                                tasks.setdefault(obj, []).append(_task_of(row, rel, views, images))
                            keys.append(f"{obj}/step_{int(row['step_index']):04d}_{VIEW_FOLDER}")
                            objects.add(obj)
                        for obj, entries in tasks.items():  # a row group is one object
                            path = tmp / TASKS_ROOT / obj / TASKS_FILE
                            if path.exists():  # an object split over row groups: append
                                entries = json.loads(path.read_text())["tasks"] + entries
                            path.write_text(json.dumps({"tasks": entries}, indent=1, ensure_ascii=False) + "\n")
                pose_out.write("\n]\n")
            (tmp / TASKS_ROOT).mkdir(exist_ok=True)
            (tmp / TASKS_ROOT / f"{split}.json").write_text(json.dumps(keys, indent=1) + "\n")
            registry[pose_name] = {
                "file_name": f"{pose_name}.json",
                "formatting": "sharegpt",
                "columns": {"messages": "conversations", "system": "system", "images": "images"},
                "tags": {"role_tag": "from", "content_tag": "value", "user_tag": "human", "assistant_tag": "gpt"},
            }
            summary["splits"][split] = {"objects": len(objects), "steps": len(keys), "pose_file": f"{pose_name}.json"}
        (tmp / "dataset_info.json").write_text(json.dumps(registry, indent=2, sort_keys=True) + "\n")
    return summary


# ============================================================================================
# BC-Bench -> ours: reading
# ============================================================================================
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


# ============================================================================================
# BC-Bench -> ours: rows
# ============================================================================================
def _png(path: Path, level: int) -> bytes:
    """The file's bytes when it is a PNG, else the image re-encoded as PNG."""
    data = path.read_bytes()
    if data.startswith(SIGNATURE):
        return data

    try:
        with Image.open(io.BytesIO(data)) as im:
            return png_bytes(im.convert("RGBA" if "A" in im.getbands() else "RGB"), level)
    except Exception as exc:  # noqa: BLE001 - any decoder failure is the same bad input
        raise BCBenchError(f"{path}: expected an image file (PNG), could not read it ({exc})") from None


def _parts_grid(paths: list[Path], level: int) -> bytes:
    """Several part renders as one image, side by side (4 a row), each labelled `Brick k`."""
    ims = []
    for p in paths:
        try:
            with Image.open(p) as im:
                ims.append(im.convert("RGB"))
        except Exception as exc:  # noqa: BLE001
            raise BCBenchError(f"{p}: expected an image file (PNG), could not read it ({exc})") from None
    w = max(i.width for i in ims)
    h = max(i.height for i in ims)
    strip = 20
    cols = min(4, len(ims))
    rows = -(-len(ims) // cols)
    out = Image.new("RGB", (cols * w + (cols - 1) * GRID_GAP, rows * (h + strip) + (rows - 1) * GRID_GAP), GRID_RGB)
    font = ImageFont.load_default(size=14)
    for k, im in enumerate(ims):
        r, c = divmod(k, cols)
        tile = Image.new("RGB", (w, h + strip), (255, 255, 255))
        tile.paste(im, (0, strip))
        ImageDraw.Draw(tile).text((4, 2), f"Brick {k + 1}", fill=(20, 20, 20), font=font)
        out.paste(tile, (c * (w + GRID_GAP), r * (h + strip + GRID_GAP)))
    return png_bytes(out, level)


def selection_text(n_bricks: int, kind: str) -> str:
    """The selection prompt of an imported step (BC-Bench's tasks carry none; their images differ
    from ours in view order and box style, so our prompt's description of them is not used)."""
    bricks = "1 brick" if n_bricks == 1 else f"{n_bricks} bricks"
    lines = [
        "Task: brick selection.",
        "Image 1: the assembly before this step, six orthographic views.",
        "Image 2: the same six views after this step; each brick added in this step is marked with a box.",
        "Image 3: the catalog of bricks still to place, 6 columns; rows and columns are numbered from 1 "
        "starting at the top-left, and the part file name is written above each tile.",
    ]
    if kind == "module":
        lines.append(f"This step attaches a sub-assembly of {bricks}.")
    lines.append(f"This step adds {bricks}. For each added brick, give the catalog cell that holds it, one line "
                 "per brick, in the format:")
    lines.append(prompts.SELECTION_FORMAT)
    return "\n".join(lines)


def _pose_user(human: str, n_images: int) -> list[dict]:
    """The human turn as content parts, images in place: image 0 before, 1 after, the last the
    axes composite, those between the part render(s), which become the one `part` image (its
    first placeholder keeps it, the others are dropped)."""
    column = ["before", "after"] + ["part"] * (n_images - 3) + ["axes"]
    parts, used = [], set()
    pieces = human.split("<image>")
    for i, text in enumerate(pieces):
        if text:
            parts.append(prompts.text_part(text))
        if i < len(pieces) - 1 and column[i] not in used:
            used.add(column[i])
            parts.append(prompts.image_part(POSE_IMAGES.index(column[i])))
    return parts


class _Geometry:
    """Symmetry, size and colour names from an LDraw library (or none)."""
    def __init__(self, ldraw):
        self.reader = None
        self.colours = None
        self.missing: set[str] = set()
        self.label = "none (no LDraw library given): every part scored without symmetry"
        self.ldraw_path = None
        self._cache: dict[str, tuple] = {}
        if ldraw is None:
            return

        if str(ldraw) == "embedded":
            self.reader = Reader(Library.embedded())
            self.label = "from the geometry of the embedded part library"
        else:
            path = Path(ldraw).expanduser()
            try:
                self.reader = get_reader(path)
            except LDrawError as exc:
                raise BCBenchError(f"{ldraw}: {exc}; give an LDraw library's root (a folder or its zip), or "
                                   "'embedded'") from None
            self.ldraw_path = os.path.realpath(path)
            self.label = f"from the geometry of the LDraw library {self.ldraw_path}"
        self.colours = self.reader.colours

    def part(self, name: str):
        """(symmetry or None, size_cm or None) of a part."""
        if self.reader is None:
            return None, None
        if name not in self._cache:

            try:
                p = load_part(self.reader, name)
                ext = (np.asarray(p.bbox)[1] - np.asarray(p.bbox)[0]) * LDU_CM
                self._cache[name] = (p.symmetry, [round(float(v), 4) for v in ext])
            except (LDrawError, OSError):
                self.missing.add(name)
                self._cache[name] = (None, None)
        return self._cache[name]

    def colour_name(self, code: int) -> str:
        if self.colours is None or code < 0:
            return ""
        return self.colours.get(int(code)).name.replace("_", " ")


def _catalog(step: Step, picks) -> list[dict]:
    """The catalog cells of a step: the task's own list when we wrote it; else the target cells
    (their part and colour are the target's) and, up to catalog_brick_count cells in rows of 6,
    unknown cells (UNKNOWN_PART, colour -1)."""
    ext = (step.task or {}).get(EXTENSION) or {}
    if isinstance(ext.get("catalog"), list):
        return [{"part": e["part"], "colour": int(e["colour"]), "row": int(e["row"]), "col": int(e["col"])}
                for e in ext["catalog"]]
    known = {}
    for b, cells in zip(step.bricks, step.cells):
        for cell in cells:
            known.setdefault(cell, (b.part, b.colour))
    count = (step.task or {}).get("catalog_brick_count") or 0
    cells = set(known) | {(i // CATALOG_COLUMNS + 1, i % CATALOG_COLUMNS + 1) for i in range(count)}
    return [{"part": known.get(c, (UNKNOWN_PART, -1))[0], "colour": int(known.get(c, (UNKNOWN_PART, -1))[1]),
             "row": c[0], "col": c[1]} for c in sorted(cells)]


def step_row(step: Step, geometry: _Geometry, dataset_id: str, num_steps: int, level: int = 6) -> dict:
    """One imported step as a row of `factory.dataset.schema.FIELDS`."""
    ext = (step.task or {}).get(EXTENSION) or {}
    n = len(step.bricks)
    gt = str((step.task or {}).get("ground_truth") or "")
    kind = ext.get("step_kind") or ("module" if gt.startswith('module "') else "part")
    used: set = set()
    bricks, picks = [], []
    for b, cells in zip(step.bricks, step.cells):
        free = [c for c in cells if c not in used]
        pick = free[0] if free else (cells[0] if cells else (0, 0))
        used.add(pick)
        sym, size = geometry.part(b.part)
        rotations = [np.eye(3).tolist()] if sym is None else [np.asarray(r, dtype=np.float64).tolist()
                                                                for r in sym.rotations]
        axis = None if sym is None or sym.continuous_axis is None else [float(v) for v in sym.continuous_axis]
        bricks.append({
            "part": b.part, "colour": int(b.colour), "colour_name": geometry.colour_name(b.colour),
            "row": int(pick[0]), "col": int(pick[1]), "cells": [[int(r), int(c)] for r, c in cells],
            "R": [list(r) for r in b.R], "T": list(b.T), "size_cm": size,
            "symmetry_order": len(rotations), "symmetry_continuous_axis": axis, "symmetry_rotations": rotations,
        })
        picks.append((b.part, pick[0], pick[1]))
    imgs = step.images
    part = _png(imgs[2], level) if len(imgs) == 4 else _parts_grid(imgs[2:-1], level)
    system = step.system if step.system is not None else prompts.SYSTEM_TEXT
    pose_answer = step.answer if step.answer is not None else format_pose([(b.T, b.R) for b in step.bricks])
    pose_messages = [{"role": "system", "content": [prompts.text_part(system)]},
                     {"role": "user", "content": _pose_user(step.human, len(imgs))},
                     {"role": "assistant", "content": [prompts.text_part(pose_answer)]}]
    if step.task is not None:
        sel_answer = format_selection(picks)
        sel_messages = prompts.conversation(prompts.SYSTEM_TEXT, len(SELECTION_IMAGES),
                                            selection_text(n, kind), sel_answer)
        sel_images = list(SELECTION_IMAGES)
    else:
        sel_answer, sel_messages, sel_images = "", [], []
    return {
        "dataset_id": dataset_id,
        "object_id": step.object,
        "step_id": ext.get("step_id") or f"{step.object}/{step.step_k:03d}",
        "step_index": step.step_k,
        "num_steps": num_steps,
        "split": step.split,
        "source": "bcbench",
        "seed": 0,
        "assembly": ext.get("assembly") or "main",
        "step_kind": kind,
        "before": {"bytes": _png(imgs[0], level), "path": None},
        "after": {"bytes": _png(imgs[1], level), "path": None},
        "isometric": None,
        "part": {"bytes": part, "path": None},
        "axes": {"bytes": _png(imgs[-1], level), "path": None},
        "catalog": None if step.catalog is None else {"bytes": _png(step.catalog, level), "path": None},
        "bricks": bricks,
        "catalog_parts": _catalog(step, picks) if step.task is not None else [],
        "physics": json.dumps({"source": "none"}, sort_keys=True, separators=(",", ":")),
        "system": system,
        "selection_messages": sel_messages,
        "selection_images": sel_images,
        "selection_answer": sel_answer,
        "pose_messages": pose_messages,
        "pose_images": list(POSE_IMAGES),
        "pose_answer": pose_answer,
    }


def import_bcbench(src, out, ldraw=None, dataset_id: str = "bcbench", default_split: str = "test",
                   objects_per_shard: int = 8, png_level: int = 6) -> dict:
    """Turn the BC-Bench layout under `src` (`read_bcbench`) into our dataset format in `out`
    (absent or empty): `data/{split}-NNNNN-of-NNNNN.parquet` (one row group per object, the row
    schema of `factory.dataset.schema`) and `meta/info.json`. `ldraw`: an LDraw library folder,
    or "embedded" (our default library), for the parts' symmetry, sizes and colour names; None:
    no symmetry. Written to a temporary folder renamed to `out` at the end. Returns the summary
    (also in info.json under `bcbench_import`)."""
    check_name(dataset_id, "dataset_id")
    if isinstance(objects_per_shard, bool) or not isinstance(objects_per_shard, int) or objects_per_shard < 1:
        raise BCBenchError(f"objects_per_shard must be an integer >= 1, got {objects_per_shard!r}")
    geometry = _Geometry(ldraw)
    data = read_bcbench(src, default_split)
    if not data.steps:
        raise BCBenchError(f"{src}: no step to import ({data.blank} blank; skipped: "
                           + ", ".join(f"{k} {v}" for k, v in data.skipped.items()) + ")")
    by_split: dict[str, dict[str, list[Step]]] = {s: {} for s in SPLITS}
    for step in data.steps:
        by_split[step.split].setdefault(step.object, []).append(step)
    counts = {s: {"objects": 0, "steps": 0, "bytes": 0} for s in SPLITS}
    with _Staging(out, "output") as tmp:
        (tmp / "data").mkdir()
        (tmp / "meta").mkdir()
        for split in SPLITS:
            objects = sorted(by_split[split])
            n_shards = max(1, -(-len(objects) // objects_per_shard))
            for k in range(n_shards):
                path = tmp / "data" / f"{split}-{k:05d}-of-{n_shards:05d}.parquet"
                with pq.ParquetWriter(str(path), SCHEMA, **WRITER_OPTIONS) as writer:
                    for obj in objects[k * objects_per_shard:(k + 1) * objects_per_shard]:
                        rows = [step_row(s, geometry, dataset_id, data.num_steps[obj], png_level)
                                for s in sorted(by_split[split][obj], key=lambda s: s.step_k)]
                        writer.write_table(pa.Table.from_pylist(rows, schema=SCHEMA))
                        counts[split]["objects"] += 1
                        counts[split]["steps"] += len(rows)
                counts[split]["bytes"] += path.stat().st_size
        summary = {
            "src": str(data.src),
            "out": str(out),
            "steps": {s: counts[s]["steps"] for s in SPLITS},
            "objects": {s: counts[s]["objects"] for s in SPLITS},
            "blank_steps_skipped": data.blank,
            "skipped": data.skipped,
            "tasks": list(data.tasks),
            "split_from": data.split_from,
            "symmetry": geometry.label,
            "parts_not_in_library": sorted(geometry.missing),
            "pose_files": [str(p.relative_to(data.src)) for p in data.pose_files],
            "ignored_json": [str(p.relative_to(data.src)) for p in data.ignored_files],
            "task_files": len(data.task_files),
            "split_lists": [str(p.relative_to(data.src)) for p in data.split_lists],
        }
        total = {key: sum(counts[s][key] for s in SPLITS) for key in ("objects", "steps", "bytes")}
        write_info(tmp, DatasetInfo(
            dataset_id=dataset_id,
            source="bcbench",
            seed=0,
            config={"source": "bcbench", "ldraw": geometry.ldraw_path, "size": FEEDBACK_SIZE},
            counts={s: Counts(**c) for s, c in counts.items()},
            total=Counts(**total),
            splits_present=tuple(s for s in SPLITS if counts[s]["steps"] > 0),
            tasks=tuple(data.tasks),
            details={"blank_steps_skipped": data.blank, "bcbench_import": summary},
        ))
    return summary


def summary_line(summary: dict) -> str:
    s, o = summary["steps"], summary["objects"]
    skipped = ", ".join(f"{k} {v}" for k, v in summary["skipped"].items()) or "none"
    return (f"imported {s['train'] + s['test']} steps of {o['train'] + o['test']} objects ({s['train']} train, "
            f"{s['test']} test; tasks: {', '.join(summary['tasks'])}); blank steps skipped: "
            f"{summary['blank_steps_skipped']}; other steps skipped: {skipped}; symmetry: {summary['symmetry']}"
            + (f" ({len(summary['parts_not_in_library'])} part(s) not in it: "
               f"{', '.join(summary['parts_not_in_library'][:5])})" if summary["parts_not_in_library"] else "")
            + f" -> {summary['out']}")


def main(argv: list[str] | None = None) -> int:
    """`python -m pipelines.bcbench import SRC OUT [--ldraw DIR|embedded] [--dataset-id ID]
    [--default-split test|train]`."""
    ap = ArgumentParser(prog="python -m pipelines.bcbench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    imp = sub.add_parser("import", help="BC-Bench's layout -> our dataset format")
    imp.add_argument("src", help="a folder holding BC-Bench's files (pose ShareGPT JSON, step folders, tasks.json)")
    imp.add_argument("out", help="dataset folder to write (absent or empty)")
    imp.add_argument("--ldraw", help="LDraw library (or 'embedded') for part symmetry; default: no symmetry")
    imp.add_argument("--dataset-id", default="bcbench", help="dataset_id of the rows (default bcbench)")
    imp.add_argument("--default-split", default="test", choices=("train", "test"),
                     help="split of steps no split list or file name places (default test)")
    args = ap.parse_args(argv)

    def body() -> int:
        summary = import_bcbench(args.src, args.out, ldraw=args.ldraw, dataset_id=args.dataset_id,
                                 default_split=args.default_split)
        print(summary_line(summary))
        return 0

    return run_guarded(body, {BCBenchError: 2, ValueError: 2, OSError: 2})


if __name__ == "__main__":
    sys.exit(main())
