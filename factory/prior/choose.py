"""Which parts of a prior a library can give the sampler (`choose_parts`), and why each other one
is left out.

A prior part is looked up in the library by its name, then the other members the designs placed,
then any unprinted member of its family the library holds (the embedded library has `3023` where
designs place `3023b`). It is usable when it loads and has studs or sockets, a joint connector
(`joints.joint_ends`), or is a minifigure piece with a place of its own (`factory.minifig`): the
sampler connects parts by these. A part left out keeps its weight in the report, so a user sees what share of real
usage their data cannot show.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass

from factory.embedded.catalog import PARTS
from factory.embedded.colours import COLOURS
from factory.errors import LDrawError
from factory.joints import held_by_joints_alone, joint_ends
from factory.minifig import role
from factory.ldraw import Reader
from factory.ldraw.colours import EDGE, MAIN
from factory.prior.families import family, unprinted
from factory.prior.prior import MINIFIG, OTHER, SIDE_STUDS, STUDS, PartUse, Prior

NOT_IN_LIBRARY = "not in the library"
TOO_MANY_TRIANGLES = "too many triangles for the physics checks"
NO_CONNECTOR = ("no studs, no sockets and no joint connector found: held by its shape (a tyre on a rim, cloth, "
                "a sticker), which the factory cannot tell where to put")
MINIFIGURE = ("a minifigure piece held by a hand, a helmet or another piece where it sits differs per piece "
              "(a tool, a weapon, a plume, a visor): the sampler attaches only pieces with a place of their own "
              "(`factory.minifig.SLOTS`)")


@dataclass(frozen=True)
class LeftOut:
    """A prior part the sampler cannot use on this library."""

    family: str
    part: str
    weight: float
    """Its weight in the prior (the weights of all prior parts sum to 1)."""
    reason: str


@dataclass(frozen=True)
class PartChoice:
    """A prior resolved against one library."""

    parts: tuple[tuple[str, float], ...]
    """(library part name, weight) for `SamplerConfig.parts`, in the prior's order."""
    colours: tuple[tuple[int, float], ...]
    """(colour code, weight) for `SamplerConfig.colours`: the prior's colours the library has."""
    left_out: tuple[LeftOut, ...]
    colours_left_out: tuple[int, ...]
    used_weight: float
    """The prior weight of the parts used (1: every part of the prior is usable)."""


def _family_index(names) -> dict[str, list[str]]:
    """Family -> the unprinted library parts of it."""
    index: dict[str, list[str]] = defaultdict(list)
    for name in names:
        if unprinted(name) == name:
            index[family(name)].append(name)
    return index


def _candidates(use: PartUse, have: set[str], index: dict[str, list[str]]) -> list[str]:
    """Library parts that can stand for a prior part, best first: its part, the other members
    the designs placed, then the family's other unprinted parts (latest revision first)."""
    names = [use.part, *use.alternatives, *sorted(index.get(use.family, ()), reverse=True)]
    return [n for n in dict.fromkeys(names) if n in have]


def embedded_choice(prior: Prior) -> tuple[tuple[tuple[str, float], ...], tuple[tuple[int, float], ...]]:
    """(parts, colours) of `prior` on the embedded library, without reading it: every embedded
    part has studs or sockets, so a family the catalog holds is usable. What the default
    `SamplerConfig` draws from (`factory.sampler.config`)."""
    have = {p.number for p in PARTS}
    index = _family_index(sorted(have))
    parts, taken = [], set()
    for use in prior.parts:
        found = _candidates(use, have, index) if use.connection != MINIFIG else []
        if found and found[0] not in taken:
            parts.append((found[0], use.weight))
            taken.add(found[0])
    codes = {c.code for c in COLOURS} - {MAIN, EDGE}
    return tuple(parts), tuple((c, w) for c, w in prior.colours if c in codes)


def not_its_own_part(reader: Reader, name: str) -> str | None:
    """Why a file of a library's `parts/` is not a part of its own, for lists of every part
    (`--parts all`): a renumbered stub (`~Moved to`), an alias (`=`), a physical-colour variant
    (`_`) or a file LDraw marks as not for use alone (`~`: a sub-part or an obsolete part). None
    for a part of its own."""
    try:
        f = reader.part(name).file
    except LDrawError as exc:
        return f"cannot be read: {exc}"
    if f.moved_to:
        return f"renumbered: moved to {f.moved_to.removesuffix('.dat')}"
    head = f.description.lstrip()[:1]
    return {"=": "an alias of another part (=)", "_": "a physical-colour variant of another part (_)",
            "~": "not for use on its own (~: a sub-part or obsolete)"}.get(head)


def why_unusable(reader: Reader, name: str) -> str | None:
    """None when the sampler can use the library part `name`, else the reason (a property of the
    part, or the LDraw error that reading it raised). Known without decomposing the part: its
    collision pieces are made where it is first drawn, and a part that coacd refuses gets its
    hull's pieces (`factory.physics.decompose`), so decomposing it leaves no part out."""
    from factory.parts import load_part  # trimesh and scipy: only when parts are chosen
    from factory.physics.geometry import too_many_triangles
    from factory.physics.unmodelled import is_minifig

    try:
        part = load_part(reader, name)
        too_many = too_many_triangles(part)
        if too_many:
            return f"{TOO_MANY_TRIANGLES}: {too_many}"
        if is_minifig(part):
            return None if role(part.description) is not None else MINIFIGURE
        if held_by_joints_alone(part):
            return None if joint_ends(part) else NO_CONNECTOR
    except LDrawError as exc:
        return f"cannot be read: {exc}"
    return None


def choose_parts(prior: Prior, reader: Reader, progress: Callable[[int, int], None] | None = None) -> PartChoice:
    """The parts and colours of `prior` that the library of `reader` can give the sampler."""
    from factory.parts import load_part  # trimesh and scipy: only when parts are chosen

    have = set(reader.library.part_names())
    index = _family_index(sorted(have))
    parts: list[tuple[str, float]] = []
    by_joints: list[bool] = []
    left: list[LeftOut] = []
    taken: set[str] = set()
    for k, use in enumerate(prior.parts):
        if progress:
            progress(k, len(prior.parts))
        found = _candidates(use, have, index)
        if not found:
            left.append(LeftOut(use.family, use.part, use.weight, NOT_IN_LIBRARY))
            continue
        reason = why_unusable(reader, found[0])
        if reason is None and found[0] not in taken:
            parts.append((found[0], use.weight))
            got = load_part(reader, found[0])
            by_joints.append(held_by_joints_alone(got) and role(got.description) is None)
            taken.add(found[0])
        else:
            left.append(LeftOut(use.family, found[0], use.weight, reason or f"{found[0]} is listed twice"))
    if progress:
        progress(len(prior.parts), len(prior.parts))
    valid = set(reader.colours.colours) - {MAIN, EDGE}
    colours = tuple((c, w) for c, w in prior.colours if c in valid)
    return PartChoice(balanced(parts, by_joints, prior), colours, tuple(left),
                      tuple(c for c, _ in prior.colours if c not in valid), sum(w for _, w in parts))


def joint_share(prior: Prior) -> float:
    """The share of the designs' placements that are of parts held by pins, axles, clips or
    hinges, among those of parts the sampler can connect (by studs, by those joints, or minifigure
    pieces by their own)."""
    shares = dict(prior.connections)
    usable = sum(shares.get(k, 0.0) for k in (STUDS, SIDE_STUDS, OTHER, MINIFIG))
    return shares.get(OTHER, 0.0) / usable if usable > 0 else 0.0


def balanced(parts: list[tuple[str, float]], by_joints: list[bool], prior: Prior) -> tuple[tuple[str, float], ...]:
    """The parts' weights with those held by joints alone (`by_joints`:
    `joints.held_by_joints_alone`) scaled together so that they are drawn `joint_share` of the
    time, as in the designs; the others keep their weights among themselves. Tempering flattens the weights of rare parts,
    and most joint parts are rare: without this they would be drawn more often than designs place
    them, or, with few of them in a library, less."""
    target = joint_share(prior)
    joints = sum(w for (_, w), j in zip(parts, by_joints) if j)
    studs = sum(w for (_, w), j in zip(parts, by_joints) if not j)
    if joints <= 0 or studs <= 0 or target <= 0:
        return tuple(parts)
    scale_j, scale_s = target / joints, (1.0 - target) / studs
    total = sum(w for _, w in parts)
    return tuple((name, round(w * (scale_j if j else scale_s) * total, 9)) for (name, w), j in zip(parts, by_joints))
