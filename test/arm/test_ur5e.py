"""UR5e kinematics: hand-checked poses, FK(IK(T)) == T, seed selection, hand-eye, units."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tof_mpd_ros.arm.tool import DEFAULT_T_FLANGE_CAMERA_M
from tof_mpd_ros.arm.ur5e import (
    HOME_JOINTS,
    UR5E,
    URParams,
    camera_pose,
    flange_pose_for_camera,
    forward_kinematics,
    inverse_kinematics,
    solve_ik,
)
from tof_mpd_ros.errors import ArmError
from tof_mpd_ros.pose import make_pose, pose_m_to_mm, pose_mm_to_m, rot_x


def test_zero_joints_by_hand() -> None:
    # All joints at 0: the arm lies stretched along -x; the tool axis points along -y.
    expected = np.array([[1.0, 0.0, 0.0, UR5E.a2 + UR5E.a3],
                         [0.0, 0.0, -1.0, -(UR5E.d4 + UR5E.d6)],
                         [0.0, 1.0, 0.0, UR5E.d1 - UR5E.d5],
                         [0.0, 0.0, 0.0, 1.0]])
    np.testing.assert_allclose(forward_kinematics(np.zeros(6)), expected, atol=1e-15)
    np.testing.assert_allclose(expected[:3, 3], [-0.8172, -0.2329, 0.0628], atol=1e-12)


def test_home_pose_by_hand() -> None:
    # Upper arm vertical, forearm horizontal towards +x, tool pointing straight down.
    pose = forward_kinematics(HOME_JOINTS)
    np.testing.assert_allclose(pose[:3, 3], [-UR5E.a3 + UR5E.d5, UR5E.d4,
                                             UR5E.d1 - UR5E.a2 - UR5E.d6], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)


def test_shoulder_pan_turns_the_whole_arm() -> None:
    q = np.array([0.3, -1.2, 1.5, -0.8, 1.1, 0.4])
    turned = q + np.array([0.7, 0, 0, 0, 0, 0])
    rz = make_pose(np.array([[math.cos(0.7), -math.sin(0.7), 0], [math.sin(0.7), math.cos(0.7), 0],
                             [0, 0, 1.0]]), np.zeros(3))
    np.testing.assert_allclose(forward_kinematics(turned), rz @ forward_kinematics(q), atol=1e-14)


def test_fk_of_every_ik_solution_is_the_pose() -> None:
    rng = np.random.default_rng(7)
    counts = []
    for _ in range(300):
        q = rng.uniform(-math.pi, math.pi, 6)
        target = forward_kinematics(q)
        solutions = inverse_kinematics(target)
        counts.append(len(solutions))
        assert len(solutions) >= 1
        for sol in solutions:
            np.testing.assert_allclose(forward_kinematics(sol), target, atol=1e-9)
        # The configuration we started from is among them (modulo 2 pi).
        wrapped = np.angle(np.exp(1j * (solutions - q)))
        assert np.abs(wrapped).max(axis=1).min() < 1e-7
    assert max(counts) == 8 and np.mean(np.array(counts) == 8) > 0.5


def test_solve_ik_returns_the_seeded_configuration() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = rng.uniform(-math.pi, math.pi, 6)
        q[2] = rng.uniform(0.3, 2.5) * rng.choice([-1, 1])  # away from the elbow singularity
        q[4] = rng.uniform(0.3, 2.8) * rng.choice([-1, 1])  # away from the wrist singularity
        found = solve_ik(forward_kinematics(q), seed=q + 0.05)
        np.testing.assert_allclose(found, q, atol=1e-7)
        assert np.all(found >= np.array(UR5E.lower)) and np.all(found <= np.array(UR5E.upper))


def test_unreachable_and_limited_poses_raise_arm_error() -> None:
    far = make_pose(rot_x(math.pi), np.array([1.5, 0.0, 0.3]))
    assert inverse_kinematics(far).shape == (0, 6)
    with pytest.raises(ArmError, match="reach"):
        solve_ik(far)
    reachable = forward_kinematics(np.array([0.2, -1.0, 1.2, -1.5, 1.0, 0.0]))
    tight = URParams(lower=(-0.1,) * 6, upper=(0.1,) * 6)
    with pytest.raises(ArmError, match="joint limits"):
        solve_ik(reachable, params=tight)


def test_hand_eye_and_unit_helpers() -> None:
    q = np.array([2.9, -1.4, 1.4, -1.6, -1.6, 0.5])
    cam = camera_pose(q)
    flange = forward_kinematics(q)
    # The camera sits 60 mm along the tool z axis and looks along it.
    np.testing.assert_allclose(cam[:3, 3], flange[:3, 3] + 0.060 * flange[:3, 2], atol=1e-15)
    np.testing.assert_allclose(cam[:3, 2], flange[:3, 2], atol=1e-15)
    np.testing.assert_allclose(flange_pose_for_camera(cam), flange, atol=1e-15)
    np.testing.assert_allclose(solve_ik(flange_pose_for_camera(cam), seed=q), q, atol=1e-8)
    in_mm = pose_m_to_mm(cam)
    np.testing.assert_allclose(in_mm[:3, 3], 1000.0 * cam[:3, 3])
    np.testing.assert_allclose(in_mm[:3, :3], cam[:3, :3])
    np.testing.assert_allclose(pose_mm_to_m(in_mm), cam, atol=1e-15)
    assert DEFAULT_T_FLANGE_CAMERA_M[2, 3] == pytest.approx(0.060)
