"""What physics does with a predicted placement: the part released at its pose and settled.

The scene is the structure as it stands (its parts' collision pieces, as the checks use them,
fixed), the floor plane at the table and the predicted part on a free joint with its real mass and
inertia (`mass.part_mass_properties`), gravity along MuJoCo's -Z (LDraw -Y is up). `settle`:

1. **Overlap first.** The checks' own overlap measure (`CollisionScene.penetration`, the floor
   included) at the predicted pose; deeper than `SettleConfig.collides_ldu` → `collides`, nothing
   simulated (a part that deep inside another cannot be told which way out it would go).
2. **Snapping** (`snap.py` states the rule: 3 LDU across a stud axis, 4.5 LDU along it, 10 degrees,
   up to the part's symmetry): before and during the simulation (every `snap_every` steps), a part
   within tolerance of a valid stud connection is moved to that connection's pose and judged by
   the checks (`check.check`, the floor fixed); the nearest one accepted → `rests-connected` at
   exactly that pose. A candidate the checks reject is not snapped to (it would not hold).
3. **Simulation** with `mujoco.mj_step` for at most `SettleConfig.seconds`, stopped once the part
   has been at rest (moved at most `rest_ldu` and `rest_degrees` over `rest_seconds`). The end state:
   - `pushed-out`: the predicted pose overlapped beyond the checks' tolerance
     (`CheckConfig.max_penetration_ldu`, 0.5 LDU) and the end pose does not (still overlapping
     beyond it: `collides`), its real surfaces measured: a part resting on another reads
     `RESTING_LDU` more (the two insets, below);
   - `fell-off`: the part ends touching no structure part (the floor or nothing), and its lowest
     point at the predicted pose was at least `fell_ldu` above the floor (it dropped to the table);
   - `rests-unconnected`: anything else (on the structure without a connection, or on the table
     where it was predicted near the table).

`moved_ldu` is how far the part's centre of mass moved (symmetry-safe: a snapped pose may be
the candidate turned by a symmetry). Same inputs, same result: MuJoCo C is deterministic and the
snapping order is fixed. The collision pieces are inset by 0.25 LDU: the floor plane lies one
inset above the table, so a part rests with its real surface on the table, but a part resting on
another sits 0.5 LDU (two insets) lower than its real surfaces would (a contact margin of 0.5 LDU
would lift it, but MuJoCo's margin made resting parts float and jitter).

`settle_model` builds the scene's `MjModel` alone, and `Release` holds the rules without the
simulation (before simulating, after every `snap_every` steps, at the end). `settle_all` runs many
cases on MuJoCo C, a scene's model, overlap measure and snapping verdicts made once; the batched
version (`settle_mjx.settle_many`) simulates them on MuJoCo Warp and applies the same `Release`.
Snapping after a chunk follows the part's path through the chunk step by step (`_path` between the
poses after each step), not only its end pose.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from factory.parts import Part
from factory.physics.check import CheckConfig, check
from factory.physics.collide import CollisionScene, _fmt, _structure_body, _template
from factory.physics.geometry import INSET_LDU, collision_shape
from factory.physics.mass import part_mass_properties
from factory.physics.snap import SnapRule, SnapTargets
from factory.physics.structure import Structure
from factory.pose import LDRAW_TO_MUJOCO, LDU_M, Pose, points_to_mujoco, poses_from_mujoco

OUTCOMES = ("rests-connected", "rests-unconnected", "fell-off", "pushed-out", "collides")

RESTING_LDU = 2 * INSET_LDU
"""What the checks' overlap measure reads for a simulated part resting on another (their inset
pieces touching): the part sits this much lower than its real surfaces would."""


@dataclass(frozen=True)
class SettleConfig:
    """Rules and MuJoCo constants of `settle`.

    Contact parameters: the parts are a few grams and millimetres, so MuJoCo's default soft
    contact (solref 0.02 s) lets a resting brick sink about a millimetre (2.5 LDU, more than a
    plate's tolerance). A time constant of 4 ms (twice the 2 ms step, the least MuJoCo keeps
    stable) with critical damping and a stiff impedance (0.95-0.99 over 1 LDU) keeps a resting
    part within a few tenths of an LDU of its contact surface. Friction 0.5 (ABS on ABS is about
    0.3-0.5; the load model's ground uses 0.8 for the table), elliptic cones, condim 3 (sliding
    friction only: a brick on a brick does not roll).
    """

    collides_ldu: float = 4.0
    """Deeper overlap at the predicted pose → `collides` without simulating (a stud's height: the
    deepest a part can sit on studs it does not fit; deeper, it is inside the other part)."""
    snap: SnapRule = field(default_factory=SnapRule)
    seconds: float = 1.0
    """Simulated at most (a brick dropped 30 LDU lands in 0.05 s; one tipping off a tower edge
    reaches the table well within 0.5 s)."""
    timestep: float = 0.001
    snap_every: int = 10
    """Steps per chunk: the rules run after each (the snapping test on the pose after every step of
    the chunk, the at-rest window on the chunks' ends; 10 ms)."""
    rest_ldu: float = 0.1
    rest_degrees: float = 0.5
    rest_seconds: float = 0.1
    """At rest: the part's centre of mass moved at most `rest_ldu` and it turned at most
    `rest_degrees` over the last `rest_seconds`. Measured over a window, not as a speed: a part on
    several stiff contacts (a brick upside down on its 8 studs) keeps a tiny bounce (0.02 LDU, speeds
    up to 6 LDU/s) that never lets its instantaneous speed settle."""
    fell_ldu: float = 8.0
    """`fell-off` needs the part's lowest point at least this high above the floor at first (a
    plate's height: a part predicted on the table and sliding on it did not fall off anything)."""
    friction: float = 0.5
    solref: tuple[float, float] = (0.002, 1.0)
    solimp: tuple[float, float, float] = (0.95, 0.99, 0.0004)
    check: CheckConfig = field(default_factory=CheckConfig)
    """The checks that judge a snapped pose (and the overlap tolerance of `pushed-out`)."""


@dataclass(frozen=True)
class Settled:
    """Where a released part ends and how (`settle`)."""

    outcome: str
    """One of `OUTCOMES`."""
    pose: Pose
    """The settled pose (LDraw frame, LDU); the predicted pose for `collides` before simulating."""
    moved_ldu: float
    """How far the part's centre of mass moved from the predicted pose."""
    connections: int
    """Stud connections at the settled pose."""
    seconds: float
    """Simulated time (0.0 when decided before simulating)."""
    at_rest: bool = True
    """False when the simulation ran out of time with the part still moving."""


@dataclass
class SettleScene:
    """A compiled settling scene of one (structure, part): `model` and what `settle` reads of it."""

    model: mujoco.MjModel
    part_body: int
    floor_geom: int
    owner: np.ndarray
    """Per geom: structure part index, -1 for the part's own geoms, -2 for the floor."""
    meshes: dict[str, str] = field(default_factory=dict)
    """The scene's mesh assets: name → vertex text as written (`settle_mjx` compiles the same text
    into its shared mesh pool, so that MuJoCo centres each mesh the same way)."""


def settle_model(structure: Structure, part: Part, floor_y: float, config: "SettleConfig" = SettleConfig(),
                 pose: Pose | None = None) -> SettleScene:
    """The settling scene of `part` on `structure` (the floor at LDraw height `floor_y`), the part's
    free joint at `pose` in `qpos0` (identity when None; `settle` sets qpos itself). One model per
    (structure, part type): a batch of predicted poses of one part only changes qpos."""
    meshes: dict[str, str] = {}
    bodies, owners = [], []
    for idx, placed in enumerate(structure.placed):
        body, body_meshes, body_info, _ = _structure_body(placed, idx)
        bodies.append(body)
        for name, verts in body_meshes:
            meshes.setdefault(name, verts)
        owners.extend(gi.owner for gi in body_info)
    info: list = []
    part_geoms = CollisionScene._geoms(collision_shape(part), meshes, -1, info)
    owners.extend(gi.owner for gi in info)
    mass, com, inertia = part_mass_properties(part)
    i_mj = LDRAW_TO_MUJOCO @ inertia @ LDRAW_TO_MUJOCO.T
    full = [i_mj[0, 0], i_mj[1, 1], i_mj[2, 2], i_mj[0, 1], i_mj[0, 2], i_mj[1, 2]]
    inertial = f'<inertial pos="{_fmt(points_to_mujoco(com))}" mass="{mass:.7g}" fullinertia="{_fmt(full)}"/>'
    pos, quat = (pose or Pose.identity()).to_mujoco_quat()
    xml = _template("settle.xml").format(
        timestep=f"{config.timestep:.7g}", condim=3, friction=f"{config.friction:.7g} 0.005 0.0001",
        solref=_fmt(config.solref), solimp=_fmt(config.solimp),
        assets="".join(f'<mesh name="{n}" vertex="{v}"/>' for n, v in meshes.items()),
        floor_z=f"{-(floor_y - INSET_LDU) * LDU_M:.7g}", structure="".join(bodies), pos=_fmt(pos), quat=_fmt(quat),
        inertial=inertial, part=part_geoms)
    model = mujoco.MjModel.from_xml_string(xml)
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    owner = np.full(model.ngeom, -2, np.int64)
    order = [g for g in range(model.ngeom) if g != floor]  # geoms in the order written, floor first
    owner[order] = owners
    return SettleScene(model, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "part"), floor, owner, meshes)


class _Judge:
    """Snapping with the checks: candidates near a pose, judged once each."""

    def __init__(self, structure: Structure, part: Part, floor_y: float, config: SettleConfig):
        self.structure, self.part, self.floor_y, self.config = structure, part, floor_y, config
        self.targets = SnapTargets.of(structure, part)
        self.overlap = CollisionScene(structure, [(part, Pose.identity())], floor_y)
        """The checks' overlap measure of the part in this scene (compiled once per scene)."""
        self.judged: dict[int, int | None] = {}  # candidate -> connections when accepted, else None

    def snap(self, pose: Pose) -> tuple[Pose, int] | None:
        """(the snapped pose, its connections) where `pose` is near a connection the checks accept."""
        hit = self.first([pose])
        return None if hit is None else hit[1:]

    def first(self, poses: Sequence[Pose]) -> tuple[int, Pose, int] | None:
        """The first of `poses`, in order, near a connection the checks accept: (its index, the
        snapped pose, its connections). Each pose's candidates nearest first, as `snap`; the
        nearness test runs on all the poses at once."""
        R = np.array([p.R for p in poses])
        t = np.array([p.t for p in poses])
        for k, hits in enumerate(self.targets.near_many(R, t, self.config.snap)):
            for c, snapped, _ in hits:
                if c not in self.judged:
                    (v,) = check(self.structure, self.part, [snapped], config=self.config.check, floor_y=self.floor_y)
                    self.judged[c] = v.connections if v.ok else None
                if self.judged[c] is not None:
                    return k, snapped, self.judged[c]
        return None


def _pose_of(data: mujoco.MjData, body: int) -> Pose:
    return Pose.from_mujoco(data.xpos[body], data.xmat[body].reshape(3, 3))


class Release:
    """One predicted placement as `settle` judges it, the simulation left to the caller (MuJoCo C in
    `settle_all`, MuJoCo Warp in `settle_mjx`): the checks before simulating (`result` set when they decide),
    `after_chunk` with the part's poses after each step of a chunk of `snap_every` steps (snapping
    along them, the at-rest window; a batch asks `sweep` and `still` itself), and `finish` with the
    end pose and the geoms' owners it touches. `judge` may be shared
    by the releases of one (structure, part): a candidate's verdict does not depend on the pose."""

    def __init__(self, structure: Structure, part: Part, pose: Pose, floor_y: float, config: SettleConfig,
                 judge: "_Judge | None" = None):
        self.structure, self.part, self.pose, self.floor_y, self.config = structure, part, pose, floor_y, config
        _, self.com, _ = part_mass_properties(part)
        self.judge = judge or _Judge(structure, part, floor_y, config)
        self.overlap = self.judge.overlap
        self.depth0, _ = self.overlap.penetration(pose, self._connected(pose))
        self.result: Settled | None = None
        self.history: list[Pose] = [pose]  # the pose after every chunk of `snap_every` steps
        self.window = max(1, int(np.ceil(config.rest_seconds / (config.timestep * config.snap_every))))
        self.at_rest = False
        if self.depth0 > config.collides_ldu:
            self.result = Settled("collides", pose, 0.0, self._conns(pose), 0.0)
            return
        hit = self.judge.snap(pose)
        if hit is not None:
            self.result = Settled("rests-connected", hit[0], self._moved(hit[0]), hit[1], 0.0)

    def _moved(self, p: Pose) -> float:
        return float(np.linalg.norm(p.apply(self.com) - self.pose.apply(self.com)))

    def _conns(self, p: Pose) -> int:
        return len(self.structure.connections_with(self.part, p))

    def _connected(self, p: Pose) -> set[int]:
        return {i for i, _ in self.structure.connections_with(self.part, p)}

    def after_chunk(self, R: np.ndarray, t: np.ndarray, done: int) -> bool:
        """The part's poses after each step of the chunk that ended after `done` steps (`R` (k, 3,
        3), `t` (k, 3), LDraw, in order): True when settling stops here (snapped: `result` set; or
        at rest: `at_rest`). The snapping test follows the path step by step: a part landing on
        studs may bounce back out of the snapping window within a chunk, and whether it was found
        in it would otherwise hang on where the chunk ended."""
        last = self.history[-1]
        # Most chunks pass no candidate connection: their poses are not swept one by one.
        if (self.judge.targets.along(np.concatenate([last.t[None], t]), self.config.snap)
                and self.sweep(last, [Pose(r, x) for r, x in zip(R, t)], done)):
            return True
        self.history.append(Pose(R[-1], t[-1]))
        if len(self.history) > self.window:
            window = self.history[-self.window - 1:]
            self.at_rest = bool(still(np.array([p.R for p in window])[None], np.array([p.t for p in window])[None],
                                      self.com, self.config)[0])
        return self.at_rest

    def sweep(self, last: Pose, path: Sequence[Pose], done: int) -> bool:
        """The snapping test along the part's path from `last` through the poses of `path` (after
        each step of the chunk that ended after `done` steps), `_path` filling in between: True,
        with `result` set, at the first pose near a connection the checks accept."""
        poses = []
        for step in path:
            poses.extend(_path(last, step, self.config.snap.plane_ldu))
            last = step
        hit = self.judge.first(poses)
        if hit is None:
            return False
        _, snapped, connections = hit
        self.result = Settled("rests-connected", snapped, self._moved(snapped), connections, done * self.config.timestep)
        return True

    def finish(self, end: Pose, touched: set[int], done: int) -> Settled:
        """The outcome of a simulation that ended at `end` after `done` steps, touching `touched`
        (`_touched`: structure part indices, -2 for the floor)."""
        config, seconds = self.config, done * self.config.timestep
        tolerance = config.check.max_penetration_ldu
        if self.depth0 > tolerance:
            depth, _ = self.overlap.penetration(end, self._connected(end))
            # Simulated, a part rests on another with their inset pieces touching: the overlap
            # measure adds both insets, so resting there it reads 2 x INSET_LDU with no overlap of
            # the real surfaces (module docstring). The tolerance applies to the real surfaces.
            outcome = "pushed-out" if depth <= tolerance + RESTING_LDU else "collides"
            return Settled(outcome, end, self._moved(end), self._conns(end), seconds, self.at_rest)
        dropped = self.floor_y - float(self.pose.apply(self.part.hull_points)[:, 1].max())
        fell = len(self.structure) and not (touched - {-2}) and dropped >= config.fell_ldu
        outcome = "fell-off" if fell else "rests-unconnected"
        return Settled(outcome, end, self._moved(end), self._conns(end), seconds, self.at_rest)


def default_floor_y(structure: Structure, part: Part, pose: Pose) -> float:
    """`settle`'s table height when none is given: the structure's lowest point (the part's, alone)."""
    return structure.floor_y() if len(structure) else float(pose.apply(part.hull_points)[:, 1].max())


def settle(structure: Structure, part: Part, pose: Pose, floor_y: float | None = None,
           config: SettleConfig = SettleConfig()) -> Settled:
    """Release `part` at `pose` (LDraw frame) on `structure` and let it settle (module docstring).
    `floor_y`: the table's LDraw height, by default the structure's lowest point."""
    (out,) = settle_all([(structure, part, pose, floor_y)], config)
    return out


class Scenes:
    """The scenes of many cases (a scene: the same `Structure` and `Part` objects and floor): each
    one's snapping verdicts and overlap measure (`_Judge`) made once, and its `settle_model` made
    once when a case of it is simulated. `settle_all` and `settle_mjx.settle_many` share it."""

    def __init__(self, config: SettleConfig):
        self.config = config
        self._judges: dict[tuple, _Judge] = {}
        self._models: dict[tuple, SettleScene] = {}

    def release(self, structure: Structure, part: Part, pose: Pose, floor_y: float | None) -> tuple[tuple, Release]:
        """(the case's scene key, its `Release`); `floor_y` None: `default_floor_y`."""
        floor = default_floor_y(structure, part, pose) if floor_y is None else float(floor_y)
        key = (id(structure), id(part), floor)
        if key not in self._judges:
            self._judges[key] = _Judge(structure, part, floor, self.config)
        return key, Release(structure, part, pose, floor, self.config, self._judges[key])

    def model(self, key: tuple, release: Release) -> SettleScene:
        """The scene's model (`release` one of its cases)."""
        if key not in self._models:
            self._models[key] = settle_model(release.structure, release.part, release.floor_y, self.config)
        return self._models[key]


@dataclass
class SettleStats:
    """Where `settle_all`'s time went (filled in when passed): what a faster simulator can save is
    `step_s` alone; the rest (the checks before simulating, snapping verdicts, the scenes' models,
    the rules after every chunk) is the same host work for MuJoCo C and MuJoCo Warp."""

    total_s: float = 0.0
    """Seconds of the whole call."""
    step_s: float = 0.0
    """Of those, seconds inside `mujoco.mj_step` (and reading the part's pose after each step)."""
    simulated: int = 0
    """Cases simulated (the others were decided before simulating)."""


def settle_all(cases, config: SettleConfig = SettleConfig(), stats: SettleStats | None = None) -> list[Settled]:
    """`settle` of every case (structure, part, pose, floor_y) on MuJoCo C, one after another, a
    scene's judge and model made once for all its cases (`Scenes`)."""
    stats = stats if stats is not None else SettleStats()
    t0 = time.perf_counter()
    scenes = Scenes(config)
    out = []
    for case in cases:
        key, release = scenes.release(*case)
        if release.result is not None:
            out.append(release.result)
        else:
            stats.simulated += 1
            out.append(_simulate(release, scenes.model(key, release), config, stats))
    stats.total_s += time.perf_counter() - t0
    return out


def _simulate(release: Release, scene: SettleScene, config: SettleConfig, stats: SettleStats | None = None) -> Settled:
    """One undecided release simulated with `mujoco.mj_step`, the rules after every chunk."""
    model, data = scene.model, mujoco.MjData(scene.model)
    pos, quat = release.pose.to_mujoco_quat()
    data.qpos[:3], data.qpos[3:7] = pos, quat
    mujoco.mj_forward(model, data)
    steps = int(round(config.seconds / config.timestep))
    pos, mat = np.zeros((config.snap_every, 3)), np.zeros((config.snap_every, 9))
    body = scene.part_body
    done = 0
    while done < steps:
        n = min(config.snap_every, steps - done)
        t0 = time.perf_counter()
        for j in range(n):
            mujoco.mj_step(model, data)
            pos[j], mat[j] = data.xpos[body], data.xmat[body]
        if stats is not None:
            stats.step_s += time.perf_counter() - t0
        done += n
        R, t = poses_from_mujoco(pos[:n], mat[:n].reshape(n, 3, 3))
        if release.after_chunk(R, t, done):
            break
    if release.result is not None:
        return release.result
    mujoco.mj_forward(model, data)
    return release.finish(_pose_of(data, scene.part_body), _touched(data, scene), done)


def _path(a: Pose, b: Pose, spacing: float) -> list[Pose]:
    """Poses from `a` (excluded) to `b` (included), at most `spacing` LDU apart: the snapping test
    sweeps the path between the poses after two steps (a part falling fast may move more than the
    snapping window in one)."""
    steps = max(1, int(np.ceil(np.linalg.norm(b.t - a.t) / spacing)))
    if steps == 1:
        return [b]
    rel = a.R.T @ b.R
    angle = np.arccos(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0))
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    norm = np.linalg.norm(axis)
    out = []
    for k in range(1, steps + 1):
        f = k / steps
        if k == steps or angle < 1e-9 or norm < 1e-12:
            R = b.R if k == steps or angle < 1e-9 else a.R
        else:
            u = axis / norm
            K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
            th = f * angle
            R = a.R @ (np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K)
        out.append(Pose(R, a.t + f * (b.t - a.t)))
    return out


def still(R: np.ndarray, t: np.ndarray, com: np.ndarray, config: SettleConfig) -> np.ndarray:
    """The at-rest rule over windows of poses: `R` (m, W, 3, 3) and `t` (m, W, 3) are m parts'
    poses (LDraw) after the last W chunks, oldest first, `com` (3,) or (m, 3) their centres of mass
    in the part's frame. True where every pose of the window lies within the rest bounds of the
    last one (`SettleConfig.rest_ldu`, `rest_degrees`). One rule for both engines: `Release` asks it
    of one part, `settle_mjx` of a whole batch at once."""
    com = np.broadcast_to(np.asarray(com, np.float64), (len(t), 3))
    at = np.einsum("mwij,mj->mwi", R, com) + t
    moved = np.linalg.norm(at[:, :-1] - at[:, -1:], axis=-1)
    cos = np.clip((np.einsum("mwij,mij->mw", R[:, :-1], R[:, -1]) - 1.0) / 2.0, -1.0, 1.0)
    return (moved <= config.rest_ldu).all(axis=1) & (np.degrees(np.arccos(cos)) <= config.rest_degrees).all(axis=1)


def _touched(data: mujoco.MjData, scene: SettleScene) -> set[int]:
    """Structure parts (and -2 for the floor) in contact with the part."""
    n = data.ncon
    if not n:
        return set()
    g1 = np.asarray(data.contact.geom1[:n], np.int64)
    g2 = np.asarray(data.contact.geom2[:n], np.int64)
    o1, o2 = scene.owner[g1], scene.owner[g2]
    other = np.where(o1 == -1, o2, o1)
    return {int(o) for o in other[(o1 == -1) | (o2 == -1)] if o != -1}
