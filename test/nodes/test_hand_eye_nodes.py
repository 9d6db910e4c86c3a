"""Hand-eye calibration through the nodes, in separate processes (loopback only).

sim_cell shows the calibration board (its true hand-eye is the default moved by 4 mm and 1 deg)
while the collector drives the simulated arm through the hand-eye plan with the *nominal*
hand-eye; `tof-mpd calibrate hand-eye` solves the recording; a scene session recorded with
``hand_eye_file`` then carries the recovered transform in every frame.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from ros_harness import domain_id, start_node, stop_node  # noqa: E402

from tof_mpd_ros.arm.tool import DEFAULT_T_FLANGE_CAMERA_M  # noqa: E402
from tof_mpd_ros.calibration.hand_eye import pose_difference  # noqa: E402
from tof_mpd_ros.calibration.hand_eye_io import (  # noqa: E402
    KEY_CALIBRATION_FILE,
    read_hand_eye_recording,
)
from tof_mpd_ros.cli.main import main  # noqa: E402
from tof_mpd_ros.collection import session  # noqa: E402
from tof_mpd_ros.pose import matrix_to_pose_vector, pose_mm_to_m  # noqa: E402
from tof_mpd_ros.recordings import RecordingReader, convert  # noqa: E402
from tof_mpd_ros.sim.hand_eye import perturb_pose  # noqa: E402
from tof_mpd_ros.sim.structured_light import StructuredLightConfig  # noqa: E402

# This run's own domains (test/conftest.py); the scene sim_cell starts early (its first frame
# takes a while) on a domain of its own.
DOMAIN, SCENE_DOMAIN = domain_id(6), domain_id(7)
VIEWS = 10
TRUE_HAND_EYE = perturb_pose(DEFAULT_T_FLANGE_CAMERA_M, np.random.default_rng(5))
# Timeouts for a busy machine: the arm client is a child interpreter, a frame a fresh render.
FAST = {"settle_time_s": 0.1, "capture_timeout_s": 120.0, "connect_timeout_s": 120.0,
        "speed": 1.0, "accel": 5.0}


def pose_param(matrix: np.ndarray) -> str:
    """A UR pose vector as a ``-p name:=[...]`` value (fixed-point: YAML reads 1e-05 as text)."""
    return "[" + ", ".join(f"{v:.12f}" for v in matrix_to_pose_vector(matrix)) + "]"


@pytest.fixture(scope="module", autouse=True)
def ros_log_dir(tmp_path_factory: pytest.TempPathFactory):
    """The node processes log under a directory of this module's own."""
    old = os.environ.get("ROS_LOG_DIR")
    os.environ["ROS_LOG_DIR"] = str(tmp_path_factory.mktemp("ros_log"))
    yield
    if old is None:
        os.environ.pop("ROS_LOG_DIR", None)
    else:
        os.environ["ROS_LOG_DIR"] = old


@pytest.fixture(scope="module")
def scene_sim_cell(tmp_path_factory: pytest.TempPathFactory):
    """sim_cell showing the scene, same true hand-eye; started before the calibration so its
    start-up (JIT compilation, first structured-light render) overlaps it."""
    log = tmp_path_factory.mktemp("scene") / "scene_sim_cell.log"
    process = start_node("sim_cell", {"views": 1, "rate_hz": 15.0,
                                      "hand_eye": pose_param(TRUE_HAND_EYE)}, SCENE_DOMAIN, log)
    yield process
    assert stop_node(process) == 0, log.read_text()[-2000:]


@pytest.fixture(scope="module")
def calibration(tmp_path_factory: pytest.TempPathFactory, scene_sim_cell) -> dict:
    """Record the calibration session through the nodes and solve it with the CLI."""
    tmp = tmp_path_factory.mktemp("hand_eye")
    sim_log, collector_log = tmp / "sim_cell.log", tmp / "collector.log"
    started = time.monotonic()
    sim = start_node("sim_cell", {"target": "hand_eye_board", "views": 1, "rate_hz": 15.0,
                                  "hand_eye": pose_param(TRUE_HAND_EYE)}, DOMAIN, sim_log)
    try:
        collector = start_node("collector", {**FAST, "plan": "hand_eye", "hand_eye_views": VIEWS,
                                             "session_path": str(tmp / "cal")},
                               DOMAIN, collector_log)
        assert collector.wait(540) == 0, collector_log.read_text()[-3000:]
    finally:
        assert stop_node(sim) == 0, sim_log.read_text()[-2000:]
    recorded_s = time.monotonic() - started
    out = tmp / "he.json"
    assert main(["calibrate", "hand-eye", str(tmp / "cal" / "part_000"), "-o", str(out)]) == 0
    return {"tmp": tmp, "session": tmp / "cal", "json": out, "recorded_s": recorded_s,
            "result": json.loads(out.read_text()), "collector_log": collector_log}


def test_the_collector_records_a_calibration_the_cli_solves(calibration: dict) -> None:
    parts = session.parts(calibration["session"])
    assert [p.name for p in parts] == ["part_000"]
    data = read_hand_eye_recording(parts[0])
    assert len(data.captures) == VIEWS
    assert all(c.tcp_to_base_m is not None and c.sl_image is not None
               and c.sl_image.dtype == np.uint8 for c in data.captures)
    assert data.sl_intrinsics.shape == (480, 640)
    result = calibration["result"]
    assert result["failures"] == [] and len(result["tof_views"]) == VIEWS
    recovered = np.asarray(result["camera_to_flange"]["matrix_m"])
    translation_mm, rotation_deg = pose_difference(recovered, TRUE_HAND_EYE)
    print(f"\nnodes: {VIEWS} views recorded in {calibration['recorded_s']:.0f} s; "
          f"camera-to-flange error {translation_mm:.3f} mm, {rotation_deg:.4f} deg "
          f"(nominal guess was off by "
          f"{pose_difference(DEFAULT_T_FLANGE_CAMERA_M, TRUE_HAND_EYE)[0]:.1f} mm, "
          f"{pose_difference(DEFAULT_T_FLANGE_CAMERA_M, TRUE_HAND_EYE)[1]:.2f} deg)")
    assert translation_mm < 1.0 and rotation_deg < 0.2
    sl_truth = pose_mm_to_m(StructuredLightConfig().sl_to_tof_mm)
    sl_mm, sl_deg = pose_difference(np.asarray(result["sl_to_tof"]["matrix_m"]), sl_truth)
    print(f"nodes: SL-to-ToF error {sl_mm:.3f} mm, {sl_deg:.4f} deg")
    assert sl_mm < 1.0 and sl_deg < 0.2


def test_a_finished_calibration_session_is_not_recorded_again(calibration: dict) -> None:
    """Resuming matches views on the TCP pose: nothing is missing, no part is added."""
    log = calibration["tmp"] / "again.log"
    again = start_node("collector", {**FAST, "plan": "hand_eye", "hand_eye_views": VIEWS,
                                     "session_path": str(calibration["session"])}, DOMAIN, log)
    assert again.wait(300) == 0, log.read_text()[-3000:]
    assert f"{VIEWS} already recorded" in log.read_text()
    assert len(session.parts(calibration["session"])) == 1
    # The session directory solves like its part.
    assert read_hand_eye_recording(calibration["session"]).captures[-1].index == VIEWS - 1


def test_a_scene_session_with_hand_eye_file_records_the_recovered_transform(
        calibration: dict, scene_sim_cell) -> None:
    tmp = calibration["tmp"]
    recovered = np.asarray(calibration["result"]["camera_to_flange"]["matrix_m"])
    collector_log = tmp / "scene_collector.log"
    collector = start_node("collector", {**FAST, "views": 2, "session_path": str(tmp / "s"),
                                         "hand_eye_file": str(calibration["json"])},
                           SCENE_DOMAIN, collector_log)
    assert collector.wait(540) == 0, collector_log.read_text()[-3000:]
    parts = session.parts(tmp / "s")
    assert len(parts) == 1
    with RecordingReader(parts[0]) as reader:
        assert reader.custom_data[KEY_CALIBRATION_FILE] == str(calibration["json"].resolve())
        frames = list(reader.frames())
        names = reader.topic_names
        by_topic: dict[str, list] = {names.hand_eye: [], names.tcp_pose: []}
        for m in reader.messages({names.hand_eye, names.tcp_pose}):
            by_topic[m.topic].append(m.message)
    assert len(frames) == 2
    hand_eyes = [convert.matrix_of_transform(m) for m in by_topic[names.hand_eye]]
    tcps = [convert.matrix_of_pose(m) for m in by_topic[names.tcp_pose]]
    assert len(hand_eyes) == len(tcps) == 2
    for frame, hand_eye, tcp in zip(frames, hand_eyes, tcps, strict=True):
        np.testing.assert_allclose(hand_eye, recovered, atol=1e-9)
        np.testing.assert_allclose(frame.pose, tcp @ recovered, atol=1e-9)
        # The recorded camera pose is where sim_cell really rendered from (the nominal
        # hand-eye would put it 4 mm and 1 deg off).
        translation_mm, rotation_deg = pose_difference(frame.pose, tcp @ TRUE_HAND_EYE)
        assert translation_mm < 1.0 and rotation_deg < 0.2
        # And the frames are complete renders: ToF and structured-light reference agree.
        valid = np.isfinite(frame.range_mm) & np.isfinite(frame.reference_mm)
        assert valid.mean() > 0.8
        assert np.nanmedian(np.abs(frame.range_mm - frame.reference_mm)[valid]) < 20.0


def test_a_scene_plan_refuses_a_calibration_session(calibration: dict) -> None:
    log = calibration["tmp"] / "mixed.log"
    mixed = start_node("collector", {**FAST, "views": 1,
                                     "session_path": str(calibration["session"])}, DOMAIN, log)
    mixed.wait(300)
    assert "holds hand-eye calibrations (part_000)" in log.read_text()
    assert len(session.parts(calibration["session"])) == 1


def test_a_bad_hand_eye_file_stops_the_collector_before_it_moves(tmp_path) -> None:
    bad = tmp_path / "he.json"
    bad.write_text('{"camera_to_flange": {}}')
    log = tmp_path / "bad.log"
    collector = start_node("collector", {**FAST, "views": 1, "hand_eye_file": str(bad),
                                         "session_path": str(tmp_path / "s")}, DOMAIN, log)
    collector.wait(300)
    assert "not a hand-eye result" in log.read_text()
    assert session.parts(tmp_path / "s") == []


def test_a_resumed_calibration_session_reads_as_one(tmp_path) -> None:
    """Parts written view by view (as the collector does) merge in stamp order, and the views
    they hold are matched on the TCP pose (no rendering: synthetic images)."""
    from tof_mpd_ros.calibration.hand_eye_board import CalibrationBoard
    from tof_mpd_ros.calibration.hand_eye_io import hand_eye_custom_data, write_hand_eye_view
    from tof_mpd_ros.camera import Intrinsics
    from tof_mpd_ros.collection.hand_eye_plan import default_tof_intrinsics
    from tof_mpd_ros.collection.plan import PlannedView
    from tof_mpd_ros.frame import ToFFrame
    from tof_mpd_ros.pose import make_pose
    from tof_mpd_ros.recordings import RecordingWriter

    tof, sl = default_tof_intrinsics(), Intrinsics.from_fov(64, 48, 65.0)
    rng = np.random.default_rng(0)
    tcps = [make_pose(np.eye(3), np.array([0.4 + 0.01 * i, 0.0, 0.3])) for i in range(4)]
    for part, views in (("part_000", (0, 1)), ("part_001", (3,))):
        with RecordingWriter(tmp_path / part,
                             custom_data=hand_eye_custom_data(CalibrationBoard())) as writer:
            for i in views:
                frame = ToFFrame(np.full(tof.shape, 300.0, np.float32),
                                 rng.random(tof.shape, dtype=np.float32), tof,
                                 stamp_ns=1_000 + i)
                write_hand_eye_view(writer, frame, tcps[i],
                                    rng.integers(0, 255, sl.shape, dtype=np.uint8), sl)
    data = read_hand_eye_recording(tmp_path)
    assert [c.stamp_ns for c in data.captures] == [1_000, 1_001, 1_003]
    assert [c.index for c in data.captures] == [0, 1, 2]
    assert all(c.sl_image.shape == sl.shape for c in data.captures)
    plan = [PlannedView(i, t) for i, t in enumerate(tcps)]
    assert session.completed_calibration_views(tmp_path, plan) == {0: 1, 1: 1, 2: 0, 3: 1}
    assert session.parts_of_other_kind(tmp_path, calibration=True) == []
    assert len(session.parts_of_other_kind(tmp_path, calibration=False)) == 2
