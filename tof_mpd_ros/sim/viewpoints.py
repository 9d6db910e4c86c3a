"""Viewpoint plans of simulated scenes: 18 reachable camera poses per scene, looking at the
objects, and the collector's plan of a simulated scene.

The planning itself is robot geometry (:func:`tof_mpd_ros.arm.viewpoints.plan_views`); this
module feeds it a :class:`~.scene.Scene`'s objects' centroid, highest top and table height.

Units: camera poses in the plan are camera-to-base with translations in **mm**
(``camera_to_base_mm``; ``camera_to_base_m`` gives metres for ROS); joints in radians.
"""

from __future__ import annotations

import numpy as np

from ..arm.ur5e import UR5E, URParams
from ..arm.viewpoints import ViewpointConfig, ViewpointPlan, plan_views
from ..collection.plan import PlannedView
from ..pose import invert_pose, pose_mm_to_m
from .scene import Scene, make_scene


def plan_viewpoints(scene: Scene, rng: np.random.Generator,
                    config: ViewpointConfig | None = None,
                    params: URParams = UR5E) -> ViewpointPlan:
    """``config.n_views`` reachable views of ``scene`` (base frame, mm) looking at its objects'
    centroid: :func:`~tof_mpd_ros.arm.viewpoints.plan_views` (its arguments, result and errors)
    on the scene's geometry; ``config`` None = the default
    :class:`~tof_mpd_ros.arm.viewpoints.ViewpointConfig`.
    """
    return plan_views(scene.objects_centroid_mm(), scene.top_height_mm(), scene.table.height_mm,
                      rng, ViewpointConfig() if config is None else config, params)


def sim_plan(seed: int, split: str, scene: int, views: int,
             hand_eye_m: np.ndarray) -> list[PlannedView]:
    """The collector's plan of a simulated scene (the same scene the ``sim_cell`` node renders).

    Args:
        seed, split, scene: the scene, as :func:`~.dataset.scene_rng` draws it.
        views: the first this many views of its plan.
        hand_eye_m: (4, 4) ToF camera pose in the flange frame, metres.

    Returns:
        The views as commanded TCP (flange) poses in the base frame, metres.
    """
    from .dataset import scene_rng  # .dataset imports this module

    rng = scene_rng(seed, split, scene)
    scene_obj = make_scene(split, rng)
    plan = plan_viewpoints(scene_obj, rng, ViewpointConfig(t_flange_camera_m=hand_eye_m))
    to_flange = invert_pose(hand_eye_m)
    return [PlannedView(i, pose_mm_to_m(v.camera_to_base_mm) @ to_flange)
            for i, v in enumerate(plan.viewpoints[:views])]
