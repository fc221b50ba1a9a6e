"""The physics checks of a candidate placement, cheapest first, with the rule that failed.

For each candidate: (1) **connection** (numpy: does a stud meet a socket?), (2) **collision**
(MuJoCo contacts between inset convex pieces, one `mj_fwdPosition`), (3) **stability** (clutch of
the new connection, then a rollout of the structure with the candidate as one rigid body on the
ground). A candidate that fails a cheap rule never reaches the expensive ones; its later fields
are None (not evaluated).

Reasons, in the order they are reported: `unsupported-connection` (no stud connection, but the
candidate touches or overlaps a structure part that may hold it by a connection the checker does
not model: Technic pins and axles, clips, hinges, tyres on rims; `factory.physics.unmodelled`
says when), `collision`, `no-connection` (floating), `clutch` (the new connection cannot hold the
part), `unstable` (the object moves on the ground).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from factory.parts import Part
from factory.physics.collide import CollisionScene
from factory.physics.stability import (
    MassAggregate,
    StabilityConfig,
    clutch_ok,
    part_mass_properties,
    rigid_object,
    rollout_cpu,
)
from factory.physics.structure import Placed, Structure, connectors, match
from factory.physics.unmodelled import may_hold
from factory.pose import Pose

BACKENDS = ("mujoco", "mjx")


@dataclass(frozen=True)
class CheckConfig:
    """Thresholds of the checks."""

    max_penetration_ldu: float = 0.5
    """Deepest overlap accepted (LDU); the collision pieces are inset by half of it each."""
    stability: StabilityConfig = field(default_factory=StabilityConfig)


@dataclass(frozen=True)
class Verdict:
    """The checks of one candidate placement."""

    pose: Pose
    connected: bool
    connections: int
    collision: bool | None = None
    max_penetration_ldu: float | None = None
    touching: bool | None = None
    clutch: bool | None = None
    stable: bool | None = None
    movement_ldu: float | None = None
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.reason is None


def _unit_connections(structure: Structure, unit: Sequence[tuple[Part, Pose]]) -> list[tuple[int, str, np.ndarray]]:
    out = []
    sp, sa, so = structure.studs
    kp, ka, ko = structure.sockets
    for part, pose in unit:
        cp, ca = connectors(part, pose, "sockets")
        for i, _ in match(sp, sa, cp, ca):
            out.append((int(so[i]), "stud", sp[i]))
        cp, ca = connectors(part, pose, "studs")
        for _, j in match(cp, ca, kp, ka):
            out.append((int(ko[j]), "socket", kp[j]))
    return out


def check_units(
    structure: Structure,
    units: Sequence[Sequence[Placed]],
    backend: str = "mujoco",
    config: CheckConfig = CheckConfig(),
    require_connection: bool = True,
    floor_y: float | None = None,
    standing: bool = True,
) -> list[Verdict]:
    """Check rigid units (each a list of placed parts, in world poses) against the structure.

    All units must share their parts and relative layout up to one rigid motion when many are
    given (the sampler's case: one part type at many poses); each unit's pose is that of its
    first part. With `floor_y` (LDraw height) the ground is fixed there and nothing may go below
    it (the sampler's case). Without it the object rests on its own lowest point with the unit
    added (a human build: a car body waits for its wheels, held above the table). With
    `standing=False` the structure is held in hand (a sub-assembly being built): only the clutch of
    the new connection is judged, not whether the whole stands.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if not units:
        return []
    first = units[0]
    anchor = first[0].pose
    rel = [(p.part, anchor.inverse() @ p.pose) for p in first]
    scene = _collision_scene(structure, rel, floor_y if floor_y is not None else 1e6)
    verdicts: list[Verdict | None] = [None] * len(units)
    pending: list[tuple[int, list[Placed]]] = []
    for k, unit in enumerate(units):
        pose = unit[0].pose
        world = [(p.part, p.pose) for p in unit]
        conns = _unit_connections(structure, world)
        connected = bool(conns) or (not require_connection) or len(structure) == 0
        touched = {c[0] for c in conns}
        depth, near = scene.penetration(pose, touched)
        collision = depth > config.max_penetration_ldu
        base = dict(pose=pose, connected=bool(conns), connections=len(conns), collision=collision,
                    max_penetration_ldu=round(depth, 4), touching=bool(near))
        if not conns and near and any(
            may_hold(p.part, p.pose, structure.placed[i].part, structure.placed[i].pose)
            for p in unit for i in near
        ):
            # Held by a connection we do not model (Technic, clip, hinge, tyre): not judged here.
            verdicts[k] = Verdict(**base, reason="unsupported-connection")
            continue
        if collision:
            verdicts[k] = Verdict(**base, reason="collision")
            continue
        if not connected:
            verdicts[k] = Verdict(**base, reason="no-connection")
            continue
        if conns and not _clutch(unit, conns, config.stability):
            verdicts[k] = Verdict(**base, clutch=False, reason="clutch")
            continue
        if standing and (conns or len(structure) == 0):
            verdicts[k] = Verdict(**base, clutch=True if conns else None)
            pending.append((k, unit))
        else:
            # Held in hand (a sub-assembly), or laid on the table beside the structure with no
            # connection yet: nothing joins it to the structure to fall with.
            verdicts[k] = Verdict(**base, clutch=True if conns else None, stable=True)
    if pending:
        objs = []
        base = MassAggregate.of(structure.placed)
        for _, unit in pending:
            ground = floor_y if floor_y is not None else Structure(structure.placed + list(unit)).floor_y()
            objs.append(rigid_object(base + MassAggregate.of(list(unit)), ground, config.stability))
        if backend == "mjx":
            from factory.physics.mjx_backend import rollout_mjx

            moves = rollout_mjx(objs, config.stability)
        else:
            moves = rollout_cpu(objs, config.stability)
        for (k, _), move in zip(pending, moves):
            v = verdicts[k]
            stable = bool(move <= config.stability.max_move_ldu)
            verdicts[k] = Verdict(**{**v.__dict__, "stable": stable, "movement_ldu": round(float(move), 4),
                                     "reason": None if stable else "unstable"})
    return verdicts  # type: ignore[return-value]


_LAST_SCENE: list = []
"""The last collision scene with what it was built from (the placed parts themselves, so their ids
cannot be reused while it is kept). The sampler checks one part against one structure in several
calls per step (batches, redraws of the same part); building the scene is most of a call's time."""


def _collision_scene(structure: Structure, rel, floor: float) -> CollisionScene:
    key = (tuple(id(p) for p in structure.placed),
           tuple((id(part), pose.R.tobytes(), pose.t.tobytes()) for part, pose in rel), float(floor))
    if _LAST_SCENE and _LAST_SCENE[0] == key:
        return _LAST_SCENE[2]
    scene = CollisionScene(structure, rel, floor)
    _LAST_SCENE[:] = [key, (list(structure.placed), [part for part, _ in rel]), scene]
    return scene


def _clutch(unit: Sequence[Placed], conns, cfg: StabilityConfig) -> bool:
    mass, weighted = 0.0, np.zeros(3)
    for p in unit:
        m, com, _ = part_mass_properties(p.part)
        mass += m
        weighted += m * p.pose.apply(com)
    points = np.array([c[2] for c in conns])
    hanging = all(c[1] == "socket" for c in conns)
    return clutch_ok(mass, weighted / mass, points, hanging, cfg)


def check(
    structure: Structure,
    part: Part,
    poses: Sequence[Pose],
    backend: str = "mujoco",
    config: CheckConfig = CheckConfig(),
    colour: int = 16,
    floor_y: float | None = None,
) -> list[Verdict]:
    """Check one part type at many candidate poses against the structure (a batch); see
    `check_units` for the ground (`floor_y`)."""
    return check_units(structure, [[Placed(part, colour, p)] for p in poses], backend, config,
                       floor_y=floor_y)
