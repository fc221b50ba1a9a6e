"""Stability: does the structure with the new part stand, and does the new connection hold?

The model (constants in `StabilityConfig`, reasons in docs/physics.md):
- **Standing**: the verified structure and the stud-connected new part are one rigid body (the
  structure was verified when each of its parts was added). It stands on the ground on its
  support points and is simulated for `duration_s` under gravity; it is stable when no corner of
  its bounding box (nor its centre of mass) moves more than `max_move_ldu`. This is the rollout
  that MJX batches: the scene has a fixed number of support points, so it compiles once.
- **Clutch**: the new part's connection must carry its weight. A part hanging under the structure
  pulls on its studs with its weight; a part sitting with its centre of mass beyond its
  connections tips about the nearest edge and the studs behind that edge resist with their clutch
  force times their lever arm. Each stud holds `clutch_n` newtons (StableLego and BrickGPT use
  about 1 N).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from factory.connections import STUD_RADIUS
from factory.parts import Part, box_corners
from factory.physics.geometry import collision_shape
from factory.physics.structure import Placed
from factory.pose import LDRAW_TO_MUJOCO, LDU_M, points_to_mujoco

TEMPLATES = Path(__file__).resolve().parents[2] / "mjcf_templates"
GRAVITY = 9.81


@dataclass(frozen=True)
class StabilityConfig:
    """Constants of the stability model."""

    duration_s: float = 0.5
    """Simulated time."""
    timestep: float = 0.001
    """Integration step; MJX needs soft contacts at this step (timeconst >= 8 steps)."""
    solref_timeconst: float = 0.008
    """Contact stiffness time constant (s)."""
    max_move_ldu: float = 2.0
    """Largest movement of any bounding-box corner that still counts as standing."""
    clutch_n: float = 1.0
    """Pull-out force one stud connection holds (N)."""
    n_feet: int = 16
    """Support points in the fixed-capacity scene (the support polygon's hull, subsampled)."""
    foot_radius_m: float = 0.0002
    """Radius of a support sphere (m)."""
    iterations: int = 8
    """Constraint solver iterations per step at most. MJX iterates a whole batch until its slowest
    member converges, so this limit sets its cost: MuJoCo's default (100, line search 50) made MJX
    rollouts 2.3x slower on this CPU than 8 (16). A body on its feet needs few: 8 gave the sampler
    the same objects as 100, byte for byte (4 did not: 17 of 166 steps changed)."""
    ls_iterations: int = 8
    """Line-search iterations per solver iteration at most: 8 gave byte-identical objects to 16 and
    to MuJoCo's 50; 4 kept every verdict but moved one recorded movement in 166 steps."""

    @property
    def steps(self) -> int:
        return int(round(self.duration_s / self.timestep))


@lru_cache(maxsize=None)
def part_mass_properties(part: Part) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass kg, centre of mass in LDU part frame, inertia about the COM in kg m^2, LDraw axes).

    From the convex collision pieces (closed, unlike LDraw meshes), scaled to the part's mass.
    """
    import trimesh

    shape = collision_shape(part)
    mass = part.mass_g / 1000.0
    vols, coms, inertias = [], [], []
    for verts in shape.body + shape.studs:
        hull = trimesh.convex.convex_hull(verts)
        if hull.volume <= 0:
            continue
        vols.append(hull.volume)
        coms.append(hull.center_mass)
        inertias.append(hull.moment_inertia / hull.volume)  # per unit density, about piece COM
    if not vols:
        centre = part.bbox.mean(axis=0)
        return mass, centre, np.eye(3) * 1e-9
    vols = np.array(vols)
    coms = np.array(coms)
    com = (vols[:, None] * coms).sum(0) / vols.sum()
    density = mass / vols.sum()
    inertia = np.zeros((3, 3))
    for v, c, i in zip(vols, coms, inertias):
        d = c - com
        inertia += density * (i * v + v * (d @ d * np.eye(3) - np.outer(d, d)))
    return mass, com, inertia * LDU_M**2


@dataclass(frozen=True)
class RigidObject:
    """A set of placed parts as one rigid body, in MuJoCo's frame (metres, Z up)."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray
    """Principal moments (3,)."""
    iquat: np.ndarray
    """Principal axes as a quaternion (w x y z)."""
    feet: np.ndarray
    """(n_feet, 3) support points relative to the COM (unused ones at the COM)."""
    corners: np.ndarray
    """(8, 3) bounding-box corners relative to the COM."""


@dataclass(frozen=True)
class MassAggregate:
    """Mass properties and points of a set of placed parts, additive, in MuJoCo's frame (metres,
    Z up, before lifting onto the ground): the structure's is computed once per step and each
    candidate's is added to it."""

    mass: float
    moment: np.ndarray
    """Sum of mass times centre of mass."""
    inertia_origin: np.ndarray
    """Inertia about the frame origin."""
    points: np.ndarray
    """Collision piece vertices (LDU, LDraw frame), for the support polygon and bounds."""

    @classmethod
    def of(cls, placed: list[Placed]) -> "MassAggregate":
        mass, moment, inertia, points = 0.0, np.zeros(3), np.zeros((3, 3)), []
        for p in placed:
            m, c, i = part_mass_properties(p.part)
            r = LDRAW_TO_MUJOCO @ p.pose.R @ LDRAW_TO_MUJOCO.T
            com = points_to_mujoco(p.pose.apply(c))
            mass += m
            moment += m * com
            inertia += r @ (LDRAW_TO_MUJOCO @ i @ LDRAW_TO_MUJOCO.T) @ r.T + m * (com @ com * np.eye(3) - np.outer(com, com))
            shape = collision_shape(p.part)
            points.extend(p.pose.apply(v) for v in shape.body + shape.studs)
        pts = np.concatenate(points) if points else np.zeros((0, 3))
        return cls(mass, moment, inertia, pts)

    def __add__(self, other: "MassAggregate") -> "MassAggregate":
        return MassAggregate(self.mass + other.mass, self.moment + other.moment,
                             self.inertia_origin + other.inertia_origin,
                             np.concatenate([self.points, other.points]))


def rigid_object(placed, floor_y: float, cfg: StabilityConfig) -> RigidObject:
    """Merge placed parts (a list, or their `MassAggregate`) into one rigid body standing on the
    ground at LDraw height floor_y."""
    agg = placed if isinstance(placed, MassAggregate) else MassAggregate.of(list(placed))
    com = agg.moment / agg.mass
    inertia = agg.inertia_origin - agg.mass * (com @ com * np.eye(3) - np.outer(com, com))
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 0] = -axes[:, 0]
    pts = points_to_mujoco(agg.points)
    corners = box_corners([pts.min(0), pts.max(0)])
    support = agg.points[agg.points[:, 1] >= floor_y - 0.5]
    feet = _support_points(points_to_mujoco(support), cfg.n_feet)
    # The scene's ground plane is z = 0: lift everything by the ground's height.
    lift = np.array([0.0, 0.0, floor_y * LDU_M])
    com = com + lift
    feet_rel = np.zeros((cfg.n_feet, 3))
    if len(feet):
        feet[:, 2] = cfg.foot_radius_m
        feet_rel[: len(feet)] = feet - com
    return RigidObject(agg.mass, com, np.maximum(moments, 1e-12), _quat(axes), feet_rel, corners + lift - com)


def _support_points(pts: np.ndarray, n: int) -> np.ndarray:
    """At most n points of the support polygon's hull (x, y in MuJoCo's ground plane)."""
    if len(pts) == 0:
        return pts
    xy = np.unique(np.round(pts[:, :2], 6), axis=0)
    if len(xy) >= 3:
        try:
            xy = xy[ConvexHull(xy).vertices]
        except QhullError:
            pass
    if len(xy) > n:
        xy = xy[np.linspace(0, len(xy), n, endpoint=False).astype(int)]
    return np.column_stack([xy, np.zeros(len(xy))])


def _quat(m: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(m).ravel())
    return q


def stability_xml(cfg: StabilityConfig) -> str:
    # A foot compiled at the body's origin would be flagged as sharing the body frame, and MuJoCo
    # would then ignore the positions written per object: give each a distinct offset.
    feet = "".join(
        f'<geom name="foot{i}" type="sphere" size="{cfg.foot_radius_m}" pos="{0.001 * (i + 1)} 0 0" '
        'contype="1" conaffinity="0"/>'
        for i in range(cfg.n_feet)
    )
    return (TEMPLATES / "stability.xml").read_text().format(
        n_feet=cfg.n_feet, timestep=cfg.timestep, solref=cfg.solref_timeconst, feet=feet,
        iterations=cfg.iterations, ls_iterations=cfg.ls_iterations,
    )


@lru_cache(maxsize=4)
def stability_model(cfg: StabilityConfig) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(stability_xml(cfg))


def load_object(model: mujoco.MjModel, data: mujoco.MjData, obj: RigidObject) -> None:
    """Write a rigid object's fields into the fixed-capacity model and reset the state."""
    body = 1
    model.body_mass[body] = obj.mass
    model.body_inertia[body] = obj.inertia
    model.body_iquat[body] = obj.iquat
    model.body_ipos[body] = 0.0
    model.body_invweight0[body] = invweight0(obj.mass, obj.inertia)
    model.geom_pos[1 : 1 + len(obj.feet)] = obj.feet
    mujoco.mj_resetData(model, data)
    data.qpos[:3] = obj.com
    data.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]


def invweight0(mass, inertia) -> np.ndarray:
    """(..., 2): MuJoCo's `body_invweight0` of a free body with its centre of mass at the body's origin:
    mean inverse mass and mean inverse principal inertia. MuJoCo computes it once, when the model
    is compiled, and scales every contact's softness by it, so it must follow the mass and inertia
    written per object: left at the template's (10 g, 1e-6 kg m^2) it made contacts on a 140 g
    object 14x too soft, and MuJoCo's C engine flung standing objects away at a 1 ms step: 271 of
    4,877 rollouts of three sampler objects disagreed with MJX, 12 with it, 1 with it and the
    Euler integrator (docs/physics.md)."""
    return np.stack([1.0 / np.asarray(mass), np.mean(1.0 / np.asarray(inertia), axis=-1)], axis=-1)


def movement_ldu(obj: RigidObject, qpos: np.ndarray) -> float:
    """Largest displacement (LDU) of the COM or a bounding-box corner, from the start pose."""
    pos = qpos[:3]
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(qpos[3:7], dtype=np.float64))
    rot = rot.reshape(3, 3)
    moved = obj.corners @ rot.T + pos - (obj.corners + obj.com)
    return float(max(np.linalg.norm(pos - obj.com), np.linalg.norm(moved, axis=1).max()) / LDU_M)


def movements_ldu(corners: np.ndarray, com: np.ndarray, qpos: np.ndarray) -> np.ndarray:
    """`movement_ldu` of many objects at once: corners (n, 8, 3) and start COMs (n, 3) of the
    objects, final qpos (n, 7); inf where a rollout diverged (NaN). At 65,536 MJX rollouts on the
    H100 a call per object took about a third of `rollout_mjx`'s time (9,154 against 13,886
    rollouts/s for the bare jitted function)."""
    q = np.asarray(qpos, dtype=np.float64)
    pos = q[:, :3]
    w, x, y, z = q[:, 3:7].T
    rot = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1).reshape(-1, 3, 3)
    moved = np.einsum("nij,nkj->nki", rot, corners) + pos[:, None] - (corners + com[:, None])
    with np.errstate(invalid="ignore"):
        out = np.maximum(np.linalg.norm(pos - com, axis=1), np.linalg.norm(moved, axis=2).max(axis=1)) / LDU_M
    out[~np.isfinite(q).all(axis=1)] = np.inf
    return out


DIVERGED_WARNINGS = [0]
"""MuJoCo warnings in this process, counted instead of printed: they come from diverging rollouts
(a candidate flung away, judged unstable) and would otherwise break progress bars and leave
MUJOCO_LOG.TXT in the working folder."""


@lru_cache(maxsize=1)
def _count_warnings() -> None:
    mujoco.set_mju_user_warning(lambda msg: DIVERGED_WARNINGS.__setitem__(0, DIVERGED_WARNINGS[0] + 1))


def rollout_cpu(objs: list[RigidObject], cfg: StabilityConfig) -> np.ndarray:
    """Movement (LDU) of each object after `cfg.duration_s`, with MuJoCo's C engine."""
    _count_warnings()
    model = stability_model(cfg)
    data = mujoco.MjData(model)
    out = np.empty(len(objs))
    for k, obj in enumerate(objs):
        load_object(model, data, obj)
        for _ in range(cfg.steps):
            mujoco.mj_step(model, data)
        q = data.qpos.copy()
        # MuJoCo resets a diverging simulation (and says so in a warning counter): count that as
        # failing, as MJX's NaNs are.
        diverged = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0
        out[k] = np.inf if diverged or not np.all(np.isfinite(q)) else movement_ldu(obj, q)
    return out


def clutch_ok(part_mass_kg: float, part_com_ldu: np.ndarray, stud_points: np.ndarray, hanging: bool,
              cfg: StabilityConfig) -> bool:
    """Whether the new connection (stud positions in LDU, world) holds the new part.

    `hanging`: every connection is a stud of the new part pushed up into the structure, so the
    weight pulls the studs out. Otherwise the part sits on its studs and only tips when its COM
    lies beyond them: the tipping moment about the nearest edge must not exceed the studs' clutch
    times their lever arms (a stud's own radius counts as a lever, so a 1-stud part holds a moment).
    """
    weight = part_mass_kg * GRAVITY
    n = len(stud_points)
    if n == 0:
        return False
    if hanging:
        return weight <= n * cfg.clutch_n
    xz = stud_points[:, [0, 2]]
    c = np.asarray(part_com_ldu)[[0, 2]]
    dist, direction = _outside(xz, c)
    if dist <= 0:
        return True
    moment = weight * dist * LDU_M
    edge = (xz @ direction).max() + STUD_RADIUS  # the part tips about this line
    levers = edge - xz @ direction  # each stud's distance behind it (>= a stud radius)
    capacity = cfg.clutch_n * levers.sum() * LDU_M
    return moment <= capacity


def _outside(points: np.ndarray, c: np.ndarray) -> tuple[float, np.ndarray]:
    """How far c lies outside the points' footprint (grown by a stud radius), and the direction."""
    centre = points.mean(0)
    d = c - centre
    norm = np.linalg.norm(d)
    if norm < 1e-9:
        return 0.0, np.array([1.0, 0.0])
    u = d / norm
    reach = (points - centre) @ u
    return float(norm - (reach.max() + STUD_RADIUS)), u
