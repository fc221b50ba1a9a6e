"""Connections beyond studs: a part's joint connectors as records, and what a mated pair keeps free.

Found from the part's own drawing (`factory.ldraw.reader.Flat`): LDraw's connector primitives
(Technic pin holes, axle holes, pins, axles, bushes, clips, click hinges, wheel pins and their
holes, bar handles: `other_connectors`, with their kinds), the cylinders of a bar's radius it is
drawn with (a bar, a clip's grip, a hinge finger's round end, the solid pin under a 1xN plate:
`bars`, solid or hollow), and its hollow studs' bores (a bar or pin goes in). Each record has a
kind, a gender (`male` goes into a `female`; `hinge` fingers sit between fingers), the stretch of
its axis it spans and the axis, in the part's LDraw frame (LDU, -Y up).

Which kinds mate, and what each joint leaves free (`FREEDOMS`): a pin turns in a pin hole and does
not slide; an axle in an axle hole slides and does not turn; an axle in a pin hole does both; a
wheel turns on its wheel pin; a clip turns about its bar and slides along it; a click hinge turns in
steps. The checker finds the joints two placed parts make (`factory.physics.unmodelled.
joints_between`), the sampler attaches through them (`factory.physics.joint_attach`), and the
load model carries them (`factory.physics.joint_capacity`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from factory.connections import first_hits
from factory.ldraw.other_connectors import CONNECTOR_KINDS

GENDERS = {
    "pin": "male", "axle": "male", "wheel-pin": "male", "handle": "male", "bar": "male",
    "pin-hole": "female", "axle-hole": "female", "bush": "female", "wheel-pin-hole": "female",
    "clip": "female", "grip": "female", "bore": "female",
    "hinge": "hinge",
}
"""Each connector kind's gender. `bar` is a solid cylinder of a bar's radius (a bar, a hinge finger's
round end, the pin under a 1xN plate), `grip` a hollow one (a clip drawn without a clip
primitive), `bore` a hollow stud's bore; the others are `CONNECTOR_KINDS`."""

@dataclass(frozen=True)
class Freedom:
    """What a mated pair of connectors leaves free about and along their shared axis."""

    turns: bool
    """It turns about the axis (a pin in a pin hole, a wheel on its pin, a clip on a bar)."""
    slides: bool
    """It slides along the axis (an axle in an axle hole, a clip along a bar)."""
    stepped: bool = False
    """It holds only at steps of its turn (a click hinge's detents, `CLICK_STEP_DEG` apart)."""


FREEDOMS: dict[frozenset[str], Freedom] = {
    frozenset({"pin", "pin-hole"}): Freedom(turns=True, slides=False),
    frozenset({"axle", "axle-hole"}): Freedom(turns=False, slides=True),
    frozenset({"axle", "bush"}): Freedom(turns=False, slides=True),
    frozenset({"axle", "pin-hole"}): Freedom(turns=True, slides=True),
    frozenset({"wheel-pin", "wheel-pin-hole"}): Freedom(turns=True, slides=False),
    frozenset({"bar", "clip"}): Freedom(turns=True, slides=True),
    frozenset({"bar", "grip"}): Freedom(turns=True, slides=True),
    frozenset({"handle", "clip"}): Freedom(turns=True, slides=True),
    frozenset({"handle", "grip"}): Freedom(turns=True, slides=True),
    frozenset({"bar", "bore"}): Freedom(turns=True, slides=True),
    frozenset({"bar", "pin-hole"}): Freedom(turns=True, slides=True),
    frozenset({"hinge"}): Freedom(turns=True, slides=False, stepped=True),
}
"""The pairs of kinds that make a joint, and what each leaves free. A pair not listed holds
nothing (two pins end to end, a pin in an axle hole's cross)."""


@dataclass(frozen=True)
class JointConnector:
    """One connector of a part (not a stud or socket), in the part's frame."""

    kind: str
    """A key of `GENDERS`."""
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    """The two ends of the stretch of the axis the connector spans (LDU)."""
    axis: tuple[float, float, float]
    """Its unit axis (the line a mating connector lies on)."""
    ref: tuple[float, float, float] | None = None
    """For a connector primitive, the direction of the primitive's own Z axis: where it is turned
    to about its axis (`click_angle`); None for a cylinder or a bore."""

    @property
    def gender(self) -> str:
        return GENDERS[self.kind]

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.subtract(self.end, self.start)))


def _records(kind_of, segments: np.ndarray, refs: np.ndarray | None = None) -> list[JointConnector]:
    return [JointConnector(kind_of(i), tuple(round(float(v), 4) for v in s[0]),
                           tuple(round(float(v), 4) for v in s[1]), tuple(round(float(v), 6) for v in s[2]),
                           None if refs is None else tuple(round(float(v), 6) for v in refs[i]))
            for i, s in enumerate(segments)]


def joint_connectors(part) -> tuple[JointConnector, ...]:
    """Every joint connector of a part (`factory.parts.Part` or anything with a `flat`): its
    connector primitives, its bar-size cylinders that are not inside one of them, and its hollow
    studs' bores."""
    flat = part.flat
    out = _records(lambda i: CONNECTOR_KINDS[int(flat.other_kinds[i])], flat.other_connectors, flat.other_refs)
    # A bar-size cylinder inside a connector primitive (a hinge's finger, a clip's grip drawn with
    # `clip*`) is that connector, not another.
    prims = flat.other_connectors
    for i, bar in enumerate(flat.bars):
        if any(_within(bar, p) for p in prims):
            continue
        out += _records(lambda _: "grip" if flat.bar_out[i] < 0 else "bar", bar[None])
    out += _records(lambda _: "bore", flat.bores)
    if not any(c.gender == "female" and c.kind in _HOLE_KINDS for c in out):
        out += drawn_holes(flat.triangles)
    return tuple(out)


_HOLE_KINDS = ("pin-hole", "axle-hole", "bush", "wheel-pin-hole")

HOLE_PROBE_LDU = (5.0, 7.0)
"""Where `drawn_holes` looks round an axis for the walls of a hole (LDU from it): at 5 a Technic
axle hole's cross is open along its arms and closed between them (the cross's arms reach 6 LDU
from its axis), a pin hole (radius 6) is open all round, a bar's hole (radius 4) closed; at 7
the part surrounds either (a gear's hub), where an opening a part merely frames (a window, an
arch) is open."""


def drawn_holes(triangles: np.ndarray) -> list[JointConnector]:
    """The Technic holes a part draws without connector primitives (a gear whose axle hole is
    made of rectangles and cylinder pieces: 3648b): along each of the part's axes, through its
    origin, a line the part does not meet, walled in as `HOLE_PROBE_LDU` says. Its stretch is
    where the walls are."""
    out = []
    tris = np.asarray(triangles, float)
    if not len(tris):
        return out
    near, wall = HOLE_PROBE_LDU
    # Off the part's planes of symmetry: a line in one runs along the seams of mirrored subfiles
    # (3648b's quarters) and may slip between their triangles.
    angles = np.radians(np.concatenate([[0.0], np.arange(22.5, 360, 45), [5, 95, 185, 275], [45, 135, 225, 315]]))
    radii = np.concatenate([[0.0], np.full(8, wall), np.full(8, near)])
    for k in range(3):
        u, v, w = np.eye(3)[k], np.eye(3)[(k + 1) % 3], np.eye(3)[(k + 2) % 3]
        points = radii[:, None] * (np.cos(angles)[:, None] * v + np.sin(angles)[:, None] * w)
        lo, hi = _line_extent(tris, points, u)
        met = np.isfinite(lo)
        centre, walls, arms, between = met[0], met[1:9], met[9:13], met[13:]
        if centre or not walls.all() or arms.any():
            continue
        kind = "axle-hole" if between.all() else "pin-hole" if not between.any() else None
        start, end = float(lo[1:9].min()), float(hi[1:9].max())
        if kind is not None and end - start >= 4.0:
            # Rounded as `_records` rounds (a far cast leaves 1e-11 LDU of noise).
            out.append(JointConnector(kind, tuple(round(float(x), 4) + 0.0 for x in start * u),
                                      tuple(round(float(x), 4) + 0.0 for x in end * u), tuple(float(x) for x in u)))
    return out


_FAR_LDU = 1e5
"""Farther along a line than any part reaches (LDU): where `_line_extent` casts from."""


def _line_extent(tris: np.ndarray, points: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each line `points[i] + s u` first and last meets the triangles: (lowest s, highest
    s), inf where it meets none (`connections.first_hits`, cast from both far ends)."""
    n = len(points)
    dirs = np.concatenate([np.tile(u, (n, 1)), np.tile(-u, (n, 1))])
    hits = first_hits(tris, np.concatenate([points - _FAR_LDU * u, points + _FAR_LDU * u]), dirs)
    return hits[:n] - _FAR_LDU, _FAR_LDU - hits[n:]


def _within(s: np.ndarray, t: np.ndarray, tol: float = 1.0) -> bool:
    """Whether the stretch `s` lies on `t`'s axis line and within its stretch (to `tol` LDU)."""
    u = t[2]
    if abs(float(s[2] @ u)) < 0.98:
        return False
    d = s[:2] - t[0]
    radial = np.linalg.norm(d - np.outer(d @ u, u), axis=1)
    lo, hi = sorted([0.0, float((t[1] - t[0]) @ u)])
    along = d @ u
    return bool(np.all(radial <= tol) and along.min() >= lo - tol and along.max() <= hi + tol)


def mates(a: str, b: str) -> Freedom | None:
    """What a joint of connector kinds `a` and `b` leaves free, or None where they make none."""
    return FREEDOMS.get(frozenset({a, b}))


def summary(part) -> dict[str, int]:
    """{kind: count} of a part's joint connectors, bores left out (every round stud has one)."""
    counts: dict[str, int] = {}
    for c in joint_connectors(part):
        if c.kind != "bore":
            counts[c.kind] = counts.get(c.kind, 0) + 1
    return dict(sorted(counts.items()))


HOLE_GAP_LDU = 16.0
"""Female primitives of one kind on one axis of one part, this close, are one hole: a Technic
brick's hole is drawn with a pin-hole primitive at each mouth, 16 LDU apart. Click hinge halves
on one axis this close are one hinge too (a dual finger is drawn as two halves, 8 LDU apart, with
the other part's single finger between them)."""
HOLE_LDU = 20.0
"""A Technic hole's length: a stud's width, the thickness of a beam or brick it goes through.
Mouths of one kind on one axis that span no more than this together are one hole, however far
apart their primitives lie: the beam 64178 draws its holes with `npeghol` primitives only 1.5 LDU
deep at each face, 17 LDU apart."""
HOME_TOL_LDU = 0.01
"""The rounding of placed coordinates, allowed on lengths compared: `HOLE_LDU`, and how far short
of wholly on the other the shorter of two mated connectors may be and still be pushed home
(`unmodelled.joints_between`)."""

CLICK_STEP_DEG = 22.5
"""A click hinge holds at steps of this angle from straight. LEGO's click hinges lock at 22.5°
steps (the part names say "9-Position": 0° to 180°); LDraw's `clh4` draws the teeth and notches
that make them at 11.25° apart round the pivot, one of each per step."""
CLICK_PLAY_DEG = 4.0
"""How far from a step a click hinge's two halves may be turned and still be held: designs set
hinges a little off a step (6966's wing hinge at 25°); half way between two steps (11.25° off)
no tooth sits in a notch and the hinge turns freely."""


def click_angle(ref_a, ref_b, axis) -> float:
    """The angle (degrees, in (-180, 180]) from one click hinge half's turn `ref_a` to the other's
    `ref_b` about `axis` (all in one frame): 0 where the two halves are straight, in line (their
    primitives' Z axes agree, as LDraw draws mated halves: 44301 on 44302 at one pose)."""
    u = np.asarray(axis, float)
    a = np.asarray(ref_a, float) - (np.asarray(ref_a, float) @ u) * u
    b = np.asarray(ref_b, float) - (np.asarray(ref_b, float) @ u) * u
    return float(np.degrees(np.arctan2(np.cross(a, b) @ u, a @ b)))


def on_a_click(angle_deg: float) -> bool:
    """Whether a click hinge turned to `angle_deg` sits in a step (`CLICK_PLAY_DEG`)."""
    off = abs(angle_deg) % CLICK_STEP_DEG
    return min(off, CLICK_STEP_DEG - off) <= CLICK_PLAY_DEG


@lru_cache(maxsize=None)
def part_connectors(part) -> tuple[JointConnector, ...]:
    """`merged_holes` of the part's `joint_connectors`, computed once per part (the checks ask for
    them at every candidate that touches a part, the sampler at every draw)."""
    return tuple(merged_holes(joint_connectors(part)))


def merged_holes(conns) -> list:
    """A part's joint connectors with the female primitives of one kind (or click hinge halves)
    that lie on one axis within `HOLE_GAP_LDU` of each other, or that together span no more than
    one hole (`HOLE_LDU`), merged into one (a hole drawn at both mouths, a dual finger drawn as two
    halves)."""
    out, merged = [], set()
    for i, c in enumerate(conns):
        if i in merged:
            continue
        if c.kind in ("pin-hole", "axle-hole", "wheel-pin-hole", "hinge"):
            seg = np.array([c.start, c.end, c.axis], float)
            for j in range(i + 1, len(conns)):
                d = conns[j]
                other = np.array([d.start, d.end, d.axis], float)
                if j not in merged and d.kind == c.kind and on_one_axis(other, seg) and (
                        stretch_overlap(other, seg) >= -HOLE_GAP_LDU or
                        c.kind != "hinge" and _span(together(other, seg)) <= HOLE_LDU + HOME_TOL_LDU):
                    seg = together(other, seg)
                    merged.add(j)
            c = JointConnector(c.kind, *(tuple(float(v) for v in row) for row in seg), c.ref)
        out.append(c)
    return out


def _span(s: np.ndarray) -> float:
    return float(np.linalg.norm(s[1] - s[0]))


def stretches(conns) -> np.ndarray:
    """Joint connectors as one array (k, 3, 3): each one's ends and axis (`place_connectors`
    moves them)."""
    return np.array([[c.start, c.end, c.axis] for c in conns], float).reshape(-1, 3, 3)


@lru_cache(maxsize=None)
def part_stretches(part) -> np.ndarray:
    """`stretches` of `part_connectors`, once per part (read-only)."""
    out = stretches(part_connectors(part))
    out.setflags(write=False)
    return out


def held_by_joints_alone(part) -> bool:
    """Whether a part can only be held by joints: it has no studs and no sockets (a pin, an axle,
    a beam, a gear)."""
    return not part.studs and not part.sockets


def joint_ends(part) -> list[JointConnector]:
    """The part's joint connectors the sampler can attach through (`part_connectors`: a hole
    drawn at both mouths is one; connectors of no length left out)."""
    return [c for c in part_connectors(part) if c.length > 0]


def on_one_axis(s: np.ndarray, t: np.ndarray, angle_deg: float = 10.0, radial_ldu: float = 1.0) -> bool:
    """Whether stretch `s` (end, end, axis) lies on `t`'s axis line: within `angle_deg` of
    parallel, its middle within `radial_ldu` of the line."""
    u = t[2]
    if abs(float(s[2] @ u)) < np.cos(np.radians(angle_deg)):
        return False
    d = s[:2].mean(0) - t[0]
    return float(np.linalg.norm(d - (d @ u) * u)) <= radial_ldu


def stretch_overlap(s: np.ndarray, t: np.ndarray) -> float:
    """How far two stretches on one axis overlap (negative: the gap between)."""
    u = t[2]
    x, y = sorted((s[:2] - t[0]) @ u), sorted((t[:2] - t[0]) @ u)
    return float(min(x[1], y[1]) - max(x[0], y[0]))


def together(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The stretch of `t`'s axis that `s` and `t` cover together (end, end, axis)."""
    u = t[2]
    along = np.concatenate([(s[:2] - t[0]) @ u, (t[:2] - t[0]) @ u])
    return np.stack([t[0] + along.min() * u, t[0] + along.max() * u, u])
