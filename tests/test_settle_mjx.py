"""The batched MJX settling (`factory.physics.settle_mjx.settle_many`) against the MuJoCo C reference
(`settle.settle`) on the hand-built cases of tests/test_settle.py. Cases decided before simulating
(inside another part, snapped, exactly right) never reach MJX and are fast; the simulated ones
compile MJX's step for their scene (minutes on JAX's CPU backend: marked slow)."""

from __future__ import annotations

import numpy as np
import pytest

from factory import Pose
from factory.physics import settle_mjx
from factory.physics.settle import settle
from factory.physics.settle_mjx import MjxStats, settle_many
from factory.physics.structure import Structure
from factory.symmetry import rotation_about
from ldraw_support import at, part
from test_settle import I3, SEATED, plate, tower

pytest.importorskip("jax")
pytestmark = pytest.mark.usefixtures("isolated_cache")


def _same(cases):
    stats = MjxStats()
    got = settle_many(cases, stats=stats)
    for (s, p, pose, floor), g in zip(cases, got):
        ref = settle(s, p, pose, floor)
        assert g.outcome == ref.outcome, (pose.t, g, ref)
        assert np.allclose(g.pose.t, ref.pose.t, atol=1.0) and g.connections == ref.connections
    return got, stats


def test_cases_decided_before_simulating_agree_without_mjx():
    brick, one = part("3001"), Structure([at("3001", 0, 0, 0)])
    p = plate()
    cases = [(one, brick, Pose(I3, [0, 0, 0]), None),  # inside: collides
             (p, brick, Pose(I3, [2, -24, 0]), None),  # 2 LDU off: snaps
             (p, brick, SEATED, None),  # exactly right
             (p, brick, Pose(I3, [-1.5, -25, 1]), None)]  # near a connection
    got, stats = _same(cases)
    assert [g.outcome for g in got] == ["collides", "rests-connected", "rests-connected", "rests-connected"]
    assert stats.simulated == 0 and stats.compiles == 0


def test_a_scene_mjx_refuses_falls_back_to_mujoco_c(monkeypatch):
    from mujoco import mjx  # lazy: mujoco.mjx imports JAX, an optional extra

    def refuse(*_, **__):
        raise NotImplementedError("not in MJX")

    monkeypatch.setattr(mjx, "put_model", refuse)
    s = tower()
    stats = MjxStats()
    (got,) = settle_many([(s, part("3001"), Pose(I3, [50, -78, 0]), None)], stats=stats)
    assert got.outcome == "fell-off" and stats.fallbacks == 1 and stats.refused == ["not in MJX"]


def test_batch_sizes_are_powers_of_two():
    assert [settle_mjx._bucket(n) for n in (1, 2, 3, 5, 9)] == [1, 2, 4, 8, 16]


def _gpus() -> list:
    import jax

    try:
        return jax.devices("gpu")
    except RuntimeError:  # no CUDA build, or no device it can open
        return []


# On JAX's CPU backend each scene compiles for 3-10 minutes here (two of these cases took 489 s,
# 465 of them compiling): the simulated cases run where a GPU is.
@pytest.mark.slow
@pytest.mark.gpu
@pytest.mark.skipif(not _gpus(), reason="MJX scenes compile for minutes on JAX's CPU backend: run with a GPU")
def test_mjx_and_mujoco_c_agree_on_the_simulated_hand_built_cases():
    brick = part("3001")
    p, t, one = plate(), tower(), Structure([at("3001", 0, 0, 0)])
    cases = [(p, brick, Pose(I3, [0, -54, 0]), None),  # dropped onto the plate: snaps
             (p, brick, Pose(rotation_about((0, 1, 0), 45), [0, -54, 0]), None),  # turned: rests on the studs
             (p, brick, Pose(I3, [3, -40, -2]), None),  # lifted and shifted: snaps on the way down
             (t, brick, Pose(I3, [50, -78, 0]), None),  # half off the tower: falls
             (one, brick, Pose(rotation_about((0, 1, 0), 30), [0, 0, 55]), None)]  # pushed out
    got, stats = _same(cases)
    assert [g.outcome for g in got] == ["rests-connected", "rests-unconnected", "rests-connected", "fell-off",
                                        "pushed-out"]
    assert stats.scenes == 3 and stats.fallbacks == 0
