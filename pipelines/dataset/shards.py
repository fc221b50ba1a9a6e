"""The unit of work: a shard, a fixed range of object indices, written as two Parquet files.

`build_shard(config, k, out)` is the whole job for shard k, the same function whether it runs in
this process, in a local worker process or as a Ray task:

1. if `OUT/meta/shards/NNNNN.json` (the completion marker) exists for this config (the hash the
   folder knows it by: `folder_identity`), return;
2. for each object of the shard, in index order: make it (sampler or design; a synthetic object
   grown ahead by a lockstep build is taken from `spool`), render and encode every step, and
   append its rows to the temporary file of its split as one row group;
3. `os.replace` both temporary files into `OUT/data/{train,test}-NNNNN-of-NNNNN.parquet` (a
   split with no object in this shard gets a file with the schema and no rows);
4. write the marker (atomically): counts, rejection statistics, bytes, per-stage seconds.

Nothing in a data file depends on time, process or order of shards (fixed writer options, sorted
JSON, render caches cleared per object), so a killed and resumed build equals an uninterrupted
one byte for byte. Stage timings live only in the markers.
"""

from __future__ import annotations

import functools
import json
import os
import socket
import sys
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from factory.atomic import write_atomic
from factory.dataset.info import json_bytes
from factory.dataset.schema import arrow_schema
from factory.dataset.tasks import SPLITS
from pipelines.dataset import cluster, spool
from pipelines.dataset.config import DatasetConfig, started_hash
from pipelines.dataset.sources import make_source

WRITER_OPTIONS = dict(
    compression="zstd",
    compression_level=3,
    version="2.6",
    use_dictionary=True,
    write_statistics=True,
    data_page_size=1 << 20,
    write_page_index=False,
)
"""Fixed Parquet writer options (part of the byte-identity guarantee, with the pyarrow version)."""

_SOURCES: dict[str, object] = {}


def marker_path(out, shard: int) -> Path:
    return Path(out) / "meta" / "shards" / f"{shard:05d}.json"


def folder_identity(config: DatasetConfig, out) -> tuple[str, dict]:
    """(hash, record) that the folder `out` knows `config` by: the `config_hash` and `config` of its
    `meta/config.json` when they are `config`'s by the rule of the schema version that wrote them
    (`started_hash`: a folder started at version 1 keeps its hash, so the shards it finished stay
    finished), else `config.hash` and `config.to_json()` (a folder not started yet, or one started
    with another config, which `build` refuses before any shard). Shard markers and
    `meta/info.json` carry this hash."""
    try:
        stored = json.loads((Path(out) / "meta" / "config.json").read_text())
    except (OSError, ValueError):
        stored = None
    known = started_hash(config, stored)
    if known is None:
        return config.hash, config.to_json()
    return known, stored["config"]


def read_marker(out, shard: int, config: DatasetConfig, config_hash: str | None = None) -> dict | None:
    """The shard's completion record when it is done under this config (`config_hash`: the hash
    the folder knows it by, `folder_identity`; read from the folder when None) and its data files
    are there at the sizes it records, else None (then the shard is built again; a missing or cut
    file is named on stderr)."""
    if config_hash is None:
        config_hash = folder_identity(config, out)[0]
    p = marker_path(out, shard)
    try:
        rec = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict) or rec.get("config_hash") != config_hash:
        return None
    try:
        files, sizes = rec["files"], rec["bytes"]
        for split, name in files.items():
            try:
                size = (Path(out) / name).stat().st_size
            except FileNotFoundError:
                size = None
            if size != sizes[split]:
                print(f"warning: {Path(out) / name} is {'missing' if size is None else f'{size} bytes'}, its marker "
                      f"{p} records {sizes[split]} bytes: shard {shard} is built again", file=sys.stderr)
                return None
    except (KeyError, TypeError, AttributeError):
        return None
    return rec


def object_source(config: DatasetConfig):
    """One object source per process and config, run settings included (a Ray or pool worker
    reuses it across shards)."""
    key = json.dumps(config.to_dict(), sort_keys=True)
    if key not in _SOURCES:
        _SOURCES.clear()
        _SOURCES[key] = make_source(config)
    return _SOURCES[key]


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def remove_stranded(out) -> None:
    """Temporary files a killed run left (`.NAME.*.tmp` of `write_atomic` and the shard writers)
    anywhere under the folder's data, meta and gallery folders (the gallery's images included).
    Only for the run holding the folder (`build.holding`): no other run can be writing them.
    Symbolic links are not followed."""
    out = Path(out)
    for top in (out / "data", out / "meta", out / "gallery"):
        for folder, _, files in os.walk(top):
            for name in files:
                f = Path(folder) / name
                if name.startswith(".") and name.endswith(".tmp") and not f.is_symlink():
                    try:
                        f.unlink()
                    except OSError:
                        pass


def _remove_stale(out: Path, names: list[str]) -> None:
    data = out / "data"
    if not data.is_dir():
        return
    for f in data.iterdir():
        if any(f.name.startswith(f".{n}.") and f.name.endswith(".tmp") for n in names):
            try:
                f.unlink()
            except OSError:
                pass


@functools.cache
def _part_images():
    """The worker process's `factory.render.PartImages`, kept across its objects and shards (a pool
    or Ray worker runs `build_shard` again and again): plain images, each drawn in a scene of that
    part alone, so they do not depend on what the process rendered before; every GL resource
    belongs to the per-object renderer (`rows.object_rows`)."""
    from factory.render import PartImages  # lazy: factory.render sets up GL at import

    return PartImages()


WAIT_POLL_S = 0.2
"""How often a waiting shard (`build_shard(..., wait=True)`) looks for newly grown objects."""


def _grown_together(out: Path, config: DatasetConfig, sampler, indices: list[int]):
    """(index, (assembly, seconds)) for each object of a shard whose checks are batched ('jax'):
    those grown ahead (`spool`) first, then the rest grown here in lockstep, each as it ends. One
    round of device calls serves every object of the shard, where growing them one at a time made
    a round per object; the objects are the same (`Sampler.grow`). An object's seconds are the
    growth between it and the one before it (not the rendering of that one)."""
    ahead = {i: spool.get(out, i, config.seed) for i in indices}
    yield from ((i, g) for i, g in ahead.items() if g is not None)
    t0 = time.perf_counter()
    for a in sampler.grow([i for i in indices if ahead[i] is None], batch=len(indices)):
        yield a.index, (a, time.perf_counter() - t0)
        t0 = time.perf_counter()


def _arrivals(out: Path, config: DatasetConfig, indices: list[int], wait: bool):
    """(index, grown) for each object of a shard, `grown` from `spool` or None (the shard makes the
    object itself). In index order; with `wait`, a synthetic object grown ahead is taken as soon as
    it is there, whatever its index, and while the build's growers run (`spool.growers_active`) the
    shard waits for its next grown object rather than growing one itself."""
    left = list(indices)
    synthetic = config.source == "synthetic"
    while left:
        pick = left[0]
        if wait and synthetic:
            present = spool.present(out)
            ready = [i for i in left if i in present]
            if not ready and spool.growers_active(out):
                time.sleep(WAIT_POLL_S)
                continue
            pick = ready[0] if ready else left[0]
        left.remove(pick)
        yield pick, spool.get(out, pick, config.seed) if synthetic else None


def build_shard(config: DatasetConfig | dict, shard: int, out: str | os.PathLike, progress=None,
                source=None, wait: bool = False) -> Path:
    """Build shard `shard` of `config` into the folder `out`; returns its completion marker's path.

    `config`: a `DatasetConfig`, or one as a dict (`DatasetConfig.from_any`: the builder sends
    `to_dict()`, which keeps the run settings, the checks' backend among them). `progress`, if given, is called with 1 after each object (in-process runs use it for a
    per-object progress bar). `source`: the object source (default `object_source(config)`); an
    object it gives with finished `rows` is written as it is (world feedback), else rendered.
    `wait` (a lockstep build, started before all the shard's objects are grown): render each
    object as it is grown (`_arrivals`), so rendering overlaps the growth of the shard's slowest
    object; the files are the same bytes (rows are written in index order, an object's rows held
    until those before it are written).
    """
    from pipelines.dataset.rows import object_rows  # lazy: it imports factory.render (GL at import)

    if isinstance(config, dict):
        config = DatasetConfig.from_any(config)
    out = Path(out)
    marker = marker_path(out, shard)
    identity = folder_identity(config, out)[0]
    if read_marker(out, shard, config, identity) is not None:
        return marker
    t_start = time.perf_counter()
    finals = {s: out / config.shard_file(s, shard) for s in SPLITS}
    _remove_stale(out, [p.name for p in finals.values()])
    finals["train"].parent.mkdir(parents=True, exist_ok=True)
    # Host and pid: the writers of a cluster's nodes share the folder.
    tmps = {s: p.with_name(f".{p.name}.{socket.gethostname()}.{os.getpid()}.tmp") for s, p in finals.items()}
    schema = arrow_schema(config.extra_images, config.extra_fields)
    writers = {s: pq.ParquetWriter(str(tmps[s]), schema, **WRITER_OPTIONS) for s in SPLITS}
    timings = {"sample": 0.0, "check": 0.0, "render": 0.0, "encode": 0.0, "write": 0.0}
    counts = {s: {"objects": 0, "steps": 0} for s in SPLITS}
    stats: dict[str, dict[str, int]] = {}
    objects = []

    def write(index, obj, rows):
        """One object's rows into its split's file, its counts and statistics into the marker's."""
        oid, split = config.object_id(index), config.split(index)
        t = time.perf_counter()
        if rows:
            writers[split].write_table(pa.Table.from_pylist(rows, schema=schema))
        timings["write"] += time.perf_counter() - t
        counts[split]["objects"] += 1
        counts[split]["steps"] += len(rows)
        for group, counter in obj.stats.items():
            agg = stats.setdefault(group, {})
            for reason, n in counter.items():
                agg[str(reason)] = agg.get(str(reason), 0) + int(n)
        objects.append({"index": index, "object_id": oid, "split": split, "steps": len(rows), **obj.info})

    try:
        source = source if source is not None else object_source(config)
        indices = config.shard_objects(shard)
        made: dict[int, tuple] = {}  # objects made out of index order, until those before them are written
        at = 0
        sampler = getattr(source, "sampler", None)
        if not wait and sampler is not None and sampler.config.backend == "jax":
            arrivals = _grown_together(out, config, sampler, indices)
        else:
            arrivals = _arrivals(out, config, indices, wait)
        for index, grown in arrivals:
            oid = config.object_id(index)
            obj = source.object(index, oid, grown) if grown is not None else source.object(index, oid)
            for k, v in obj.timings.items():
                timings[k] = timings.get(k, 0.0) + v
            rows = obj.rows if obj.rows is not None else object_rows(obj, config, config.split(index), timings,
                                                                     _part_images())
            made[index] = (obj, rows)
            del rows
            while at < len(indices) and indices[at] in made:
                write(indices[at], *made.pop(indices[at]))
                at += 1
            if progress is not None:
                progress(1)
        t = time.perf_counter()
        for w in writers.values():
            w.close()
        writers = {}
        for s in SPLITS:
            _fsync(tmps[s])  # on disk before its name and its marker say it is done
            os.replace(tmps[s], finals[s])
        timings["write"] += time.perf_counter() - t
    finally:
        for w in writers.values():
            try:
                w.close()
            except Exception:  # noqa: BLE001 - already failing; the temporary file is removed
                pass
        for p in tmps.values():
            if p.exists():
                p.unlink()
    record = {
        "shard": shard,
        "config_hash": identity,
        "files": {s: config.shard_file(s, shard) for s in SPLITS},
        "bytes": {s: finals[s].stat().st_size for s in SPLITS},
        "counts": counts,
        "stats": {g: dict(sorted(c.items())) for g, c in sorted(stats.items())},
        "objects": objects,
        "seconds": {k: round(v, 3) for k, v in timings.items()},
        "wall_seconds": round(time.perf_counter() - t_start, 3),
        **cluster.where(),
    }
    write_atomic(marker, json_bytes(record))
    if config.source == "synthetic":
        spool.drop(out, config.shard_objects(shard))
    return marker
