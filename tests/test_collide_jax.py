"""The batched collision rule (`collide_jax`, JAX on the CPU here) against MuJoCo's contacts
(`CollisionScene.penetration`) on real candidates of the sampler."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")

from factory.physics import collide_jax  # noqa: E402
from factory.physics.attach import attachment_arrays  # noqa: E402
from factory.physics.check import _unit_connections  # noqa: E402
from factory.physics.collide import CollisionScene  # noqa: E402
from factory.physics.structure import Placed, Structure  # noqa: E402
from factory.pose import Pose  # noqa: E402
from factory.sampler import Sampler, SamplerConfig  # noqa: E402
from ldraw_support import part  # noqa: E402


@pytest.fixture(scope="module")
def questions():
    """Structures of four objects grown by the default sampler (plates, bricks, slopes, tiles), each
    asked about three part types at up to 60 feasible attachments: most collide, some by a stud
    entering another part, some on the ground."""
    s = Sampler(SamplerConfig(seed=1, min_steps=8, max_steps=12))
    rng = np.random.default_rng(0)
    parts = {p.name: p for p in s.parts}
    out = []
    for a in s.sample_many(range(4)):
        structure = Structure([Placed(parts[st.part], st.colour, st.pose) for st in a.steps])
        for part in rng.choice(s.parts, 3, replace=False):
            r, t = attachment_arrays(structure, part)
            pick = rng.choice(len(t), min(60, len(t)), replace=False)
            poses = [Pose(r[i], t[i]) for i in pick]
            touched = []
            for p in poses:
                conns = _unit_connections(structure, [(part, p)])
                touched.append({min(c[0], c[1]) for c in conns if min(c[0], c[1]) < len(structure)})
            out.append((structure, part, poses, touched, structure.floor_y()))
    return out


@pytest.mark.slow
def test_depths_and_touching_parts_are_those_of_mujoco(questions, monkeypatch):
    probes = []
    real = collide_jax._Job._studs_cross
    monkeypatch.setattr(collide_jax._Job, "_studs_cross", lambda self, keys: probes.extend(real(self, keys)) or
                        np.array(probes[len(probes) - len(keys):], bool))
    got = collide_jax.penetrations([(st, [(part, Pose.identity())], poses, touched, floor)
                                    for st, part, poses, touched, floor in questions])
    total = colliding = 0
    for (st, part, poses, touched, floor), found in zip(questions, got):
        scene = CollisionScene(st, [(part, Pose.identity())], floor)
        for pose, conn, pen in zip(poses, touched, found):
            depth, near = scene.penetration(pose, conn)
            total += 1
            colliding += depth > 0.5
            assert (pen.depth > 0.5) == (depth > 0.5)
            assert pen.near == near
            if depth <= 2.0:  # shallow: both are the pieces' exact depth (deep ones: see the docstring)
                assert pen.depth == pytest.approx(depth, abs=1e-3)
    assert total >= 400 and 0.2 * total < colliding < 0.9 * total
    assert True in probes and False in probes  # studs standing in hollows and studs crossing walls
    # With the tolerance (as the checker asks), fewer probes and the same verdicts; the depth of a
    # candidate that collides anyway may stop at a pair that needs no probe.
    asked = len(probes)
    fast = collide_jax.penetrations([(st, [(part, Pose.identity())], poses, touched, floor, 0.5)
                                     for st, part, poses, touched, floor in questions])
    assert len(probes) - asked < asked
    for exact, quick in zip(got, fast):
        for a, b in zip(exact, quick):
            assert (a.depth > 0.5) == (b.depth > 0.5) and a.near == b.near
            assert b.depth == a.depth if a.depth <= 0.5 else b.depth <= a.depth


def test_the_ground_counts_by_the_lowest_piece():
    brick = part("3001")
    structure = Structure([Placed(brick, 4, Pose.identity())])
    poses = [Pose(np.eye(3), [80, 0, 0]), Pose(np.eye(3), [80, 3, 0])]  # on the ground, 3 LDU into it
    (found,) = collide_jax.penetrations([(structure, [(brick, Pose.identity())], poses, [set(), set()], 24.0)])
    scene = CollisionScene(structure, [(brick, Pose.identity())], 24.0)
    assert found[0].depth == pytest.approx(scene.penetration(poses[0], set())[0], abs=1e-4)
    assert found[0].depth < 0.5
    assert found[1].depth == pytest.approx(scene.penetration(poses[1], set())[0], abs=1e-3)
    assert found[1].depth > 0.5
