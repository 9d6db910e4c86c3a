"""Collection plans: the TCP poses the arm visits, in order (a plan file; the simulator's plan of
a simulated scene is :func:`tof_mpd_ros.sim.viewpoints.sim_plan`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from ..pose import matrix_to_pose_vector, pose_vector_to_matrix


@dataclass(frozen=True, eq=False)
class PlannedView:
    """One viewpoint: ``index`` in the plan and the commanded TCP pose.

    Attributes:
        index: position in the plan.
        tcp_to_base_m: (4, 4) float64 TCP (flange) pose in the base frame, metres.
    """

    index: int
    tcp_to_base_m: np.ndarray

    def camera_to_base_m(self, hand_eye_m: np.ndarray) -> np.ndarray:
        """(4, 4) camera pose in the base frame, metres, through the hand-eye transform."""
        return self.tcp_to_base_m @ hand_eye_m


def load_plan(path: str | Path) -> list[PlannedView]:
    """A plan from YAML: ``views: [[x, y, z, rx, ry, rz], ...]`` UR pose vectors (m, rad)."""
    try:
        document = yaml.safe_load(Path(path).read_text())
        vectors = np.asarray(document["views"], dtype=np.float64)
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as err:
        raise InputError(f"{path}: not a plan file (expected 'views: [[x, y, z, rx, ry, rz], "
                         f"...]'): {err}") from err
    if vectors.ndim != 2 or vectors.shape[1] != 6 or len(vectors) == 0:
        raise InputError(f"{path}: views must be a non-empty list of 6-vectors, got shape "
                         f"{vectors.shape}")
    return [PlannedView(i, pose_vector_to_matrix(v)) for i, v in enumerate(vectors)]


def save_plan(path: str | Path, plan: list[PlannedView]) -> None:
    """Write a plan as YAML UR pose vectors (inverse of :func:`load_plan`)."""
    views = [matrix_to_pose_vector(v.tcp_to_base_m).tolist() for v in plan]
    Path(path).write_text(yaml.safe_dump({"views": views}))
