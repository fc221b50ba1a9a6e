"""Fit a usage prior to a folder of real designs (`fit_prior`).

Each design weighs the same: a family's share is its placements over the design's placements,
averaged over the designs (a 3,000-part set would otherwise decide the prior alone). The weights
are those mean shares raised to `temper` and normalised: below 1 a part few designs use is drawn
more often than its share, so a prior fitted on some designs still shows, now and then, parts
other designs use. Colours are fitted the same way; connection kinds are the plain mean shares.
"""

from __future__ import annotations

import os
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from factory.errors import LDrawError
from factory.ldraw import Reader
from factory.ldraw.colours import EDGE, MAIN
from factory.prior.families import family, part_name, unprinted
from factory.prior.placements import Design, Use, read_design
from factory.prior.prior import (
    MINIFIG, NONE, OTHER, SIDE_STUDS, STUDS, UNKNOWN, DesignSource, PartUse, Prior, PriorError,
)

DEFAULT_TEMPER = 0.6
"""The default `temper` (docs/prior.md: chosen by leave-one-design-out coverage)."""

MAX_MOVES = 8
"""`~Moved to` stubs followed in a row at most (a longer chain is left where it stops)."""


def resolved_name(reader: Reader, use: Use) -> str:
    """The name a use stands for: past `~Moved to` stubs, then unprinted where the library has
    the unprinted part (`3068bp01` -> `3068b`; a pattern whose base the library lacks stays)."""
    name, res = use.part, use.resolved
    for _ in range(MAX_MOVES):
        if res is None or not res.file.moved_to:
            break
        name = part_name(res.file.moved_to)
        res = _find(reader, name)
    base = unprinted(name)
    if base != name and _find(reader, base) is not None:
        return base
    return name


def _find(reader: Reader, name: str):
    """The library part `name`, or None (no 'did you mean' search: many names are missing)."""
    return reader.part(name) if reader.library.lookup(name + ".dat") is not None else None


def connection_kind(reader: Reader, name: str) -> tuple[str, str]:
    """(connection kind, description) of a library part, judged from the part alone: a
    minifigure piece; studs (any pointing sideways: `SIDE_STUDS`); else connector primitives of
    pins, axles, clips or hinges; else sockets (a tile: `STUDS`); else a joint connector found
    from its drawing as the sampler finds them (`joints.joint_ends`: a bar, a rim's grip, a hole
    drawn without primitives); else `NONE`."""
    from factory.joints import joint_ends
    from factory.parts import load_part  # trimesh and scipy: only when fitting
    from factory.physics.unmodelled import is_minifig

    try:
        part = load_part(reader, name)
    except LDrawError:
        return UNKNOWN, ""
    if is_minifig(part):
        return MINIFIG, part.description
    studs = part.flat.studs
    if len(studs):  # a Technic brick or a round brick with an axle hole is built on its studs
        sideways = np.abs(studs[:, 1, 1]) < 0.99  # axis not along y
        return (SIDE_STUDS if sideways.any() else STUDS), part.description
    if len(part.flat.other_connectors):
        return OTHER, part.description
    if part.sockets:  # a tile, a cheese slope: sockets only (found once, cached on disk)
        return STUDS, part.description
    if joint_ends(part):  # held by joints alone, found as the sampler finds them: a bar, a rim
        return OTHER, part.description
    return NONE, part.description


def fit_prior(designs: Iterable[str | os.PathLike], reader: Reader, temper: float = DEFAULT_TEMPER,
              progress: Callable[[str], None] | None = None, skip_unreadable: bool = False,
              require_licence: bool = False) -> Prior:
    """The prior of the designs (files), resolved against `reader`'s library. A design that
    cannot be read raises its LDraw error (naming file and line), or with `skip_unreadable` is
    left out (`progress` says why); parts no library holds are counted by name (connection kind
    `UNKNOWN`). With `require_licence`, a design without a `0 !LICENSE` line is left out (the
    shipped prior is fitted on designs that say they may be redistributed)."""
    if not (0 < temper <= 1):
        raise PriorError(f"temper must be in (0, 1], got {temper}")
    read: list[Design] = []
    for path in designs:
        try:
            d = read_design(reader, path)
        except LDrawError as exc:
            if not skip_unreadable:
                raise
            if progress:
                progress(f"{Path(path).name}: left out, cannot be read: {exc}")
            continue
        if require_licence and not d.licence:
            if progress:
                progress(f"{Path(path).name}: left out, it states no licence (0 !LICENSE)")
            continue
        if d.uses:
            read.append(d)
        if progress:
            progress(f"{Path(path).name}: {len(d.uses)} placements, {len(d.missing)} parts not in the library"
                     + (f", {d.primitives} primitives placed as parts (not counted)" if d.primitives else ""))
    if not read:
        raise PriorError("no design placed any part; give LDraw models (.ldr, .mpd) that place parts")
    valid_colours = set(reader.colours.colours) - {MAIN, EDGE}
    part_share: dict[str, float] = defaultdict(float)
    colour_share: dict[int, float] = defaultdict(float)
    kind_share: dict[str, float] = defaultdict(float)
    members: dict[str, Counter] = defaultdict(Counter)
    placements: Counter = Counter()
    in_designs: Counter = Counter()
    kinds: dict[str, tuple[str, str]] = {}
    for d in read:
        n = len(d.uses)
        fams = Counter()
        for use in d.uses:
            name = resolved_name(reader, use)
            fam = family(name)
            fams[fam] += 1
            members[fam][name] += 1
            if name not in kinds:  # (a printed part no library holds may stand for its base, which one does)
                in_library = use.resolved is not None or _find(reader, name) is not None
                kinds[name] = connection_kind(reader, name) if in_library else (UNKNOWN, "")
            kind_share[kinds[name][0]] += 1 / n / len(read)
        for fam, k in fams.items():
            part_share[fam] += k / n / len(read)
            placements[fam] += k
            in_designs[fam] += 1
        coloured = [u.colour for u in d.uses if u.colour in valid_colours]
        for code, k in Counter(coloured).items():
            colour_share[code] += k / len(coloured) / len(read)
    parts = []
    for fam, share in part_share.items():
        ranked = [name for name, _ in sorted(members[fam].items(), key=lambda kv: (-kv[1], kv[0]))]
        in_library = [name for name in ranked if kinds[name][0] != UNKNOWN]
        order = in_library + [name for name in ranked if name not in in_library]
        kind, description = kinds[order[0]]
        parts.append(PartUse(fam, order[0], share ** temper, placements[fam], in_designs[fam], tuple(order[1:]),
                             description, kind))
    total = sum(p.weight for p in parts)
    # Rounded as the file keeps them, so that a prior and the prior read back from its file are equal.
    parts = sorted((_reweigh(p, round(p.weight / total, 8)) for p in parts), key=lambda p: (-p.weight, p.family))
    ctotal = sum(s ** temper for s in colour_share.values()) or 1.0
    colours = tuple(sorted(((c, round(s ** temper / ctotal, 8)) for c, s in colour_share.items()),
                           key=lambda cw: (-cw[1], cw[0])))
    connections = tuple((k, round(kind_share.get(k, 0.0), 6)) for k in (STUDS, SIDE_STUDS, OTHER, MINIFIG, NONE, UNKNOWN))
    sources = tuple(DesignSource(Path(d.path).name, len(d.uses), d.licence) for d in read)
    return Prior(tuple(parts), colours, connections, sources, temper, reader.library.description)


def _reweigh(p: PartUse, weight: float) -> PartUse:
    return PartUse(p.family, p.part, weight, p.placements, p.designs, p.alternatives, p.description, p.connection)
