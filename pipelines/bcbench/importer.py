"""BC-Bench's layout -> our dataset format: `import_bcbench` (`python -m pipelines.bcbench import
SRC OUT`) writes the steps `read_bcbench` finds as rows of `factory.dataset.schema` (`step_row`):
images as PNG, several part renders as one labelled image, the pose conversation with their human
turn, a selection prompt of ours (`selection_text`; their tasks carry none), the catalog cells
(`_catalog`), the parts' symmetry, sizes and colour names from an LDraw library (`_Geometry`); and
meta/info.json, holding the import's summary (`summary_line`: its one line).
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from PIL import Image, ImageDraw, ImageFont

from factory.dataset import prompts
from factory.dataset.answers import format_pose, format_selection
from factory.dataset.info import Counts, DatasetInfo, write_info
from factory.dataset.schema import SCHEMA
from factory.dataset.tasks import POSE_IMAGES, SELECTION_IMAGES, SPLITS
from factory.errors import LDrawError
from factory.ldraw import Library, Reader, get_reader
from factory.parts import LDU_CM, load_part
from pipelines.bcbench.layout import CATALOG_COLUMNS, EXTENSION, GRID_GAP, GRID_RGB, BCBenchError, _Staging
from pipelines.bcbench.read import Step, read_bcbench
from pipelines.dataset.config import check_name
from pipelines.dataset.png import SIGNATURE, png_bytes
from pipelines.dataset.shards import WRITER_OPTIONS

UNKNOWN_PART = ""
"""Part (with colour -1) of a catalog cell an imported task does not name (only the target cells and
the cell count are in BC-Bench's tasks)."""
FEEDBACK_SIZE = 256
"""`config.size` of an imported folder: the view size of world-feedback renders (eval.predict --feedback)."""


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
