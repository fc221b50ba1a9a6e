"""Contact-only collision checks with MuJoCo: the structure as static bodies, the candidate free.

One MuJoCo model per (structure, candidate part type); each candidate pose costs one
`mj_fwdPosition` (kinematics and collision, no dynamics). A contact between inset pieces is a real
overlap; contacts between a stud and the part it is connected into are ignored (the coarse body
pieces fill the hollow a connected stud sits in).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from factory.parts import Part
from factory.physics.geometry import INSET_LDU, CollisionShape, collision_shape
from factory.physics.structure import Structure
from factory.pose import LDU_M, Pose, points_to_mujoco

TEMPLATES = Path(__file__).resolve().parents[2] / "mjcf_templates"


def _fmt(a: np.ndarray) -> str:
    return " ".join(f"{v:.7g}" for v in np.asarray(a).ravel())


@dataclass(frozen=True)
class _GeomInfo:
    owner: int
    """Index of the structure part, -1 for the candidate, -2 for the floor."""
    stud: bool


NEAR_LDU = 1.0
"""A candidate this close to the structure (real gap, LDU) touches it."""


class CollisionScene:
    """A compiled scene for checking one candidate (a part, or a rigid unit of parts given with
    their poses in the unit's frame) against one structure."""

    def __init__(self, structure: Structure, unit: list[tuple[Part, Pose]]):
        self.structure = structure
        shapes = [collision_shape(p.part) for p in structure.placed]
        meshes: dict[str, np.ndarray] = {}
        bodies = []
        info: list[_GeomInfo] = []
        for idx, (placed, shape) in enumerate(zip(structure.placed, shapes)):
            pos, quat = placed.pose.to_mujoco_quat()
            geoms = self._geoms(shape, meshes, idx, info)
            bodies.append(f'<body name="s{idx}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">{geoms}</body>')
        cand_geoms = ""
        for part, rel in unit:
            pos, quat = rel.to_mujoco_quat()
            inner = self._geoms(collision_shape(part), meshes, -1, info)
            cand_geoms += f'<body pos="{_fmt(pos)}" quat="{_fmt(quat)}">{inner}</body>'
        floor_z = -structure.floor_y() * LDU_M if len(structure) else 0.0
        template = (TEMPLATES / "collision.xml").read_text()
        xml = template.format(
            assets="".join(f'<mesh name="{n}" vertex="{_fmt(points_to_mujoco(v))}"/>' for n, v in meshes.items()),
            floor_z=f"{floor_z:.7g}",
            margin=f"{(NEAR_LDU - 2 * INSET_LDU + 0.5) * LDU_M:.7g}",
            structure="".join(bodies),
            candidate=cand_geoms,
        )
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        floor_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        # Geoms were written in order after the floor; map MuJoCo geom ids to owners.
        self.owner = np.full(self.model.ngeom, -2, np.int64)
        self.is_stud = np.zeros(self.model.ngeom, bool)
        order = [g for g in range(self.model.ngeom) if g != floor_id]
        for g, gi in zip(order, info):
            self.owner[g] = gi.owner
            self.is_stud[g] = gi.stud

    @staticmethod
    def _geoms(shape: CollisionShape, meshes: dict, owner: int, info: list) -> str:
        out = []
        for kind, pieces in (("b", shape.body), ("s", shape.studs)):
            for i, verts in enumerate(pieces):
                name = f"{shape.key}_{kind}{i}"
                meshes.setdefault(name, verts)
                cls = "stud" if kind == "s" else "body"
                out.append(f'<geom class="{cls}" mesh="{name}"/>')
                info.append(_GeomInfo(owner, kind == "s"))
        return "".join(out)

    def penetration(self, pose: Pose, connected: set[int]) -> tuple[float, bool]:
        """(Deepest overlap in LDU with the structure or the floor, whether it touches the structure).

        Overlap = depth between inset pieces + 2 x inset; 0 when no inset pieces touch. Stud
        contacts with parts in `connected` are ignored. Touching = a real gap under NEAR_LDU.
        """
        pos, quat = pose.to_mujoco_quat()
        self.data.qpos[:3] = pos
        self.data.qpos[3:7] = quat
        mujoco.mj_fwdPosition(self.model, self.data)
        deepest = 0.0
        near = False
        for c in self.data.contact[: self.data.ncon]:
            g1, g2 = c.geom1, c.geom2
            o1, o2 = self.owner[g1], self.owner[g2]
            if o1 != -1 and o2 != -1:
                continue
            other, other_g, cand_g = (o2, g2, g1) if o1 == -1 else (o1, g1, g2)
            if other == -1:
                continue
            if other >= 0 and other in connected and (self.is_stud[other_g] or self.is_stud[cand_g]):
                continue
            inset = INSET_LDU if other == -2 else 2 * INSET_LDU
            overlap = -c.dist / LDU_M + inset
            if overlap > 0:
                deepest = max(deepest, overlap)
            if other >= 0 and overlap > -NEAR_LDU:
                near = True
        return deepest, near


