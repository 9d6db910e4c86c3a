"""Viewpoint plans: 18 reachable views, the paper's ranges, rejections reported."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tof_mpd_ros.arm.ur5e import camera_pose, link_frames
from tof_mpd_ros.arm.viewpoints import ViewpointConfig, plan_views, view_pose_mm
from tof_mpd_ros.errors import InputError, SimulationError
from tof_mpd_ros.pose import pose_m_to_mm
from tof_mpd_ros.sim.scene import SceneConfig, make_box_scene, make_scene
from tof_mpd_ros.sim.viewpoints import plan_viewpoints


def test_view_pose_geometry_by_hand() -> None:
    target = np.array([450.0, 0.0, 50.0])
    pose = view_pose_mm(target, top_z_mm=100.0, height_mm=250.0, tilt_deg=0.0, azimuth_deg=0.0,
                        roll_deg=0.0)
    np.testing.assert_allclose(pose[:3, 3], [450.0, 0.0, 350.0], atol=1e-9)
    np.testing.assert_allclose(pose[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)
    tilted = view_pose_mm(target, 100.0, 250.0, 30.0, 90.0, 0.0)
    # 300 mm of height over the target at 30 deg: 300 tan(30) sideways towards +y.
    np.testing.assert_allclose(tilted[:3, 3], [450.0, 300.0 * math.tan(math.pi / 6), 350.0],
                               atol=1e-9)


@pytest.mark.parametrize("split,seed", [("train", 0), ("test", 1)])
def test_plan_has_18_reachable_views_in_the_paper_ranges(split: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    scene = make_scene(split, rng)
    config = ViewpointConfig()
    plan = plan_viewpoints(scene, rng, config)
    assert len(plan.viewpoints) == 18
    top = scene.top_height_mm()
    heights, azimuths = [], []
    for i, view in enumerate(plan.viewpoints):
        assert view.index == i
        pose = view.camera_to_base_mm
        above = pose[2, 3] - top
        assert 180.0 - 1e-9 <= above <= 350.0 + 1e-9
        assert above == pytest.approx(view.height_mm)
        tilt = math.degrees(math.acos(-pose[2, 2]))
        assert tilt <= 30.0 + 1e-9 and tilt == pytest.approx(view.tilt_deg, abs=1e-6)
        # The optical axis passes through the target.
        to_target = plan.target_mm - pose[:3, 3]
        assert np.linalg.norm(np.cross(pose[:3, 2], to_target)) < 1e-6
        # The joints realise the pose (FK + hand-eye), within the limits, above the table.
        np.testing.assert_allclose(pose_m_to_mm(camera_pose(view.joints_rad)), pose, atol=1e-6)
        assert link_frames(view.joints_rad)[1:, 2, 3].min() * 1000.0 >= 50.0
        np.testing.assert_allclose(view.camera_to_base_m[:3, 3], pose[:3, 3] / 1000.0)
        heights.append(above)
        azimuths.append(view.azimuth_deg)
    # Stratified: every height band and azimuth sector is used.
    assert np.histogram(heights, bins=3, range=(180, 350))[0].min() >= 1
    assert np.histogram(azimuths, bins=6, range=(0, 360))[0].min() >= 1
    # Candidate numbers account for every draw, accepted or rejected.
    numbers = sorted([v.candidate for v in plan.viewpoints] + [c for c, _ in plan.rejected])
    assert numbers == list(range(len(numbers)))


def test_plan_is_deterministic() -> None:
    scene = make_box_scene()
    a = plan_viewpoints(scene, np.random.default_rng(5))
    b = plan_viewpoints(scene, np.random.default_rng(5))
    for va, vb in zip(a.viewpoints, b.viewpoints, strict=True):
        np.testing.assert_array_equal(va.camera_to_base_mm, vb.camera_to_base_mm)
        np.testing.assert_array_equal(va.joints_rad, vb.joints_rad)


def test_unreachable_candidates_are_reported_and_replaced() -> None:
    # Objects at the edge of the reach: some views are out of reach, others replace them.
    scene = make_box_scene(centre_xy_mm=(760.0, 0.0))
    plan = plan_viewpoints(scene, np.random.default_rng(0))
    assert len(plan.viewpoints) == 18
    assert len(plan.rejected) > 0
    assert all(reason.startswith("unreachable") for _, reason in plan.rejected)


def test_hopeless_plan_raises_simulation_error() -> None:
    scene = make_scene("train", np.random.default_rng(0),
                       SceneConfig(workspace_centre_mm=(1500.0, 0.0)))
    with pytest.raises(SimulationError, match="only 0 of 18 views reachable after 40"):
        plan_viewpoints(scene, np.random.default_rng(0), ViewpointConfig(max_candidates=40))
    with pytest.raises(InputError, match="must be positive"):
        plan_viewpoints(scene, np.random.default_rng(0), replace(ViewpointConfig(), n_views=0))


def test_any_number_of_views_is_stratified() -> None:
    plan = plan_viewpoints(make_box_scene(), np.random.default_rng(4),
                           ViewpointConfig(n_views=4))
    assert len(plan.viewpoints) == 4
    bands = [int((v.height_mm - 180.0) // (170.0 / 3)) for v in plan.viewpoints]
    sectors = [int(v.azimuth_deg // 180.0) for v in plan.viewpoints]
    assert bands == [0, 1, 2, 0] and sectors == [0, 0, 0, 1]


def test_the_simulator_plans_with_the_arm_planner() -> None:
    # sim.viewpoints only feeds a scene's geometry to the one planner, arm.viewpoints.plan_views.
    scene = make_scene("train", np.random.default_rng(4))
    config = ViewpointConfig(n_views=5)
    ours = plan_viewpoints(scene, np.random.default_rng(9), config)
    direct = plan_views(scene.objects_centroid_mm(), scene.top_height_mm(),
                        scene.table.height_mm, np.random.default_rng(9), config)
    assert ours.rejected == direct.rejected
    np.testing.assert_array_equal(ours.target_mm, direct.target_mm)
    for a, b in zip(ours.viewpoints, direct.viewpoints, strict=True):
        np.testing.assert_array_equal(a.camera_to_base_mm, b.camera_to_base_mm)
        np.testing.assert_array_equal(a.joints_rad, b.joints_rad)
