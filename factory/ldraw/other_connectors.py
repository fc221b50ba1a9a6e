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
)
"""(primitive name pattern, a point on its axis, the axis), in the primitive's frame; anything
else (Technic holes, pins, axles, bushes, wheel pins and their holes) runs along Y through the
origin, as LDraw draws them."""


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
