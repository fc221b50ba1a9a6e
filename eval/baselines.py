"""Reference answers: the oracle, chance, and a simple non-learned heuristic, in the answer formats.

The answers are written by the dataset contract's formatters (`factory.dataset.answers`), the
one writer of both formats, which the dataset builder also uses for the training answers.

Baselines give a scale to read model numbers against:

- `oracle`: the ground truth; scores 1.0 selection and step success in both modes.
- `random_baseline`: chance. A uniformly random cell holding a brick of the catalog (of the
  ``n_rows x n_cols`` grid when no catalog is given), labelled with the part in that cell (the
  target's own name, as it was until 2026-11-26, gave the answer away to any scorer that reads
  names, as BC-Bench's does; no part is named without a catalog), a translation on the 20-LDU
  grid within +-200 LDU per axis, one of the 24 axis-aligned rotations.
- `heuristic`: uses only what a model also sees. Selection: a cell of the catalog's most common
  (part, colour), when the catalog is given (the most plentiful brick is the likeliest next one),
  else the top-left cell, labelled with the part in that cell (`EMPTY_LABEL` without a catalog).
  Pose: stack on the last brick placed: its position 24 LDU higher (one
  brick height; y points down, so y - 24) with the identity rotation; at the first step, the
  origin. The previous step is what the "before" views show, so this is fair.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from eval.metrics import StepTarget, match_cells
from factory.dataset.answers import format_pose, format_selection
from factory.symmetry import axis_rotations

BRICK_HEIGHT_LDU = 24.0
GRID_LDU = 20
RANDOM_RANGE_LDU = 200
EMPTY_LABEL = "unknown.dat"
"""The part label of a picked cell the baselines do not know the part of (never a target's name)."""


def oracle(step: StepTarget) -> dict[str, str]:
    """The ground-truth answers; identical bricks get distinct cells (one cell holds one brick)."""
    targets = [b.cells for b in step.bricks]
    cells = sorted({c for b in step.bricks for c in b.cells})
    match = match_cells(targets, cells)
    picks = []
    for b, ci in zip(step.bricks, match):
        row, col = cells[ci] if ci is not None else min(b.cells, default=(1, 1))
        picks.append((b.part, row, col))
    return {"selection": format_selection(picks), "pose": format_pose([(b.t, b.R) for b in step.bricks])}


_ROTATIONS = axis_rotations()


def random_baseline(step: StepTarget, rng: np.random.Generator, n_rows: int, n_cols: int = 6,
                    catalog: dict | None = None) -> dict[str, str]:
    """Chance answers for every brick of the step (see the module docstring). `catalog` maps
    (row, col) to (part, colour), as for `heuristic`."""
    picks, poses = [], []
    k = RANDOM_RANGE_LDU // GRID_LDU
    cells = sorted(catalog) if catalog else None
    for _ in step.bricks:
        if cells:
            cell = cells[int(rng.integers(len(cells)))]
        else:
            cell = (int(rng.integers(1, n_rows + 1)), int(rng.integers(1, n_cols + 1)))
        picks.append((_label(catalog, cell), *cell))
        t = rng.integers(-k, k + 1, size=3) * GRID_LDU
        poses.append((t, _ROTATIONS[int(rng.integers(len(_ROTATIONS)))]))
    return {"selection": format_selection(picks), "pose": format_pose(poses)}


def _label(catalog: dict | None, cell: tuple[int, int]) -> str:
    """The part in `cell` of the catalog, or `EMPTY_LABEL`."""
    entry = (catalog or {}).get(cell)
    return entry[0] if entry else EMPTY_LABEL


def heuristic(step: StepTarget, previous: StepTarget | None = None, catalog: dict | None = None) -> dict[str, str]:
    """Most common catalog brick, stacked on the last placed brick (see the module docstring).

    `catalog` maps (row, col) to (part, colour) for the bricks still to place.
    """
    picks, poses = [], []
    if catalog:
        common = Counter(catalog.values()).most_common(1)[0][0]
        cells = sorted(c for c, v in catalog.items() if v == common)
    else:
        cells = [(1, 1)]
    base = previous.bricks[-1].t if previous is not None and previous.bricks else np.zeros(3)
    for i in range(len(step.bricks)):
        row, col = cells[min(i, len(cells) - 1)]
        picks.append((_label(catalog, (row, col)), row, col))
        poses.append((base + np.array([0.0, -BRICK_HEIGHT_LDU * (i + 1), 0.0]), np.eye(3)))
    return {"selection": format_selection(picks), "pose": format_pose(poses)}

