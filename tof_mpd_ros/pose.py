"""Rigid poses and their conversions: the package's one module for them (the simulator, the
collection, the recordings, the nodes and the mismatch tool all use it).

A pose is a (4, 4) float64 homogeneous matrix ``T_a_b`` that maps coordinates in frame ``b`` to
frame ``a`` (``p_a = T_a_b @ p_b``). Inside the simulator geometry is in **millimetres**; poses
that face ROS (``ToFFrame.pose``, ``PoseStamped``, the UR5e kinematics) are in **metres**.
:func:`pose_m_to_mm` and :func:`pose_mm_to_m` convert the translation only.

Other forms of a rotation, all through scipy's :class:`~scipy.spatial.transform.Rotation`:
rotation vectors (axis × angle, rad; :func:`rotvec_to_matrix`, :func:`matrix_to_rotvec`), UR pose
vectors ``[x, y, z, rx, ry, rz]`` (:func:`pose_vector_to_matrix`, :func:`matrix_to_pose_vector`)
and ROS quaternions ``(x, y, z, w)`` (:func:`pose_from_quaternion`, :func:`quaternion_xyzw`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .validation import check_array

MM_PER_M = 1000.0


def make_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Assemble a pose.

    Args:
        rotation: (3, 3) float rotation matrix.
        translation: (3,) float translation (any length unit; the pose keeps it).

    Returns:
        (4, 4) float64 homogeneous transform.
    """
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = translation
    return pose


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) transform, computed as ``[R^T, -R^T t]`` (exact, no solve)."""
    p = check_array("pose", pose, ndim=2, shape=(4, 4), dtype_kind="fiu")
    rot = p[:3, :3].T
    return make_pose(rot, -rot @ p[:3, 3])


def pose_m_to_mm(pose_m: np.ndarray) -> np.ndarray:
    """(4, 4) pose with translation in metres -> same pose with translation in millimetres."""
    p = check_array("pose_m", pose_m, ndim=2, shape=(4, 4), dtype_kind="fiu").astype(np.float64)
    p[:3, 3] *= MM_PER_M
    return p


def pose_mm_to_m(pose_mm: np.ndarray) -> np.ndarray:
    """(4, 4) pose with translation in millimetres -> same pose with translation in metres."""
    p = check_array("pose_mm", pose_mm, ndim=2, shape=(4, 4), dtype_kind="fiu").astype(np.float64)
    p[:3, 3] /= MM_PER_M
    return p


def rot_x(angle_rad: float) -> np.ndarray:
    """(3, 3) rotation about x by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    """(3, 3) rotation about y by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    """(3, 3) rotation about z by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """Camera-to-world pose of an optical-frame camera at ``eye`` looking at ``target``.

    The optical frame is x right, y down, z forward (REP 103). With ``roll_rad = 0`` the image
    x axis is horizontal (perpendicular to world z); ``roll_rad`` then turns the camera about its
    optical axis (an in-plane rotation of the image).

    Args:
        eye: (3,) camera centre in world coordinates (any length unit, kept in the pose).
        target: (3,) point the optical axis passes through, same unit.
        roll_rad: in-plane rotation about the optical axis, radians.

    Returns:
        (4, 4) float64 camera-to-world transform.
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    # Any horizontal x works; choose one that is well defined even when looking straight down.
    ref = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x = np.cross(z, ref) if abs(z[2]) < 0.99 else np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z], axis=1) @ rot_z(roll_rad)
    return make_pose(rot, eye)


def rotate(vectors: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Apply a (3, 3) matrix to each of (..., 3) vectors (``rot @ v``); returns float64.

    Written with ``einsum`` on purpose: ``matmul`` hands a 3-wide product to multithreaded
    BLAS, which is several times slower for millions of rays (and far slower on a busy CPU).
    """
    v = np.asarray(vectors, dtype=np.float64)
    return np.einsum("nj,ij->ni", v.reshape(-1, 3), rot).reshape(v.shape)


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a pose to points.

    Args:
        pose: (4, 4) transform ``T_a_b``.
        points: (..., 3) points in frame ``b``, same length unit as the pose translation.

    Returns:
        (..., 3) float64 points in frame ``a``.
    """
    return rotate(points, pose[:3, :3]) + pose[:3, 3]


# ---------------------------------------------------------------------------------------------
# rotation vectors, UR pose vectors, quaternions


def rotvec_to_matrix(rotvec: np.ndarray | Sequence[float]) -> np.ndarray:
    """(3, 3) float64 rotation of a (3,) rotation vector (unit axis × angle in rad)."""
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_matrix()


def matrix_to_rotvec(rotation: np.ndarray) -> np.ndarray:
    """(3,) float64 rotation vector (axis × angle, angle in [0, π]) of a (3, 3) rotation, or of
    the rotation part of a (4, 4) pose."""
    return Rotation.from_matrix(np.asarray(rotation, dtype=np.float64)[:3, :3]).as_rotvec()


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in rad (0 to π) of the rotation between two orientations, each a (3, 3) rotation
    or a (4, 4) pose (translations are ignored)."""
    cos = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_vector_to_matrix(pose: np.ndarray | Sequence[float]) -> np.ndarray:
    """UR pose vector ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad) -> (4, 4) float64
    transform (translation in metres)."""
    v = check_array("pose", pose, ndim=1, shape=(6,), dtype_kind="fiu").astype(np.float64)
    return make_pose(rotvec_to_matrix(v[3:]), v[:3])


def matrix_to_pose_vector(matrix: np.ndarray) -> np.ndarray:
    """(4, 4) transform (metres) -> (6,) float64 UR pose vector ``[x, y, z, rx, ry, rz]``."""
    m = check_array("matrix", matrix, ndim=2, shape=(4, 4), dtype_kind="fiu").astype(np.float64)
    return np.concatenate([m[:3, 3], matrix_to_rotvec(m)])


def pose_from_quaternion(translation: Sequence[float], quat_xyzw: Sequence[float]) -> np.ndarray:
    """(4, 4) float64 transform from a translation and a ROS ``(x, y, z, w)`` quaternion (any
    norm but zero; scipy normalises it).

    Raises:
        ValueError: a zero-norm or non-finite quaternion (scipy's error).
    """
    return make_pose(Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)).as_matrix(),
                     np.asarray(translation, dtype=np.float64))


def quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """(4,) float64 unit quaternion in ROS order ``(x, y, z, w)`` of a (3, 3) rotation or of the
    rotation part of a (4, 4) pose."""
    return Rotation.from_matrix(np.asarray(rotation, dtype=np.float64)[:3, :3]).as_quat()


def mean_pose(poses: Sequence[np.ndarray] | np.ndarray) -> np.ndarray:
    """(4, 4) chordal mean of (4, 4) poses: the mean rotation (quaternion average) and the mean
    translation (same unit as the poses)."""
    stack = np.asarray(poses, dtype=np.float64)
    rotation = Rotation.from_matrix(stack[:, :3, :3]).mean().as_matrix()
    return make_pose(rotation, stack[:, :3, 3].mean(axis=0))
