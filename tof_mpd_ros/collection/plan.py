"""Collection plans: the TCP poses the arm visits, in order."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from ..pose import invert_pose, matrix_to_pose_vector, pose_mm_to_m, pose_vector_to_matrix


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


def sim_plan(seed: int, split: str, scene: int, views: int,
             hand_eye_m: np.ndarray) -> list[PlannedView]:
    """The viewpoint plan of a simulated scene (the same scene the ``sim_cell`` node renders)."""
    from ..sim.dataset import scene_rng
    from ..sim.scene import make_scene
    from ..sim.viewpoints import ViewpointConfig, plan_viewpoints

    rng = scene_rng(seed, split, scene)
    scene_obj = make_scene(split, rng)
    plan = plan_viewpoints(scene_obj, rng, ViewpointConfig(t_flange_camera_m=hand_eye_m))
    to_flange = invert_pose(hand_eye_m)
    return [PlannedView(i, pose_mm_to_m(v.camera_to_base_mm) @ to_flange)
            for i, v in enumerate(plan.viewpoints[:views])]


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
