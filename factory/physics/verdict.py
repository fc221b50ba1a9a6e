"""What the physics checks take and give: their thresholds (`CheckConfig`) and one candidate's
`Verdict` (which checks ran, what they found, and the rule that failed, `check.py` lists them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from factory.physics.load_model import Link, LoadConfig
from factory.physics.statics import Failure
from factory.pose import Pose


@dataclass(frozen=True)
class CheckConfig:
    """Thresholds of the checks."""

    max_penetration_ldu: float = 0.5
    """Deepest overlap accepted (LDU); the collision pieces are inset by half of it each."""
    loads: LoadConfig = field(default_factory=LoadConfig)
    """The whole-structure load model's constants (clutch per stud, shear, ground friction)."""
    threaded: bool = False
    """Whether a part on an axle or pins that is blocked both ways along them is accepted as
    threaded on (`approach` 'threaded') where only parts its axle goes through block it, or where
    it goes on by its own holes and reaches its place from the side with those pins and axles left
    out: a builder pulls the axle back, threads the bush or gear on (or holds the part in place)
    and pushes the axle or pin in again. Replays of people's designs
    (`factory.replay.REPLAY_CONFIG`) turn it on; the sampler leaves it off, so that every
    synthetic step goes straight in."""


@dataclass(frozen=True)
class Verdict:
    """The checks of one candidate placement; a field is None where its check did not run."""

    pose: Pose
    connected: bool
    connections: int
    collision: bool | None = None
    max_penetration_ldu: float | None = None
    touching: bool | None = None
    clutch: bool | None = None
    """Whether the candidate's own connections hold it with the rest of the structure fixed."""
    stable: bool | None = None
    """Whether the whole structure stands with it: nothing tips, no connection overloaded."""
    buildable: bool | None = None
    """Whether it reaches its pose along its connection axis from clear space (`sweep.py`); None
    where that is not judged: connections on two axes (`approach` says so) or no stud connection."""
    approach: str | None = None
    """Why buildability was not judged, or 'clamped'/'blocked' when it failed."""
    blocked_by: tuple[int, ...] = ()
    """Structure parts in the way of the approach."""
    load: float | None = None
    """The largest share of any connection's capacity used in the whole structure (<= 1 stands)."""
    failing: tuple[Failure, ...] = ()
    """The connections at that load, when it is over capacity."""
    joints: tuple[Link, ...] = ()
    """The joints that hold it (not studs), as the load model's links (`Link.kind`: a name of
    `unmodelled.JOINTS`; `a`: the part of the candidate's unit it holds, 0 for a one-part
    candidate; `b`: the structure part holding it); the load check carries them (`joint_capacity`)."""
    held_by: tuple[int, ...] = ()
    """For 'unsupported-connection': the structure parts that may hold it by a connection the
    checker does not model (they become rigid links once it is placed)."""
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.reason is None

    def links(self, index: int, part: int = 0) -> list[Link]:
        """The links to the parts before it of the unit's part `part`, placed as structure part
        `index`: the joints that hold it (`joints`) and, for the unit's first part, rigid links to
        the parts that may hold it by a connection the checker cannot place (`held_by`), so that
        the whole-structure loads of later candidates carry it through them (studs are found
        from the parts themselves; joints are not). A holder not placed yet is not linked."""
        rigid = [Link(index, j, tuple(float(v) for v in self.pose.t)) for j in self.held_by if j < index] \
            if part == 0 else []
        return rigid + [Link(index, l.b, l.point, l.kind, l.axis) for l in self.joints if l.a == part and l.b < index]
