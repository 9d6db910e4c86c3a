"""Per-pixel descriptors that localise a mismatch: where in the image, the scene and the sweep.

Every descriptor is computed from what a real recording holds (reference, amplitude, poses,
stamps) and from the nominal prediction, never from simulator internals the real camera lacks.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from ..frame import ToFFrame
from ..sim.tof import CameraMotion
from .data import camera_speed
from .predict import FramePredictor

#: depth edge: neighbouring reference ranges differ by more than this (mm) or this fraction
EDGE_JUMP_MM = 10.0
EDGE_JUMP_REL = 0.03

#: descriptor name -> (unit, words for "high values")
DESCRIPTORS: dict[str, tuple[str, str]] = {
    "radius_px": ("px", "far from the principal point"),
    "edge_distance_px": ("px", "far from depth edges"),
    "interreflection_mm": ("mm", "with strong predicted interreflection"),
    "concavity": ("mm/px²", "in concave creases"),
    "range_mm": ("mm", "at long range"),
    "amplitude": ("amplitude", "at high amplitude"),
    "incidence_deg": ("deg", "at grazing incidence"),
    "frame_index": ("frame", "late in the recording"),
    "time_s": ("s", "late in the recording"),
    "speed_mm_s": ("mm/s", "while the camera moves fast"),
    "angular_speed_deg_s": ("deg/s", "while the camera turns fast"),
}


def depth_edges(range_mm: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels beside a depth discontinuity (or a hole) of the reference."""
    r = np.asarray(range_mm, dtype=np.float64)
    edge = np.zeros(r.shape, dtype=bool)
    for axis in (0, 1):
        d = np.abs(np.diff(r, axis=axis))
        limit = np.maximum(EDGE_JUMP_MM, EDGE_JUMP_REL * np.fmin(
            np.delete(r, -1, axis=axis), np.delete(r, 0, axis=axis)))
        jump = ~(d <= limit)  # NaN (hole) counts as a jump
        pad_lo = [(0, 0), (0, 0)]
        pad_hi = [(0, 0), (0, 0)]
        pad_lo[axis] = (1, 0)
        pad_hi[axis] = (0, 1)
        edge |= np.pad(jump, pad_lo) | np.pad(jump, pad_hi)
    return edge & np.isfinite(r)


def edge_jump_mm(range_mm: np.ndarray) -> np.ndarray:
    """(H, W) float64 largest range step (mm) to a 4-neighbour at depth-edge pixels, else 0.

    Holes count as no step (their side of the edge is unknown)."""
    r = np.asarray(range_mm, dtype=np.float64)
    jump = np.zeros(r.shape)
    for axis in (0, 1):
        d = np.abs(np.diff(r, axis=axis))
        d = np.where(np.isfinite(d), d, 0.0)
        lo = [(0, 0), (0, 0)]
        hi = [(0, 0), (0, 0)]
        lo[axis], hi[axis] = (1, 0), (0, 1)
        jump = np.maximum(jump, np.maximum(np.pad(d, lo), np.pad(d, hi)))
    return np.where(depth_edges(r), jump, 0.0)


def concavity(range_mm: np.ndarray, frame: ToFFrame, sigma_px: float = 1.5) -> np.ndarray:
    """Negative Laplacian of the smoothed z-depth (mm per px²): > 0 in concave creases.

    Depth edges are excluded (NaN) because a discontinuity is not a crease.
    """
    z = frame.intrinsics.radial_to_z(np.nan_to_num(range_mm, nan=np.nanmedian(range_mm)))
    lap = ndimage.gaussian_laplace(z.astype(np.float64), sigma_px)
    edge_zone = ndimage.binary_dilation(depth_edges(range_mm), iterations=2)
    return np.where(edge_zone | ~np.isfinite(range_mm), np.nan, -lap)


def incidence_deg(predictor: FramePredictor) -> np.ndarray:
    """(H, W) angle between the surface normal and the pixel ray, degrees (NaN = hole)."""
    rays = predictor.frame.intrinsics.ray_directions()
    cos = -np.einsum("hwk,hwk->hw", predictor.surface.normal, rays)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def frame_descriptors(predictor: FramePredictor, index: int, t_s: float,
                      motion: CameraMotion | None) -> dict[str, np.ndarray]:
    """All descriptors of one frame, each (H, W) float64 (NaN where undefined)."""
    frame = predictor.frame
    k = frame.intrinsics
    ref = np.asarray(frame.reference_mm, dtype=np.float64)
    v, u = np.mgrid[0:k.height, 0:k.width].astype(np.float64)
    edges = depth_edges(ref)
    edge_dist = (ndimage.distance_transform_edt(~edges) if edges.any()
                 else np.full(ref.shape, float(max(k.shape))))
    base = predictor.base
    # interreflection potential at physical strength (gain 1), whatever the current model says
    with_mp = predictor.predict(base.with_effect("multipath", enabled=True, gain=1.0)).range_mm
    no_mp = predictor.predict(base.with_effect("multipath", enabled=False)).range_mm
    speed, turn = camera_speed(motion)
    full = np.ones(ref.shape)
    return {
        "radius_px": np.hypot(u - k.cx, v - k.cy),
        "edge_distance_px": edge_dist,
        "interreflection_mm": with_mp - no_mp,
        "concavity": concavity(ref, frame),
        "range_mm": ref,
        "amplitude": np.asarray(frame.amplitude, dtype=np.float64),
        "incidence_deg": incidence_deg(predictor),
        "frame_index": full * index,
        "time_s": full * t_s,
        "speed_mm_s": full * speed,
        "angular_speed_deg_s": full * np.degrees(turn),
    }


def all_descriptors(predictors: Sequence[FramePredictor],
                    motions: Sequence[CameraMotion | None]) -> list[dict[str, np.ndarray]]:
    """Descriptors of every frame (time from the stamps, relative to the first frame)."""
    t0 = predictors[0].frame.stamp_ns
    return [frame_descriptors(p, i, (p.frame.stamp_ns - t0) * 1e-9, m)
            for i, (p, m) in enumerate(zip(predictors, motions, strict=True))]
