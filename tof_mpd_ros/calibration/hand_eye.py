"""Hand–eye calibration before collecting: camera-to-flange and ToF-to-SL from checkerboard views.

As in the paper, before a collection run the arm shows a flat checkerboard lying on the table
to the ToF camera and the structured-light (SL) camera from several tilted viewpoints. The board
is found in the ToF *amplitude* image and in the SL intensity image; a per-view ``solvePnP``
gives each camera's board pose; the hand–eye equation ``A X = X B`` (arm motion A, camera motion
B) gives the ToF camera in the flange frame X; the per-view board poses of the two cameras give
the SL camera in the ToF frame. A joint least-squares refinement then fits X, the SL offset and
the board's pose on the table to every detected corner of both cameras at once.

Frames and units: poses are (4, 4) float64 ``T_a_b`` mapping frame ``b`` to frame ``a``, with
translations in **metres** (they face ROS and ``ur_rtde``). ``camera_to_flange_m`` is the ToF
optical frame in the flange (``tool0``) frame, the hand-eye transform a recording stores;
``sl_to_tof_m`` is the SL camera optical frame in the ToF optical frame (the convention of
:func:`~tof_mpd_ros.arm.tool.default_sl_to_tof_mm`). The board frame is that of
:mod:`tof_mpd_ros.sim.checkerboard`: origin at the centre of the squares, x along the rows, y down
the columns, z into the board (the printed face looks along -z).

:mod:`.hand_eye_board` describes and finds the board; :mod:`.hand_eye_io` reads and writes
calibration recordings. The views are planned by the collection
(:mod:`tof_mpd_ros.collection.hand_eye_plan`, the arm's capture plan) and simulated by
:mod:`tof_mpd_ros.sim.hand_eye`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from ..camera import Intrinsics
from ..errors import CalibrationError, InputError
from ..pose import (
    invert_pose,
    make_pose,
    matrix_to_pose_vector,
    matrix_to_rotvec,
    mean_pose,
    rotvec_to_matrix,
)
from ..validation import check_array
from .hand_eye_board import BoardDetection, CalibrationBoard, detect_board

__all__ = [
    "MIN_VIEWS",
    "CalibrationBoard",
    "HandEyeCapture",
    "HandEyeResult",
    "ViewFailure",
    "available_methods",
    "ax_xb_residuals",
    "linear_hand_eye",
    "pose_difference",
    "solve_hand_eye",
]

# Fewer views than this leave the hand-eye rotation poorly constrained (Tsai-Lenz needs >= 3
# views with non-parallel motion axes; one more absorbs a bad view).
MIN_VIEWS = 4
# Corners of the ToF amplitude image are found on a 4x upsampled copy (180x140 is coarse).
TOF_UPSAMPLE = 4

# OpenCV 5.0.0.93's Python package lacks cv2.calibrateHandEye (opencv/opencv#29565, fixed
# upstream by #29584); these numpy versions of two of its methods stand in until it is there.
_OPENCV_METHODS = {"TSAI": "CALIB_HAND_EYE_TSAI", "PARK": "CALIB_HAND_EYE_PARK",
                   "HORAUD": "CALIB_HAND_EYE_HORAUD", "ANDREFF": "CALIB_HAND_EYE_ANDREFF",
                   "DANIILIDIS": "CALIB_HAND_EYE_DANIILIDIS"}


@dataclass(frozen=True, eq=False)
class HandEyeCapture:
    """One calibration view.

    Attributes:
        index: position in the recording.
        stamp_ns: capture time, integer ns.
        tcp_to_base_m: (4, 4) float64 TCP (flange) pose in the base frame, metres; None when the
            recording has no pose for this view.
        tof_amplitude: (h, w) float32 ToF amplitude (sensor units, NaN = invalid), or None.
        sl_image: (H, W) uint8 or float SL camera intensity image, or None.
    """

    index: int
    stamp_ns: int
    tcp_to_base_m: np.ndarray | None
    tof_amplitude: np.ndarray | None
    sl_image: np.ndarray | None


@dataclass(frozen=True)
class ViewFailure:
    """A view (or one camera of it) left out of the calibration, and why."""

    index: int
    camera: str  # "tof", "sl" or "arm"
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {"index": self.index, "camera": self.camera, "reason": self.reason}


@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """The calibrated transforms and how well they explain the views.

    Attributes:
        camera_to_flange_m: (4, 4) float64 ToF optical frame -> flange frame, metres.
        sl_to_tof_m: (4, 4) float64 SL camera optical frame -> ToF optical frame, metres.
        board_to_base_m: (4, 4) float64 board frame -> base frame, metres (by-product).
        method: the linear hand-eye method that initialised the refinement.
        tof_views, sl_views: indices of the views whose ToF / SL detection was used.
        failures: every view or camera left out, with the reason.
        residuals: JSON-ready numbers: per-view PnP RMS (px), reprojection RMS through the
            calibrated chain (px), the ``A X = X B`` consistency over all view pairs (mm, deg)
            and each linear method's chain RMS (px).
    """

    camera_to_flange_m: np.ndarray
    sl_to_tof_m: np.ndarray
    board_to_base_m: np.ndarray
    method: str
    tof_views: tuple[int, ...]
    sl_views: tuple[int, ...]
    failures: tuple[ViewFailure, ...]
    residuals: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form: 4x4 matrices (m) and UR pose vectors (m, axis-angle rad)."""
        return {"camera_to_flange": _transform_dict(self.camera_to_flange_m),
                "sl_to_tof": _transform_dict(self.sl_to_tof_m),
                "board_to_base": _transform_dict(self.board_to_base_m),
                "method": self.method, "tof_views": list(self.tof_views),
                "sl_views": list(self.sl_views),
                "failures": [f.as_dict() for f in self.failures],
                "residuals": self.residuals}


def _transform_dict(matrix: np.ndarray) -> dict[str, Any]:
    return {"matrix_m": np.asarray(matrix).tolist(),
            "ur_pose_vector": matrix_to_pose_vector(matrix).tolist()}


# ---------------------------------------------------------------------------- pose helpers


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle (degrees) of a (3, 3) rotation matrix."""
    cos = (float(np.trace(rotation)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def pose_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(translation mm, rotation deg) between two (4, 4) poses in metres."""
    delta = invert_pose(a) @ b
    return float(np.linalg.norm(delta[:3, 3]) * 1000.0), rotation_angle_deg(delta[:3, :3])


def _vec_to_pose(v: np.ndarray) -> np.ndarray:
    """(4, 4) pose of the optimiser's (6,) ``[rotation vector (rad), translation]``."""
    return make_pose(rotvec_to_matrix(v[:3]), v[3:])


# -------------------------------------------------------------------- linear hand-eye solvers


def _motions(tcp: Sequence[np.ndarray], board_in_cam: Sequence[np.ndarray]
             ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Arm motions A and camera motions B of every view pair, with ``A X = X B``.

    The board is fixed in the base: ``G_i X C_i = G_j X C_j`` for TCP poses G and board-in-camera
    poses C, so ``A = G_j^-1 G_i`` and ``B = C_j C_i^-1``.
    """
    a, b = [], []
    for i, j in combinations(range(len(tcp)), 2):
        a.append(invert_pose(tcp[j]) @ tcp[i])
        b.append(board_in_cam[j] @ invert_pose(board_in_cam[i]))
    return a, b


def _translation_lsq(a: list[np.ndarray], b: list[np.ndarray], rotation: np.ndarray) -> np.ndarray:
    """t_X from ``(R_A - I) t_X = R_X t_B - t_A`` stacked over all motions (least squares)."""
    lhs = np.concatenate([m[:3, :3] - np.eye(3) for m in a])
    rhs = np.concatenate([rotation @ n[:3, 3] - m[:3, 3] for m, n in zip(a, b, strict=True)])
    return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _tsai_lenz(a: list[np.ndarray], b: list[np.ndarray]) -> np.ndarray:
    """Tsai & Lenz (1989): rotation from modified Rodrigues vectors, then translation."""
    def rodrigues(m: np.ndarray) -> np.ndarray:
        rv = matrix_to_rotvec(m)
        angle = np.linalg.norm(rv)
        return rv if angle == 0 else 2.0 * math.sin(angle / 2.0) * rv / angle
    pa, pb = [rodrigues(m) for m in a], [rodrigues(n) for n in b]
    lhs = np.concatenate([_skew(x + y) for x, y in zip(pa, pb, strict=True)])
    rhs = np.concatenate([y - x for x, y in zip(pa, pb, strict=True)])
    prime = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    p = 2.0 * prime / math.sqrt(1.0 + prime @ prime)
    norm2 = p @ p
    rotation = ((1.0 - norm2 / 2.0) * np.eye(3)
                + 0.5 * (np.outer(p, p) + math.sqrt(4.0 - norm2) * _skew(p)))
    return make_pose(rotation, _translation_lsq(a, b, rotation))


def _park_martin(a: list[np.ndarray], b: list[np.ndarray]) -> np.ndarray:
    """Park & Martin (1994): rotation ``(M^T M)^-1/2 M^T`` with ``M = sum beta alpha^T``."""
    m = sum(np.outer(matrix_to_rotvec(n), matrix_to_rotvec(k))
            for k, n in zip(a, b, strict=True))
    w, v = np.linalg.eigh(m.T @ m)
    if w.min() <= 1e-12:
        raise CalibrationError("hand-eye motions are degenerate (all rotation axes parallel); "
                               "tilt the views in different directions")
    rotation = v @ np.diag(w ** -0.5) @ v.T @ m.T
    u, _, vt = np.linalg.svd(rotation)  # project onto SO(3) against round-off
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return make_pose(rotation, _translation_lsq(a, b, rotation))


def linear_hand_eye(tcp_to_base_m: Sequence[np.ndarray], board_to_camera_m: Sequence[np.ndarray],
                    method: str) -> np.ndarray:
    """Camera-to-flange from views of a fixed target with one classical method.

    Uses ``cv2.calibrateHandEye`` when this OpenCV exposes it; otherwise numpy Tsai-Lenz and
    Park-Martin (the others need OpenCV).

    Args:
        tcp_to_base_m: (4, 4) flange poses in the base frame, metres, one per view.
        board_to_camera_m: (4, 4) board poses in the camera frame, metres, same views.
        method: ``"TSAI"``, ``"PARK"``, ``"HORAUD"``, ``"ANDREFF"`` or ``"DANIILIDIS"``.

    Returns:
        (4, 4) float64 camera optical frame -> flange frame, metres.
    """
    if method not in _OPENCV_METHODS:
        raise InputError(f"hand-eye method {method!r} is not one of {sorted(_OPENCV_METHODS)}")
    solver = getattr(cv2, "calibrateHandEye", None)
    if solver is not None:
        r_x, t_x = solver([g[:3, :3] for g in tcp_to_base_m], [g[:3, 3] for g in tcp_to_base_m],
                          [c[:3, :3] for c in board_to_camera_m],
                          [c[:3, 3] for c in board_to_camera_m],
                          method=getattr(cv2, _OPENCV_METHODS[method]))
        return make_pose(r_x, np.ravel(t_x))
    a, b = _motions(tcp_to_base_m, board_to_camera_m)
    if method == "TSAI":
        return _tsai_lenz(a, b)
    if method == "PARK":
        return _park_martin(a, b)
    raise CalibrationError(f"hand-eye method {method} needs cv2.calibrateHandEye, which this "
                           f"OpenCV {cv2.__version__} does not expose; use TSAI or PARK")


def available_methods() -> tuple[str, ...]:
    """Linear hand-eye methods this installation can run."""
    if hasattr(cv2, "calibrateHandEye"):
        return tuple(_OPENCV_METHODS)
    return ("TSAI", "PARK")


# ------------------------------------------------------------------------- residuals


def ax_xb_residuals(tcp_to_base_m: Sequence[np.ndarray], board_to_camera_m: Sequence[np.ndarray],
                    camera_to_flange_m: np.ndarray) -> dict[str, float]:
    """Consistency of ``A X = X B`` over all view pairs.

    Args:
        tcp_to_base_m: (4, 4) flange poses in the base frame, metres, one per view.
        board_to_camera_m: (4, 4) board poses in the camera frame (PnP), metres, same views.
        camera_to_flange_m: (4, 4) the camera's pose in the flange frame, metres.

    Returns:
        RMS and max over pairs of the translation (mm) and rotation (deg) of
        ``(A X)^-1 (X B)``.
    """
    a, b = _motions(tcp_to_base_m, board_to_camera_m)
    x = camera_to_flange_m
    errors = np.array([pose_difference(m @ x, x @ n) for m, n in zip(a, b, strict=True)])
    return {"translation_rms_mm": float(np.sqrt(np.mean(errors[:, 0] ** 2))),
            "translation_max_mm": float(errors[:, 0].max()),
            "rotation_rms_deg": float(np.sqrt(np.mean(errors[:, 1] ** 2))),
            "rotation_max_deg": float(errors[:, 1].max()), "pairs": len(a)}


def _rms(errors: np.ndarray) -> float:
    """RMS length of (..., 2) pixel error vectors."""
    return float(np.sqrt(np.mean(np.sum(errors ** 2, axis=-1))))


# ---------------------------------------------------------------------------- solver


@dataclass
class _CameraViews:
    """One camera's usable views: capture indices, TCP poses (m) and detections."""

    intrinsics: Intrinsics
    index: list[int] = field(default_factory=list)
    tcp: list[np.ndarray] = field(default_factory=list)
    det: list[BoardDetection] = field(default_factory=list)

    def board_poses(self) -> list[np.ndarray]:
        """(4, 4) board -> camera poses (m) of the views."""
        return [d.board_to_camera_m for d in self.det]

    def pnp_rms_px(self) -> float:
        return float(np.mean([d.rms_px for d in self.det]))

    def chain_errors(self, camera_to_flange: np.ndarray, board_to_base: np.ndarray,
                     object_points: np.ndarray) -> np.ndarray:
        """(V, N, 2) reprojection errors (px) of every corner through base -> flange -> camera.

        Args:
            camera_to_flange: (4, 4) this camera's pose in the flange frame, m.
            board_to_base: (4, 4) board pose in the base frame, m.
            object_points: (N, 3) board corners, m.
        """
        errors = []
        for g, det in zip(self.tcp, self.det, strict=True):
            board_in_cam = invert_pose(g @ camera_to_flange) @ board_to_base
            pts = object_points @ board_in_cam[:3, :3].T + board_in_cam[:3, 3]
            errors.append(self.intrinsics.project(pts) - det.corners_px)
        return np.asarray(errors)

    def board_in_base(self, camera_to_flange: np.ndarray) -> np.ndarray:
        """Board pose in the base (m) implied by each view through the hand-eye, averaged."""
        return mean_pose([g @ camera_to_flange @ c
                               for g, c in zip(self.tcp, self.board_poses(), strict=True)])


def _detect_all(captures: Sequence[HandEyeCapture], board: CalibrationBoard,
                tof_intrinsics: Intrinsics, sl_intrinsics: Intrinsics
                ) -> tuple[_CameraViews, _CameraViews, list[ViewFailure]]:
    """Detect the board in every image; a view or camera that fails is listed with why."""
    tof, sl = _CameraViews(tof_intrinsics), _CameraViews(sl_intrinsics)
    failures: list[ViewFailure] = []
    for cap in captures:
        if cap.tcp_to_base_m is None:
            failures.append(ViewFailure(cap.index, "arm", "no TCP pose recorded"))
            continue
        tcp = check_array("tcp_to_base_m", cap.tcp_to_base_m, ndim=2, shape=(4, 4),
                          dtype_kind="fiu").astype(np.float64)
        for name, views, image, upsample in (("tof", tof, cap.tof_amplitude, TOF_UPSAMPLE),
                                             ("sl", sl, cap.sl_image, 1)):
            if image is None:
                failures.append(ViewFailure(cap.index, name, "no image recorded"))
                continue
            try:
                det = detect_board(image, board, views.intrinsics, upsample=upsample)
            except CalibrationError as err:
                failures.append(ViewFailure(cap.index, name, str(err)))
                continue
            views.index.append(cap.index)
            views.tcp.append(tcp)
            views.det.append(det)
    return tof, sl, failures


def _require(views: _CameraViews, camera: str, failures: list[ViewFailure],
             min_views: int) -> None:
    """CalibrationError naming the views left out if ``views`` has fewer than ``min_views``."""
    if len(views.det) >= min_views:
        return
    shown = "; ".join(f"view {f.index} {f.camera}: {f.reason}" for f in failures[:6])
    if len(failures) > 6:
        shown += f"; +{len(failures) - 6} more"
    raise CalibrationError(f"hand-eye needs at least {min_views} views with the board detected "
                           f"in the {camera} image, got {len(views.det)}"
                           + (f" (left out: {shown})" if shown else ""))


def _pick_linear(tof: _CameraViews, object_points: np.ndarray
                 ) -> tuple[str, np.ndarray, dict[str, float]]:
    """The linear method whose X reprojects the ToF corners best through the chain."""
    scores: dict[str, float] = {}
    best: tuple[float, str, np.ndarray] | None = None
    for method in available_methods():
        try:
            x = linear_hand_eye(tof.tcp, tof.board_poses(), method)
        except (CalibrationError, cv2.error, np.linalg.LinAlgError):
            continue
        if not np.all(np.isfinite(x)):
            continue
        scores[method] = _rms(tof.chain_errors(x, tof.board_in_base(x), object_points))
        if best is None or scores[method] < best[0]:
            best = (scores[method], method, x)
    if best is None:
        raise CalibrationError("no linear hand-eye method converged; the views' rotations are "
                               "probably too similar")
    return best[1], best[2], scores


def _sl_to_tof_initial(tof: _CameraViews, sl: _CameraViews) -> np.ndarray:
    """Average over views with both detections of ``C_tof C_sl^-1`` (SL pose in ToF frame)."""
    sl_pose = dict(zip(sl.index, sl.board_poses(), strict=True))
    pairs = [c @ invert_pose(sl_pose[i]) for i, c in zip(tof.index, tof.board_poses(),
                                                          strict=True) if i in sl_pose]
    if not pairs:
        raise CalibrationError("no view has the board detected by both the ToF and the SL "
                               "camera; the ToF-to-SL transform cannot be estimated")
    return mean_pose(pairs)


def _refine(x0: np.ndarray, s0: np.ndarray, b0: np.ndarray, tof: _CameraViews,
            sl: _CameraViews, object_points: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint least squares of X, SL-in-ToF and board-in-base over every corner of both cameras.

    Each camera's residuals are divided by its median per-view PnP RMS, so the sharp SL image
    and the coarse ToF image count by their precision. Parameters are small corrections
    (rotation vector, metres) applied on the right of the initial poses.
    """
    sigma_tof = max(float(np.median([d.rms_px for d in tof.det])), 0.02)
    sigma_sl = max(float(np.median([d.rms_px for d in sl.det])), 0.02)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return x0 @ _vec_to_pose(p[0:6]), s0 @ _vec_to_pose(p[6:12]), b0 @ _vec_to_pose(p[12:18])

    def residuals(p: np.ndarray) -> np.ndarray:
        x, s, b = unpack(p)
        return np.concatenate([tof.chain_errors(x, b, object_points).ravel() / sigma_tof,
                               sl.chain_errors(x @ s, b, object_points).ravel() / sigma_sl])

    # A 1 mrad turn moves corners about as much as a 0.3 mm shift at these ranges.
    scale = np.tile(np.array([1e-3] * 3 + [3e-4] * 3), 3)
    fit = least_squares(residuals, np.zeros(18), x_scale=scale, method="lm")
    return unpack(fit.x)


def solve_hand_eye(captures: Sequence[HandEyeCapture], board: CalibrationBoard,
                   tof_intrinsics: Intrinsics, sl_intrinsics: Intrinsics, *,
                   min_views: int = MIN_VIEWS, refine: bool = True) -> HandEyeResult:
    """Camera-to-flange and ToF-to-SL transforms from checkerboard views.

    Args:
        captures: the views: TCP pose (m), ToF amplitude, SL image.
        board: the printed target.
        tof_intrinsics: intrinsics of the ToF amplitude images (e.g. the 180x140 crop).
        sl_intrinsics: intrinsics of the SL images.
        min_views: fewest usable views per camera.
        refine: run the joint reprojection refinement after the linear hand-eye solution.

    Returns:
        The transforms, the views used, every view left out with its reason, and residuals.

    Raises:
        CalibrationError: fewer than ``min_views`` views with the board detected in either
            camera (the message lists why views were left out), or a degenerate set of motions.
    """
    if min_views < 3:
        raise InputError(f"min_views must be >= 3 (hand-eye needs two independent motions), "
                         f"got {min_views}")
    tof, sl, failures = _detect_all(captures, board, tof_intrinsics, sl_intrinsics)
    _require(tof, "ToF amplitude", failures, min_views)
    _require(sl, "SL", failures, min_views)
    obj = board.object_points_m()
    method, x, method_rms = _pick_linear(tof, obj)
    s = _sl_to_tof_initial(tof, sl)
    b = tof.board_in_base(x)
    if refine:
        x, s, b = _refine(x, s, b, tof, sl, obj)
    residuals = {
        "pnp_rms_px": {"tof": tof.pnp_rms_px(), "sl": sl.pnp_rms_px()},
        "chain_rms_px": {"tof": _rms(tof.chain_errors(x, b, obj)),
                         "sl": _rms(sl.chain_errors(x @ s, b, obj))},
        # A X = X B over view pairs with each camera's own PnP poses: the ToF one shows the
        # coarse amplitude image's pose noise, the SL one (X S for the SL camera) the sharper.
        "ax_xb": {"tof": ax_xb_residuals(tof.tcp, tof.board_poses(), x),
                  "sl": ax_xb_residuals(sl.tcp, sl.board_poses(), x @ s)},
        "linear_methods_chain_rms_px": method_rms,
        "refined": refine,
    }
    return HandEyeResult(camera_to_flange_m=x, sl_to_tof_m=s, board_to_base_m=b, method=method,
                         tof_views=tuple(tof.index), sl_views=tuple(sl.index),
                         failures=tuple(failures), residuals=residuals)
