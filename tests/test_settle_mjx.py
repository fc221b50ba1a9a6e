"""The batched settling on MuJoCo Warp (`factory.physics.settle_mjx.settle_many`) against the
MuJoCo C reference (`settle.settle`) on the hand-built cases of tests/test_settle.py. Cases decided
before simulating (inside another part, snapped, exactly right) never reach Warp; the simulated
ones run Warp's kernels on its CPU device where there is no GPU (the first run in a fresh cache
compiles them: about a minute here, marked slow)."""

from __future__ import annotations

import numpy as np
import pytest

from factory import Pose
from factory.pose import LDU_M, points_to_mujoco
from factory.physics import settle_mjx
from factory.physics.settle import settle
from factory.physics.settle_mjx import MjxStats, settle_many
from factory.physics.snap import SnapRule, SnapTargets
from factory.physics.structure import Structure
from factory.symmetry import rotation_about
from ldraw_support import at, part
from test_settle import I3, SEATED, plate, tower

pytest.importorskip("warp")
pytestmark = pytest.mark.usefixtures("isolated_cache")


def _same(cases):
    stats = MjxStats()
    got = settle_many(cases, stats=stats)
    for (s, p, pose, floor), g in zip(cases, got):
        ref = settle(s, p, pose, floor)
        assert g.outcome == ref.outcome, (pose.t, g, ref)
        assert g.connections == ref.connections
        if g.outcome == "rests-connected" or ref.seconds == 0.0:  # a connection's pose, or never simulated
            assert np.allclose(g.pose.t, ref.pose.t, atol=1.0), (g, ref)
        elif g.outcome == "fell-off":  # both on the table; where a tumbling part lands differs between engines
            assert abs(g.pose.t[1] - ref.pose.t[1]) < 1.0, (g, ref)
    return got, stats


def test_cases_decided_before_simulating_agree_without_warp():
    brick, one = part("3001"), Structure([at("3001", 0, 0, 0)])
    p = plate()
    cases = [(one, brick, Pose(I3, [0, 0, 0]), None),  # inside: collides
             (p, brick, Pose(I3, [2, -24, 0]), None),  # 2 LDU off: snaps
             (p, brick, SEATED, None),  # exactly right
             (p, brick, Pose(I3, [-1.5, -25, 1]), None)]  # near a connection
    got, stats = _same(cases)
    assert [g.outcome for g in got] == ["collides", "rests-connected", "rests-connected", "rests-connected"]
    assert stats.simulated == 0 and stats.batches == 0


def test_a_batch_warp_refuses_falls_back_to_mujoco_c(monkeypatch):
    _, mjw = settle_mjx._warp()

    def refuse(*_, **__):
        raise NotImplementedError("not in MuJoCo Warp")

    monkeypatch.setattr(mjw, "put_model", refuse)
    stats = MjxStats()
    (got,) = settle_many([(tower(), part("3001"), Pose(I3, [50, -78, 0]), None)], stats=stats)
    assert got.outcome == "fell-off" and stats.fallbacks == 1 and stats.refused == ["not in MuJoCo Warp"]


def test_slot_counts_are_the_least_bucket_that_holds_the_scene():
    assert [settle_mjx._bucket(n, settle_mjx.PART_SLOTS) for n in (1, 4, 5, 17)] == [4, 4, 8, 32]
    with pytest.raises(ValueError, match="more than the largest slot count"):
        settle_mjx._bucket(settle_mjx.STRUCTURE_SLOTS[-1] + 1, settle_mjx.STRUCTURE_SLOTS)


@pytest.mark.slow
def test_warp_and_mujoco_c_agree_on_the_simulated_hand_built_cases_in_one_batch():
    brick = part("3001")
    p, t, one = plate(), tower(), Structure([at("3001", 0, 0, 0)])
    cases = [(p, brick, Pose(I3, [0, -54, 0]), None),  # dropped onto the plate: snaps
             (p, brick, Pose(rotation_about((0, 1, 0), 45), [0, -54, 0]), None),  # turned: rests on the studs
             (p, brick, Pose(I3, [2, -40, -1]), None),  # lifted, 2.2 LDU across: snaps on the way down
             (t, brick, Pose(I3, [50, -78, 0]), None),  # half off the tower: falls
             (one, brick, Pose(rotation_about((0, 1, 0), 30), [0, 0, 55]), None),  # pushed out
             (p, brick, Pose(rotation_about((0, 1, 0), 45), [0, -25.5, 0]), None)]  # pushed up onto the studs
    got, stats = _same(cases)
    assert [g.outcome for g in got] == ["rests-connected", "rests-unconnected", "rests-connected", "fell-off",
                                        "pushed-out", "pushed-out"]
    # Three scenes, one model: the worlds of a batch hold different structures and parts.
    assert stats.batches == 1 and stats.fallbacks == 0 and stats.simulated >= 3
    assert stats.contacts_dropped == 0


def test_a_world_whose_part_stops_takes_the_next_case():
    # Two worlds for five simulated cases: each world is cleared and takes the next case when its
    # part stops (snapped, at rest or out of time); every case ends as it does with a world each.
    brick = part("3001")
    p, t, one = plate(), tower(), Structure([at("3001", 0, 0, 0)])
    cases = [(p, brick, Pose(I3, [0, -54, 0]), None),
             (t, brick, Pose(I3, [50, -78, 0]), None),
             (p, brick, Pose(rotation_about((0, 1, 0), 45), [0, -54, 0]), None),
             (one, brick, Pose(rotation_about((0, 1, 0), 30), [0, 0, 55]), None),
             (p, brick, Pose(I3, [2, -40, -1]), None)]
    alone, refilled = MjxStats(), MjxStats()
    each = settle_many(cases, stats=alone)
    two = settle_many(cases, stats=refilled, batch=2)
    assert alone.simulated == refilled.simulated == 5 and refilled.fallbacks == 0
    assert refilled.batches == 1  # the five cases ran on the one model's two worlds
    assert [g.outcome for g in two] == [g.outcome for g in each]
    for a, b in zip(two, each):
        assert abs(a.seconds - b.seconds) < 1e-9 and np.allclose(a.pose.t, b.pose.t, atol=0.5), (a, b)


@pytest.mark.slow
def test_a_part_whose_centre_of_mass_is_off_its_origin_falls_without_turning():
    # A 45-degree slope's centre of mass lies 13 LDU below and 6 LDU behind its origin. Dropped
    # 40 LDU onto the table beside the plate, it falls straight and lands as it was released, on
    # both engines (Warp once turned such a part in the air: its template's inertia sat at the
    # body's origin, and Warp took that for every world).
    slope = part("3040b")
    pose = Pose(I3, [200, -40, 0])
    (got,), _ = _same([(plate(), slope, pose, None)])
    assert got.outcome == "fell-off"
    assert np.allclose(got.pose.R, pose.R, atol=1e-3), got.pose.R
    assert np.allclose(got.pose.t[[0, 2]], pose.t[[0, 2]], atol=0.1)
    assert got.pose.t[1] == pytest.approx(-16.0, abs=0.6)  # on the table (y 8), the slope 24 LDU tall


def test_a_world_whose_state_diverges_is_settled_on_mujoco_c(monkeypatch):
    # A Warp world can blow up (its solver out of constraint rows): its state turns NaN. That case
    # is run again on the reference instead of failing the batch, and counted.
    wp, mjw = settle_mjx._warp()
    real = mjw.step

    def blows_up(m, d):
        real(m, d)
        q = d.qpos.numpy()
        q[0, 0] = np.nan
        d.qpos.assign(wp.array(q, dtype=d.qpos.dtype))

    monkeypatch.setattr(mjw, "step", blows_up)
    case = (plate(), part("3001"), Pose(rotation_about((0, 1, 0), 45), [0, -54, 0]), None)
    stats = MjxStats()
    (got,) = settle_many([case], stats=stats, device="cpu")
    assert stats.diverged == 1 and stats.fallbacks == 1
    ref = settle(*case[:3])
    assert got.outcome == ref.outcome == "rests-unconnected" and got.pose.allclose(ref.pose)


def test_the_device_prefilter_passes_the_paths_the_reference_one_passes():
    # The batch tests every world's chunk path against its candidates at once on the device
    # (`near`); the host sweeps only the worlds it flags, so it must flag every path that
    # `SnapTargets.along` passes (by its float32 margin of 1e-3 LDU it may pass a few more).
    wp, _ = settle_mjx._warp()
    _, _, near = settle_mjx._kernels()
    targets, rule = SnapTargets.of(plate(), part("3001")), SnapRule()
    rng = np.random.default_rng(3)
    n, k = 96, 10
    start = rng.uniform([-60, -70, -40], [60, -5, 40], size=(n, 3))
    path = np.concatenate([start[None], start[None] + np.cumsum(rng.normal(scale=4.0, size=(k, n, 3)), axis=0)])
    want = [targets.along(path[:, w], rule) for w in range(n)]
    # Every world its own case, all of them with the same candidates (one stretch of `target`).
    case, first, count = np.arange(n, dtype=np.int32), np.zeros(n, np.int32), np.full(n, len(targets.t), np.int32)
    target = points_to_mujoco(targets.t).astype(np.float32)
    reach = np.full(n, (targets.reach(rule) + 1e-3) * LDU_M, np.float32)
    flag = wp.zeros(n, dtype=wp.int32, device="cpu")
    arrays = [wp.array(x, dtype=wp.int32, device="cpu") for x in (case, first, count)]
    wp.launch(near, dim=n, device="cpu",
              inputs=[wp.array(points_to_mujoco(path).astype(np.float32), dtype=wp.vec3, device="cpu"), k, *arrays,
                      wp.array(target, dtype=wp.vec3, device="cpu"), wp.array(reach, dtype=wp.float32, device="cpu"),
                      flag])
    assert 10 < sum(want) < n - 10  # paths of both kinds
    assert flag.numpy().astype(bool).tolist() == want
