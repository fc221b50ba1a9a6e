"""The one frame convention of the project, in one place.

At the edges (files, prompts, metrics) poses are in LDraw units with LDraw's axes: x right, y *down*,
z toward the viewer. Inside MuJoCo they are in metres with Z up. `Pose` holds the LDraw form and
converts; nothing else in the project converts frames by hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LDU_M = 0.0004
"""Metres per LDraw unit (1 LDU = 0.4 mm)."""

LDRAW_TO_MUJOCO = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rotation taking LDraw axes to MuJoCo's: LDraw -Y (up) becomes +Z, LDraw +Z becomes +Y."""


@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid placement in LDraw units: a point p of the part lands at `R @ p + t`.

    `R` is the matrix of an LDraw type 1 line (`a b c / d e f / g h i` as rows), so its columns are
    the part's axes in the parent frame.
    """

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self):
        r = np.array(self.R, dtype=np.float64).reshape(3, 3)
        t = np.array(self.t, dtype=np.float64).reshape(3)
        r.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R", r)
        object.__setattr__(self, "t", t)

    # -- named constructors ---------------------------------------------------------------
    @classmethod
    def identity(cls) -> "Pose":
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_ldraw(cls, values) -> "Pose":
        """From the 12 numbers of a type 1 line: `x y z a b c d e f g h i`."""
        v = np.asarray(values, dtype=np.float64).reshape(12)
        return cls(v[3:].reshape(3, 3), v[:3])

    @classmethod
    def from_ldraw_line(cls, line: str) -> tuple[int, "Pose", str]:
        """Parse a whole type 1 line into (colour, pose, part name)."""
        tokens = line.split(None, 14)
        if len(tokens) != 15 or tokens[0] != "1":
            raise ValueError(f"expected a type 1 line '1 colour x y z a b c d e f g h i part', got {line!r}")
        return int(tokens[1], 0), cls.from_ldraw([float(x) for x in tokens[2:14]]), tokens[14].strip()

    @classmethod
    def from_mujoco(cls, pos_m, rot) -> "Pose":
        """From a MuJoCo position (metres, Z up) and a 3x3 rotation matrix in MuJoCo's frame."""
        c = LDRAW_TO_MUJOCO
        return cls(c.T @ np.asarray(rot, dtype=np.float64).reshape(3, 3) @ c,
                   c.T @ np.asarray(pos_m, dtype=np.float64) / LDU_M)

    # -- conversions ----------------------------------------------------------------------
    def to_ldraw(self) -> list[float]:
        """The 12 numbers of a type 1 line: `x y z a b c d e f g h i`."""
        return [*self.t.tolist(), *self.R.reshape(9).tolist()]

    def to_ldraw_line(self, colour: int, part: str) -> str:
        nums = " ".join(_fmt(v) for v in self.to_ldraw())
        return f"1 {colour} {nums} {part}"

    def to_mujoco(self) -> tuple[np.ndarray, np.ndarray]:
        """(position in metres, 3x3 rotation) in MuJoCo's Z-up frame."""
        c = LDRAW_TO_MUJOCO
        return c @ self.t * LDU_M, c @ self.R @ c.T

    def to_mujoco_quat(self) -> tuple[np.ndarray, np.ndarray]:
        """(position in metres, unit quaternion w x y z) in MuJoCo's frame."""
        pos, rot = self.to_mujoco()
        return pos, _quat_from_matrix(rot)

    # -- algebra --------------------------------------------------------------------------
    def __matmul__(self, other: "Pose") -> "Pose":
        """Composition: `(a @ b)` places b's frame inside a's."""
        return Pose(self.R @ other.R, self.R @ other.t + self.t)

    def inverse(self) -> "Pose":
        return Pose(self.R.T, -self.R.T @ self.t)

    def apply(self, points) -> np.ndarray:
        """Points (..., 3) in the child frame to the parent frame."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def is_rotation(self, tol: float = 1e-6) -> bool:
        return bool(np.allclose(self.R @ self.R.T, np.eye(3), atol=tol) and np.linalg.det(self.R) > 0)

    def allclose(self, other: "Pose", atol: float = 1e-6) -> bool:
        return bool(np.allclose(self.R, other.R, atol=atol) and np.allclose(self.t, other.t, atol=atol))

    def __repr__(self) -> str:
        return f"Pose(R={self.R.round(6).tolist()}, t={self.t.round(6).tolist()})"


def poses_from_mujoco(pos_m, rot) -> tuple[np.ndarray, np.ndarray]:
    """`Pose.from_mujoco` of many at once, as arrays: (R (..., 3, 3), t (..., 3)) in LDraw from
    MuJoCo positions (..., 3) in metres and rotation matrices (..., 3, 3)."""
    c = LDRAW_TO_MUJOCO
    return c.T @ np.asarray(rot, np.float64) @ c, np.asarray(pos_m, np.float64) @ c / LDU_M


def nearest_rotation_matrix(m) -> np.ndarray:
    """The proper rotation nearest to a finite 3x3 matrix in the Frobenius norm: with the SVD
    `m = U S V^T`, `U diag(1, 1, det(U V^T)) V^T` (a reflection's nearest rotation keeps det +1)."""
    u, _, vt = np.linalg.svd(np.asarray(m, dtype=np.float64).reshape(3, 3))
    d = 1.0 if np.linalg.det(u @ vt) > 0 else -1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


def points_to_mujoco(points) -> np.ndarray:
    """Points (..., 3) in LDU with LDraw axes to metres with MuJoCo's axes (mesh vertices)."""
    return np.asarray(points, dtype=np.float64) @ LDRAW_TO_MUJOCO.T * LDU_M


def _fmt(v: float) -> str:
    r = round(v, 6)
    if r == int(r):
        return str(int(r))
    return f"{r:.6f}".rstrip("0").rstrip(".")


def _quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix, w >= 0 (Shepperd's method)."""
    m = r
    tr = np.trace(m)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q
