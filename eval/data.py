"""Reading a dataset folder (`make synth` / `pipelines.designs` output) for scoring, prediction and
training: its `meta/info.json` (`factory.dataset.DatasetInfo`), its shard files, rows streamed shard
by shard and row group by row group (never the whole dataset in memory), and rows turned into the
scorer's `StepTarget`s.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from eval.metrics import BrickTarget, StepTarget
from factory.dataset.info import DatasetInfo, InfoError, read_info
from factory.dataset.tasks import SPLITS
from factory.symmetry import Symmetry

TARGET_COLUMNS = ("step_id", "object_id", "step_index", "num_steps", "split", "source", "assembly",
                  "step_kind", "bricks", "catalog_parts")
"""The columns `step_target` and the baselines need (no images)."""


class DatasetError(ValueError):
    """A folder that is not a dataset, or a split that is not in it."""


def info(out) -> DatasetInfo:
    """`OUT/meta/info.json`, checked and typed, with a clear error when the folder is not a dataset."""
    if not (Path(out) / "meta" / "info.json").is_file():
        raise DatasetError(f"{out}: not a dataset folder (no meta/info.json); make one with `make synth` "
                           f"or `python -m pipelines.designs`")
    try:
        return read_info(out)
    except InfoError as exc:
        raise DatasetError(str(exc)) from None


def library(out, ldraw=None, src: DatasetInfo | None = None) -> str | None:
    """The LDraw library to draw the dataset `out`'s parts from: `ldraw` when given, else the one
    it was built with (`config.ldraw`; None: the embedded library). A dataset moved to another
    machine records a folder that may not be there: that is a clear error asking for `ldraw`.
    `src`: `info(out)` where the caller has read it already."""
    if ldraw is not None:
        return str(ldraw)
    recorded = (src if src is not None else info(out)).config.get("ldraw")
    if recorded is not None and not Path(recorded).is_dir():
        raise DatasetError(f"{out}: built with the LDraw library {recorded}, which is not a folder here; "
                           f"give the same library's folder on this machine (--ldraw DIR)")
    return recorded


def shard_files(out, split: str | None = None) -> list[Path]:
    """The Parquet shards of `split` (None: all splits), in file-name order."""
    if split is not None and split not in SPLITS:
        raise DatasetError(f"unknown split {split!r}; valid: {', '.join(SPLITS)}")
    info(out)
    files = sorted((Path(out) / "data").glob(f"{split or '*'}-*-of-*.parquet"))
    if not files:
        raise DatasetError(f"{out}: no {split or 'any'} shards under data/")
    return files


def iter_rows(out, split: str | None = None, columns=None) -> Iterator[dict]:
    """Rows as dicts, one row group (one object) in memory at a time."""
    for f in shard_files(out, split):
        yield from iter_file(f, columns)


def iter_file(path, columns=None) -> Iterator[dict]:
    """The rows of one shard file (`shard_files`), one row group at a time."""
    cols = list(columns) if columns is not None else None
    pf = pq.ParquetFile(path)
    for g in range(pf.num_row_groups):
        yield from pf.read_row_group(g, columns=cols).to_pylist()


def iter_objects(rows) -> Iterator[list[dict]]:
    """Consecutive rows of one object as a list (a row group holds one object)."""
    group: list[dict] = []
    for row in rows:
        if group and row["object_id"] != group[0]["object_id"]:
            yield group
            group = []
        group.append(row)
    if group:
        yield group


def count_rows(out, split: str | None = None) -> int:
    return sum(pq.ParquetFile(f).metadata.num_rows for f in shard_files(out, split))


def symmetry_of(brick: dict) -> Symmetry:
    axis = brick.get("symmetry_continuous_axis")
    return Symmetry(tuple(np.asarray(r, dtype=np.float64) for r in brick["symmetry_rotations"]),
                    tuple(axis) if axis else None)


def step_target(row: dict) -> StepTarget:
    """The scorer's target for one row: every brick with its equivalent cells, pose and symmetry."""
    bricks = tuple(
        BrickTarget(b["part"], b["colour"], [tuple(c) for c in b["cells"]], np.asarray(b["R"], dtype=np.float64),
                    np.asarray(b["T"], dtype=np.float64), symmetry_of(b))
        for b in row["bricks"])
    return StepTarget(row["step_id"], row["object_id"], bricks)


def catalog_of(row: dict) -> dict:
    """{(row, col): (part, colour)} of the row's catalog grid."""
    return {(int(e["row"]), int(e["col"])): (e["part"], int(e["colour"])) for e in row["catalog_parts"]}


def catalog_rows(row: dict) -> int:
    """Rows of the catalog grid (at least 1)."""
    return max([int(e["row"]) for e in row["catalog_parts"]] or [1])


def load_targets(out, split: str | None = "test") -> list[StepTarget]:
    """Every step of `split` as a `StepTarget`, in dataset order."""
    return [step_target(r) for r in iter_rows(out, split, ["step_id", "object_id", "bricks"])]
