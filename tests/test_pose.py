"""Property tests for Pose: LDraw lines, MuJoCo's frame, composition and inversion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.pose import LDRAW_TO_MUJOCO, LDU_M, Pose


@st.composite
def rotations(draw):
    q = np.array(draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4)))
    if np.linalg.norm(q) < 1e-3:
        q = np.array([1.0, 0, 0, 0])
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


translations = st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3).map(np.array)
poses = st.builds(Pose, rotations(), translations)


@given(poses)
def test_ldraw_numbers_round_trip(p):
    assert Pose.from_ldraw(p.to_ldraw()).allclose(p)


@given(poses)
@settings(max_examples=50)
def test_ldraw_line_round_trip(p):
    colour, back, name = Pose.from_ldraw_line(p.to_ldraw_line(4, "3001.dat"))
    assert colour == 4 and name == "3001.dat" and back.allclose(p, atol=1e-5)


@given(poses)
def test_mujoco_round_trip_and_rotation_stays_proper(p):
    pos, rot = p.to_mujoco()
    assert np.allclose(rot @ rot.T, np.eye(3)) and np.linalg.det(rot) == pytest.approx(1.0)
    assert Pose.from_mujoco(pos, rot).allclose(p, atol=1e-6)


@given(poses)
def test_quaternion_matches_matrix(p):
    _, q = p.to_mujoco_quat()
    _, rot = p.to_mujoco()
    w, x, y, z = q
    from_q = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    assert np.allclose(from_q, rot, atol=1e-9) and w >= 0


@given(poses, poses, st.lists(st.floats(-100, 100), min_size=3, max_size=3))
def test_composition_applies_in_order_and_inverse_undoes(a, b, point):
    p = np.array(point)
    assert np.allclose((a @ b).apply(p), a.apply(b.apply(p)), atol=1e-6)
    assert (a @ a.inverse()).allclose(Pose.identity(), atol=1e-6)


@given(poses, st.lists(st.floats(-100, 100), min_size=3, max_size=3))
def test_mujoco_frame_maps_points_the_same_way(p, point):
    """A point placed in LDraw, then converted, equals the point converted then placed in MuJoCo."""
    pos, rot = p.to_mujoco()
    local_mj = LDRAW_TO_MUJOCO @ np.array(point) * LDU_M
    world_ld = p.apply(point)
    assert np.allclose(rot @ local_mj + pos, LDRAW_TO_MUJOCO @ world_ld * LDU_M, atol=1e-9)


def test_ldraw_up_is_mujoco_z_and_units_are_metres():
    pos, rot = Pose(np.eye(3), [20.0, -24.0, 0.0]).to_mujoco()
    assert np.allclose(pos, [0.008, 0.0, 0.0096])
    assert np.allclose(LDRAW_TO_MUJOCO @ [0, -1, 0], [0, 0, 1])
    assert np.allclose(rot, np.eye(3))


def test_pose_is_immutable():
    p = Pose.identity()
    with pytest.raises(ValueError):
        p.t[0] = 1.0
    with pytest.raises(Exception):
        p.t = np.zeros(3)


def test_bad_type1_line_is_refused():
    with pytest.raises(ValueError, match="type 1 line"):
        Pose.from_ldraw_line("3 16 0 0 0 1 0 0 0 1 0")


@given(poses, st.lists(st.floats(-100, 100), min_size=3, max_size=3))
def test_points_to_mujoco_agrees_with_pose_conversion(p, point):
    from factory.pose import points_to_mujoco

    pos, rot = p.to_mujoco()
    assert np.allclose(points_to_mujoco(p.apply(point)), rot @ points_to_mujoco(point) + pos, atol=1e-9)
