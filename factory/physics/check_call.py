"""One call of the checks walked through its rules (`_Call`): each candidate's connections, then
collision, the cheap rules after it (unsupported, no connection, clutch), the sweep, and the queue
for the loads (`check_loads`); the seconds spent per stage, and the last collision scene and load
base kept for the calls after, both in the checker's state (`check_state.current()`:
`stage_seconds`, `scenes`, `load_bases`).

`check.py` runs calls: the reference's (backend 'cpu') go through every rule as they are made; the
batched backend's ('jax') give each stage of many calls to the device together.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable, Sequence

import numpy as np

from factory.gears import meshes
from factory.joints import on_one_axis, part_connectors, part_stretches
from factory.ldraw.other_connectors import place_connectors
from factory.parts import Part
from factory.physics.clutch import holds_alone_many
from factory.physics.collide import CollisionScene, Penetration
from factory.physics.check_state import current
from factory.physics.load_model import Link, LoadBase, LoadConfig, support_points
from factory.physics.joint_capacity import FREE_TWIST_NLDU, TURNS_FREELY
from factory.physics.mass import GRAVITY, part_mass_properties
from factory.physics.solid_overlap import REFINE_LDU, deepest_solid
from factory.physics.statics import Failure
from factory.physics.structure import Placed, Structure, connections_at, lowest_point
from factory.physics.sweep import SAME_AXIS, held_in_place, seating_from_connections, sweep, sweep_joint
from factory.physics.unmodelled import NEAR_LDU, Joint, joints_between, may_hold, zone_moved
from factory.physics.verdict import CheckConfig, Verdict
from factory.pose import Pose

STAGES = ("rules", "collide", "clutch", "sweep", "loads")
"""The stages whose seconds a checker counts (`CheckState.stage_seconds`) in `check_units`/`check_many`:
'rules' (connection, clutch, and for the reference collision and the CPU sweep), 'collide' (the
batched collision rule, `collide_jax`), 'clutch' (for 'jax': the clutch rule of every call at
once), 'sweep' (the batched sweeps), 'loads'."""


def _unit_connections(structure: Structure, unit: Sequence[tuple[Part, Pose]]) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """Stud connections of a unit with the structure and among its own parts, as
    (stud part, socket part, stud base, stud axis); the unit's parts are numbered after the
    structure's."""
    out = []
    base = len(structure)
    for j, (part, pose) in enumerate(unit):
        out += connections_at(structure, part, pose.R[None], pose.t[None], base + j)[0]
    if len(unit) > 1:
        inner = Structure([Placed(part, 16, pose) for part, pose in unit])
        out += [(base + a, base + b, p, n) for a, b, p, n in inner.connections]
    return out


class _Call:
    """One `check_units` call: each candidate's connections at construction, then collision (the
    scene's contacts for the reference; for 'jax' `collide_group`/`collided`, where many calls share
    the device), the cheap rules after it (and the CPU sweep for the reference), then its sweeps
    (`sweep_group`, `swept`) and loads (`check_loads._judge_loads`)."""

    def __init__(self, structure: Structure, units: Sequence[Sequence[Placed]], backend: str, config: CheckConfig,
                 require_connection: bool = True, floor_y: float | None = None, standing: bool = True,
                 unit_links: Sequence[Link] = (), explain: bool = True, judge_first: int | None = None,
                 order: Callable[[list[int]], list[int]] | None = None, sweep: bool = True):
        t0 = time.perf_counter()
        if judge_first is not None and judge_first < 1:
            raise ValueError(f"judge_first must be None or >= 1, got {judge_first}")
        self.judge_first, self.order = judge_first, order
        self.structure, self.config, self.floor_y, self.backend = structure, config, floor_y, backend
        self.standing, self.unit_links, self.explain = standing, unit_links, explain
        self.require_connection, self.sweep = require_connection, sweep
        first = units[0]
        anchor = first[0].pose
        self.rel = [(p.part, anchor.inverse() @ p.pose) for p in first]
        self._scene: CollisionScene | None = None
        self.base_n = base_n = len(structure)
        self.verdicts: list[Verdict | None] = [None] * len(units)
        self.pending: list[tuple[int, list[Placed], list]] = []
        self.to_sweep: list[tuple] = []
        self.to_collide: list[tuple] = []
        self.to_clutch: list[tuple] = []
        self.joint_links: dict[int, list[Link]] = {}
        """Each candidate's joints as the load model's links (`joint_links`), by its position."""
        self.joint_zones: dict[int, dict] = {}
        """... and where their overlap lies (`_zones`)."""
        if len(first) == 1:  # one part at many poses: every candidate's connections in one query
            each = connections_at(structure, first[0].part, np.array([u[0].pose.R for u in units]),
                                  np.array([u[0].pose.t for u in units]))
        for k, unit in enumerate(units):
            world = [(p.part, p.pose) for p in unit]
            conns = each[k] if len(first) == 1 else _unit_connections(structure, world)
            outer = [c for c in conns if min(c[0], c[1]) < base_n]
            self.to_collide.append((k, unit, world, conns, outer, {min(c[0], c[1]) for c in outer}))
        current().stage_seconds["rules"] += time.perf_counter() - t0
        if backend != "jax":
            # The reference: MuJoCo's contacts, one candidate pose at a time.
            t0 = time.perf_counter()
            found = []
            for _, unit, *_, touched in self.to_collide:
                depth, near = self.scene.penetration(unit[0].pose, touched)
                found.append(Penetration(depth, frozenset(near)))
            current().stage_seconds["rules"] += time.perf_counter() - t0
            self.collided(found)

    @property
    def scene(self) -> CollisionScene:
        """The MuJoCo collision scene (the reference's; for 'jax' built only if a sweep is referred
        to the CPU)."""
        if self._scene is None:
            self._scene = _collision_scene(self.structure, self.rel, self.floor_y if self.floor_y is not None else 1e6)
        return self._scene

    def _depth_round_joints(self, pen: Penetration, pose: Pose, touched: set[int], zones: dict) -> float:
        """The candidate's depth with its overlap round its joints left out (`zones`, as
        `CollisionScene.penetration`'s `joints`). From a device result, each part holding it by
        joints is asked of a MuJoCo scene of that part alone, in its own frame (where the contacts
        lie decides what is the joints'; the scene serves that part and unit in any structure), and
        every other part of the device's pairs: the whole structure's scene, built again for each
        structure, cost the batched checks more than their launches on real parts."""
        if pen.apart is None:
            return self.scene.penetration(pose, touched, zones)[0]
        own = max((self._holder_depth(i, zone, pose, touched) for i, zone in zones.items()), default=0.0)
        return max(own, pen.apart(set(zones)))

    def _holder_depth(self, i: int, zone, pose: Pose, touched: set[int]) -> float:
        """The candidate's depth with structure part `i` alone, its overlap round the joint `zone`
        left out, asked of that part's own scene (`_holder_scene`, in its frame)."""
        held = self.structure.placed[i]
        back = held.pose.inverse()
        return _holder_scene(held.part, self.rel).penetration(
            back @ pose, {0} if i in touched else set(), {0: zone_moved(zone, back)})[0]

    def _cleared(self, pen: Penetration, unit: Sequence[Placed], pose: Pose, touched: set[int],
                 mated: list, zones: dict | None = None) -> float | None:
        """The candidate's overlap in the parts themselves where that is within the tolerance, else
        None (`solid_overlap.deepest_solid`: the pieces' depth with each structure part it meets,
        less what the pieces reach past the solids; studs in sockets, at `mated`, left out; with
        its pieces' overlap with the ground). `zones`: the overlap round joints left out, as
        `_depth_round_joints` takes them."""
        zones = zones or {}
        near = sorted(set(pen.near) | set(zones))
        if pen.apart is not None:
            ground = pen.apart(set(near))
        else:
            ground = self.scene.penetration(pose, touched, {i: None for i in near})[0]
        tol = self.config.max_penetration_ldu
        if ground > tol:
            return None
        # The pieces' depth with each part alone (the others it meets left out).
        if pen.apart is None:
            depths = self.scene.depths_alone(pose, touched, near, zones)
        else:
            depths = [self._holder_depth(i, zones[i], pose, touched) if i in zones else pen.apart(set(near) - {i})
                      for i in near]
        solid = deepest_solid([(p.part, p.pose) for p in unit],
                              [(self.structure.placed[i].part, self.structure.placed[i].pose) for i in near],
                              depths, tol, mated)
        return None if solid is None or solid > tol else max(ground, solid)

    def collide_group(self):
        """This call's candidates for `collide_jax.penetrations`."""
        return (self.structure, self.rel, [unit[0].pose for _, unit, *_ in self.to_collide],
                [touched for *_, touched in self.to_collide], self.floor_y, self.config.max_penetration_ldu)

    def collided(self, found: Sequence[Penetration]) -> None:
        """The rules after collision, given each candidate's `Penetration`: verdicts for those
        that collide or connect to nothing; the rest queued for the clutch rule (`clutch_cases`,
        `clutched`: for 'jax' the programs of every call go to the device together)."""
        t0 = time.perf_counter()
        structure, config, base_n = self.structure, self.config, self.base_n
        self.to_clutch = []
        for (k, unit, world, conns, outer, touched), pen in zip(self.to_collide, found):
            depth, near = pen.depth, pen.near
            pose = unit[0].pose
            connected = bool(outer) or (not self.require_connection) or base_n == 0
            collision = depth > config.max_penetration_ldu
            base = dict(pose=pose, connected=bool(outer), connections=len(outer), collision=collision,
                        max_penetration_ldu=round(depth, 4), touching=bool(near))
            # Joints matter only to a candidate that collides or has no stud connection.
            joints = self._joints(unit, near) if collision or not outer else {}
            # Gears that mesh with it: their teeth's overlap is the mesh's (`gears.meshes`), where
            # it stands and on its way in along its joints' axis.
            geared = self._meshing(unit, near) if collision or joints else set()
            # Overlap round a joint's axis (a pin in its hole, a bar in a clip, fingers between
            # fingers), or anywhere with a part held by its shape or a gear it meshes with, is the
            # joint's or the mesh's.
            zones = {**_zones(joints), **dict.fromkeys(geared)}
            mated = [c[2] for c in conns]
            if zones and collision:
                depth = self._depth_round_joints(pen, pose, touched, zones)
                if config.max_penetration_ldu < depth <= REFINE_LDU:
                    # Shallow beyond the joints (a liftarm on the pins of a motor's curved housing):
                    # measured again in the parts themselves, the holding parts among them.
                    cleared = self._cleared(pen, unit, pose, touched, mated, zones)
                    depth = depth if cleared is None else cleared
                if depth > config.max_penetration_ldu:
                    joints, geared = {}, set()  # it overlaps beyond them too: judged on that overlap
                else:
                    collision = False
                    base.update(collision=False, max_penetration_ldu=round(depth, 4))
            if collision and not joints and pen.depth <= REFINE_LDU:
                # Shallow, and no joint explains it: maybe only a piece reaching past a curved face.
                # Measured again in the parts themselves (`solid_overlap`), which may clear it.
                cleared = self._cleared(pen, unit, pose, touched, mated)
                if cleared is not None:
                    collision = False
                    base.update(collision=False, max_penetration_ldu=round(cleared, 4))
            if not outer and near and not joints:
                holders = tuple(sorted(i for i in near if any(
                    may_hold(p.part, p.pose, structure.placed[i].part, structure.placed[i].pose) for p in unit)))
                if holders:
                    # May be held by a connection whose place the checker cannot find (connector
                    # primitives that do not mate in line): not judged, held rigid once placed.
                    self.verdicts[k] = Verdict(**base, held_by=holders, reason="unsupported-connection")
                    continue
            if collision:
                self.verdicts[k] = Verdict(**base, reason="collision")
                continue
            if joints:
                self.joint_links[k] = joint_links(joints, base_n)
                self.joint_zones[k] = zones
                base.update(connected=True, joints=tuple(joint_links(joints, 0)))
                swing = swings(unit, joints) if not outer else None
                if swing is not None:
                    # It turns on its free joints: the failing joint named, as for an overload.
                    (holder, (_, joint)) = next((i, js[0]) for i, js in joints.items())
                    self.verdicts[k] = Verdict(**base, stable=False, reason="unstable", failing=(
                        Failure(base_n, holder, joint.point, round(swing / FREE_TWIST_NLDU, 4), joint.kind),))
                    continue
            elif not connected:
                self.verdicts[k] = Verdict(**base, reason="no-connection")
                continue
            self.to_clutch.append((k, base, unit, world, conns, outer, touched))
        self.to_collide = []
        current().stage_seconds["rules"] += time.perf_counter() - t0
        if self.backend != "jax":
            self.clutched(holds_alone_many(self.clutch_cases(), config.loads))

    def _threaded(self, k: int, blockers: Sequence[int], world) -> bool:
        """Whether candidate `k`, held on pins or an axle and blocked both ways along them, is
        put in place before they go through it. Either the parts blocking it are all ones its
        axle goes through (a builder threads a bush or a gear onto the axle as the axle goes in,
        between the beams it passes: the Gearbox's bushes between its Technic bricks), or it goes
        on them by its own holes and reaches its place from the side with those pins and axles
        left out (`sweep.held_in_place`: a knob wheel held in mesh with another while its axle is
        pushed through it and the beam behind). Either way the axle's or pin's own way in, judged
        when it was placed, is the candidate's too."""
        links = [l for l in self.joint_links[k] if l.kind in AXIAL and l.axis is not None]
        if not links or not blockers:
            return False
        axles = [l for l in links if l.kind == "technic-axle"]
        held = {l.b for l in axles}
        through = set()
        for l in self.structure.links:
            if l.kind not in AXIAL or l.axis is None or not ({l.a, l.b} & held):
                continue
            for x in axles:
                u = np.asarray(x.axis, float)
                d = np.asarray(l.point, float) - np.asarray(x.point, float)
                parallel = abs(float(np.asarray(l.axis, float) @ u)) > SAME_AXIS
                if parallel and np.linalg.norm(d - (d @ u) * u) < AXLE_LINE_LDU:
                    through |= {l.a, l.b} - held
        if axles and set(blockers) <= through:
            return True
        if not all(_on_its_hole(world[l.a - self.base_n], l) for l in links):
            return False  # a pin or an axle of its own goes in along the axis, whatever holds it
        return held_in_place(self.scene, self.structure, world, {l.b for l in links}, links[0].axis,
                             self.config.max_penetration_ldu)

    def _meshing(self, unit: Sequence[Placed], near) -> set[int]:
        """The structure parts among `near` that are gears meshing with a gear of the unit."""
        placed = self.structure.placed
        return {i for i in near if any(meshes(p.part, p.pose, placed[i].part, placed[i].pose) for p in unit)}

    def _joints(self, unit: Sequence[Placed], near) -> dict[int, list[tuple[int, Joint]]]:
        """The structure parts among `near` that hold a part of the unit by a joint, with the
        joints (`unmodelled.joints_between`, world frame), each with the unit's part it holds."""
        placed = self.structure.placed
        out = {}
        for i in sorted(near):
            found = [(u, j) for u, p in enumerate(unit) for j in joints_between(p.part, p.pose, placed[i].part, placed[i].pose)]
            if found:
                out[i] = found
        return out

    def clutch_cases(self) -> list[tuple]:
        """`clutch.holds_alone_many`'s cases for the connected candidates (mass, centre, the
        connections with the structure, ground support points)."""
        t0 = time.perf_counter()
        cfg, base_n = self.config.loads, self.base_n
        floor = None
        cases = []
        for k, base, unit, world, conns, outer, touched in self.to_clutch:
            if not outer or k in self.joint_links:
                continue  # held by a joint too: the whole structure's loads judge it with its joints
            ground_y = None
            if self.standing:
                if self.floor_y is not None:
                    ground_y = self.floor_y
                else:
                    floor = self.structure.floor_y() if floor is None else floor
                    ground_y = max(floor, lowest_point(unit))
            cases.append(_alone_case(unit, outer, base_n, ground_y, cfg))
        current().stage_seconds["rules"] += time.perf_counter() - t0
        return cases

    def clutched(self, holds: Sequence[bool]) -> None:
        """The verdicts after the clutch rule (`holds`: one per candidate with a connection, in
        `clutch_cases`' order), then the CPU sweep for the reference or the queue for the batched
        sweeps."""
        t0 = time.perf_counter()
        structure, config = self.structure, self.config
        held = iter(holds)
        judged = 0
        for k, base, unit, world, conns, outer, touched in self.to_clutch:
            if outer and k not in self.joint_links and not next(held):
                self.verdicts[k] = Verdict(**base, clutch=False, reason="clutch")
                continue
            if self.judge_first is not None and judged >= self.judge_first:
                continue  # not judged: its verdict stays None (`check.CheckRequest.judge_first`)
            judged += 1
            dirs = seating_from_connections(outer, self.base_n)
            if not self.sweep:
                # Put in place before what holds it: its holder's sweep finds the way in.
                if outer or k in self.joint_links:
                    base.update(approach="held")
                self._after_sweep(k, base, None, unit, conns, outer)
                continue
            if k in self.joint_links:
                # Held by joints: swept in along their axis (`sweep.sweep_joint`) when held by
                # pins, axles or wheel pins alone, which go in along it. A clip or a hinge snaps
                # on across its bar, a minifigure joint or a part held by its shape has no axis,
                # and a part on studs too goes on along two ways: not swept yet.
                zones = self.joint_zones[k]
                if outer or any(l.kind not in AXIAL for l in self.joint_links[k]):
                    base.update(approach="joint")
                    self._after_sweep(k, base, None, unit, conns, outer)
                else:
                    built = sweep_joint(self.scene, structure, world, zones, config.max_penetration_ldu)
                    if built.buildable is False and config.threaded and self._threaded(k, built.blocked_by, world):
                        built = replace(built, buildable=True, reason="threaded")
                    self._after_sweep(k, base, built, unit, conns, outer)
                continue
            if outer and self.backend == "jax":
                # Swept later, with every call's candidates at once on the device (`sweep_jax`).
                self.to_sweep.append((k, base, unit, conns, world, touched, dirs))
                continue
            built = sweep(self.scene, structure, world, touched, config.max_penetration_ldu, directions=dirs) if outer else None
            self._after_sweep(k, base, built, unit, conns, outer)
        self.to_clutch = []
        current().stage_seconds["rules"] += time.perf_counter() - t0

    def sweep_group(self):
        """This call's sweeps for `sweep_jax.sweep_groups`, None if it has none."""
        if not self.to_sweep:
            return None
        return (lambda: self.scene, self.structure, [x[4] for x in self.to_sweep], [x[5] for x in self.to_sweep],
                self.config.max_penetration_ldu, [x[6] for x in self.to_sweep])

    def swept(self, built_all) -> None:
        for (k, base, unit, conns, *_), built in zip(self.to_sweep, built_all):
            self._after_sweep(k, base, built, unit, conns, True)
        self.to_sweep = []

    def _after_sweep(self, k, base, built, unit, conns, outer) -> None:
        """The verdict after buildability (`built`: None where not swept), or the candidate queued
        for the load check."""
        if built is not None:
            base.update(buildable=built.buildable, approach=built.reason, blocked_by=built.blocked_by)
            if built.buildable is False:
                self.verdicts[k] = Verdict(**base, clutch=True if outer else None, reason=built.reason)
                return
        if self.standing and (outer or k in self.joint_links or self.base_n == 0):
            self.verdicts[k] = Verdict(**base, clutch=True if outer else None)
            self.pending.append((k, list(unit), conns))
        else:
            # Held in hand (a sub-assembly), or laid on the table beside the structure with no
            # connection yet: nothing joins it to the structure to fall with.
            self.verdicts[k] = Verdict(**base, clutch=True if outer else None, stable=True)

    def loaded(self, results) -> None:
        """The verdicts after the loads (`results`: one per pending candidate, in order); pending
        candidates past the end of `results` are left unjudged (None: `check_loads._until_standing`)."""
        for (k, *_), lv in zip(self.pending, results):
            v = self.verdicts[k]
            self.verdicts[k] = replace(v, stable=lv.stands, load=None if lv.load is None else round(lv.load, 6),
                                       failing=lv.failing, reason=lv.reason)
        for k, *_ in self.pending[len(results):]:
            self.verdicts[k] = None
        self.pending = []


AXLE_LINE_LDU = 2 * NEAR_LDU
"""How far apart two joints on one axle may lie across it (`_Call._threaded`): each lies within
`unmodelled.NEAR_LDU` of the axle's line (the Gearbox draws its axles 2 LDU above the holes they go
through); the holes of a beam are 20 LDU apart."""

AXIAL = ("technic-pin", "technic-axle", "wheel-pin")
"""Joint kinds a part goes onto along the joint's axis (`sweep.sweep_joint`)."""


def swings(unit: Sequence[Placed], joints: dict[int, list[tuple[int, Joint]]]) -> float | None:
    """The moment (N LDU) by which a unit held by joints alone, all of them turning freely about
    one axis line (a part hung on one Technic pin, a wheel on its pin: `joint_capacity.
    TURNS_FREELY`), swings: its weight turns it about that line by more than such a joint holds
    (`FREE_TWIST_NLDU`: a wheel, its centre of mass on its axis, does not; a beam hung by its end
    hole does); None where it does not swing. Whatever else may hold it later (a second pin)
    does not hold it at its own step."""
    found = [j for js in joints.values() for _, j in js]
    if not found or any(j.kind not in TURNS_FREELY or j.axis is None for j in found):
        return None
    u = np.asarray(found[0].axis, float)
    p = np.asarray(found[0].point, float)
    for j in found[1:]:
        d = np.asarray(j.point, float) - p
        if abs(float(np.asarray(j.axis, float) @ u)) < 0.999 or np.linalg.norm(d - (d @ u) * u) > 1.0:
            return None  # two axes: the joints hold each other's turn
    twist = 0.0
    for placed in unit:
        mass_kg, com, _ = part_mass_properties(placed.part)
        weight = np.array([0.0, mass_kg * GRAVITY, 0.0])  # LDraw's +y is down
        twist += float(np.cross(placed.pose.apply(com) - p, weight) @ u)
    return abs(twist) if abs(twist) > FREE_TWIST_NLDU else None


def _on_its_hole(placed: tuple[Part, Pose], link: Link) -> bool:
    """Whether a unit's part (world pose) meets `link`'s pin or axle with a hole of its own: a
    female connector on the link's axis (`joints.on_one_axis`), within `AXLE_LINE_LDU` of its line."""
    part, pose = placed
    line = np.array([link.point, np.add(link.point, link.axis), link.axis], float)
    return any(c.gender == "female" and on_one_axis(st, line, SAME_AXIS_DEG, AXLE_LINE_LDU)
               for c, st in zip(part_connectors(part), place_connectors(part_stretches(part), pose.R, pose.t)))


SAME_AXIS_DEG = float(np.degrees(np.arccos(SAME_AXIS)))
"""`SAME_AXIS` as an angle, for `joints.on_one_axis`."""


def _zones(joints: dict[int, list[tuple[int, Joint]]]) -> dict[int, np.ndarray | None]:
    """`CollisionScene.penetration`'s joints: per holding part, the stretches of axis round which
    its overlap with the candidate is the joints' (None: all of it, a joint with no axis)."""
    out = {}
    for i, js in joints.items():
        if any(j.zone is None for _, j in js):
            out[i] = None
        else:
            out[i] = (np.array([j.zone for _, j in js], float).reshape(-1, 3, 3), np.array([j.radius for _, j in js]))
    return out


def joint_links(joints: dict[int, list[tuple[int, Joint]]], base_n: int) -> list[Link]:
    """The load model's links of a candidate's joints (`_joints`): unit part `u` is numbered
    `base_n + u`, the holding structure part by its index."""
    return [Link(base_n + u, i, j.point, j.kind, j.axis) for i, js in sorted(joints.items()) for u, j in js]


def _alone_case(unit: Sequence[Placed], outer, base_n: int, ground_y: float | None, cfg: LoadConfig) -> tuple:
    """(mass, centre of mass, connections, ground support points) of a unit for `holds_alone_many`."""
    mass, weighted = 0.0, np.zeros(3)
    for p in unit:
        m, com, _ = part_mass_properties(p.part)
        mass += m
        weighted += m * p.pose.apply(com)
    conns = [(a >= base_n, pos, axis) for a, b, pos, axis in outer]
    ground = np.zeros((0, 3))
    if ground_y is not None:
        pts = [support_points(p, ground_y, cfg) for p in unit]
        ground = np.concatenate(pts) if pts else ground
    return mass, weighted / mass, conns, ground


# The last collision scenes and `LoadBase`s are the checker's (`CheckState.scenes`, `load_bases`):
# the sampler checks one part against one structure in several calls per step (batches, redraws
# of the same part); building the scene is most of a call's time.


def _placed_key(placed: Sequence, rel) -> tuple:
    """Placed parts (or parts) by identity, and a unit's parts and poses."""
    return (tuple(id(p) for p in placed),
            tuple((id(part), pose.R.tobytes(), pose.t.tobytes()) for part, pose in rel))


def _collision_scene(structure: Structure, rel, floor: float) -> CollisionScene:
    return current().scenes.get((_placed_key(structure.placed, rel), float(floor)),
                      (list(structure.placed), [part for part, _ in rel]),
                      lambda: CollisionScene(structure, rel, floor))


def _holder_scene(part: Part, rel) -> CollisionScene:
    """The kept scene of `part` alone at the origin (no ground) and the unit `rel`."""
    return current().holder_scenes.get(_placed_key([part], rel), (part, [p for p, _ in rel]), lambda: CollisionScene(
        Structure([Placed(part, 0, Pose.identity())]), rel, 1e6))


def _load_base(structure: Structure, floor_y: float | None, cfg) -> LoadBase:
    return current().load_bases.get((_placed_key(structure.placed, ()), len(structure.links), floor_y, cfg), list(structure.placed),
                      lambda: LoadBase(structure.placed, structure.connections, floor_y, structure.links, cfg))
