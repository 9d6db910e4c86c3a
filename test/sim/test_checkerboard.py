"""Graded checkerboard: albedo grading, ray-plane geometry, calibration pose ranges."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.pose import make_pose, rot_y
from tof_mpd_ros.sim.checkerboard import (
    CalibrationPoseConfig,
    CheckerboardConfig,
    calibration_poses,
    render_checkerboard,
)

INTR = Intrinsics(fx=200.0, fy=200.0, cx=60.0, cy=45.0, width=121, height=91)


def test_albedo_grades_from_top_to_bottom() -> None:
    config = CheckerboardConfig()
    albedo = config.albedo_map()
    assert albedo.shape == (config.n_rows, config.n_cols)
    assert albedo[0, 0] == 0.0 and albedo[0, 1] == 0.5
    assert albedo[-1, 0] == pytest.approx(1.0) and albedo[-1, 1] == pytest.approx(0.5)
    assert np.all(np.diff(albedo[:, 0][::2]) > 0) and np.all(np.diff(albedo[:, 1][1::2]) > 0)
    is_dark = (np.add.outer(np.arange(config.n_rows), np.arange(config.n_cols)) % 2) == 0
    assert albedo[is_dark].max() <= 0.5 <= albedo[~is_dark].min()


def test_frontal_board_by_hand() -> None:
    config = CheckerboardConfig(n_cols=4, n_rows=4, square_mm=50.0)
    surf = render_checkerboard(make_pose(np.eye(3), np.array([0.0, 0.0, 300.0])), INTR, config)
    rays = INTR.ray_directions()
    on = surf.valid
    np.testing.assert_allclose(surf.range_mm[on], (300.0 / rays[..., 2])[on], rtol=1e-12)
    np.testing.assert_allclose(surf.normal[on], np.tile([0.0, 0.0, -1.0], (on.sum(), 1)))
    # Board 200 mm wide at 300 mm covers |u - cx| <= 200 * 100 / 300 = 66.7 px: all columns.
    assert on[45].all()
    # ... and the centre pixel sees the corner of squares (row 2, col 2): look just off it.
    x, y = 200.0 * 10.0 / 300.0, 200.0 * 30.0 / 300.0  # 10 mm right, 30 mm down
    pix = (round(45 + y), round(60 + x))
    assert surf.albedo[pix] == config.albedo_map()[2, 2]
    assert surf.object_id[pix] == 1 and surf.material_id[pix] == 0
    far = render_checkerboard(make_pose(np.eye(3), np.array([0.0, 0.0, 2000.0])), INTR, config)
    assert not far.valid[0, 0] and far.albedo[0, 0] == 0.0 and far.object_id[0, 0] == -1


def test_tilted_board_range_follows_the_plane() -> None:
    tilt = math.radians(35.0)
    pose = make_pose(rot_y(tilt), np.array([10.0, -5.0, 250.0]))
    surf = render_checkerboard(pose, INTR)
    points = surf.points_mm()[surf.valid]
    normal = pose[:3, 2]
    np.testing.assert_allclose((points - pose[:3, 3]) @ normal, 0.0, atol=1e-9)
    assert np.all(surf.normal[surf.valid] @ normal == pytest.approx(-1.0))
    # Turning about +y brings the board's +x side towards the camera: on the centre row the
    # range falls with u, from the far edge to the near edge.
    row = surf.range_mm[45][surf.valid[45]]
    assert np.all(np.diff(row) < 0) and row[0] - row[-1] > 50.0


def test_calibration_poses_are_in_range_and_deterministic() -> None:
    config = CalibrationPoseConfig()
    poses = calibration_poses(300, np.random.default_rng(0), config)
    assert poses.shape == (300, 4, 4)
    np.testing.assert_array_equal(poses, calibration_poses(300, np.random.default_rng(0)))
    ranges = np.linalg.norm(poses[:, :3, 3], axis=1)
    assert ranges.min() >= 150.0 and ranges.max() <= 450.0
    assert ranges.min() < 170.0 and ranges.max() > 430.0
    tilts = np.degrees(np.arccos(poses[:, 2, 2]))
    assert tilts.max() <= 40.0 + 1e-9 and tilts.max() > 35.0
    rot = poses[:, :3, :3]
    np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.tile(np.eye(3), (300, 1, 1)),
                               atol=1e-12)
    # The board centre stays inside the paper's 180x140 crop.
    crop = Intrinsics.ds325().crop(180, 140)
    uv = crop.project(poses[:, :3, 3])
    assert np.all((uv >= 0) & (uv <= [crop.width - 1, crop.height - 1]))
    # Every capture sees the board over most of the crop.
    coverage = [render_checkerboard(p, crop).valid.mean() for p in poses[:20]]
    assert min(coverage) > 0.5
    with pytest.raises(InputError, match="n must be"):
        calibration_poses(-1, np.random.default_rng(0))
