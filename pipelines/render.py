"""Render one build step's BC-Bench image set: `python -m pipelines.render MODEL --step K --out DIR`.

Writes into DIR: `before.png`, `after.png` (six labelled orthographic views; new parts boxed in red
in `after`), `isometric.png`, `part_1.png`.. (each new part in its own LDraw frame with axes),
`axes.png` (7 views of the assembly before the step, LDU ticks), `catalog.png` (the parts still to
place: this step's and every later step's, sorted by part name and colour), `feedback.png` (the
step's first part at a predicted pose, in red) and `step.json` (the step's parts, their catalog
cells, the red boxes and the framing).

K is the 0-based step index that `python -m factory.ldraw steps MODEL` prints. Every step of a model
is framed on the whole model's bounds, so views of different steps line up.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

from eval.metrics import rotation_kind
from factory.atomic import write_atomic
from factory.cli import ArgumentParser, run_guarded
from factory.errors import LDrawError
from factory.ldraw import PlacedPart, get_reader, read_steps
from factory.parts import load_part
from factory.pose import Pose


PREDICT_REACH_LDU = 10_000.0
"""The farthest a `--predict` translation may be from the model's origin (LDU, 4 m): a feedback
image frames the model and the prediction together, and farther the model is a speck."""


class PredictError(ValueError):
    """A `--predict` value that is not a pose the feedback image can show."""


def parse_predict(text: str) -> Pose:
    """The pose of `--predict 'x y z a b c d e f g h i'`: 12 finite numbers, the translation
    within `PREDICT_REACH_LDU` and the matrix a rotation within `eval.metrics.DEGENERATE_TOL`
    (det > 0); `PredictError` naming what is wrong otherwise."""
    expected = "expected 12 numbers 'x y z a b c d e f g h i'"
    try:
        values = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise PredictError(f"--predict: {expected}, got {text[:60]!r}") from None
    if len(values) != 12:
        raise PredictError(f"--predict: {expected}, got {len(values)}")
    if not all(np.isfinite(values)):
        raise PredictError(f"--predict: {expected}, all finite; got {text[:60]!r}")
    if max(abs(v) for v in values[:3]) > PREDICT_REACH_LDU:
        raise PredictError(f"--predict: x, y and z must be within +-{PREDICT_REACH_LDU:g} LDU of the model's origin")
    kind = rotation_kind(np.reshape(values[3:], (3, 3)))
    if kind in ("degenerate", "mirrored"):
        raise PredictError(f"--predict: the matrix 'a b c d e f g h i' must be a rotation (orthonormal rows, "
                           f"determinant 1); this one is {kind}")
    return Pose.from_ldraw(values)


def _predicted(args, part):
    if args.predict:
        pose = parse_predict(args.predict)
    else:
        # A typical wrong answer: one stud off along X and turned 90 degrees about the part's Y axis.
        turn = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
        pose = Pose(part.pose.R @ turn, part.pose.t + np.array([20.0, 0.0, 0.0]))
    return PlacedPart(part.part, part.colour, pose, "predicted", part.model)  # the model's own parts too


def _json(meta: dict) -> str:
    """JSON with one entry per line at the top two levels and short lists kept on one line."""
    lines = ["{"]
    items = list(meta.items())
    for i, (k, v) in enumerate(items):
        comma = "," if i < len(items) - 1 else ""
        if isinstance(v, list) and v and isinstance(v[0], dict):
            inner = ",\n".join("  " + json.dumps(x) for x in v)
            lines.append(f" {json.dumps(k)}: [\n{inner}\n ]{comma}")
        else:
            lines.append(f" {json.dumps(k)}: {json.dumps(v)}{comma}")
    lines.append("}")
    return "\n".join(lines)


def view_rates(model, ldraw, sizes, repeats: int = 3) -> list[dict]:
    """Views per second of a whole model at each size: RGB (outlines, multisampling) and
    segmentation over the six orthographic views plus the isometric, best of `repeats`, and the
    seconds of one full step render (every image of a step but the catalog)."""
    # lazy: factory.render picks the GL backend at import (fails without one), so only a render loads it
    from factory.render import ALL_VIEWS, Framing, Renderer, bounds_of, render_step_full
    from factory.render.images import EDGE_PX
    from factory.render.scene import Item
    from factory.render.views import render_rgb, render_seg

    reader = get_reader(ldraw)
    steps = read_steps(model, ldraw)
    every = [p for s in steps for p in s.parts]
    items = [Item(load_part(reader, p), p.colour, p.pose) for p in every]
    framing = Framing.from_bounds(bounds_of(every, reader))
    out = []
    with Renderer(reader) as renderer:
        colours = renderer.colours
        for size in sizes:
            t = time.perf_counter()
            scene = renderer.scene_for([it.part for it in items], EDGE_PX * framing.height / size)
            render_rgb(scene, items, colours, "Front", framing, size)
            render_seg(scene, items, colours, "Front", framing, size)
            setup = time.perf_counter() - t
            tris = sum(int(scene.model.mesh_facenum[scene.model.geom_dataid[g]]) for g in range(scene.model.ngeom))
            row = {"model": Path(model).name, "steps": len(steps), "parts": len(every), "size": size,
                   "triangles": tris, "setup_s": round(setup, 2)}
            for kind, fn in (("rgb", render_rgb), ("seg", render_seg)):
                rates = []
                for _ in range(repeats):
                    t = time.perf_counter()
                    for v in ALL_VIEWS:
                        fn(scene, items, colours, v, framing, size)
                    rates.append(len(ALL_VIEWS) / (time.perf_counter() - t))
                row[f"{kind}_views_per_s"] = round(max(rates), 1)
                row[f"{kind}_views_per_s_median"] = round(sorted(rates)[len(rates) // 2], 1)
            k = len(steps) // 2
            before = [p for s in steps[:k] for p in s.parts]
            t = time.perf_counter()
            render_step_full(renderer, before, list(steps[k].parts), size, bounds=bounds_of(every, reader),
                             scene_parts=every)
            row["step_render_s"] = round(time.perf_counter() - t, 3)
            out.append(row)
    return out


def _bench(args) -> int:
    """Print `view_rates` of the model, one line per size."""
    try:
        sizes = [int(s) for s in args.bench.split(",")]
        rows = view_rates(args.model, args.ldraw, sizes)
    except (ValueError, LDrawError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.model}: {rows[0]['steps']} steps, {rows[0]['parts']} parts")
    for r in rows:
        print(f"{r['size']}px: scene + contexts {r['setup_s']:.2f} s, {r['triangles']} triangles, "
              f"rgb {r['rgb_views_per_s']:.1f} views/s (median {r['rgb_views_per_s_median']:.1f}), "
              f"seg {r['seg_views_per_s']:.1f} views/s (median {r['seg_views_per_s_median']:.1f}), "
              f"render_step {r['step_render_s']:.2f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m pipelines.render", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="an .ldr, .mpd or .dat model file")
    parser.add_argument("--step", type=int, help="0-based build step index")
    parser.add_argument("--out", help="output folder (created)")
    parser.add_argument("--ldraw", help="LDraw library: a folder or LDraw's complete.zip (default: "
                        "$LDRAWDIR, else the embedded library)")
    parser.add_argument("--size", type=int, default=256, help="pixels per view (default 256)")
    parser.add_argument("--tile", type=int, default=128, help="pixels per catalog tile (default 128)")
    parser.add_argument("--predict", help="predicted pose of the step's first part for feedback.png: "
                                          "'x y z a b c d e f g h i' (default: one stud off, turned 90 degrees)")
    parser.add_argument("--bench", metavar="SIZES",
                        help="instead of writing images, time views per second at these sizes, e.g. 256,512")
    args = parser.parse_args(argv)
    if args.bench:
        return _bench(args)
    if args.step is None or args.out is None:
        print("error: --step and --out are required (or --bench SIZES)", file=sys.stderr)
        return 2
    if not 32 <= args.size <= 2048 or not 32 <= args.tile <= 1024:
        print("error: --size must be in 32..2048 and --tile in 32..1024", file=sys.stderr)
        return 2
    if args.predict is not None:
        try:
            parse_predict(args.predict)  # before anything is read or rendered
        except PredictError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2

    try:
        # lazy: factory.render picks the GL backend at import; without one, a line, not a traceback
        from factory.render.scene import MAX_SCENE_PARTS
        from factory.render import (
            Renderer,
            RenderUnavailableError,
            bounds_of,
            render_catalog,
            render_feedback,
            render_step_full,
        )
    except Exception as exc:  # noqa: BLE001 - e.g. no GL library: one line, not a traceback
        print(f"error: {exc}", file=sys.stderr)
        return 3

    t0 = time.perf_counter()

    def body() -> int:
        reader = get_reader(args.ldraw)
        steps = read_steps(args.model, args.ldraw)
        if not steps:
            print(f"error: {args.model} places no parts", file=sys.stderr)
            return 2
        if not 0 <= args.step < len(steps):
            print(f"error: --step {args.step} is out of range: {args.model} has steps 0..{len(steps) - 1}",
                  file=sys.stderr)
            return 2
        every = [p for s in steps for p in s.parts]
        if len(every) > MAX_SCENE_PARTS:  # refused before any scene is built, naming the file
            print(f"error: {args.model}: model places {len(every):,} parts; at most {MAX_SCENE_PARTS:,} are rendered",
                  file=sys.stderr)
            return 2
        before = [p for s in steps[: args.step] for p in s.parts]
        new = list(steps[args.step].parts)
        bounds = bounds_of(every, reader)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)

        remaining = [p for s in steps[args.step:] for p in s.parts]
        order = sorted(range(len(remaining)),
                       key=lambda i: (remaining[i].part.lower(), remaining[i].colour, i))
        candidates = [remaining[i] for i in order]
        with Renderer(reader) as renderer:
            res = render_step_full(renderer, before, new, args.size, bounds=bounds, scene_parts=every)
            catalog, cells = render_catalog(renderer, candidates, tile=args.tile)
            feedback = render_feedback(renderer, before, [_predicted(args, new[0])], args.size, bounds=bounds,
                                       scene_parts=every)

        images = dict(res.images, catalog=catalog, feedback=feedback)
        for name, img in images.items():
            buf = io.BytesIO()
            img.save(buf, format="PNG", optimize=False)
            write_atomic(out / f"{name}.png", buf.getvalue())
        # The step's parts are the first len(new) entries of `remaining`.
        where = {order[k]: cells[k] for k in range(len(order))}
        meta = {
            "model": str(args.model),
            "step": args.step,
            "size": args.size,
            "parts": [
                {
                    "part": p.part,
                    "colour": p.colour,
                    "R": p.pose.R.tolist(),
                    "T": p.pose.t.tolist(),
                    "catalog_cell": list(where[j]),
                    "boxes": {v: (list(b[j]) if b[j] is not None else None) for v, b in res.boxes.items()},
                }
                for j, p in enumerate(new)
            ],
            "catalog": [{"part": c.part, "colour": c.colour, "cell": list(cell)} for c, cell in zip(candidates, cells)],
            "framing": {"center": list(res.framing.center), "height": res.framing.height,
                        "iso_height": res.framing.iso_height},
            "images": sorted(f"{n}.png" for n in images),
        }
        write_atomic(out / "step.json", (_json(meta) + "\n").encode())
        print(f"wrote {len(images)} images and step.json to {out} in {time.perf_counter() - t0:.1f} s")
        return 0

    return run_guarded(body, {RenderUnavailableError: 3, OSError: 2})


if __name__ == "__main__":
    sys.exit(main())
