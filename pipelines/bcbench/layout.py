"""What the export and the import of BC-Bench's layout share: the layout's file and folder names,
the names of our six views in it, the task key of our fields it has no place for, the grid of our
composite images; the error of input not in the layout (`BCBenchError`: the message names the file,
the JSON path and what was expected); and `_Staging`, the temporary folder that leaves an output
folder whole or absent.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

from factory.atomic import umask

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
GRID_GAP = 2
GRID_RGB = (200, 200, 200)


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
