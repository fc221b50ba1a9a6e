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

# Modules: layout.py (the names both directions share, BCBenchError, the staging folder), write.py
# (ours -> theirs: write_bcbench), read.py (their files found, checked and joined: read_bcbench),
# importer.py (their steps -> our rows and dataset folder: import_bcbench), __main__.py (the
# command line; its help is this docstring).

from pipelines.bcbench.importer import import_bcbench, selection_text, step_row, summary_line
from pipelines.bcbench.layout import EXTENSION, VIEW_NAMES, BCBenchError
from pipelines.bcbench.read import BCBenchData, PoseBrick, Step, read_bcbench
from pipelines.bcbench.write import six_views, write_bcbench

__all__ = [
    "EXTENSION",
    "VIEW_NAMES",
    "BCBenchData",
    "BCBenchError",
    "PoseBrick",
    "Step",
    "import_bcbench",
    "read_bcbench",
    "selection_text",
    "six_views",
    "step_row",
    "summary_line",
    "write_bcbench",
]
