"""Ours -> BC-Bench's layout: `write_bcbench` (`python -m pipelines.export DATA --format bcbench DEST`).

Per split, the pose records in one ShareGPT JSON file (registered in dataset_info.json for
LLaMA-Factory); per row, a step folder with its images, the six views of the before and after
composites as files of their own (`six_views`) and brick_pose.json; per object, tasks.json; per
split, the list of its step keys. The pose step folder is the selection step folder, every path is
relative to DEST, and one object's rows are in memory at a time. Fields of ours that the layout has
no place for travel in a `brick_factory` key of each task (ignored by BC-Bench's scripts), so our
data comes back unchanged through `pipelines.bcbench.importer`.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from PIL import Image

from factory.dataset.info import read_info
from factory.dataset.tasks import SPLITS
from pipelines.bcbench.layout import (
    EXTENSION,
    FILES,
    GRID_GAP,
    GRID_RGB,
    POSE_FILE,
    TASKS_FILE,
    TASKS_ROOT,
    VIEW_FOLDER,
    VIEW_NAMES,
    BCBenchError,
    _Staging,
)
from pipelines.dataset.config import check_name
from pipelines.dataset.png import png_bytes


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
