"""The graded checkerboard used to fit the per-pixel intrinsic calibration.

As in the paper, the patch reflectances grow from the top row to the bottom row: dark patches
from 0 % to 50 %, bright ones from 50 % to 100 %, so one capture spans many amplitudes. The board
is shown to the ToF camera at many random poses (range 150-450 mm, tilted up to 40 degrees).

Frames and units: the *board frame* has its origin at the board centre, x along the rows
(to the right), y down the columns (towards the brighter rows), z into the board, so the printed
face looks along -z. A pose ``board_to_camera_mm`` maps the board frame to the ToF camera optical
frame, translation in millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from ..pose import make_pose, rot_z, rotate, rotvec_to_matrix
from ..validation import check_array
from .surface import SurfaceImage


@dataclass(frozen=True)
class CheckerboardConfig:
    """The printed target.

    Attributes:
        n_cols, n_rows: number of squares across and down.
        square_mm: side of one square, mm.
        dark_albedo: (top row, bottom row) reflectance of the dark squares.
        bright_albedo: (top row, bottom row) reflectance of the bright squares.
        material_id: material index of the print (0 = default diffuse).
    """

    n_cols: int = 10
    n_rows: int = 8
    square_mm: float = 50.0
    dark_albedo: tuple[float, float] = (0.0, 0.5)
    bright_albedo: tuple[float, float] = (0.5, 1.0)
    material_id: int = 0

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the board, mm."""
        return self.n_cols * self.square_mm, self.n_rows * self.square_mm

    def albedo_map(self) -> np.ndarray:
        """(n_rows, n_cols) float64 reflectance of each square; square (0, 0) is dark."""
        grade = np.linspace(0.0, 1.0, self.n_rows)[:, None]
        dark = self.dark_albedo[0] + grade * (self.dark_albedo[1] - self.dark_albedo[0])
        bright = self.bright_albedo[0] + grade * (self.bright_albedo[1] - self.bright_albedo[0])
        rows, cols = np.mgrid[0:self.n_rows, 0:self.n_cols]
        return np.where((rows + cols) % 2 == 0, dark, bright)


@dataclass(frozen=True)
class CalibrationPoseConfig:
    """How :func:`calibration_poses` places the board in front of the camera.

    Attributes:
        range_mm: range of the distance from the optical centre to the board centre, mm.
        max_tilt_deg: largest angle between the board normal and the optical axis, degrees.
        max_roll_deg: largest in-plane rotation of the board, degrees.
        max_off_axis_deg: largest angle between the optical axis and the ray to the board
            centre, degrees (keep it inside the cropped field of view).
    """

    range_mm: tuple[float, float] = (150.0, 450.0)
    max_tilt_deg: float = 40.0
    max_roll_deg: float = 20.0
    max_off_axis_deg: float = 12.0


def calibration_poses(n: int, rng: np.random.Generator,
                      config: CalibrationPoseConfig = CalibrationPoseConfig()) -> np.ndarray:
    """Random board poses for calibration captures.

    The board centre is at a uniform range in ``config.range_mm`` along a ray at most
    ``max_off_axis_deg`` from the optical axis; the board faces the camera, then is tilted by a
    uniform angle up to ``max_tilt_deg`` about a random in-plane axis and turned in-plane by up to
    ``max_roll_deg``.

    Args:
        n: number of poses.
        rng: source of randomness.
        config: pose ranges.

    Returns:
        (n, 4, 4) float64 board-to-camera poses (optical frame), translation in mm.
    """
    if n < 0:
        raise InputError(f"n must be >= 0, got {n}")
    poses = np.empty((n, 4, 4))
    for i in range(n):
        off_axis = math.radians(config.max_off_axis_deg) * math.sqrt(rng.uniform())
        heading = rng.uniform(0.0, 2.0 * math.pi)
        direction = np.array([math.sin(off_axis) * math.cos(heading),
                              math.sin(off_axis) * math.sin(heading), math.cos(off_axis)])
        tilt_axis_angle = rng.uniform(0.0, 2.0 * math.pi)
        tilt_axis = np.array([math.cos(tilt_axis_angle), math.sin(tilt_axis_angle), 0.0])
        tilt = rotvec_to_matrix(tilt_axis * (math.radians(config.max_tilt_deg) * rng.uniform()))
        roll = rot_z(math.radians(rng.uniform(-config.max_roll_deg, config.max_roll_deg)))
        poses[i] = make_pose(tilt @ roll, direction * rng.uniform(*config.range_mm))
    return poses


def render_checkerboard(board_to_camera_mm: np.ndarray, intrinsics: Intrinsics,
                        config: CheckerboardConfig = CheckerboardConfig()) -> SurfaceImage:
    """What each pixel centre sees of the board (ray-plane intersection, per-square albedo).

    Args:
        board_to_camera_mm: (4, 4) float board frame -> camera optical frame, mm.
        intrinsics: the image grid (``intrinsics.scaled(s)`` to supersample).
        config: the printed target.

    Returns:
        A :class:`SurfaceImage`: radial range (mm, the true range), normal facing the camera,
        per-square albedo, object id 1 and ``config.material_id`` on the board; off the board
        range and normal NaN, albedo 0, ids -1.
    """
    pose = check_array("board_to_camera_mm", board_to_camera_mm, ndim=2, shape=(4, 4),
                       dtype_kind="fiu").astype(np.float64, copy=False)
    rot, centre = pose[:3, :3], pose[:3, 3]
    normal = rot[:, 2]
    rays = intrinsics.ray_directions()
    along = np.einsum("hwj,j->hw", rays, normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (centre @ normal) / along
    local = rotate(rays * np.where(t > 0, t, 0.0)[..., None] - centre, rot.T)
    width, height = config.size_mm
    col = np.floor((local[..., 0] + width / 2.0) / config.square_mm).astype(np.int64)
    row = np.floor((local[..., 1] + height / 2.0) / config.square_mm).astype(np.int64)
    on_board = ((t > 0) & (col >= 0) & (col < config.n_cols) & (row >= 0)
                & (row < config.n_rows))
    albedo = config.albedo_map()[np.clip(row, 0, config.n_rows - 1),
                                 np.clip(col, 0, config.n_cols - 1)]
    facing = np.where(along > 0, -1.0, 1.0)[..., None] * normal
    return SurfaceImage(
        range_mm=np.where(on_board, t, np.nan),
        normal=np.where(on_board[..., None], facing, np.nan),
        albedo=np.where(on_board, albedo, 0.0),
        object_id=np.where(on_board, 1, -1).astype(np.int32),
        material_id=np.where(on_board, config.material_id, -1).astype(np.int32),
        intrinsics=intrinsics,
    )
