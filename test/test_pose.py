"""tof_mpd_ros.pose: the one module of pose conversions.

Each conversion that replaced a copy elsewhere is checked against that copy (kept here as the
reference) on random inputs: bit for bit where the new one runs the same scipy calls, within
float64 rounding where a hand-written Rodrigues formula gave way to scipy.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.pose import (
    make_pose,
    matrix_to_pose_vector,
    matrix_to_rotvec,
    mean_pose,
    pose_from_quaternion,
    pose_vector_to_matrix,
    quaternion_xyzw,
    rotation_angle,
    rotvec_to_matrix,
)

N = 200
EPS = 4 * np.finfo(np.float64).eps  # a few ulps of an entry of magnitude <= 1


# --- the copies these functions replaced --------------------------------------------------------

def rodrigues_reference(rotvec: np.ndarray) -> np.ndarray:
    """sim/tof/warp.rotation_matrix (the simulator's and the mismatch tool's copy)."""
    w = np.asarray(rotvec, dtype=np.float64)
    theta = float(np.linalg.norm(w))
    if theta < 1e-15:
        return np.eye(3)
    k = w / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * kx + (1.0 - np.cos(theta)) * kx @ kx


def axis_angle_reference(axis: np.ndarray, angle: float) -> np.ndarray:
    """sim/checkerboard._axis_angle (the calibration board's tilt)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def rigid_reference(matrix: np.ndarray) -> tuple[list[float], list[float]]:
    """recordings/convert._rigid and nodes/ros_messages.pose_message: matrix -> (t, xyzw)."""
    quat = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    return [float(v) for v in matrix[:3, 3]], [float(v) for v in quat]


def matrix_reference(translation: list[float], quat_xyzw: list[float]) -> np.ndarray:
    """recordings/convert._matrix and nodes/ros_messages.pose_matrix: (t, xyzw) -> matrix."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    out[:3, 3] = translation
    return out


def ur_reference(pose: np.ndarray) -> np.ndarray:
    """arm/ur_pose.pose_vector_to_matrix."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(pose[3:]).as_matrix()
    out[:3, 3] = pose[:3]
    return out


def angle_reference(a: np.ndarray, b: np.ndarray) -> float:
    """collection/session.matches and nodes/sim_cell_node._same_pose."""
    cos = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


# --- inputs --------------------------------------------------------------------------------------

def rotvecs(seed: int = 0) -> np.ndarray:
    """Random rotation vectors from tiny to near π (and zero)."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(N, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-16, 1e-12, 1e-8, 1e-4, math.pi - 1e-9],
                             rng.uniform(0.0, math.pi, N - 6)])
    return axes * angles[:, None]


def poses(seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([make_pose(rotvec_to_matrix(rv), rng.normal(scale=0.5, size=3))
                     for rv in rotvecs(seed)])


# --- against the replaced copies -----------------------------------------------------------------

def test_rotvec_to_matrix_matches_rodrigues_within_rounding() -> None:
    for rv in rotvecs():
        np.testing.assert_allclose(rotvec_to_matrix(rv), rodrigues_reference(rv), rtol=0,
                                   atol=EPS)


def test_axis_angle_matches_the_checkerboard_copy_within_rounding() -> None:
    rng = np.random.default_rng(2)
    for _ in range(N):
        a = rng.uniform(0.0, 2.0 * math.pi)
        axis = np.array([math.cos(a), math.sin(a), 0.0])
        angle = math.radians(40.0) * rng.uniform()
        np.testing.assert_allclose(rotvec_to_matrix(axis * angle),
                                   axis_angle_reference(axis, angle), rtol=0, atol=EPS)


def test_rotvec_to_matrix_matches_opencv_rodrigues_within_rounding() -> None:
    """collection/hand_eye_detect took solvePnP's rotation through cv2.Rodrigues."""
    for rv in rotvecs(3):
        np.testing.assert_allclose(rotvec_to_matrix(rv), cv2.Rodrigues(rv.reshape(3, 1))[0],
                                   rtol=0, atol=EPS)


def test_quaternions_are_bit_identical_to_the_replaced_copies() -> None:
    for pose in poses():
        t, q = rigid_reference(pose)
        np.testing.assert_array_equal(quaternion_xyzw(pose), q)
        np.testing.assert_array_equal(pose_from_quaternion(t, q), matrix_reference(t, q))


def test_ur_pose_vectors_are_bit_identical_to_the_replaced_copy() -> None:
    for pose in poses(4):
        vector = np.concatenate([pose[:3, 3], Rotation.from_matrix(pose[:3, :3]).as_rotvec()])
        np.testing.assert_array_equal(matrix_to_pose_vector(pose), vector)
        np.testing.assert_array_equal(pose_vector_to_matrix(vector), ur_reference(vector))


def test_rotation_angle_is_the_replaced_formula() -> None:
    a, b = poses(5), poses(6)
    for x, y in zip(a, b, strict=True):
        assert rotation_angle(x, y) == angle_reference(x, y)
        assert rotation_angle(x[:3, :3], y[:3, :3]) == angle_reference(x, y)


# --- properties ----------------------------------------------------------------------------------

def test_round_trips() -> None:
    for pose in poses(7):
        np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(pose)), pose[:3, :3],
                                   atol=1e-12)
        np.testing.assert_allclose(pose_vector_to_matrix(matrix_to_pose_vector(pose)), pose,
                                   atol=1e-12)
        np.testing.assert_allclose(pose_from_quaternion(pose[:3, 3], quaternion_xyzw(pose)),
                                   pose, atol=1e-12)


def test_small_hand_computed_values() -> None:
    quarter = rotvec_to_matrix([0.0, 0.0, math.pi / 2])
    np.testing.assert_allclose(quarter, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(quaternion_xyzw(quarter), [0, 0, math.sqrt(0.5), math.sqrt(0.5)],
                               atol=1e-15)
    assert rotation_angle(np.eye(3), quarter) == pytest.approx(math.pi / 2)
    np.testing.assert_array_equal(matrix_to_rotvec(np.eye(4)), np.zeros(3))


def test_mean_pose() -> None:
    pose = poses(8)[10]
    np.testing.assert_allclose(mean_pose([pose, pose, pose]), pose, atol=1e-12)
    a = make_pose(rotvec_to_matrix([0.0, 0.0, 0.2]), [0.0, 0.0, 0.0])
    b = make_pose(rotvec_to_matrix([0.0, 0.0, 0.4]), [2.0, 0.0, 0.0])
    np.testing.assert_allclose(mean_pose([a, b]),
                               make_pose(rotvec_to_matrix([0.0, 0.0, 0.3]), [1.0, 0.0, 0.0]),
                               atol=1e-12)


def test_bad_input_is_refused_with_the_name() -> None:
    with pytest.raises(InputError, match="pose"):
        pose_vector_to_matrix([1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="matrix"):
        matrix_to_pose_vector(np.eye(3))
    with pytest.raises(ValueError):
        pose_from_quaternion([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0])
