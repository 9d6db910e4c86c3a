"""Collection without ROS: plans, resumable sessions, and the capture loop with a failing arm."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sim_helpers import small_camera

from tof_mpd_ros.arm.isolated import IsolatedArm
from tof_mpd_ros.arm.tool import DEFAULT_T_FLANGE_CAMERA_M
from tof_mpd_ros.collection import session
from tof_mpd_ros.collection.plan import load_plan, save_plan
from tof_mpd_ros.collection.runner import run_plan
from tof_mpd_ros.errors import CaptureError, InputError
from tof_mpd_ros.pose import pose_m_to_mm
from tof_mpd_ros.recordings import RecordingReader, RecordingWriter
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.dataset import scene_rng
from tof_mpd_ros.sim.scene import make_scene
from tof_mpd_ros.sim.viewpoints import sim_plan

HAND_EYE = DEFAULT_T_FLANGE_CAMERA_M
START_S = 120.0  # the arm client's start-up on a busy machine (its connect timeout is not tested)
VIEWS = 4


@pytest.fixture(scope="module")
def plan():
    return sim_plan(0, "test", 0, VIEWS, HAND_EYE)


def simulated_capture():
    """A capture function rendering the sim scene directly at the requested camera pose."""
    scene = make_scene("test", scene_rng(0, "test", 0))
    cell = SimCell(camera=small_camera())
    rng = np.random.default_rng(0)

    def capture(after_ns: int, camera_to_base_m: np.ndarray):
        frame = cell.capture(scene, pose_m_to_mm(camera_to_base_m), rng, stamp_ns=after_ns + 1)
        frame.pose = camera_to_base_m
        return frame

    return capture


def run(session_dir: Path, pending, arm, capture=None):
    with RecordingWriter(session.next_part(session_dir)) as writer:
        return run_plan(pending, arm, capture or simulated_capture(), writer, HAND_EYE,
                        settle_s=0.0)


def test_plan_round_trips_through_yaml(plan, tmp_path: Path) -> None:
    save_plan(tmp_path / "plan.yaml", plan)
    loaded = load_plan(tmp_path / "plan.yaml")
    assert len(loaded) == VIEWS
    for a, b in zip(plan, loaded, strict=True):
        np.testing.assert_allclose(a.tcp_to_base_m, b.tcp_to_base_m, atol=1e-12)


def test_bad_plan_file_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "bad.yaml").write_text("views: [[1, 2, 3]]")
    with pytest.raises(InputError, match="6-vectors"):
        load_plan(tmp_path / "bad.yaml")


def test_arm_crash_mid_plan_then_resume_records_every_view_once(plan, tmp_path: Path) -> None:
    with IsolatedArm("sim", connect_timeout_s=START_S, faults={"crash_on_move": 3}) as arm:
        first = run(tmp_path, plan, arm)
    assert first.recorded == [0, 1] and first.failed_view == 2
    assert "died" in first.error

    done = session.completed_views(tmp_path, plan, HAND_EYE)
    assert done == {0: 1, 1: 1, 2: 0, 3: 0}
    pending = [v for v in plan if done[v.index] == 0]
    with IsolatedArm("sim", connect_timeout_s=START_S) as arm:
        second = run(tmp_path, pending, arm)
    assert second.ok and second.recorded == [2, 3]
    assert session.completed_views(tmp_path, plan, HAND_EYE) == {i: 1 for i in range(VIEWS)}
    assert [p.name for p in session.parts(tmp_path)] == ["part_000", "part_001"]


def test_recorded_frames_hold_tcp_pose_and_hand_eye(plan, tmp_path: Path) -> None:
    with IsolatedArm("sim", connect_timeout_s=START_S) as arm:
        result = run(tmp_path, plan[:2], arm)
    assert result.recorded == [0, 1]
    with RecordingReader(session.parts(tmp_path)[0]) as reader:
        frames = list(reader.frames())
    for frame, view in zip(frames, plan[:2], strict=True):
        np.testing.assert_allclose(frame.pose, view.camera_to_base_m(HAND_EYE), atol=1e-6)
        assert np.isfinite(frame.reference_mm).mean() > 0.5


def test_capture_timeouts_skip_the_view_and_are_reported(plan, tmp_path: Path) -> None:
    def never(after_ns: int, pose: np.ndarray):
        raise CaptureError("nothing on the topics")

    with IsolatedArm("sim", connect_timeout_s=START_S) as arm:
        result = run(tmp_path, plan[:2], arm, capture=never)
    assert result.ok and result.recorded == [] and result.skipped == [0, 1]
