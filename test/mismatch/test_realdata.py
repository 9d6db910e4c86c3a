"""The real Azure Kinect frame: pinhole resampling and the plane-fit reference."""

from __future__ import annotations

import numpy as np

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.mismatch.realdata import (
    BrownConrady,
    azure_kinect_frame,
    plane_reference,
)


def test_zero_distortion_is_a_pinhole():
    m = BrownConrady(500.0, 500.0, 320.0, 288.0, (0.0,) * 6, 0.0, 0.0)
    u, v = m.distort(np.array([0.1]), np.array([-0.2]))
    np.testing.assert_allclose([u[0], v[0]], [370.0, 188.0])


def test_plane_reference_of_two_planes():
    k = Intrinsics.from_fov(60, 40, 70.0)
    rays = k.ray_directions()
    # a floor y = 100 mm and a wall z = 600 mm: concave crease across the image
    t_floor = np.where(rays[..., 1] > 0, 100.0 / np.maximum(rays[..., 1], 1e-9), np.inf)
    t_wall = 600.0 / rays[..., 2]
    truth = np.minimum(t_floor, t_wall)
    noisy = truth + np.random.default_rng(0).normal(0, 1.0, truth.shape)
    ref = plane_reference(noisy, k, crease_margin_mm=30.0)
    ok = np.isfinite(ref.reference_mm)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(ref.reference_mm[ok], truth[ok], atol=3.0)


def test_azure_kinect_frame_has_a_plane_reference(azure_kinect_dir):
    frame, ref = azure_kinect_frame(azure_kinect_dir, downsample=8)
    assert frame.intrinsics.shape == (72, 80)
    ok = np.isfinite(frame.reference_mm) & np.isfinite(frame.range_mm)
    assert ok.mean() > 0.3
    res = frame.range_mm[ok] - frame.reference_mm[ok]
    assert abs(np.median(res)) < 5.0
    assert np.all(np.abs(ref.planes[:, :3] @ ref.planes[:, :3].T).diagonal() > 0.999)
