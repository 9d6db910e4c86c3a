"""The hand–eye calibration board and its detection in one image (OpenCV).

The board is a standard high-contrast checkerboard (dark 10 %, bright 90 % reflectance, equal
across the board: not the graded intrinsic-calibration board) printed on white paper with a
one-square white border, the quiet zone ``findChessboardCorners`` needs around the outer squares.
One of ``n_cols``, ``n_rows`` is even and the other odd, so the board does not look the same
turned by 180 degrees and every detection is labelled the same way (corner 0 touches the dark
square (0, 0)).

Units: corner pixel coordinates in pixels of the given image (integer = pixel centre, the
convention of :class:`~tof_mpd_ros.camera.Intrinsics`); board points and poses in metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..camera import Intrinsics
from ..errors import CalibrationError, InputError
from ..pose import make_pose, rotvec_to_matrix
from ..validation import check_array

# A PnP fit worse than this (px RMS) means a mislabelled or partly wrong detection.
MAX_PNP_RMS_PX = 1.0
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)


@dataclass(frozen=True)
class CalibrationBoard:
    """The printed hand–eye target.

    Attributes:
        n_cols, n_rows: squares across and down; one even and one odd.
        square_mm: side of a square, mm.
        dark_albedo, bright_albedo: reflectance of the dark and bright squares (and the white
            border, which is bright).
    """

    n_cols: int = 9
    n_rows: int = 6
    square_mm: float = 20.0
    dark_albedo: float = 0.1
    bright_albedo: float = 0.9

    def __post_init__(self) -> None:
        if self.n_cols < 3 or self.n_rows < 3:
            raise InputError(f"board needs at least 3x3 squares, got {self.n_cols}x{self.n_rows}")
        if (self.n_cols + self.n_rows) % 2 == 0:
            raise InputError(f"board {self.n_cols}x{self.n_rows}: one of n_cols, n_rows must be "
                             "odd and the other even, or the board looks the same turned by "
                             "180 degrees and its corners cannot be labelled consistently")
        if not self.square_mm > 0:
            raise InputError(f"square_mm must be > 0, got {self.square_mm}")
        if not 0.0 <= self.dark_albedo < self.bright_albedo <= 1.0:
            raise InputError(f"albedos must satisfy 0 <= dark < bright <= 1, got "
                             f"{self.dark_albedo}, {self.bright_albedo}")

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(columns, rows) of inner corners, OpenCV's ``patternSize``."""
        return self.n_cols - 1, self.n_rows - 1

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the squares area, mm (the white border is one more square)."""
        return self.n_cols * self.square_mm, self.n_rows * self.square_mm

    def object_points_m(self) -> np.ndarray:
        """(N, 3) float64 inner corners in the board frame, metres, in OpenCV's order.

        Row-major (x fastest); corner 0 is the inner corner of square (0, 0), at
        ``(-w/2 + s, -h/2 + s, 0)``.
        """
        cols, rows = self.pattern_size
        width, height = self.size_mm
        y, x = np.mgrid[1:rows + 1, 1:cols + 1].astype(np.float64) * self.square_mm
        pts = np.stack([x.ravel() - width / 2.0, y.ravel() - height / 2.0,
                        np.zeros(x.size)], axis=1)
        return pts / 1000.0

    def outline_mm(self, border_squares: float) -> np.ndarray:
        """(4, 3) float64 corners of the squares area grown by ``border_squares`` squares, mm."""
        w = self.size_mm[0] / 2.0 + border_squares * self.square_mm
        h = self.size_mm[1] / 2.0 + border_squares * self.square_mm
        return np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]])

    def as_dict(self) -> dict[str, Any]:
        return {"n_cols": self.n_cols, "n_rows": self.n_rows, "square_mm": self.square_mm,
                "dark_albedo": self.dark_albedo, "bright_albedo": self.bright_albedo}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CalibrationBoard:
        try:
            return cls(int(data["n_cols"]), int(data["n_rows"]), float(data["square_mm"]),
                       float(data.get("dark_albedo", 0.1)), float(data.get("bright_albedo", 0.9)))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"board description {data!r} lacks n_cols/n_rows/square_mm: "
                             f"{err}") from err


@dataclass(frozen=True, eq=False)
class BoardDetection:
    """The board found in one image.

    Attributes:
        corners_px: (N, 2) float64 inner corners (u, v), pixels, in the order of
            :meth:`CalibrationBoard.object_points_m`.
        board_to_camera_m: (4, 4) float64 board frame -> camera optical frame, metres (PnP).
        rms_px: RMS reprojection error of the PnP fit, pixels.
    """

    corners_px: np.ndarray
    board_to_camera_m: np.ndarray
    rms_px: float


def to_gray8(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 for the detector: uint8 as is; floats stretched between their 1st and
    99th percentile (the ToF amplitude falls with range squared), NaN -> 0."""
    img = check_array("image", image, ndim=2, dtype_kind="fiu")
    if img.dtype == np.uint8:
        return img
    finite = np.isfinite(img)
    if finite.sum() < 16:
        raise CalibrationError(f"image has only {int(finite.sum())} valid pixels")
    lo, hi = np.percentile(img[finite], [1.0, 99.0])
    if not hi > lo:
        raise CalibrationError("image has no contrast (1st and 99th percentiles are equal)")
    scaled = np.clip((np.where(finite, img, lo) - lo) / (hi - lo), 0.0, 1.0)
    return np.rint(scaled * 255.0).astype(np.uint8)


def _find_corners(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """(N, 2) float32 corners refined to sub-pixel accuracy, or CalibrationError."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, pattern, flags=flags)
    if not found:
        raise CalibrationError(f"findChessboardCorners found no {pattern[0]}x{pattern[1]} "
                               "inner-corner pattern")
    corners = corners.reshape(-1, 2)
    # The search window spans ~40 % of the nearest corner spacing: large enough for a stable
    # gradient fit, small enough never to reach a neighbouring corner.
    grid = corners.reshape(pattern[1], pattern[0], 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=1), axis=-1).min(),
                  np.linalg.norm(np.diff(grid, axis=0), axis=-1).min())
    half = max(2, int(0.4 * spacing))
    refined = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2).astype(np.float32),
                               (half, half), (-1, -1), _SUBPIX_CRITERIA)
    return refined.reshape(-1, 2)


def _label(gray: np.ndarray, corners: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """Corners re-ordered so that the board is seen from its front and corner 0 touches the
    dark square (0, 0)."""
    cols, rows = pattern
    grid = corners.reshape(rows, cols, 2)
    dx, dy = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    # Seen from the front, board x (right) and y (down) keep the image's orientation.
    if dx[0] * dy[1] - dx[1] * dy[0] < 0:
        grid = grid[:, ::-1]
        dx, dy = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    outside = grid[0, 0] - 0.5 * dx - 0.5 * dy  # centre of square (0, 0): dark
    beside = grid[0, 0] + 0.5 * dx - 0.5 * dy   # centre of square (0, 1): bright
    if _sample(gray, outside) > _sample(gray, beside):
        grid = grid[::-1, ::-1]
    return grid.reshape(-1, 2)


def _sample(gray: np.ndarray, point: np.ndarray) -> float:
    patch = cv2.getRectSubPix(gray, (3, 3), (float(point[0]), float(point[1])))
    return float(patch.mean())


def _camera_matrix(intr: Intrinsics) -> np.ndarray:
    return np.array([[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]])


def board_pose(corners_px: np.ndarray, board: CalibrationBoard,
               intrinsics: Intrinsics) -> tuple[np.ndarray, float]:
    """PnP board pose from labelled corners.

    Returns:
        ((4, 4) float64 board -> camera, metres; RMS reprojection error, px).
    """
    obj = board.object_points_m()
    k, dist = _camera_matrix(intrinsics), np.zeros(5)
    ok, rvec, tvec = cv2.solvePnP(obj, corners_px, k, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationError("solvePnP failed on the detected corners")
    rvec, tvec = cv2.solvePnPRefineLM(obj, corners_px, k, dist, rvec, tvec)
    projected, _ = cv2.projectPoints(obj, rvec, tvec, k, dist)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - corners_px) ** 2, axis=1))))
    return make_pose(rotvec_to_matrix(rvec.ravel()), tvec.ravel()), rms


def detect_board(image: np.ndarray, board: CalibrationBoard, intrinsics: Intrinsics, *,
                 upsample: int = 1, max_rms_px: float = MAX_PNP_RMS_PX) -> BoardDetection:
    """Find the board in one image and its pose.

    Args:
        image: (H, W) uint8 intensity, or float (ToF amplitude; NaN = invalid).
        board: the printed target.
        intrinsics: of this H x W image (no distortion).
        upsample: search on an image enlarged this many times (bicubic); a coarse ToF
            amplitude image gives more exact corners that way.
        max_rms_px: reject a detection whose PnP fit is worse than this.

    Returns:
        The labelled corners (pixels of ``image``), the board pose and the PnP RMS.

    Raises:
        CalibrationError: no board, no contrast, or a PnP fit worse than ``max_rms_px``; the
            message says which.
    """
    gray = to_gray8(image)
    if gray.shape != intrinsics.shape:
        raise InputError(f"image is {gray.shape[1]}x{gray.shape[0]} but the intrinsics are "
                         f"{intrinsics.width}x{intrinsics.height}")
    if upsample < 1:
        raise InputError(f"upsample must be >= 1, got {upsample}")
    if upsample > 1:
        gray = cv2.resize(gray, None, fx=upsample, fy=upsample, interpolation=cv2.INTER_CUBIC)
    corners = _label(gray, _find_corners(gray, board.pattern_size), board.pattern_size)
    # Pixel centres are integers at both scales: u = (u_up + 0.5) / s - 0.5.
    corners = (corners.astype(np.float64) + 0.5) / upsample - 0.5
    pose, rms = board_pose(corners, board, intrinsics)
    if rms > max_rms_px:
        raise CalibrationError(f"board pose fits the corners with {rms:.2f} px RMS "
                               f"(> {max_rms_px} px): detection is unreliable")
    return BoardDetection(corners, pose, rms)
