"""Preparing a library's parts once: each part's connections and collision pieces, computed over
all cores and kept in the cache (`factory.cache`), so that growing objects never waits on them.

`survey` says, part by part, whether the sampler can use it and why not (`factory.prior.choose.
why_unusable`: not readable, a minifigure piece, no studs and no sockets); with `prepare=True` a
usable part is also decomposed into its collision pieces (`factory.physics.geometry.
collision_shape`: seconds per part on a cold cache), and one the decomposition refuses is left
out with that reason. Everything computed is cached, so a second run, or one cut short and run
again, does only what is left.

`pack` writes the cache's part entries (sockets, collision pieces, outlines) into one zip to hand
to another machine; `unpack` puts them into that machine's cache, refusing any member that is not
such an entry.
"""

from __future__ import annotations

import multiprocessing as mp
import re
import time
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from factory.atomic import write_atomic
from factory.cache import cache_root
from factory.errors import LDrawError
from factory.joints import summary as joint_summary
from factory.ldraw import get_reader
from factory.prior.choose import not_its_own_part, why_unusable
from pipelines import workers

PACKED = ("coacd", "sockets", "symmetry", "hulls", "outlines")
"""Cache folders of per-part entries (`factory.cache`); the JAX kernels are not packed (they run
code, and they are compiled for one machine)."""
_ENTRY = re.compile(r"^(coacd|sockets|symmetry|hulls|outlines)/[0-9a-f]{16,64}(\.npz|\.npy|\.json|\.slow\.json)$")
MAX_ENTRY_BYTES = 64 << 20
"""An entry larger than this is refused when unpacking (the largest decomposition is under 1 MB)."""


@dataclass(frozen=True)
class PartStatus:
    """What the factory can do with one part of a library."""

    part: str
    category: str
    reason: str | None
    """None: usable; else why it is left out."""
    seconds: float = 0.0
    joints: dict[str, int] | None = None
    """{kind: count} of its joint connectors (`factory.joints.summary`: pins, axles, holes, clips,
    bars, hinges...), where it could be read."""


_LDRAW: str | None = None


def _init(counter, parent: int, ldraw: str | None) -> None:
    global _LDRAW
    workers.start_worker(counter, parent)
    _LDRAW = ldraw


def part_status(ldraw: str | None, name: str, prepare: bool, own_parts: bool = False,
                every: bool = False) -> PartStatus:
    """The status of one part (in a worker process: the reader is that process's own). With
    `own_parts`, renumbered stubs, aliases and parts not for use alone are left out too (a list
    of every file of a library's `parts/`). With `every`, `prepare` prepares a readable part the
    sampler cannot use as well (a design's parts: replaying it needs the collision pieces of
    every part it places, a Technic beam or a minifigure arm included)."""
    from factory.physics.geometry import collision_shape  # MuJoCo-free, but coacd: only when preparing
    from factory.parts import load_part

    t0 = time.perf_counter()
    reader = get_reader(ldraw)
    try:
        category = reader.part(name).file.part_category or "?"
    except LDrawError:
        category = "?"
    reason = (not_its_own_part(reader, name) if own_parts else None) or why_unusable(reader, name)
    joints = None
    if not (reason or "").startswith("cannot be read"):
        try:
            joints = joint_summary(load_part(reader, name))
        except LDrawError:
            pass
    if prepare and (reason is None or (every and not reason.startswith("cannot be read"))):
        try:
            part = load_part(reader, name)
            part.symmetry, part.hull_points
            collision_shape(part)
        except LDrawError as exc:
            reason = reason or f"collision pieces refused: {exc}"
    return PartStatus(name, category, reason, time.perf_counter() - t0, joints)


def _one(args: tuple[str, bool, bool, bool]) -> PartStatus:
    return part_status(_LDRAW, *args)


def survey(ldraw: str | None, names: Iterable[str], prepare: bool = False, n_workers: int = 1,
           progress: Callable[[PartStatus], None] | None = None, own_parts: bool = False,
           every: bool = False) -> list[PartStatus]:
    """Every part's status, in the order of `names`, over `n_workers` processes (`own_parts`,
    `every`: `part_status`)."""
    names = list(names)
    out: dict[str, PartStatus] = {}
    if n_workers <= 1:
        for name in names:
            out[name] = part_status(ldraw, name, prepare, own_parts, every)
            if progress:
                progress(out[name])
    else:
        # One numeric thread per worker, for the coacd children too (they inherit it): coacd
        # otherwise starts OpenMP's default, a thread per core, in every worker's child at once.
        with workers.one_thread_each_meanwhile():
            ctx = mp.get_context("fork")
            with ctx.Pool(n_workers, initializer=_init, initargs=(*workers.numbering(ctx), ldraw)) as pool:
                for status in pool.imap_unordered(_one, [(n, prepare, own_parts, every) for n in names],
                                                  chunksize=1):
                    out[status.part] = status
                    if progress:
                        progress(status)
    return [out[n] for n in names]


def pack(path: str | Path) -> int:
    """Write the cache's per-part entries into one zip at `path`; returns how many."""
    root = cache_root()
    entries = sorted(p for folder in PACKED for p in (root / folder).glob("*") if p.is_file() and
                     _ENTRY.match(f"{folder}/{p.name}"))
    tmp = Path(path).with_name(f".{Path(path).name}.tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for p in entries:
            z.write(p, f"{p.parent.name}/{p.name}")
    tmp.replace(path)
    return len(entries)


def unpack(path: str | Path) -> int:
    """Put the entries of a zip `pack` wrote into this machine's cache (existing entries are
    kept); a member that is not a cache entry, or too large, refuses the whole file."""
    root = cache_root()
    with zipfile.ZipFile(path) as z:
        infos = [i for i in z.infolist() if not i.is_dir()]
        for info in infos:
            if not _ENTRY.match(info.filename) or info.file_size > MAX_ENTRY_BYTES:
                raise ValueError(f"{path}: member {info.filename!r} is not a cache entry written by `pack` "
                                 f"(expected {'/, '.join(PACKED)}/ and a hex name ending .npz, .npy, .json or .slow.json, "
                                 f"at most {MAX_ENTRY_BYTES >> 20} MB); nothing was unpacked")
        added = 0
        for info in infos:
            target = root / info.filename
            if target.exists():
                continue
            with z.open(info) as f:
                data = f.read(MAX_ENTRY_BYTES + 1)
            write_atomic(target, data)
            added += 1
    return added
