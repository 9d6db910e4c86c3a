"""The isolated arm client: moves, and every failure becomes an ArmError, never a hang."""

from __future__ import annotations

import time

import numpy as np
import pytest

from tof_mpd_ros.arm import ur5e
from tof_mpd_ros.arm.isolated import IsolatedArm
from tof_mpd_ros.errors import ArmError
from tof_mpd_ros.pose import matrix_to_pose_vector, pose_vector_to_matrix

# A child interpreter starts in about a second on an idle machine, far slower on a busy one: tests
# that do not test the connect timeout give it this long.
START_S = 120.0


def reachable_pose(dz: float = 0.0) -> np.ndarray:
    joints = ur5e.HOME_JOINTS + np.array([0.2, 0.1, -0.2, 0.1, 0.05, 0.3])
    pose = ur5e.forward_kinematics(joints)
    pose[2, 3] += dz
    return pose


def test_pose_vector_round_trip() -> None:
    pose = reachable_pose()
    np.testing.assert_allclose(pose_vector_to_matrix(matrix_to_pose_vector(pose)), pose,
                               atol=1e-12)


def test_simulated_arm_moves_to_the_commanded_pose() -> None:
    with IsolatedArm("sim", connect_timeout_s=START_S) as arm:
        for dz in (0.0, 0.05):
            arm.move_to(reachable_pose(dz))
            np.testing.assert_allclose(arm.tcp_pose(), reachable_pose(dz), atol=1e-9)
        assert arm.status()["connected"] is True


def test_unreachable_pose_is_an_error_and_the_arm_stays_usable() -> None:
    far = np.eye(4)
    far[:3, 3] = [3.0, 0.0, 0.5]  # 3 m away: beyond a UR5e's ~0.85 m reach
    with IsolatedArm("sim", connect_timeout_s=START_S) as arm:
        with pytest.raises(ArmError, match="unreachable"):
            arm.move_to(far)
        assert arm.alive
        arm.move_to(reachable_pose())


def test_hanging_connect_times_out_and_kills_the_client() -> None:
    start = time.monotonic()
    with pytest.raises(ArmError, match="connect timed out"):
        IsolatedArm("sim", connect_timeout_s=3.0, faults={"hang_on_connect": True})
    # The client hangs for an hour: returning at all shows the timeout; the bound is generous
    # for a busy machine (the kill and the join take seconds there).
    assert time.monotonic() - start < 120.0


def test_client_crash_mid_plan_is_reported_with_its_exit_code() -> None:
    arm = IsolatedArm("sim", connect_timeout_s=START_S, faults={"crash_on_move": 2})
    arm.move_to(reachable_pose())
    with pytest.raises(ArmError, match=r"died during move_l \(exit code 134"):
        arm.move_to(reachable_pose(0.02))
    assert not arm.alive
    with pytest.raises(ArmError, match="not running"):
        arm.tcp_pose()
    arm.close()


def test_hanging_move_times_out() -> None:
    with IsolatedArm("sim", connect_timeout_s=START_S, call_timeout_s=2.0,
                     faults={"hang_on_move": 1}) as arm:
        with pytest.raises(ArmError, match="move_l timed out"):
            arm.move_to(reachable_pose())
        assert not arm.alive


def test_protective_stop_is_an_error_with_status() -> None:
    with IsolatedArm("sim", connect_timeout_s=START_S,
                     faults={"protective_stop_on_move": 1}) as arm:
        with pytest.raises(ArmError, match="protective stop"):
            arm.move_to(reachable_pose())
        assert arm.status()["protective_stopped"] is True


def test_ur_rtde_against_no_controller_fails_cleanly() -> None:
    pytest.importorskip("rtde_control")
    start = time.monotonic()
    with pytest.raises(ArmError, match="connect"):
        IsolatedArm("ur_rtde", connect_timeout_s=10.0, host="127.0.0.1")
    assert time.monotonic() - start < 120.0  # refused at once, or the 10 s timeout: no hang


def test_unknown_backend() -> None:
    with pytest.raises(ArmError, match="unknown arm backend"):
        IsolatedArm("kuka")
