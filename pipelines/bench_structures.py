"""The structures and candidates the physics benchmarks judge (`pipelines.bench_physics`).

Structures are grown from a seed with 2x4 bricks (embedded library) by the checker itself, so they
are valid (`grow`; the first 90 bricks of seed 0 kept in `GROWN`); candidates are feasible
attachments of a 2x4 brick (drawn with replacement to fill a batch).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from factory import Pose, get_reader, load_part
from factory.physics.attach import feasible_poses, lowest_y
from factory.physics.check import CheckConfig, _unit_connections, check
from factory.physics.load_model import LoadBase
from factory.physics.structure import Placed, Structure
from factory.physics.sweep import _boxes


GROWN = Path(__file__).with_name("grown_3001.json")
"""The poses `grow(90, seed=0)` placed, in order (a structure of n bricks is the first n): growing
90 takes minutes."""


def grown(n: int, seed: int = 0) -> Structure:
    """`grow(n, seed)`, from `GROWN` where it holds it."""
    if seed == 0 and GROWN.exists():
        poses = json.loads(GROWN.read_text())
        if len(poses) >= n:
            brick = load_part(get_reader(), "3001")
            return Structure([Placed(brick, 4, Pose(np.array(p["R"]), np.array(p["t"]))) for p in poses[:n]])
    return grow(n, seed)


def grow(n: int, seed: int = 0) -> Structure:
    """A valid structure of n 2x4 bricks, grown compactly on the ground plane and upward.

    Each step checks 16 of the nearest quarter of the attachments; once a step finds none valid
    (near 50 bricks almost every near attachment collides: 14 of 4,130 were valid at 48), the
    attachments whose boxes overlap a placed brick's are left out first, and the rest checked 16
    at a time until one is valid. Until a step fails 20 times in a row, the structure is the one
    the plain rule grows."""
    rng = np.random.default_rng(seed)
    brick = load_part(get_reader(), "3001")
    s = Structure([Placed(brick, 4, Pose.identity())])
    stalled, failed = False, 0
    while len(s) < n:
        poses = [p for p in feasible_poses(s, brick) if p.t[1] <= 0]  # on top, not hanging
        poses.sort(key=lambda p: (abs(p.t[0]) + abs(p.t[2]), -p.t[1]))
        if stalled:
            poses = _clear_of(s, brick, poses)
        pick = poses[: max(8, len(poses) // 4)] if not stalled else poses
        order = rng.permutation(len(pick))
        for start in range(0, len(order) if stalled else 1, 16):
            verdicts = check(s, brick, [pick[i] for i in order[start:start + 16]], floor_y=24.0)
            ok = [v for v in verdicts if v.ok]
            if ok:
                s.add(Placed(brick, 4, ok[0].pose))
                failed = 0
                break
        else:
            if stalled:
                raise RuntimeError(f"no valid attachment at {len(s)} bricks")
            failed += 1
            stalled = failed >= 20
    return s


def _clear_of(s: Structure, brick, poses: list[Pose]) -> list[Pose]:
    """The poses whose bounding box overlaps no placed brick's (by more than 1 LDU across, 4.5 LDU
    in height: a brick's studs stand 4 LDU into the one above)."""
    placed = _boxes([(q.part, q.pose) for q in s.placed])  # (k, 2, 3)
    boxes = _boxes([(brick, p) for p in poses])
    overlap = np.minimum(boxes[:, None, 1], placed[None, :, 1]) - np.maximum(boxes[:, None, 0], placed[None, :, 0])
    clear = ~(overlap > [1.0, 4.5, 1.0]).all(axis=2).any(axis=1)
    return [p for p, ok in zip(poses, clear) if ok]


def candidates(s: Structure, batch: int, seed: int = 1) -> list[Pose]:
    """`batch` feasible attachments of a 2x4 brick above the ground at y = 24 (as the sampler keeps
    them), drawn with replacement."""
    brick = load_part(get_reader(), "3001")
    poses = [p for p in feasible_poses(s, brick)
             if lowest_y(brick, p.R[None], p.t[None])[0] <= 24.0 + CheckConfig().max_penetration_ldu]
    rng = np.random.default_rng(seed)
    return [poses[i] for i in rng.integers(0, len(poses), size=batch)]


def load_models(s: Structure, poses: list[Pose], config: CheckConfig = CheckConfig()) -> list:
    """The whole-structure load model of the structure with each candidate (as `check` builds it)."""
    brick = load_part(get_reader(), "3001")
    base = LoadBase(s.placed, s.connections, 24.0, s.links, config.loads)
    return [base.model([Placed(brick, 4, p)], _unit_connections(s, [(brick, p)])) for p in poses]
