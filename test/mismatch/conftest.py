"""Small analytic "real" sweeps for the mismatch tests.

A box stands on a table (a concave crease) and the camera slides sideways at a varying speed.
The "real" frames are rendered from the analytic solids, supersampled 3 x 3 (a different path
from the tool's reference-based predictor); the reference is the true range plus 0.5 mm noise.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from oracles.analytic_scenes import box_on_table_scene, raycast

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.mismatch.data import camera_motion, split_frames
from tof_mpd_ros.mismatch.fit import Problem
from tof_mpd_ros.mismatch.predict import FramePredictor
from tof_mpd_ros.pose import rotvec_to_matrix
from tof_mpd_ros.sim.tof import ToFConfig, render_tof

SMALL = Intrinsics.from_fov(48, 36, 74.0)
PERIOD_S = 0.1


def camera_x_mm(t_s: float) -> float:
    """Sideways camera position: 150 mm/s on average, speed varying by ±80 %."""
    return 150.0 * t_s + 12.0 * np.sin(2 * np.pi * t_s / 0.6) - 40.0


def _scene_from(x_mm: float, rotvec: np.ndarray, shift_mm: np.ndarray) -> list:
    """Solids in the frame of a camera at (x_mm, 0, 0) + shift, rotated by rotvec."""
    rot = rotvec_to_matrix(rotvec)
    t = np.array([x_mm, 0.0, 0.0]) + shift_mm
    out = []
    for s in box_on_table_scene(table_mm=320.0, height_mm=110.0, wall_x_mm=20.0,
                                box_albedo=0.35):
        # n·p <= c with p = R p' + t  ->  (Rᵀ n)·p' <= c − n·t
        out.append(replace(s, normals=s.normals @ rot, offsets=s.offsets - s.normals @ t))
    return out


def make_sweep(effects: dict[str, dict], *, n_frames: int = 6, seed: int = 0,
               intrinsics: Intrinsics = SMALL, camera: ToFConfig | None = None,
               amplitude_scale: float = 1.0) -> list[ToFFrame]:
    """Frames carrying ``effects`` (name -> params; hand_eye and time_offset are physical) on
    ``camera`` (default the nominal cell), its amplitude reported in units
    ``amplitude_scale`` × the simulator's."""
    rng = np.random.default_rng(seed)
    cfg = ToFConfig.nominal() if camera is None else camera
    for name, params in effects.items():
        if name not in ("hand_eye", "time_offset"):
            cfg = cfg.with_effect(name, enabled=True, **params)
    frames = []
    for i in range(n_frames):
        t = i * PERIOD_S
        t_real = t + 1e-3 * effects.get("time_offset", {}).get("offset_ms", 0.0)
        he = effects.get("hand_eye", {})
        rot = 1e-3 * np.array([he.get("rx_mrad", 0.0), he.get("ry_mrad", 0.0),
                               he.get("rz_mrad", 0.0)])
        shift = np.array([he.get("tx_mm", 0.0), he.get("ty_mm", 0.0), he.get("tz_mm", 0.0)])
        real = raycast(_scene_from(camera_x_mm(t_real), rot, shift), intrinsics.scaled(3))
        meas = render_tof(real, cfg, rng, supersample=3, frame_index=i)
        truth = raycast(_scene_from(camera_x_mm(t), np.zeros(3), np.zeros(3)), intrinsics)
        ref = truth.range_mm + rng.normal(0.0, 0.5, truth.range_mm.shape)
        pose = np.eye(4)
        pose[0, 3] = camera_x_mm(t) * 1e-3
        frames.append(ToFFrame(meas.range_mm, meas.amplitude * amplitude_scale, intrinsics,
                               mod_freq_hz=cfg.mod_freq_hz, reference_mm=ref,
                               stamp_ns=round(t * 1e9), pose=pose))
    return frames


@pytest.fixture(scope="session")
def sweep():
    """``sweep(effects, **kw)``: a cached analytic sweep."""
    cache: dict = {}

    def build(effects: dict[str, dict] | None = None, **kw) -> list[ToFFrame]:
        key = (repr(sorted((effects or {}).items())), repr(sorted(kw.items())))
        if key not in cache:
            cache[key] = make_sweep(effects or {}, **kw)
        return cache[key]

    return build


def make_problem(frames: list[ToFFrame], config: ToFConfig) -> Problem:
    """The analysis's fitting problem for ``frames`` around the model ``config`` (every pixel
    with a real and a predicted range usable; alternate frames train / held-out)."""
    predictors = [FramePredictor(f, config, frame_index=i, motion=m)
                  for i, (f, m) in enumerate(zip(frames, camera_motion(frames), strict=True))]
    real = [np.asarray(f.range_mm, dtype=np.float64) for f in frames]
    usable = [np.isfinite(r) & np.isfinite(p.predict().range_mm)
              for r, p in zip(real, predictors, strict=True)]
    return Problem(real, predictors, split_frames(frames), usable)


@pytest.fixture(scope="session")
def problem_of():
    """``problem_of(frames, config)``: :func:`make_problem`."""
    return make_problem
