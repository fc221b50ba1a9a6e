"""What a joint (a connection that is not a stud in a socket) carries in the load model: a force
along its axis, across it, a moment bending it and one turning it about its axis, each within a
capacity (`JointCapacity`), by the joint's kind (`JOINT_CAPACITY`, keyed by
`factory.physics.unmodelled.JOINTS`' names).

A joint that turns freely carries almost no moment about its axis (a Technic pin in a pin hole, a
wheel on its pin: `FREE_TWIST_NLDU`): a part hung on one such joint swings until its centre of mass
is under the axis, and is `unstable` unless something else holds it (`check_call.swings`); a wheel,
whose centre of mass is on its axis, stays as it is. In a structure, such a joint carries only
that little moment about its axis. A joint
that slides (an axle in an axle hole, a clip along a bar) carries along its axis only what its
friction holds. Where no axis is known (minifigure joints, a tyre pressed on a rim: parts held by
their shapes) the joint is a friction fit of stated capacity in every direction.

The capacities are estimates on the scale of the stud's clutch (`LoadConfig.clutch_n`, 1 N) and
shear (10 N), not measurements: no published measurement of Technic or clip joints was found.
docs/concepts/physics.md gives the reasons for each.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

INF = math.inf


@dataclass(frozen=True)
class JointCapacity:
    """The most a joint carries (each in both senses); `INF`: not limited, 0: carries none."""

    pull_n: float
    """Force along the axis (N): pulling it apart or pushing it further in."""
    shear_n: float
    """Force across the axis (N, per direction across)."""
    bend_nldu: float
    """Moment across the axis (N LDU, per direction across): levering the joint."""
    twist_nldu: float
    """Moment about the axis (N LDU): 0 for a joint that turns freely."""

    def as_row(self) -> tuple[float, float, float, float, float, float]:
        """The six capacities in the load program's column order of a link: force along the
        axis, across (two), moment about the axis, across (two)."""
        return (self.pull_n, self.shear_n, self.shear_n, self.twist_nldu, self.bend_nldu, self.bend_nldu)


FREE_TWIST_NLDU = 0.05
"""The moment about its axis a joint that turns freely carries (N LDU): the error of the mass
model, not a friction. A part's centre of mass is computed from its convex pieces, which put a
round wheel's up to 2 LDU off its axis (30285: 1.07 g, 2.0 LDU: 0.02 N LDU); a Technic beam 3
hung by its end hole turns its pin with 0.14 N LDU, and swings."""

TURNS_FREELY = ("technic-pin", "wheel-pin")
"""Joint kinds that turn freely about their axis (`FREE_TWIST_NLDU`): a part held by them alone,
on one axis line, swings unless its centre of mass is under (or over) that line
(`check_call.swings`: `unstable`)."""

RIGID = JointCapacity(INF, INF, INF, INF)
"""A connection held rigid (a joint the checker cannot place: `unsupported-connection`)."""

JOINT_CAPACITY: dict[str, JointCapacity] = {
    # A pin turns freely in its hole (a frictionless pin "rotates freely ... and is removed fairly
    # easily"; a friction pin's ridges hold a little, not told apart here); the hole's walls hold
    # it across its axis like a socket's walls hold a stud, over a hole's depth (20 LDU, lever 10).
    "technic-pin": JointCapacity(pull_n=1.0, shear_n=10.0, bend_nldu=100.0, twist_nldu=FREE_TWIST_NLDU),
    # An axle's cross cannot turn in an axle hole (the cross's arms, 2 LDU from its axis, bear on
    # the hole's), and slides with the friction of its fit.
    "technic-axle": JointCapacity(pull_n=0.5, shear_n=10.0, bend_nldu=100.0, twist_nldu=40.0),
    # A wheel spins on its wheel pin and is held on by the pin's lip.
    "wheel-pin": JointCapacity(pull_n=1.0, shear_n=10.0, bend_nldu=50.0, twist_nldu=FREE_TWIST_NLDU),
    # A clip grips its bar (radius 4 LDU) with about a stud's clutch: it turns and slides under
    # more than that friction, and opens under a pull across the bar of twice it.
    "clip-bar": JointCapacity(pull_n=1.0, shear_n=2.0, bend_nldu=20.0, twist_nldu=4.0),
    "bar": JointCapacity(pull_n=1.0, shear_n=2.0, bend_nldu=20.0, twist_nldu=4.0),
    # A bar or a pin in a hollow stud's bore: as tight as a clip round it, boxed in by the stud.
    "bar-in-stud": JointCapacity(pull_n=1.0, shear_n=10.0, bend_nldu=40.0, twist_nldu=4.0),
    # A click hinge holds each step by its teeth (stepped, not free).
    "click-hinge": JointCapacity(pull_n=2.0, shear_n=10.0, bend_nldu=100.0, twist_nldu=20.0),
    # Minifigure joints (neck, hips, shoulders, wrists, headgear) and parts held by their shapes
    # (a tyre pressed on a rim): friction fits, no axis known.
    "minifig": JointCapacity(pull_n=1.0, shear_n=5.0, bend_nldu=20.0, twist_nldu=4.0),
    "by-shape": JointCapacity(pull_n=1.0, shear_n=10.0, bend_nldu=50.0, twist_nldu=10.0),
}
"""Each joint kind's capacities (the module says why)."""


def capacity(kind: str) -> JointCapacity:
    """The capacities of a joint kind; 'rigid' for a connection held rigid."""
    if kind == "rigid":
        return RIGID
    try:
        return JOINT_CAPACITY[kind]
    except KeyError:
        raise ValueError(f"unknown joint kind {kind!r}; expected 'rigid' or one of {sorted(JOINT_CAPACITY)}") from None
