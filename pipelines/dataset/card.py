"""`OUT/README.md`: the dataset card, with the YAML front matter `datasets.load_dataset` reads."""

from __future__ import annotations

import yaml

from factory.dataset.tasks import POSE_IMAGES, SELECTION_IMAGES


def _size_category(n: int) -> str:
    for limit, name in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"),
                        (1_000_000, "100K<n<1M")):
        if n < limit:
            return name
    return "1M<n<10M"


TAGS = {"synthetic": "synthetic", "design": "human-designs", "feedback": "world-feedback"}

SOURCE_TEXT = {
    "synthetic": "objects grown by the Brick Factory sampler (`factory.sampler`), every placement checked for "
                 "connection, collision, clutch and stability",
    "design": "human-designed LDraw models, sub-assemblies shown as a manual shows them (their own steps, "
              "then one multi-brick step attaching them)",
    "feedback": "world-feedback correction rows: a model's wrong pose answers on another dataset's steps, each "
                "drawn in red (`feedback` image column) with the revision prompt, then the right answer "
                "(pose task only; `meta/info.json` names the dataset and the predictions)",
}


def dataset_card(config, info: dict) -> str:
    splits = info["splits_present"]
    # The config's name carries the dataset's config hash: `datasets` caches a local folder under
    # its name and this YAML only, so two datasets in folders of the same name would otherwise
    # share (and serve each other) one cache entry.
    # Written by a YAML library: names the id rule allows, such as `null`, `yes` or `1e3`, are
    # YAML's null, a boolean and a number when written by hand.
    front = {
        "configs": [{"config_name": f"bf-{info['config_hash'][:12]}",
                     "data_files": [{"split": s, "path": f"data/{s}-*"} for s in splits]}],
        "pretty_name": config.dataset_id,
        "task_categories": ["image-text-to-text"],
        "tags": ["lego", "ldraw", "assembly", TAGS[config.source]],
        "size_categories": [_size_category(info["total"]["steps"])],
    }
    header = "---\n" + yaml.safe_dump(front, sort_keys=False, default_flow_style=False, allow_unicode=True) + "---"
    c = info["counts"]
    stats = info["statistics"]
    stat_lines = []
    for group, counter in stats.items():
        items = ", ".join(f"{k}: {v}" for k, v in sorted(counter.items(), key=lambda kv: (-kv[1], kv[0])))
        stat_lines.append(f"- {group}: {items or 'none'}")
    missing = [s for s in ("train", "test") if s not in splits]
    note = (f"\nThe {' and '.join(missing)} split has no objects in this build (too few objects); it is not "
            "listed above.\n" if missing else "")
    src = SOURCE_TEXT[config.source]
    if config.source == "synthetic":
        prior = config.sampler.prior
        src += (f"; parts and colours drawn with the weights of the usage prior `{prior}` (Brick Factory's "
                "docs/prior.md)" if prior else "; parts and colours as the build's config lists them")
    return header + f"""

# {config.dataset_id}

Step-wise LEGO-style assembly data for vision-language models (BC-Bench's brick selection and pose
estimation tasks): {src}. One row per assembly step. Written by Brick Factory
(`pipelines.dataset`, schema version {info['schema_version']}); config hash `{info['config_hash']}`.

| split | objects | steps | bytes |
|---|---|---|---|
| train | {c['train']['objects']} | {c['train']['steps']} | {c['train']['bytes']} |
| test | {c['test']['objects']} | {c['test']['steps']} | {c['test']['bytes']} |
{note}
The split is by object (no object has steps in both), {config.train_fraction:g} / {1 - config.train_fraction:g}.

```python
from datasets import load_dataset
ds = load_dataset("path/to/this/folder")        # images decode to PIL
row = ds["train"][0]
images = [row[c] for c in row["pose_images"]]   # the pose conversation's images, in order
messages = row["pose_messages"]                 # TRL vision format
```

## Columns

- identity: `dataset_id`, `object_id`, `step_id`, `step_index` (0-based), `num_steps`, `split`,
  `source` (`synthetic` or `design`), `seed`, `assembly` (`main` or a sub-assembly tag), `step_kind`
  (`part`, or `module`: a finished sub-assembly attached as one multi-brick step);
- images (PNG, Hugging Face `Image`): `before` and `after` (six orthographic views Top, Front, Right
  / Bottom, Back, Left; in `after` each new brick in a red dashed box), `isometric` (after, boxed),
  `part` (the new brick alone in its own LDraw frame with axes; several bricks: a grid labelled
  Brick 1, 2, ...), `axes` (seven views of the assembly before the step with LDU ticks), `catalog`
  (the bricks still to place, sorted by part and colour, 6 columns, cells 1-indexed from the top-left);
- targets: `bricks` (per new brick: `part`, `colour`, `colour_name`, its catalog cell `row`/`col`,
  `cells` = every catalog cell holding an equivalent brick (same geometry and colour), `R` (3x3, rows
  of the LDraw type-1 line), `T` (LDU), `size_cm`, `symmetry_order`, `symmetry_continuous_axis`,
  `symmetry_rotations` (part frame)), `catalog_parts` (every catalog cell's part and colour),
  `physics` (JSON: the physics check of the step);
- tasks: `system`, `selection_messages` / `selection_images` {list(SELECTION_IMAGES)} /
  `selection_answer`, `pose_messages` / `pose_images` {list(POSE_IMAGES)} / `pose_answer`. Messages are
  TRL's vision format (system, user with image placeholders then text, assistant answer); content
  parts carry `type`, `text` and `index` (position in the task's image list).

Answer formats: selection one line per brick, `3023.dat, row 6, col 3`; pose one block per brick,
`Brick 1:` / `Translation:` / `x=..., y=..., z=...` / `Rotation:` / three rows `[a, b, c]`. Pose
convention (stated in every pose prompt): R is the matrix of the LDraw type-1 line, rows
`[a b c] [d e f] [g h i]`; a part point p lands at R p + T; LDU (1 LDU = 0.4 mm); y points down.

## Statistics

{chr(10).join(stat_lines) or '- none'}

Full configuration, package versions and counts: `meta/info.json`; per object: `meta/objects.jsonl`;
sample steps: `gallery/index.html`, `gallery/contact_sheet.png`.

## Licence

Code and generated data: MIT (Brick Factory). Renders of parts from the LDraw parts library are
derived from that library (CC BY); see its licence when a real library was used (`config.ldraw`).
"""
