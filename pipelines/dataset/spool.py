"""Objects grown ahead of their shards: the producer's side of a lockstep build.

`build(..., batch=B)` grows the synthetic objects of every missing shard in grower tasks (`grow`:
each takes the objects of every G-th shard and grows them B at a time, `Sampler.grow`: their
checks of a step in one call, on the device with the 'jax' backend) while the other workers render
and encode the shards whose objects are all grown. Each grown object is
written here at once, atomically (`OUT/meta/spool/NNNNNNN.json`: the `Assembly` and its seconds,
as data only: `factory.sampler.record`; a file here is never run as code, whoever wrote it),
so a killed build loses no grown object: the resumed one takes them from here. A shard's files
are removed once its completion marker is written. The shard function reads an object from here
when it is present and samples it itself when not; both give the same object, so the data files
are the same either way.
"""

from __future__ import annotations

import os
import json
import time
from contextlib import contextmanager
from pathlib import Path

from factory.atomic import write_atomic
from factory.sampler import Sampler, record
from pipelines.dataset.config import DatasetConfig

SPOOL_VERSION = 2
"""Bumped when what is written here changes; an entry of another version is grown again (1: pickles,
no longer read)."""

SUFFIX = ".json"


def folder(out) -> Path:
    """The build's spool folder."""
    return Path(out) / "meta" / "spool"


def spool_path(out, index: int) -> Path:
    return folder(out) / f"{index:07d}{SUFFIX}"


def put(out, index: int, assembly, seconds: float) -> None:
    """Keep object `index` (an `Assembly`) and the seconds its growth took."""
    entry = {"version": SPOOL_VERSION, "seconds": float(seconds),
             "assembly": record.to_json(assembly)}
    write_atomic(spool_path(out, index), json.dumps(entry, separators=(",", ":")).encode("utf-8"))


def get(out, index: int, seed: int):
    """(assembly, seconds) of object `index` when spooled for this seed, else None (an unreadable
    or foreign entry counts as absent: the object is grown again)."""
    try:
        entry = json.loads(spool_path(out, index).read_bytes())
        if not isinstance(entry, dict) or entry.get("version") != SPOOL_VERSION:
            return None
        seconds = entry["seconds"]
        assembly = record.from_json(entry["assembly"])
    except (OSError, ValueError, KeyError, RecursionError):  # record.RecordError is a ValueError
        return None
    if not isinstance(seconds, float) or assembly.index != index or assembly.seed != seed:
        return None
    return assembly, seconds


def has(out, index: int) -> bool:
    return spool_path(out, index).exists()


def present(out) -> set[int]:
    """The indices of every object kept here (one listing of the folder)."""
    try:
        names = os.listdir(folder(out))
    except FileNotFoundError:
        return set()
    k = len(SUFFIX)
    return {int(n[:-k]) for n in names if n.endswith(SUFFIX) and n[:-k].isdigit()}


GROWING = ".growing"
"""A file in the spool folder while a build's growers run (`growers_running`): a shard started
before all its objects are grown waits for them (`build_shard(..., wait=True)`) instead of
growing them itself."""


def growing_path(out) -> Path:
    return folder(out) / GROWING


@contextmanager
def growers_running(out):
    """Say, for the span of the block, that growers are growing this build's objects (the file
    `GROWING`); removed when the block ends, however it ends, or earlier by `growers_stopped`."""
    path = growing_path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(str(os.getpid()).encode())
    try:
        yield
    finally:
        growers_stopped(out)


def growers_stopped(out) -> None:
    """No object is grown ahead any more (a grower failed, or all ended): waiting shards grow what
    is still missing themselves."""
    try:
        os.unlink(growing_path(out))
    except FileNotFoundError:
        pass


def growers_active(out) -> bool:
    return growing_path(out).exists()


def drop(out, indices) -> None:
    """Forget the objects of a finished shard (also an entry of version 1, never read)."""
    for i in indices:
        for path in (spool_path(out, i), folder(out) / f"{i:07d}.pkl"):
            try:
                os.unlink(path)
            except FileNotFoundError:
                pass


def grow(config_json: dict, indices: list[int], out, batch: int) -> int:
    """Grow objects `indices` of a synthetic dataset config (`DatasetConfig.to_dict()`, as the
    builder sends it, or `to_json()`: `DatasetConfig.from_any`) `batch` at a time and keep each
    here as it ends (a grower task of a lockstep build; runs in a worker process or a Ray task).
    Objects already here are not grown again. Returns how many it grew."""
    config = DatasetConfig.from_any(config_json)
    todo = [i for i in indices if not has(out, i)]
    sampler = Sampler(config.sampler, config.ldraw)
    t0 = time.perf_counter()
    for a in sampler.grow(todo, batch):
        t1 = time.perf_counter()
        put(out, a.index, a, t1 - t0)
        t0 = t1
    return len(todo)
