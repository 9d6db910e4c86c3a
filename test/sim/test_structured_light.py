"""Structured-light scans (noise, projector shadows) and the paper's multi-scan fusion."""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracles.raycast_reference import visible_from

from tof_mpd_ros.arm.viewpoints import view_pose_mm
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.pose import invert_pose, look_at, make_pose, rot_z, transform_points
from tof_mpd_ros.sim.objects import ObjectSpec
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import PlacedObject, Scene, Table, make_box_scene
from tof_mpd_ros.sim.structured_light import (
    FusionConfig,
    StructuredLightConfig,
    fuse_points,
    reference_range,
    scan_poses,
    sl_scan,
)

TOF = Intrinsics.ds325().crop(180, 140)


def test_fusion_rule_by_hand() -> None:
    intr = Intrinsics(fx=100.0, fy=100.0, cx=2.0, cy=2.0, width=5, height=5)
    centre_ray = np.array([0.0, 0.0, 1.0])
    left_ray = np.array([-0.01, 0.0, 1.0]) / math.hypot(0.01, 1.0)  # pixel (row 2, col 1)
    near = [100.0, 100.2, 100.4, 100.6, 100.8]
    points = [centre_ray * r for r in near + [150.0] * 6]          # two clusters
    points += [left_ray * r for r in [90.0] * 3 + [200.0, 200.5, 201.0, 201.5, 202.0, 203.0]]
    points += [np.array([-0.02, -0.02, 1.0]) * 100.0] * 4          # pixel (0, 0): too few
    points += [np.array([0.0, 0.0, -100.0])] * 9                    # behind the camera
    ref = fuse_points(np.array(points), np.eye(4), intr, FusionConfig(min_points=5))
    assert ref.dtype == np.float32 and ref.shape == (5, 5)
    assert ref[2, 2] == pytest.approx(100.4)       # median of the nearest cluster
    assert ref[2, 1] == pytest.approx(201.25)      # the 3-point sliver in front is ignored
    assert np.isnan(ref[0, 0])
    assert np.isfinite(ref).sum() == 2
    with pytest.raises(InputError, match="min_points"):
        fuse_points(np.array(points), np.eye(4), intr, FusionConfig(min_points=0))


def test_scan_noise_is_half_a_millimetre_along_the_ray() -> None:
    scene = Scene(Table())
    pose = look_at(np.array([450.0, 0.0, 500.0]), np.array([450.0, 0.0, 0.0]))
    points = sl_scan(scene, pose, np.random.default_rng(0))
    offset = points - pose[:3, 3]
    measured = np.linalg.norm(offset, axis=1)
    true = 500.0 / (-offset[:, 2] / measured)  # range to z = 0 along the same ray
    residual = measured - true
    assert points.shape[0] > 30000
    assert abs(residual.mean()) < 0.02
    assert residual.std() == pytest.approx(0.5, rel=0.05)


def test_projector_shadow_is_missing() -> None:
    scene = make_box_scene((150.0, 150.0, 100.0))
    pose = look_at(np.array([450.0, 0.0, 500.0]), np.array([450.0, 0.0, 0.0]))
    assert np.allclose(pose[:3, 0], [0.0, 1.0, 0.0])  # projector 75 mm towards -y
    points = sl_scan(scene, pose, np.random.default_rng(0), StructuredLightConfig(noise_mm=0.0))
    on_table = (np.abs(points[:, 2]) < 1e-6) & (np.abs(points[:, 0] - 450.0) < 60.0)
    # The top edge at y = +75 shadows the table out to y = 75 + 150 * 100 / 400 = 112.5.
    shadow = on_table & (points[:, 1] < 110.0) & (points[:, 1] > 77.0)
    lit_side = on_table & (points[:, 1] < -77.0) & (points[:, 1] > -110.0)
    beyond = on_table & (points[:, 1] > 115.0) & (points[:, 1] < 150.0)
    assert shadow.sum() == 0
    assert lit_side.sum() > 200 and beyond.sum() > 200


def test_scan_poses_circle_the_tof_axis() -> None:
    tof = look_at(np.array([450.0, 0.0, 400.0]), np.array([450.0, 0.0, 0.0]))
    poses = scan_poses(tof)
    assert poses.shape == (30, 4, 4)
    local = transform_points(invert_pose(tof), poses[:, :3, 3])
    np.testing.assert_allclose(np.hypot(local[:, 0], local[:, 1]), 50.0, atol=1e-9)
    np.testing.assert_allclose(np.unique(np.round(local[:, 2], 6)), [-40.0, 0.0, 40.0])
    np.testing.assert_allclose(poses[:, :3, 2], np.tile(tof[:3, 2], (30, 1)), atol=1e-12)


def _true_neighbourhood(true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, min and max of the true range over its 3x3 neighbourhood (NaN-aware)."""
    h, w = true.shape
    pad = np.pad(true, 1, constant_values=np.nan)
    stack = np.stack([pad[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)])
    return np.nanmin(stack, axis=0), np.nanmax(stack, axis=0)


def test_fused_reference_matches_the_true_range() -> None:
    scene = make_box_scene((150.0, 120.0, 100.0), yaw_rad=0.3)
    tof = view_pose_mm(scene.objects_centroid_mm(), scene.top_height_mm(), 250.0, 20.0, 30.0,
                       10.0)
    true = render_surface(scene, tof, TOF).range_mm
    ref = reference_range(scene, tof, TOF, np.random.default_rng(1))
    valid = np.isfinite(ref)
    assert valid.mean() > 0.95
    lo, hi = _true_neighbourhood(true)
    smooth = (hi - lo) < 10.0  # no depth discontinuity next to the pixel
    err = (ref - true)[valid & smooth]
    assert np.sqrt(np.mean(err**2)) < 1.0
    assert np.abs(err).max() < 3.0
    # At discontinuities the nearest-cluster rule may take the neighbouring foreground: the
    # value is still a range seen within one pixel.
    edge = valid & ~smooth
    assert edge.sum() > 100
    assert np.all((ref[edge] >= lo[edge] - 1.5) & (ref[edge] <= hi[edge] + 1.5))


def _pit_scene(gap_mm: float = 20.0, height_mm: float = 190.0) -> Scene:
    """Four tall boxes in a pinwheel around a square pit of side ``gap_mm`` at (450, 0)."""
    boxes = []
    for i in range(4):
        yaw = i * math.pi / 2
        # Box i spans x in [-g/2 - 100, -g/2] and y in [-g/2, -g/2 + 125] before the turn.
        centre = np.array([-gap_mm / 2 - 50.0, -gap_mm / 2 + 62.5])
        x, y = rot_z(yaw)[:2, :2] @ centre
        spec = ObjectSpec(100 + i, "box", (100.0, 125.0, height_mm), 0.5)
        boxes.append(PlacedObject(spec, i + 1, 450.0 + x, y, 0.0, yaw))
    return Scene(Table(), tuple(boxes))


def _measurable(scene: Scene, points: np.ndarray, tof: np.ndarray,
                sensor: StructuredLightConfig) -> np.ndarray:
    """(N,) bool: some scan's camera and projector both see the point (FOV and occlusion)."""
    hit = np.zeros(points.shape[0], dtype=bool)
    for pose in scan_poses(tof, sensor):
        projector = pose @ make_pose(np.eye(3), np.array(sensor.projector_in_sl_mm))
        ok = np.ones_like(hit)
        for eye in (pose, projector):
            local = transform_points(invert_pose(eye), points)
            uv = sensor.intrinsics.project(local)
            ok &= ((local[:, 2] > 0) & (uv[:, 0] > -0.5) & (uv[:, 0] < sensor.intrinsics.width)
                   & (uv[:, 1] > -0.5) & (uv[:, 1] < sensor.intrinsics.height))
            ok &= visible_from(scene, points, eye[:3, 3])
        hit |= ok
    return hit


def test_pixels_no_scan_can_measure_are_missing() -> None:
    scene = _pit_scene()
    sensor = StructuredLightConfig()
    tof = look_at(np.array([450.0, 0.0, 430.0]), np.array([450.0, 0.0, 0.0]))
    surface = render_surface(scene, tof, TOF)
    ref = reference_range(scene, tof, TOF, np.random.default_rng(2), sensor)
    floor_in_pit = (surface.object_id == 0) & (surface.range_mm < 440.0)
    assert floor_in_pit.sum() > 50
    assert np.all(np.isnan(ref[floor_in_pit]))
    assert np.isfinite(ref[surface.object_id > 0]).mean() > 0.95
    # In general: a pixel is missing when no scan measures its point nor its neighbours'
    # (a neighbour's points may land in it).
    points = transform_points(tof, surface.points_mm()).reshape(-1, 3)
    measurable = _measurable(scene, points, tof, sensor).reshape(TOF.shape)
    padded = np.pad(measurable, 1)
    near_measurable = np.any([padded[dy:dy + TOF.height, dx:dx + TOF.width]
                              for dy in range(3) for dx in range(3)], axis=0)
    assert (~near_measurable).sum() >= 30
    assert np.all(np.isnan(ref[~near_measurable]))
