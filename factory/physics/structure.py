"""A structure of placed parts and its connection points in the world (attachments: `attach.py`).

World = the model's LDraw frame (LDU, y down). A stud and a socket are connected when they sit at
the same place with the same axis; a connection point that is connected is occupied.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from factory.parts import Part, box_corners
from factory.pose import Pose
from factory.symmetry import rotation_about

MATCH_LDU = 0.1
"""How close a stud and a socket must be (LDU) to count as connected."""


@dataclass(frozen=True, eq=False)
class Placed:
    """A part placed in the world."""

    part: Part
    colour: int
    pose: Pose


def connectors(part: Part, pose: Pose, which: str) -> tuple[np.ndarray, np.ndarray]:
    """World positions and axes (k, 3) of a placed part's 'studs' or 'sockets'."""
    items = part.studs if which == "studs" else part.sockets
    if not items:
        return np.zeros((0, 3)), np.zeros((0, 3))
    pos = np.array([c.pos for c in items]) @ pose.R.T + pose.t
    axis = np.array([c.axis for c in items]) @ pose.R.T
    return pos, axis


def match(pos_a, axis_a, pos_b, axis_b, tol: float = MATCH_LDU) -> list[tuple[int, int]]:
    """Index pairs (i, j) where connector i of a and j of b coincide with the same axis."""
    if len(pos_a) == 0 or len(pos_b) == 0:
        return []
    tree = cKDTree(pos_b)
    out = []
    for i, js in enumerate(tree.query_ball_point(pos_a, tol)):
        for j in js:
            if axis_a[i] @ axis_b[j] > 0.999:
                out.append((i, j))
    return out


def _pairs_within(pos_a, axis_a, pos_b, axis_b, tol: float, tree_a=None, tree_b=None) -> tuple[np.ndarray, np.ndarray]:
    """All index pairs (i, j) that `match` gives, as two arrays sorted by (i, j): in one tree query
    instead of one Python list per point. `tree_a`, `tree_b`: the points' trees when the caller
    keeps them (a structure's, asked for every candidate of a step)."""
    if len(pos_a) == 0 or len(pos_b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    tree_a = cKDTree(pos_a) if tree_a is None else tree_a
    tree_b = cKDTree(pos_b) if tree_b is None else tree_b
    near = tree_a.sparse_distance_matrix(tree_b, tol, output_type="ndarray")
    i, j = near["i"].astype(np.int64), near["j"].astype(np.int64)
    # sparse_distance_matrix leaves out pairs at distance 0 only when both trees are the same
    # object; here they never are. It stores pairs with distance <= tol, as query_ball_point.
    keep = np.einsum("kd,kd->k", axis_a[i], axis_b[j]) > 0.999
    i, j = i[keep], j[keep]
    order = np.lexsort((j, i))
    return i[order], j[order]


def connections_at(structure: "Structure", part: Part, rotations: np.ndarray, translations: np.ndarray,
                   number: int | None = None) -> list[list[tuple[int, int, np.ndarray, np.ndarray]]]:
    """The stud connections one part would make with the structure at each of many poses
    (rotations (B, 3, 3), translations (B, 3)), as (stud part, socket part, stud base, stud axis)
    with the part numbered `number` (default `len(structure)`): the structure's studs in the
    part's sockets, then the part's studs in the structure's sockets, each in `match`'s order.
    All poses in two tree queries (the sampler and the batched checks ask for thousands at once)."""
    batch, base = len(rotations), len(structure) if number is None else number
    out: list[list] = [[] for _ in range(batch)]
    sp, sa, so = structure.studs
    kp, ka, ko = structure.sockets
    for which in ("sockets", "studs"):
        items = part.sockets if which == "sockets" else part.studs
        if not items or batch == 0:
            continue
        local_p = np.array([c.pos for c in items], float)
        local_a = np.array([c.axis for c in items], float)
        k = len(items)
        pos = (np.einsum("bij,kj->bki", rotations, local_p) + translations[:, None, :]).reshape(-1, 3)
        axis = np.einsum("bij,kj->bki", rotations, local_a).reshape(-1, 3)
        if which == "sockets":
            # Structure stud i, candidate socket j.
            i, j = _pairs_within(sp, sa, pos, axis, MATCH_LDU, tree_a=structure.tree("studs"))
            owner = j // k
            order = np.argsort(owner, kind="stable")  # per candidate, still by (i, j)
            for c, si in zip(owner[order], i[order]):
                out[c].append((int(so[si]), base, sp[si], sa[si]))
        else:
            # Candidate stud i, structure socket j.
            i, j = _pairs_within(pos, axis, kp, ka, MATCH_LDU, tree_b=structure.tree("sockets"))
            for ci, kj in zip(i, j):  # sorted by i, so by candidate, then stud, then socket
                out[ci // k].append((base, int(ko[kj]), pos[ci], axis[ci]))
    return out


@dataclass
class Structure:
    """Parts placed so far, with their world connection points, which are occupied, the stud
    connections between them and the connections held rigid because the checker does not model
    them (`links`: Technic, clips, hinges)."""

    placed: list[Placed] = field(default_factory=list)

    def __post_init__(self):
        parts, self.placed = self.placed, []
        self.connections: list[tuple[int, int, np.ndarray, np.ndarray]] = []
        """(stud part, socket part, stud base, stud axis) of every stud connection."""
        self.links: list = []
        """`factory.physics.load_model.Link`s: rigid connections the checker does not model."""
        self._stud_pos = np.zeros((0, 3))
        self._stud_axis = np.zeros((0, 3))
        self._stud_owner = np.zeros(0, np.int64)
        self._sock_pos = np.zeros((0, 3))
        self._sock_axis = np.zeros((0, 3))
        self._sock_owner = np.zeros(0, np.int64)
        self._stud_busy = np.zeros(0, bool)
        self._sock_busy = np.zeros(0, bool)
        self._trees: dict[str, cKDTree] = {}
        self.solved_loads = None
        """Load programs solved on this structure, kept by `physics.check_loads` (`_LoadStarts`): the
        basis its last part's program ended at, when that part was a candidate, starts the
        candidates' programs after it (`started_loads.solve_from`)."""
        for p in parts:
            self.add(p)

    def add(self, placed: Placed, links=()) -> None:
        """Place a part; `links` are rigid connections it makes that the checker does not model."""
        idx = len(self.placed)
        self.placed.append(placed)
        sp, sa = connectors(placed.part, placed.pose, "studs")
        kp, ka = connectors(placed.part, placed.pose, "sockets")
        stud_busy = np.concatenate([self._stud_busy, np.zeros(len(sp), bool)])
        sock_busy = np.concatenate([self._sock_busy, np.zeros(len(kp), bool)])
        # Each stud-socket pair of two parts is matched once, when the later part comes: the
        # occupied masks follow from these matches (as `match` of all studs and sockets would).
        for i, j in match(self._stud_pos, self._stud_axis, kp, ka):
            self.connections.append((int(self._stud_owner[i]), idx, self._stud_pos[i], self._stud_axis[i]))
            stud_busy[i] = sock_busy[len(self._sock_pos) + j] = True
        for i, j in match(sp, sa, self._sock_pos, self._sock_axis):
            self.connections.append((idx, int(self._sock_owner[j]), sp[i], sa[i]))
            stud_busy[len(self._stud_pos) + i] = sock_busy[j] = True
        self._stud_busy, self._sock_busy = stud_busy, sock_busy
        self._trees = {}
        self.links.extend(links)
        self._stud_pos = np.concatenate([self._stud_pos, sp])
        self._stud_axis = np.concatenate([self._stud_axis, sa])
        self._stud_owner = np.concatenate([self._stud_owner, np.full(len(sp), idx)])
        self._sock_pos = np.concatenate([self._sock_pos, kp])
        self._sock_axis = np.concatenate([self._sock_axis, ka])
        self._sock_owner = np.concatenate([self._sock_owner, np.full(len(kp), idx)])

    def __len__(self) -> int:
        return len(self.placed)

    @property
    def studs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self._stud_pos, self._stud_axis, self._stud_owner

    @property
    def sockets(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self._sock_pos, self._sock_axis, self._sock_owner

    def tree(self, which: str) -> cKDTree:
        """The k-d tree of the 'studs' or 'sockets' positions, built once per part added (every
        candidate of a step asks which of them it meets: `connections_at`)."""
        if which not in self._trees:
            self._trees[which] = cKDTree({"studs": self._stud_pos, "sockets": self._sock_pos}[which])
        return self._trees[which]

    def occupied(self) -> tuple[np.ndarray, np.ndarray]:
        """Boolean masks over studs and sockets: connected to another part of the structure (kept
        as parts are added: `add`). Copies, so a caller may change them."""
        return self._stud_busy.copy(), self._sock_busy.copy()

    def connections_with(self, part: Part, pose: Pose) -> list[tuple[int, str]]:
        """(structure part index, 'stud'|'socket') for each connection a placed part would make.

        'stud' means a structure stud enters the new part's socket; 'socket' means a stud of the
        new part enters a structure socket.
        """
        out = []
        kp, ka = connectors(part, pose, "sockets")
        for i, _ in match(self._stud_pos, self._stud_axis, kp, ka):
            out.append((int(self._stud_owner[i]), "stud"))
        sp, sa = connectors(part, pose, "studs")
        for _, j in match(sp, sa, self._sock_pos, self._sock_axis):
            out.append((int(self._sock_owner[j]), "socket"))
        return out

    def floor_y(self) -> float:
        """The ground plane's height: the lowest point of the structure (LDraw y grows down)."""
        return lowest_point(self.placed) if self.placed else 0.0


def lowest_point(placed) -> float:
    """The largest LDraw y (y grows down) of the placed parts. A part turned off the axes has
    its box corners reaching further than any of its points (the Covered Wagon's cannon, tilted
    15 degrees: its wheels' boxes 9.4 LDU below the wheels), which put the ground under the
    table and the barrels laid on it afloat: its convex hull's vertices give its real lowest
    point. A part on the axes has its box exact, and cheaper."""
    def low(p: Placed) -> float:
        R = p.pose.R
        on_axes = np.allclose(np.abs(R).sum(axis=0), 1.0, atol=1e-9)
        pts = box_corners(p.part.bbox) if on_axes else p.part.hull_points
        return float(p.pose.apply(pts)[:, 1].max())

    return max(low(p) for p in placed)


def align(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """A rotation taking unit vector b onto unit vector a (a fixed choice when they are opposite)."""
    v = np.cross(b, a)
    c = float(b @ a)
    if np.linalg.norm(v) < 1e-9:
        if c > 0:
            return np.eye(3)
        perp = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 0, 1.0])
        return rotation_about(np.cross(a, perp), 180.0)
    if 1 + c < 1e-6:
        # Nearly opposite: 1 / (1 + c) below loses the rotation (or divides by zero where c
        # rounds to -1 with v not quite zero); turn about v's direction by the angle between.
        s = float(np.linalg.norm(v))
        return rotation_about(v / s, float(np.degrees(np.arctan2(s, c))))
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k * (1 / (1 + c))


def canonical_key(part: Part, pose: Pose) -> tuple:
    """A key equal for poses that place the part's geometry identically (symmetry-aware)."""
    keys = []
    for s in part.symmetry.rotations:
        r = pose.R @ s
        keys.append(tuple(np.round(r, 4).ravel().tolist()))
    return (min(keys), tuple(np.round(pose.t, 3).tolist()))
