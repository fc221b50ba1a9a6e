"""Non-stud connector primitives (Technic holes, pins and axles, clips, click hinges, wheel pins):
which primitives they are, and the stretch of axis each one occupies in its own frame.

The checker does not model these connections, but with where each connector's axis runs it can
tell whether two parts' connectors meet (see `factory.physics.unmodelled`).
"""

from __future__ import annotations

import re

import numpy as np

_OTHER_CONNECTOR = re.compile(
    r"^(?:.*/)?(axl\d?ho\w*|axle\w*|beamhole|bush\d?|clh\d\w*|clip\d\w*|confric\d*|connect\d*|connhole|"
    r"npeghol\w*|peghole|wpin\w*|wpinhol\w*|phandle\d*)\.dat$"
)
"""Primitives of connections the checker does not model: Technic axles and pin holes, clips,
bushes, wheel pins, handles."""

_X = (1.0, 0.0, 0.0)
_Y = (0.0, 1.0, 0.0)
_Z = (0.0, 0.0, 1.0)

_AXES = (
    # Click hinges turn about their local X. The pivot is the centre of the rounded finger: for
    # clh4 (dual finger) its half discs are centred at z = 4; for clh6 (single finger, plate
    # ends) it was measured from three mated hinges of 4915 (44301/44567 on 44302, within 0.5 LDU
    # of clh4's pivot at local z = -10).
    (re.compile(r"clh4"), (0.0, 0.0, 4.0), _X),
    (re.compile(r"clh6"), (0.0, 0.0, -10.0), _X),
    # Other click hinges (not in the subset this was measured on): X through the origin.
    (re.compile(r"clh"), (0.0, 0.0, 0.0), _X),
    # Clips and bar handles hold a bar along X, its centre 2 LDU below the origin (clip3's and
    # phandle1's cylinders).
    (re.compile(r"clip|phandle"), (0.0, 2.0, 0.0), _X),
    # Bushes run along their Z: bush0 places its axle hole (axlehol5) turned from Y onto Z, from
    # z = -10 to 10, and bush1/bush2 draw their collars in planes z = const (the bush 3713 and
    # the stop bush of the long pin 32054 are drawn so: flanges and pin along the bush's Z).
    (re.compile(r"bush"), (0.0, 0.0, 0.0), _Z),
)
"""(primitive name pattern, a point on its axis, the axis), in the primitive's frame; anything
else (Technic holes, pins, axles, wheel pins and their holes) runs along Y through the origin,
as LDraw draws them (each checked against the primitives of LDraw's library: the stretch of
their geometry along that axis, their cross-section round it)."""


def place_connectors(conns: np.ndarray, rotation: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Connectors (j, 3, 3: end, end, axis) moved by a rotation (or an LDraw type 1 matrix, which
    may scale: the axis is made unit again) and an offset."""
    out = conns @ np.asarray(rotation).T
    out[:, :2] += offset
    if len(out):
        out[:, 2] /= np.maximum(np.linalg.norm(out[:, 2], axis=1, keepdims=True), 1e-12)
    return out


def is_other_connector(name: str) -> bool:
    return _OTHER_CONNECTOR.match(name) is not None


CONNECTOR_KINDS = ("pin-hole", "axle-hole", "pin", "axle", "bush", "clip", "hinge", "wheel-pin", "wheel-pin-hole",
                   "handle")
"""What each connector primitive is (`connector_kind`), by LDraw's primitive names: pin holes
(`peghole`, `npeghol*`, `connhole`, `beamhole`), axle holes (`axlho*`, `axl2ho*`, `axlehol*`),
pins (`connect*`, `confric*`), axles (`axle*`, `axl*` without a hole), bushes (`bush*`), clips
(`clip*`), click hinges (`clh*`), wheel pins (`wpin*`) and their holes (`wpinhol*`), bar handles
(`phandle*`)."""

_KIND_PATTERNS = (
    (re.compile(r"^(?:.*/)?(?:wpinhol\w*)\.dat$"), "wheel-pin-hole"),
    (re.compile(r"^(?:.*/)?(?:wpin\w*)\.dat$"), "wheel-pin"),
    (re.compile(r"^(?:.*/)?(?:axl\d?ho\w*|axlehol\w*|axlho\w*)\.dat$"), "axle-hole"),
    (re.compile(r"^(?:.*/)?(?:axle\w*|axl\d?\w*)\.dat$"), "axle"),
    (re.compile(r"^(?:.*/)?(?:peghole|npeghol\w*|connhole|beamhole)\.dat$"), "pin-hole"),
    (re.compile(r"^(?:.*/)?(?:connect\d*|confric\d*)\.dat$"), "pin"),
    (re.compile(r"^(?:.*/)?bush\d?\w*\.dat$"), "bush"),
    (re.compile(r"^(?:.*/)?clip\d\w*\.dat$"), "clip"),
    (re.compile(r"^(?:.*/)?clh\d\w*\.dat$"), "hinge"),
    (re.compile(r"^(?:.*/)?phandle\d*\.dat$"), "handle"),
)


def connector_kind(name: str) -> int:
    """The index in `CONNECTOR_KINDS` of a connector primitive (`is_other_connector`)."""
    for pattern, kind in _KIND_PATTERNS:
        if pattern.match(name):
            return CONNECTOR_KINDS.index(kind)
    raise ValueError(f"{name!r} is not a connector primitive")


def axis_segment(name: str, triangles: np.ndarray) -> np.ndarray:
    """(3, 3) in the primitive's own frame: the two ends of the stretch of the connector's axis
    that its geometry spans (its triangles projected on the axis), then the axis itself (kept
    apart, since a flat primitive such as an axle hole's rim spans no length of it)."""
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    point, axis = np.zeros(3), np.array(_Y)
    for pattern, p, a in _AXES:
        if pattern.match(base):
            point, axis = np.array(p), np.array(a)
            break
    along = (triangles.reshape(-1, 3) - point) @ axis if len(triangles) else np.zeros(1)
    return np.stack([point + along.min() * axis, point + along.max() * axis, axis])


BAR_RADIUS = 4.0
"""LDU. LEGO's bar (3.2 mm across): a bar or a handle, the grip of a clip, the rounded end of a
hinge finger and the solid pin under a 1xN plate or brick are all cylinders of this radius, and a
hollow stud's bore is one too (`Flat.bores`). Two of them on one axis are a clip, bar or hinge
joint (`factory.physics.unmodelled.bars_meet`)."""
BAR_RADIUS_TOL = 0.25
"""How far a cylinder's radius may be from `BAR_RADIUS` (LDraw files draw it as 4 exactly)."""

_CYLINDER = re.compile(r"^(?:.*/)?\d+-\d+cyl[a-z]*\d?\.dat$")
"""LDraw's cylinder primitives (`4-4cyli`, `2-4cylc`, `5-8cylo`, `1-8cyls`, in any resolution
folder): a unit circle in X-Z swept along Y from 0 to 1."""


def bar_cylinder(name: str, matrix: np.ndarray, pos: np.ndarray) -> np.ndarray | None:
    """(3, 3) like a connector (end, end, unit axis) for a cylinder primitive placed with a round
    cross-section of the bar's radius, square to its axis; None for anything else (an ellipse, a
    sheared or any other radius: a stud's 6, a tube's 8). `name` as `parse.normalize_name` writes it."""
    if not _CYLINDER.match(name):
        return None
    m = np.asarray(matrix, float)
    a, h, b = m[:, 0], m[:, 1], m[:, 2]
    ra, rb, length = float(np.linalg.norm(a)), float(np.linalg.norm(b)), float(np.linalg.norm(h))
    if length < 1e-6 or abs(ra - BAR_RADIUS) > BAR_RADIUS_TOL or abs(rb - BAR_RADIUS) > BAR_RADIUS_TOL:
        return None
    if max(abs(a @ b) / (ra * rb), abs(a @ h) / (ra * length), abs(b @ h) / (rb * length)) > 1e-3:
        return None
    p = np.asarray(pos, float)
    return np.stack([p, p + h, h / length])


def facing_out(triangles: np.ndarray, segment: np.ndarray) -> float:
    """+1 where the triangles of a cylinder face away from its axis (a solid bar, pin or finger),
    -1 where they face it (a clip's grip, a hole), 0 where that cannot be told. The triangles must
    be wound as the part draws them (counter-clockwise seen from outside)."""
    if not len(triangles):
        return 0.0
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    d = triangles.mean(axis=1) - segment[0]
    radial = d - (d @ segment[2])[:, None] * segment[2]
    lengths = np.linalg.norm(radial, axis=1)
    ok = lengths > 1e-6
    out = np.einsum("ij,ij->i", n[ok], radial[ok] / lengths[ok, None])  # caps add nothing
    s, total = float(out.sum()), float(np.abs(out).sum())
    if total < 1e-9 or abs(s) < 0.5 * total:
        return 0.0
    return 1.0 if s > 0 else -1.0
