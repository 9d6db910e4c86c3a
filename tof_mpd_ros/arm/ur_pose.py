"""UR pose vectors ``[x, y, z, rx, ry, rz]`` (metres, axis-angle radians) <-> 4x4 transforms."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..validation import check_array


def pose_vector_to_matrix(pose: np.ndarray | list[float]) -> np.ndarray:
    """UR pose vector -> (4, 4) float64 transform (translation in metres)."""
    v = check_array("pose", pose, ndim=1, shape=(6,), dtype_kind="fiu").astype(np.float64)
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(v[3:]).as_matrix()
    out[:3, 3] = v[:3]
    return out


def matrix_to_pose_vector(matrix: np.ndarray) -> np.ndarray:
    """(4, 4) transform (metres) -> (6,) float64 UR pose vector."""
    m = check_array("matrix", matrix, ndim=2, shape=(4, 4), dtype_kind="fiu").astype(np.float64)
    return np.concatenate([m[:3, 3], Rotation.from_matrix(m[:3, :3]).as_rotvec()])
