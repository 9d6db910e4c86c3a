"""Simulated hand–eye calibration captures in the simulated cell.

The board (squares on a white sheet, lying on a darker table) is rendered into

* the ToF camera through the cell's full AMCW physics (:func:`~tof_mpd_ros.sim.tof.render_tof`
  on the cell's supersampled window: mixed pixels, multipath, amplitude-dependent noise), so the
  amplitude image the detector sees is as coarse and noisy as a real one;
* the SL camera as an intensity image: Lambertian shading under light from the camera,
  supersampled, with a little Gaussian noise, 8-bit.

The arm follows :func:`~tof_mpd_ros.collection.hand_eye_plan.hand_eye_plan`; the TCP poses are
exact forward
kinematics. The *true* camera-to-flange and SL-to-ToF transforms are parameters, so tests can
move them off the defaults and check that the calibration finds them.

Units: simulator geometry in millimetres, poses facing ROS in metres (``*_m``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..arm.tool import DEFAULT_T_FLANGE_CAMERA_M
from ..calibration.hand_eye import HandEyeCapture
from ..calibration.hand_eye_board import CalibrationBoard
from ..calibration.hand_eye_io import write_hand_eye_recording
from ..camera import Intrinsics
from ..collection.hand_eye_plan import HandEyePlanConfig, default_sl_intrinsics, hand_eye_plan
from ..errors import InputError
from ..frame import ToFFrame
from ..pose import invert_pose, make_pose, pose_m_to_mm, pose_mm_to_m, rotvec_to_matrix
from .cell import SimCell
from .checkerboard import CheckerboardConfig, render_checkerboard
from .structured_light import StructuredLightConfig
from .surface import SurfaceImage
from .tof import render_tof

# Board centre on the table in front of the robot (the scenes' workspace centre), flat: board
# x along base +x, board z (into the board) pointing down into the table.
_BOARD_ON_TABLE_M = make_pose(np.diag([1.0, -1.0, -1.0]), np.array([0.45, 0.0, 0.0]))


def _board_on_table() -> np.ndarray:
    return _BOARD_ON_TABLE_M.copy()


@dataclass(frozen=True, eq=False)
class HandEyeSimConfig:
    """The simulated calibration session.

    Attributes:
        n_views: views in the plan.
        board: the printed target.
        board_to_base_m: (4, 4) where the board lies, metres (z into the table).
        t_flange_camera_m: (4, 4) the *true* ToF camera pose in the flange frame, metres.
        hand_eye_guess_m: (4, 4) what the planner assumes for it, metres.
        sl_intrinsics: the SL camera's intensity image.
        table_albedo: reflectance of the table around the sheet.
        sheet_thickness_mm: the sheet's top lies this far above the table.
        sl_noise_dn: standard deviation of the SL image noise, 8-bit counts.
        sl_supersample: SL samples per pixel and axis (anti-aliased edges).
        start_ns, period_ns: stamp of the first view and the time between views, ns.
    """

    n_views: int = 12
    board: CalibrationBoard = field(default_factory=CalibrationBoard)
    board_to_base_m: np.ndarray = field(default_factory=_board_on_table)
    t_flange_camera_m: np.ndarray = field(default_factory=lambda: DEFAULT_T_FLANGE_CAMERA_M.copy())
    hand_eye_guess_m: np.ndarray = field(default_factory=lambda: DEFAULT_T_FLANGE_CAMERA_M.copy())
    sl_intrinsics: Intrinsics = field(default_factory=default_sl_intrinsics)
    table_albedo: float = 0.3
    sheet_thickness_mm: float = 1.0
    sl_noise_dn: float = 1.5
    sl_supersample: int = 2
    start_ns: int = 1_000_000_000
    period_ns: int = 100_000_000


def board_squares(board: CalibrationBoard) -> CheckerboardConfig:
    """The board's squares, for :func:`~.checkerboard.render_checkerboard`."""
    return CheckerboardConfig(n_cols=board.n_cols, n_rows=board.n_rows,
                              square_mm=board.square_mm,
                              dark_albedo=(board.dark_albedo, board.dark_albedo),
                              bright_albedo=(board.bright_albedo, board.bright_albedo))


def board_paper(board: CalibrationBoard) -> CheckerboardConfig:
    """The white sheet under the board's squares (one square wider on every side), all
    bright, for :func:`~.checkerboard.render_checkerboard`."""
    white = (board.bright_albedo, board.bright_albedo)
    return CheckerboardConfig(n_cols=board.n_cols + 2, n_rows=board.n_rows + 2,
                              square_mm=board.square_mm, dark_albedo=white,
                              bright_albedo=white)


def _nearer(front: SurfaceImage, back: SurfaceImage) -> SurfaceImage:
    """Per sample, the surface of whichever image is hit nearer the camera."""
    use_back = ~front.valid | (back.valid & (back.range_mm < front.range_mm))

    def pick(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        mask = use_back[..., None] if a.ndim == 3 else use_back
        return np.where(mask, b, a)
    return SurfaceImage(range_mm=pick(front.range_mm, back.range_mm),
                        normal=pick(front.normal, back.normal),
                        albedo=pick(front.albedo, back.albedo),
                        object_id=pick(front.object_id, back.object_id),
                        material_id=pick(front.material_id, back.material_id),
                        intrinsics=front.intrinsics)


def render_board_scene(board: CalibrationBoard, board_to_camera_mm: np.ndarray,
                       intrinsics: Intrinsics, *, table_albedo: float = 0.3,
                       sheet_thickness_mm: float = 1.0) -> SurfaceImage:
    """What each ray hits: the squares, the white sheet around them, the table behind.

    Args:
        board: the target.
        board_to_camera_mm: (4, 4) board frame -> camera optical frame, mm.
        intrinsics: the (possibly supersampled) image grid.

    Returns:
        SurfaceImage; the sheet and squares are object 1, the table object 0.
    """
    squares = render_checkerboard(board_to_camera_mm, intrinsics, board_squares(board))
    sheet = render_checkerboard(board_to_camera_mm, intrinsics, board_paper(board))
    # The table: a large plain plane just under the sheet (board z points into the table).
    under = board_to_camera_mm @ make_pose(np.eye(3), np.array([0.0, 0.0, sheet_thickness_mm]))
    plain = (table_albedo, table_albedo)
    table = render_checkerboard(under, intrinsics, CheckerboardConfig(
        n_cols=1, n_rows=1, square_mm=4000.0, dark_albedo=plain, bright_albedo=plain))
    table = replace(table, object_id=np.where(table.valid, 0, -1).astype(np.int32))
    on_board = squares.valid
    board_first = SurfaceImage(
        range_mm=np.where(on_board, squares.range_mm, sheet.range_mm),
        normal=np.where(on_board[..., None], squares.normal, sheet.normal),
        albedo=np.where(on_board, squares.albedo, sheet.albedo),
        object_id=np.where(on_board, squares.object_id, sheet.object_id),
        material_id=np.where(on_board, squares.material_id, sheet.material_id),
        intrinsics=intrinsics)
    return _nearer(board_first, table)


def simulate_tof_capture(cell: SimCell, board: CalibrationBoard, board_to_camera_mm: np.ndarray,
                         rng: np.random.Generator, *, frame_index: int = 0, stamp_ns: int = 0,
                         table_albedo: float = 0.3, sheet_thickness_mm: float = 1.0) -> ToFFrame:
    """ToF range + amplitude of the board through the cell's physics (no reference, no pose).

    Args:
        cell: the simulated cell (camera model and ToF effects).
        board_to_camera_mm: (4, 4) board frame -> ToF optical frame, mm.
        rng: sensor noise.

    Returns:
        ToFFrame of the cell's crop: radial range (mm) and amplitude, NaN = invalid.
    """
    cam = cell.camera
    surface = render_board_scene(board, board_to_camera_mm, cam.window.scaled(cam.supersample),
                                 table_albedo=table_albedo, sheet_thickness_mm=sheet_thickness_mm)
    measured = render_tof(surface, cell.tof, rng, supersample=cam.supersample,
                          frame_index=frame_index)
    return ToFFrame(range_mm=cam.keep_crop(measured.range_mm),
                    amplitude=cam.keep_crop(measured.amplitude), intrinsics=cam.intrinsics,
                    mod_freq_hz=cell.tof.mod_freq_hz, stamp_ns=stamp_ns)


def _plane_albedo_and_cos(board: CalibrationBoard, board_to_camera_mm: np.ndarray,
                          intrinsics: Intrinsics, table_albedo: float
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Albedo and cosine of incidence of every ray on the board plane (sheet and table taken
    as one plane: the sheet's thickness does not show in an intensity image).

    Returns:
        ((H, W) float32 albedo, (H, W) float32 cos(incidence)); 0 where the ray misses.
    """
    rot = board_to_camera_mm[:3, :3].astype(np.float32)
    centre = board_to_camera_mm[:3, 3].astype(np.float32)
    normal = rot[:, 2]
    v, u = np.mgrid[0:intrinsics.height, 0:intrinsics.width].astype(np.float32)
    x = (u - np.float32(intrinsics.cx)) / np.float32(intrinsics.fx)
    y = (v - np.float32(intrinsics.cy)) / np.float32(intrinsics.fy)
    along = x * normal[0] + y * normal[1] + normal[2]  # ray (x, y, 1) . normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.float32(centre @ normal) / along
    hit = np.isfinite(t) & (t > 0)
    t = np.where(hit, t, 0.0).astype(np.float32)
    # Board coordinates of the hit point: R^T (t ray - centre).
    px, py, pz = t * x - centre[0], t * y - centre[1], t - centre[2]
    bx = rot[0, 0] * px + rot[1, 0] * py + rot[2, 0] * pz
    by = rot[0, 1] * px + rot[1, 1] * py + rot[2, 1] * pz
    width, height = board.size_mm
    col = np.floor((bx + width / 2.0) / board.square_mm)
    row = np.floor((by + height / 2.0) / board.square_mm)
    on_squares = (col >= 0) & (col < board.n_cols) & (row >= 0) & (row < board.n_rows)
    on_sheet = (col >= -1) & (col <= board.n_cols) & (row >= -1) & (row <= board.n_rows)
    dark = (row + col) % 2 == 0
    albedo = np.where(on_squares, np.where(dark, board.dark_albedo, board.bright_albedo),
                      np.where(on_sheet, board.bright_albedo, table_albedo))
    cos = np.abs(along) / np.sqrt(x * x + y * y + 1.0)
    return np.where(hit, albedo, 0.0).astype(np.float32), np.where(hit, cos, 0.0)


def render_sl_image(board: CalibrationBoard, board_to_sl_mm: np.ndarray, intrinsics: Intrinsics,
                    rng: np.random.Generator, *, supersample: int = 3, noise_dn: float = 1.5,
                    table_albedo: float = 0.3) -> np.ndarray:
    """The SL camera's 8-bit intensity image of the board.

    Lambertian shading under a light at the camera (``albedo * cos(incidence)``), white
    facing the camera at ~240 counts, averaged over ``supersample``^2 samples per pixel, plus
    Gaussian noise of ``noise_dn`` counts.

    Args:
        board_to_sl_mm: (4, 4) board frame -> SL camera optical frame, mm.
        intrinsics: the SL image grid.

    Returns:
        (H, W) uint8 intensity.
    """
    if supersample < 1:
        raise InputError(f"supersample must be >= 1, got {supersample}")
    pose = np.asarray(board_to_sl_mm, dtype=np.float64)
    albedo, cos = _plane_albedo_and_cos(board, pose, intrinsics.scaled(supersample),
                                        table_albedo)
    shade = albedo * cos * np.float32(240.0 / board.bright_albedo)
    h, w = intrinsics.shape
    pixel = shade.reshape(h, supersample, w, supersample).mean(axis=(1, 3))
    noisy = pixel + rng.normal(0.0, noise_dn, size=pixel.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def simulate_hand_eye_session(rng: np.random.Generator, config: HandEyeSimConfig | None = None,
                              cell: SimCell | None = None
                              ) -> tuple[list[HandEyeCapture], list[ToFFrame]]:
    """Plan the views, move the simulated arm and capture both cameras at each.

    Args:
        rng: source of the plan and of all sensor noise.
        config: the session (true transforms, board, SL camera).
        cell: the simulated cell; its ``structured_light.sl_to_tof_mm`` is the *true* SL pose.

    Returns:
        (captures for :func:`~tof_mpd_ros.calibration.hand_eye.solve_hand_eye`, the ToF frames
        for a recording).
    """
    config = config or HandEyeSimConfig()
    cell = cell or SimCell()
    sl: StructuredLightConfig = cell.structured_light
    # The planner knows only the nominal SL offset (its default), as on the real cell.
    plan_config = HandEyePlanConfig(board=config.board, tof_intrinsics=cell.camera.intrinsics,
                                    sl_intrinsics=config.sl_intrinsics)
    tcp_poses = hand_eye_plan(config.board_to_base_m, config.n_views, rng,
                              config.hand_eye_guess_m, plan_config)
    board_mm = pose_m_to_mm(config.board_to_base_m)
    captures, frames = [], []
    for i, tcp in enumerate(tcp_poses):
        stamp = config.start_ns + i * config.period_ns
        tof_to_base = pose_m_to_mm(tcp @ config.t_flange_camera_m)
        board_in_tof = invert_pose(tof_to_base) @ board_mm
        frame = simulate_tof_capture(cell, config.board, board_in_tof, rng, frame_index=i,
                                     stamp_ns=stamp, table_albedo=config.table_albedo,
                                     sheet_thickness_mm=config.sheet_thickness_mm)
        board_in_sl = invert_pose(sl.sl_to_tof_mm) @ board_in_tof
        image = render_sl_image(config.board, board_in_sl, config.sl_intrinsics, rng,
                                supersample=config.sl_supersample, noise_dn=config.sl_noise_dn,
                                table_albedo=config.table_albedo)
        captures.append(HandEyeCapture(i, stamp, tcp, frame.amplitude, image))
        frames.append(frame)
    return captures, frames



def simulate_hand_eye_recording(path: str | Path, rng: np.random.Generator,
                                config: HandEyeSimConfig | None = None,
                                cell: SimCell | None = None, *,
                                overwrite: bool = False) -> list[HandEyeCapture]:
    """Simulate a calibration session and write it as a recording
    (:mod:`~tof_mpd_ros.calibration.hand_eye_io`).

    The recording also stores the true transforms (``sim_truth``: ``camera_to_flange`` and
    ``sl_to_tof``, metres) so reports can show the calibration error.

    Returns:
        The captures, as :func:`simulate_hand_eye_session` returns them.
    """
    config = config or HandEyeSimConfig()
    cell = cell or SimCell()
    captures, frames = simulate_hand_eye_session(rng, config, cell)
    truth = {"camera_to_flange": config.t_flange_camera_m,
             "sl_to_tof": pose_mm_to_m(cell.structured_light.sl_to_tof_mm)}
    write_hand_eye_recording(path, frames, [c.tcp_to_base_m for c in captures],
                             [c.sl_image for c in captures], config.board, config.sl_intrinsics,
                             sim_truth=truth, overwrite=overwrite)
    return captures


def perturb_pose(pose_m: np.ndarray, rng: np.random.Generator, *, translation_mm: float = 4.0,
                 rotation_deg: float = 1.0) -> np.ndarray:
    """A pose moved by a random translation of ``translation_mm`` and rotation of
    ``rotation_deg`` (random directions, applied in the pose's own frame), e.g. a camera that
    is not exactly where its CAD model puts it.

    Args:
        pose_m: (4, 4) pose, metres.

    Returns:
        (4, 4) float64 perturbed pose, metres.
    """
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    rotvec = np.radians(rotation_deg) * axis / np.linalg.norm(axis)
    offset = translation_mm / 1000.0 * direction / np.linalg.norm(direction)
    delta = make_pose(rotvec_to_matrix(rotvec), offset)
    return np.asarray(pose_m, dtype=np.float64) @ delta
