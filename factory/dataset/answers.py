"""The two answer formats: the one writer of both, and the part-name rule the parser shares.

The dataset's training answers, the oracle's answers and `eval.parse`'s round-trip tests all use
these formatters, so what a model is trained on is exactly what the scorer reads back. Numbers are
rounded to 6 decimals (1e-6 LDU and 1e-6 in a matrix entry are far below every threshold) and
printed shortest, with ``.0`` on whole numbers as in the brief's example; -0.0 prints as 0.0.
"""

from __future__ import annotations

import numpy as np


def normalise_part(name: str) -> str:
    """`3023`, `3023.DAT` and `3023.dat` all become `3023.dat`; "" stays ""."""
    name = name.strip().lower()
    if not name:
        return ""
    return name if name.endswith(".dat") else name + ".dat"


def _num(v: float, decimals: int = 6) -> str:
    r = round(float(v), decimals) + 0.0  # + 0.0 turns -0.0 into 0.0
    return repr(r)


def format_selection(selections) -> str:
    """Lines ``3023.dat, row 6, col 3`` from `Selection`s or (part, row, col) tuples."""
    lines = []
    for s in selections:
        part, row, col = (s.part, s.row, s.col) if hasattr(s, "row") else s
        lines.append(f"{normalise_part(str(part))}, row {int(row)}, col {int(col)}")
    return "\n".join(lines)


def format_pose(poses, decimals: int = 6) -> str:
    """``Brick N:`` blocks from (t, R) pairs or objects with ``.t`` and ``.R`` (Pose, PoseAnswer)."""
    blocks = []
    for n, p in enumerate(poses, start=1):
        t, r = (p.t, p.R) if hasattr(p, "R") else p
        t = np.asarray(t, dtype=np.float64).reshape(3)
        r = np.asarray(r, dtype=np.float64).reshape(3, 3)
        lines = [f"Brick {n}:", "Translation:", ", ".join(f"{a}={_num(v, decimals)}" for a, v in zip("xyz", t))]
        lines.append("Rotation:")
        lines += ["[" + ", ".join(_num(v, decimals) for v in row) + "]" for row in r]
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)
