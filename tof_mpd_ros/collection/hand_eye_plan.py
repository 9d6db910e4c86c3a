"""The hand–eye calibration plan: tilted views of the board lying on the table.

Each view looks at (near) the board centre from 250-400 mm, tilted from the board normal
towards an azimuth that advances around the board from view to view, and turned in-plane by a
random roll: the relative rotations between views then have widely spread axes, which Tsai-Lenz
and the other hand-eye methods need. A candidate is kept only if the whole board plus half a
square of its white border lies inside both the ToF crop and the SL image (through the assumed
hand-eye and SL offsets) and the UR5e reaches it within its joint limits, clear of the table.

It is a capture plan (where the arm goes, what the collector runs), so it lives with the other
plans; the solver that uses the captures is :mod:`tof_mpd_ros.calibration.hand_eye`.

Units: poses in metres (TCP = flange in the base frame, as ``ur_rtde`` reports it), distances in
millimetres where the name says so, angles in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import combinations, pairwise

import numpy as np

from ..arm.tool import DEFAULT_T_FLANGE_CAMERA_M, default_sl_to_tof_mm
from ..arm.ur5e import HOME_JOINTS, forward_kinematics
from ..arm.viewpoints import ViewpointConfig, reach_camera_pose
from ..calibration.hand_eye_board import CalibrationBoard
from ..camera import PAPER_CROP, Intrinsics
from ..errors import ArmError, CalibrationError, InputError
from ..pose import (
    invert_pose,
    look_at,
    matrix_to_rotvec,
    pose_m_to_mm,
    pose_mm_to_m,
    transform_points,
)
from ..validation import check_array
from .plan import PlannedView


def default_tof_intrinsics() -> Intrinsics:
    """The ToF camera's 180x140 crop (DS325-like sensor)."""
    return Intrinsics.ds325().crop(*PAPER_CROP)


def default_sl_intrinsics() -> Intrinsics:
    """The SL camera as an intensity camera: 640x480 with the SL sensor's 65 deg HFOV."""
    return Intrinsics.from_fov(640, 480, 65.0)


def _default_sl_to_tof_m() -> np.ndarray:
    return pose_mm_to_m(default_sl_to_tof_mm())


@dataclass(frozen=True, eq=False)
class HandEyePlanConfig:
    """How :func:`hand_eye_plan` draws views.

    Attributes:
        distance_mm: range of the camera's distance to its aim point, mm.
        tilt_deg: range of the angle between the optical axis and the board normal, degrees.
        max_roll_deg: largest in-plane turn of the camera, degrees.
        aim_jitter_mm: the aim point is this far (at most) from the board centre, mm.
        board: the target.
        tof_intrinsics, sl_intrinsics: images the board must fit in.
        sl_to_tof_m: (4, 4) assumed SL camera pose in the ToF frame, metres.
        edge_px: the board (plus half a square of border) keeps this far from the image edges.
        max_candidates: draws before giving up.
        table_clearance_mm: arm joints keep this far above the table, mm.
        seed_joints: (6,) configuration the first view's IK stays close to, radians.
    """

    distance_mm: tuple[float, float] = (250.0, 400.0)
    tilt_deg: tuple[float, float] = (10.0, 30.0)
    max_roll_deg: float = 30.0
    aim_jitter_mm: float = 10.0
    board: CalibrationBoard = field(default_factory=CalibrationBoard)
    tof_intrinsics: Intrinsics = field(default_factory=default_tof_intrinsics)
    sl_intrinsics: Intrinsics = field(default_factory=default_sl_intrinsics)
    sl_to_tof_m: np.ndarray = field(default_factory=_default_sl_to_tof_m)
    edge_px: float = 2.0
    max_candidates: int = 500
    table_clearance_mm: float = 50.0
    seed_joints: np.ndarray = field(default_factory=lambda: HOME_JOINTS.copy())


def _in_image(points_cam_mm: np.ndarray, intr: Intrinsics, edge_px: float) -> bool:
    if np.any(points_cam_mm[:, 2] <= 0):
        return False
    uv = intr.project(points_cam_mm)
    return bool(np.all((uv[:, 0] >= edge_px) & (uv[:, 0] <= intr.width - 1 - edge_px)
                       & (uv[:, 1] >= edge_px) & (uv[:, 1] <= intr.height - 1 - edge_px)))


def board_visible(board_to_tof_mm: np.ndarray, config: HandEyePlanConfig) -> str | None:
    """None if the board (and half a square of border) is inside both images, else why not."""
    outline = config.board.outline_mm(0.5)
    if not _in_image(transform_points(board_to_tof_mm, outline), config.tof_intrinsics,
                     config.edge_px):
        return "board not inside the ToF image"
    board_to_sl = invert_pose(pose_m_to_mm(config.sl_to_tof_m)) @ board_to_tof_mm
    if not _in_image(transform_points(board_to_sl, outline), config.sl_intrinsics,
                     config.edge_px):
        return "board not inside the SL image"
    return None


def _draw_camera(board_to_base_mm: np.ndarray, slot: int, n_views: int,
                 config: HandEyePlanConfig, rng: np.random.Generator) -> np.ndarray:
    """(4, 4) camera-to-base pose (mm) of one candidate for view ``slot``."""
    rot, centre = board_to_base_mm[:3, :3], board_to_base_mm[:3, 3]
    face = -rot[:, 2]  # the printed face looks along board -z
    azimuth = 2.0 * math.pi * (slot + rng.uniform()) / n_views
    tilt = math.radians(rng.uniform(*config.tilt_deg))
    along = math.cos(azimuth) * rot[:, 0] + math.sin(azimuth) * rot[:, 1]
    direction = math.cos(tilt) * face + math.sin(tilt) * along
    jitter = rng.uniform(-config.aim_jitter_mm, config.aim_jitter_mm, size=2)
    target = centre + jitter[0] * rot[:, 0] + jitter[1] * rot[:, 1]
    eye = target + rng.uniform(*config.distance_mm) * direction
    return look_at(eye, target, math.radians(rng.uniform(-config.max_roll_deg,
                                                         config.max_roll_deg)))


def hand_eye_plan(board_to_base_m: np.ndarray, n_views: int, rng: np.random.Generator,
                  hand_eye_guess: np.ndarray = DEFAULT_T_FLANGE_CAMERA_M,
                  config: HandEyePlanConfig | None = None) -> list[np.ndarray]:
    """TCP poses that show the board to both cameras from varied tilts, all reachable.

    Args:
        board_to_base_m: (4, 4) board frame -> base frame, metres; the board lies on the table
            (its z axis points into the table), whose top is at the board's height.
        n_views: number of views.
        rng: source of randomness.
        hand_eye_guess: (4, 4) assumed ToF camera pose in the flange frame, metres.
        config: view ranges, images and arm limits.

    Returns:
        ``n_views`` (4, 4) float64 TCP (flange) poses in the base frame, metres, in visiting
        order (consecutive views are close in joint space).

    Raises:
        InputError: ``n_views`` < 3.
        CalibrationError: fewer than ``n_views`` usable candidates in ``config.max_candidates``
            draws (the message shows the last rejection reasons).
    """
    config = config or HandEyePlanConfig()
    if n_views < 3:
        raise InputError(f"a hand-eye plan needs at least 3 views, got {n_views}")
    board_mm = pose_m_to_mm(check_array("board_to_base_m", board_to_base_m, ndim=2,
                                        shape=(4, 4), dtype_kind="fiu"))
    guess = check_array("hand_eye_guess", hand_eye_guess, ndim=2, shape=(4, 4), dtype_kind="f")
    reach = ViewpointConfig(t_flange_camera_m=guess, table_clearance_mm=config.table_clearance_mm)
    seed = np.asarray(config.seed_joints, dtype=np.float64)
    poses: list[np.ndarray] = []
    rejected: list[str] = []
    for _ in range(config.max_candidates):
        if len(poses) == n_views:
            break
        camera = _draw_camera(board_mm, len(poses), n_views, config, rng)
        reason = board_visible(invert_pose(camera) @ board_mm, config)
        if reason is None:
            try:
                seed = reach_camera_pose(camera, seed, float(board_mm[2, 3]), reach)
            except ArmError as err:
                reason = str(err)
        if reason is not None:
            rejected.append(reason)
            continue
        poses.append(forward_kinematics(seed))
    if len(poses) < n_views:
        raise CalibrationError(f"only {len(poses)} of {n_views} hand-eye views are reachable and "
                               f"show the whole board after {config.max_candidates} candidates "
                               f"(last rejections: {'; '.join(rejected[-3:])})")
    return poses


def rotation_axis_spread_deg(tcp_to_base_m: list[np.ndarray] | np.ndarray,
                             min_angle_deg: float = 2.0) -> float:
    """Largest angle (0-90 deg) between the rotation axes of two view-to-view motions.

    Motions are between consecutive views; those turning less than ``min_angle_deg`` have no
    well-defined axis and are skipped. Hand-eye methods need motions about non-parallel axes;
    the wider this spread, the better conditioned the rotation.
    """
    poses = np.asarray(tcp_to_base_m, dtype=np.float64)
    axes = []
    for a, b in pairwise(poses):
        rotvec = matrix_to_rotvec(a[:3, :3].T @ b[:3, :3])
        if np.linalg.norm(rotvec) >= math.radians(min_angle_deg):
            axes.append(rotvec / np.linalg.norm(rotvec))
    spread = 0.0
    for u, v in combinations(axes, 2):
        spread = max(spread, math.degrees(math.acos(min(1.0, abs(float(u @ v))))))
    return spread


def hand_eye_plan_views(board_to_base_m: np.ndarray, n_views: int, seed: int,
                        hand_eye_guess: np.ndarray = DEFAULT_T_FLANGE_CAMERA_M,
                        board: CalibrationBoard | None = None) -> list[PlannedView]:
    """:func:`hand_eye_plan` as a collection plan (the ``collector`` node's ``plan:=hand_eye``).

    Deterministic in ``seed``, so a resumed session plans the same views.

    Args:
        board_to_base_m: (4, 4) where the board lies, metres.
        n_views: number of views.
        seed: seed of the plan's random draws.
        hand_eye_guess: (4, 4) assumed ToF camera pose in the flange frame, metres.
        board: the target (default :class:`CalibrationBoard`).
    """
    config = HandEyePlanConfig(board=board or CalibrationBoard())
    rng = np.random.default_rng([seed, 0x4E])
    tcp_poses = hand_eye_plan(board_to_base_m, n_views, rng, hand_eye_guess, config)
    return [PlannedView(i, tcp) for i, tcp in enumerate(tcp_poses)]
