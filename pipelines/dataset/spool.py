"""Objects grown ahead of their shards: the producer's side of a lockstep build.

`build(..., batch=B)` grows the synthetic objects of every missing shard B at a time in one process
(`Sampler.grow`: their checks of a step in one call, on the device with the 'mjx' backend) while
worker processes render and encode the shards whose objects are all grown. Each grown object is
written here at once, atomically (`OUT/meta/spool/NNNNNNN.pkl`: the `Assembly` and its seconds),
so a killed build loses no grown object: the resumed one takes them from here. A shard's files
are removed once its completion marker is written. The shard function reads an object from here
when it is present and samples it itself when not; both give the same object, so the data files
are the same either way.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

from factory.atomic import write_atomic

SPOOL_VERSION = 1
"""Bumped when what is written here changes; an entry of another version is grown again."""


def spool_path(out, index: int) -> Path:
    return Path(out) / "meta" / "spool" / f"{index:07d}.pkl"


def put(out, index: int, assembly, seconds: float) -> None:
    """Keep object `index` (an `Assembly`) and the seconds its growth took."""
    write_atomic(spool_path(out, index), pickle.dumps((SPOOL_VERSION, assembly, float(seconds)),
                                                       protocol=pickle.HIGHEST_PROTOCOL))


def get(out, index: int, seed: int):
    """(assembly, seconds) of object `index` when spooled for this seed, else None (an unreadable
    or foreign entry counts as absent: the object is grown again)."""
    try:
        version, assembly, seconds = pickle.loads(spool_path(out, index).read_bytes())
    except (OSError, ValueError, EOFError, pickle.UnpicklingError, AttributeError, TypeError):
        return None
    if version != SPOOL_VERSION or assembly.index != index or assembly.seed != seed:
        return None
    return assembly, seconds


def has(out, index: int) -> bool:
    return spool_path(out, index).exists()


def drop(out, indices) -> None:
    """Forget the objects of a finished shard."""
    for i in indices:
        try:
            os.unlink(spool_path(out, i))
        except FileNotFoundError:
            pass
