"""Viewpoint plans: reachable camera poses looking at a point of the table, for the UR5e.

As in the paper, the camera is 180-350 mm above the objects (here: above the highest object
top) and looks at the objects' centroid from varied distances, azimuths, tilts (<= 30 degrees
from vertical) and in-plane rotations. The views are stratified (height bands x azimuth sectors)
so a plan always spans the whole range. Every candidate is checked with the UR5e inverse
kinematics and for table clearance (:func:`reach_camera_pose`, also the hand–eye plan's check);
a rejected candidate is recorded with its reason and replaced by a new draw for the same slot,
never silently dropped. Only geometry: the simulator's
:func:`~tof_mpd_ros.sim.viewpoints.plan_viewpoints` feeds it a simulated scene's centroid and
heights.

Units: camera poses in the plan are camera-to-base with translations in **mm**
(``camera_to_base_mm``; ``camera_to_base_m`` gives metres for ROS); joints in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ArmError, InputError, SimulationError
from ..pose import look_at, pose_mm_to_m
from .tool import DEFAULT_T_FLANGE_CAMERA_M
from .ur5e import HOME_JOINTS, UR5E, URParams, flange_pose_for_camera, link_frames, solve_ik


@dataclass(frozen=True, eq=False)
class ViewpointConfig:
    """Parameters of :func:`plan_viewpoints`.

    Attributes:
        n_views: number of reachable views per scene.
        height_range_mm: camera height above the highest object top, mm.
        n_height_bands: the height range is split into this many bands and the azimuths into
            ``ceil(n_views / n_height_bands)`` sectors; view i takes band ``i % n_height_bands``
            and sector ``i // n_height_bands`` (18 views: 3 bands x 6 sectors).
        max_tilt_deg: largest angle between the optical axis and the vertical, degrees.
        max_candidates: total candidates drawn before giving up with SimulationError.
        table_clearance_mm: every arm joint must stay this far above the table top, mm.
        t_flange_camera_m: (4, 4) hand-eye transform, camera in the flange frame, metres.
        seed_joints: (6,) configuration the first view's IK stays close to, radians; later
            views stay close to the previous one.
    """

    n_views: int = 18
    height_range_mm: tuple[float, float] = (180.0, 350.0)
    n_height_bands: int = 3
    max_tilt_deg: float = 30.0
    max_candidates: int = 200
    table_clearance_mm: float = 50.0
    t_flange_camera_m: np.ndarray = field(default_factory=lambda: DEFAULT_T_FLANGE_CAMERA_M.copy())
    seed_joints: np.ndarray = field(default_factory=lambda: HOME_JOINTS.copy())


@dataclass(frozen=True, eq=False)
class Viewpoint:
    """One reachable view.

    Attributes:
        index: position in the plan, 0..n_views-1.
        candidate: which draw of the plan produced it (rejected draws keep their numbers).
        camera_to_base_mm: (4, 4) float64 ToF camera optical frame in the base frame, mm.
        joints_rad: (6,) float64 UR5e joint angles that realise it, radians.
        height_mm: camera height above the highest object top, mm.
        tilt_deg: angle of the optical axis from the vertical, degrees.
        azimuth_deg: direction of the camera from the target, about the vertical, degrees.
        roll_deg: in-plane rotation about the optical axis, degrees.
    """

    index: int
    candidate: int
    camera_to_base_mm: np.ndarray
    joints_rad: np.ndarray
    height_mm: float
    tilt_deg: float
    azimuth_deg: float
    roll_deg: float

    @property
    def camera_to_base_m(self) -> np.ndarray:
        """(4, 4) float64 camera-to-base pose with the translation in metres (for ROS)."""
        return pose_mm_to_m(self.camera_to_base_mm)


@dataclass(frozen=True, eq=False)
class ViewpointPlan:
    """The views of one scene and the candidates that were rejected.

    Attributes:
        target_mm: (3,) float64 point every view looks at (objects' centroid), base frame, mm.
        viewpoints: the ``n_views`` reachable views, in order.
        rejected: (candidate number, reason) of every candidate that was not reachable.
    """

    target_mm: np.ndarray
    viewpoints: tuple[Viewpoint, ...]
    rejected: tuple[tuple[int, str], ...]


def view_pose_mm(target_mm: np.ndarray, top_z_mm: float, height_mm: float, tilt_deg: float,
                 azimuth_deg: float, roll_deg: float) -> np.ndarray:
    """Camera-to-base pose (mm) looking at ``target_mm`` from ``height_mm`` above ``top_z_mm``.

    The camera lies on the ray leaving the target at ``tilt_deg`` from the vertical towards
    ``azimuth_deg``, at the distance that puts it ``height_mm`` above ``top_z_mm``.

    Returns:
        (4, 4) float64 camera optical frame -> base frame, translation in mm.
    """
    target = np.asarray(target_mm, dtype=np.float64)
    tilt, azimuth = math.radians(tilt_deg), math.radians(azimuth_deg)
    direction = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth),
                          math.cos(tilt)])
    distance = (top_z_mm + height_mm - target[2]) / direction[2]
    return look_at(target + distance * direction, target, math.radians(roll_deg))


def reach_camera_pose(camera_to_base_mm: np.ndarray, seed_joints: np.ndarray,
                      table_z_mm: float, config: ViewpointConfig = ViewpointConfig(),
                      params: URParams = UR5E) -> np.ndarray:
    """Joint angles (rad) that put the camera at ``camera_to_base_mm``, closest to the seed.

    Raises:
        ArmError: unreachable (out of reach, singular, joint limits) or an arm joint would come
            closer than ``config.table_clearance_mm`` to the table; the message says which.
    """
    flange = flange_pose_for_camera(pose_mm_to_m(camera_to_base_mm), config.t_flange_camera_m)
    joints = solve_ik(flange, seed_joints, params)
    # DH frames 2..6 sit on the elbow, wrists and flange; frame 1 is the fixed shoulder.
    lowest_mm = float(link_frames(joints, params)[1:, 2, 3].min()) * 1000.0
    if lowest_mm < table_z_mm + config.table_clearance_mm:
        raise ArmError(f"unreachable: an arm joint would be {lowest_mm - table_z_mm:.0f} mm above "
                       f"the table (< {config.table_clearance_mm:.0f} mm clearance)")
    return joints


def _draw_view(slot: int, config: ViewpointConfig,
               rng: np.random.Generator) -> tuple[float, float, float, float]:
    """(height_mm, tilt_deg, azimuth_deg, roll_deg) for a slot: its height band and azimuth
    sector, jittered uniformly inside them."""
    lo, hi = config.height_range_mm
    n_sectors = math.ceil(config.n_views / config.n_height_bands)
    band, sector = slot % config.n_height_bands, slot // config.n_height_bands
    band_size = (hi - lo) / config.n_height_bands
    height = lo + band_size * (band + rng.uniform())
    azimuth = 360.0 / n_sectors * (sector + rng.uniform())
    tilt = config.max_tilt_deg * rng.uniform()
    roll = rng.uniform(-180.0, 180.0)
    return height, tilt, azimuth, roll


def plan_views(target_mm: np.ndarray, top_z_mm: float, table_z_mm: float,
               rng: np.random.Generator, config: ViewpointConfig = ViewpointConfig(),
               params: URParams = UR5E) -> ViewpointPlan:
    """``config.n_views`` reachable views looking at ``target_mm``: the package's one viewpoint
    planner.

    Args:
        target_mm: (3,) float point every view looks at (e.g. the objects' centroid), base
            frame, mm.
        top_z_mm: z of the highest object top (the heights are above it), base frame, mm.
        table_z_mm: z of the table top (the arm keeps clear of it), base frame, mm.
        rng: source of randomness (the plan is a deterministic function of its state).
        config: plan parameters.
        params: the arm.

    Returns:
        The plan, with every rejected candidate and its reason.

    Raises:
        InputError: ``n_views`` or ``n_height_bands`` is not positive.
        SimulationError: fewer than ``n_views`` reachable views after ``max_candidates`` draws.
    """
    if config.n_views <= 0 or config.n_height_bands <= 0:
        raise InputError(f"n_views ({config.n_views}) and n_height_bands "
                         f"({config.n_height_bands}) must be positive")
    seed = np.asarray(config.seed_joints, dtype=np.float64)
    views: list[Viewpoint] = []
    rejected: list[tuple[int, str]] = []
    candidate = 0
    while len(views) < config.n_views:
        if candidate >= config.max_candidates:
            reasons = "; ".join(f"#{i}: {r}" for i, r in rejected[-3:])
            raise SimulationError(f"only {len(views)} of {config.n_views} views reachable after "
                                  f"{candidate} candidates (last rejections: {reasons})")
        params_view = _draw_view(len(views), config, rng)
        pose = view_pose_mm(target_mm, top_z_mm, *params_view)
        try:
            joints = reach_camera_pose(pose, seed, table_z_mm, config, params)
        except ArmError as err:
            rejected.append((candidate, str(err)))
        else:
            views.append(Viewpoint(len(views), candidate, pose, joints, *params_view))
            seed = joints
        candidate += 1
    return ViewpointPlan(target_mm, tuple(views), tuple(rejected))
