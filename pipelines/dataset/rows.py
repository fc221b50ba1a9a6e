"""One object's steps into rows: renders, PNG encoding, targets and the two conversations."""

from __future__ import annotations

import hashlib
import json
import time

import numpy as np

from factory.dataset import prompts
from factory.dataset.answers import normalise_part
from factory.dataset.tasks import POSE_IMAGES, SELECTION_IMAGES
from factory.ldraw import get_reader
from factory.parts import LDU_CM, load_part
from factory.render import Renderer, bounds_of, compose, render_catalog, render_step_full
from pipelines.dataset.png import png_bytes
from pipelines.dataset.sources import _py

_GEOMETRY: dict[tuple[int, str | None, str], str] = {}

SINGLE_SCENES = 6
"""One-part render scenes (the part images) an object's renderer keeps. Each costs about 90 MB
on llvmpipe (MuJoCo's default 4096x4096 shadow map per render context, unused by our renders), so
the renderer's default of 64 would reach gigabytes on objects with many distinct parts."""


def geometry_key(reader, name: str, model: str | None = None) -> str:
    """A digest of a part's geometry (its distinct vertices, rounded to 1e-3 LDU): parts under two
    names (a `~Moved to` stub and its target, say) with the same shape get the same key. `model`
    as `PlacedPart.model` (a part the model ships)."""
    key = (id(reader), model, name.lower())
    if key not in _GEOMETRY:
        tris = load_part(reader, name, model).flat.triangles.reshape(-1, 3)
        verts = np.unique(np.round(tris, 3), axis=0) if len(tris) else np.zeros((0, 3))
        _GEOMETRY[key] = hashlib.sha1(np.ascontiguousarray(verts, dtype=np.float64).tobytes()).hexdigest()
    return _GEOMETRY[key]


def _parts_image(images: dict, n: int):
    """One image of the step's parts: the part render, or for several bricks a grid of them, each
    labelled `Brick k` (the numbering of the pose answer)."""
    if n == 1:
        return images["part_1"]
    tiles = [compose.labelled(images[f"part_{k}"], f"Brick {k}") for k in range(1, n + 1)]
    return compose.grid(tiles, cols=min(4, n))


def catalog_layout(reader, offered):
    """The catalog's entries sorted by part name and colour (build order would give the answer
    away), as (normalised name, colour, model): `offered` items are (part, colour) or
    (part, colour, model), `model` as `PlacedPart.model`."""
    entries = []
    for name, colour, *model in offered:
        model = model[0] if model else None
        entries.append((normalise_part(load_part(reader, name, model).name), int(colour), model))
    return sorted(entries, key=lambda e: (e[0], e[1]))


def assign_cells(reader, new, entries, cells):
    """Per new brick: (equivalent cells, the cell picked for it). Equivalent: same geometry and
    colour. Identical bricks of one step get distinct cells (one cell holds one brick)."""
    keys = [(geometry_key(reader, name, model), colour) for name, colour, model in entries]
    used: set = set()
    out = []
    for p in new:
        k = (geometry_key(reader, p.part, p.model), int(p.colour))
        eq = sorted(cells[i] for i, kk in enumerate(keys) if kk == k)
        free = [c for c in eq if c not in used]
        pick = free[0] if free else (eq[0] if eq else (0, 0))
        used.add(pick)
        out.append((eq, pick))
    return out


def _placed_key(placed) -> tuple:
    """Placed parts as a hashable, exactly comparable key (name, colour, pose bytes)."""
    return tuple((p.part.lower(), p.model, int(p.colour), np.asarray(p.pose.R, np.float64).tobytes(),
                  np.asarray(p.pose.t, np.float64).tobytes()) for p in placed)


def object_rows(obj, config, split: str, timings: dict, part_images=None) -> list[dict]:
    """Every step of `obj` (an `ObjectSpec`) as a row dict in `schema.FIELDS` order.

    `timings` gets seconds added under 'render' (views, part and catalog renders) and 'encode'
    (PNG). The object gets its own renderer, freed after it, so a row's pixels do not depend on
    which objects the process rendered before (a resumed run writes the same bytes as an
    uninterrupted one); `part_images` (a `factory.render.PartImages`) may be shared across objects.
    """
    with Renderer(get_reader(config.ldraw), max_singles=SINGLE_SCENES, part_images=part_images) as renderer:
        return _rows(obj, config, split, timings, renderer)


def _rows(obj, config, split, timings, renderer) -> list[dict]:
    reader, colours = renderer.reader, renderer.colours

    bounds: dict[str, np.ndarray] = {}
    last_after: tuple = (None, None)  # (what the previous step rendered after it, its StepRender)
    rows = []
    n_steps = len(obj.steps)
    for k, step in enumerate(obj.steps):
        t0 = time.perf_counter()
        if step.assembly not in bounds:
            bounds[step.assembly] = bounds_of(list(step.scene), reader)
        before_key = (step.assembly, _placed_key(step.before))
        prev = last_after[1] if last_after[0] == before_key else None
        res = render_step_full(renderer, list(step.before), list(step.new), config.size,
                               bounds=bounds[step.assembly], scene_parts=list(step.scene),
                               before_views=prev and prev.after_views,
                               before_isometric=prev and prev.after_isometric,
                               before_segmentation=prev and prev.segmentation)
        last_after = ((step.assembly, before_key[1] + _placed_key(step.new)), res)
        entries = catalog_layout(reader, step.catalog)
        catalog_img, cells = render_catalog(renderer, entries, tile=config.tile)
        images = {
            "before": res.images["before"],
            "after": res.images["after"],
            "isometric": res.images["isometric"],
            "part": _parts_image(res.images, len(step.new)),
            "axes": res.images["axes"],
            "catalog": catalog_img,
        }
        t1 = time.perf_counter()
        encoded = {name: {"bytes": png_bytes(img, config.png_compress_level), "path": None}
                   for name, img in images.items()}
        t2 = time.perf_counter()
        timings["render"] = timings.get("render", 0.0) + (t1 - t0)
        timings["encode"] = timings.get("encode", 0.0) + (t2 - t1)

        bricks, picks, poses, described = [], [], [], []
        for p, (eq, pick) in zip(step.new, assign_cells(reader, step.new, entries, cells)):
            part = load_part(reader, p)
            name = normalise_part(part.name)
            sym = part.symmetry
            ext = (np.asarray(part.bbox)[1] - np.asarray(part.bbox)[0]) * LDU_CM
            cname = colours.get(int(p.colour)).name.replace("_", " ")
            bricks.append({
                "part": name,
                "colour": int(p.colour),
                "colour_name": cname,
                "row": int(pick[0]),
                "col": int(pick[1]),
                "cells": [[int(r), int(c)] for r, c in eq],
                "R": (np.round(np.asarray(p.pose.R, dtype=np.float64), 9) + 0.0).tolist(),
                "T": (np.round(np.asarray(p.pose.t, dtype=np.float64), 9) + 0.0).tolist(),
                "size_cm": [round(float(v), 4) for v in ext],
                "symmetry_order": int(sym.order),
                "symmetry_continuous_axis": None if sym.continuous_axis is None
                else [float(v) for v in sym.continuous_axis],
                "symmetry_rotations": [np.asarray(r, dtype=np.float64).tolist() for r in sym.rotations],
            })
            picks.append((name, pick[0], pick[1]))
            poses.append((p.pose.t, p.pose.R))
            described.append({"part": name, "colour": int(p.colour), "colour_name": cname, "size_cm": ext})
        first = not step.before
        sel_answer = prompts.selection_answer(picks)
        pose_answer = prompts.pose_answer(poses)
        sel_text = prompts.selection_prompt(len(step.new), first, step.kind, step.assembly)
        pose_text = prompts.pose_prompt(described, first, step.kind, step.assembly)
        rows.append({
            "dataset_id": config.dataset_id,
            "object_id": obj.object_id,
            "step_id": f"{obj.object_id}/{k:03d}",
            "step_index": k,
            "num_steps": n_steps,
            "split": split,
            "source": obj.source,
            "seed": int(config.seed),
            "assembly": step.assembly,
            "step_kind": step.kind,
            **encoded,
            "bricks": bricks,
            "catalog_parts": [{"part": n, "colour": c, "row": int(rc[0]), "col": int(rc[1])}
                              for (n, c, _), rc in zip(entries, cells)],
            "physics": json.dumps(_py(step.physics), sort_keys=True, separators=(",", ":"), allow_nan=False),
            "system": prompts.SYSTEM_TEXT,
            "selection_messages": prompts.conversation(prompts.SYSTEM_TEXT, len(SELECTION_IMAGES),
                                                       sel_text, sel_answer),
            "selection_images": list(SELECTION_IMAGES),
            "selection_answer": sel_answer,
            "pose_messages": prompts.conversation(prompts.SYSTEM_TEXT, len(POSE_IMAGES), pose_text,
                                                  pose_answer),
            "pose_images": list(POSE_IMAGES),
            "pose_answer": pose_answer,
        })
    return rows
