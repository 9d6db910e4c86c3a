"""Hand–eye calibration on the simulated cell: plan, detection, solvers, recording, CLI.

One simulated session (8 views, true hand-eye and SL offset moved off their defaults by a few
mm and ~1 degree) is rendered once per module (~10-20 s) and shared.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tof_mpd_ros.arm.tool import DEFAULT_T_FLANGE_CAMERA_M
from tof_mpd_ros.arm.ur5e import solve_ik
from tof_mpd_ros.calibration.hand_eye import (
    CalibrationBoard,
    HandEyeCapture,
    linear_hand_eye,
    pose_difference,
    solve_hand_eye,
)
from tof_mpd_ros.calibration.hand_eye_board import detect_board
from tof_mpd_ros.calibration.hand_eye_io import (
    load_hand_eye_json,
    read_hand_eye_recording,
    write_hand_eye_recording,
)
from tof_mpd_ros.cli.main import main
from tof_mpd_ros.collection.hand_eye_plan import (
    HandEyePlanConfig,
    board_visible,
    default_sl_intrinsics,
    hand_eye_plan,
    rotation_axis_spread_deg,
)
from tof_mpd_ros.errors import CalibrationError, InputError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.pose import (
    invert_pose,
    make_pose,
    pose_m_to_mm,
    pose_mm_to_m,
    rot_x,
    rot_y,
    rot_z,
)
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.hand_eye import (
    HandEyeSimConfig,
    perturb_pose,
    render_sl_image,
    simulate_hand_eye_session,
)
from tof_mpd_ros.sim.structured_light import StructuredLightConfig

BOARD = CalibrationBoard()
N_VIEWS = 8


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Simulated session written to a recording and read back, with the true transforms."""
    rng = np.random.default_rng(7)
    true_x = perturb_pose(DEFAULT_T_FLANGE_CAMERA_M, rng, translation_mm=4.0, rotation_deg=1.0)
    true_s = perturb_pose(pose_mm_to_m(StructuredLightConfig().sl_to_tof_mm), rng,
                          translation_mm=3.0, rotation_deg=1.0)
    cell = SimCell(structured_light=StructuredLightConfig(sl_to_tof_mm=pose_m_to_mm(true_s)))
    config = HandEyeSimConfig(n_views=N_VIEWS, t_flange_camera_m=true_x)
    captures, frames = simulate_hand_eye_session(rng, config, cell)
    path = tmp_path_factory.mktemp("hand_eye") / "calib"
    write_hand_eye_recording(path, frames, [c.tcp_to_base_m for c in captures],
                             [c.sl_image for c in captures], BOARD, config.sl_intrinsics,
                             sim_truth={"camera_to_flange": true_x, "sl_to_tof": true_s})
    return {"path": path, "x": true_x, "s": true_s, "frames": frames, "captures": captures,
            "data": read_hand_eye_recording(path)}


# ------------------------------------------------------------------------------ end to end


def test_recovers_simulated_transforms_from_recording(session):
    # The truth is off the defaults, so returning a default would fail.
    assert pose_difference(session["x"], DEFAULT_T_FLANGE_CAMERA_M)[0] > 3.0
    data = session["data"]
    assert len(data.captures) == N_VIEWS and data.board == BOARD
    result = solve_hand_eye(data.captures, data.board, data.tof_intrinsics, data.sl_intrinsics)
    x_mm, x_deg = pose_difference(result.camera_to_flange_m, session["x"])
    s_mm, s_deg = pose_difference(result.sl_to_tof_m, session["s"])
    assert x_mm < 1.0 and x_deg < 0.2, (x_mm, x_deg)
    assert s_mm < 1.0 and s_deg < 0.2, (s_mm, s_deg)
    assert result.failures == () and len(result.tof_views) == N_VIEWS
    # Corners are reprojected through the calibrated chain to a fraction of a pixel.
    assert result.residuals["chain_rms_px"]["tof"] < 0.3
    assert result.residuals["chain_rms_px"]["sl"] < 0.3
    assert result.residuals["ax_xb"]["tof"]["pairs"] == N_VIEWS * (N_VIEWS - 1) // 2
    # Arm and camera motions agree to about a millimetre and a tenth of a degree per view pair
    # (single-view PnP noise); the fit averages it down to the accuracy above.
    for camera in ("tof", "sl"):
        assert result.residuals["ax_xb"][camera]["translation_rms_mm"] < 2.0
        assert result.residuals["ax_xb"][camera]["rotation_rms_deg"] < 0.3
    assert set(result.residuals["linear_methods_chain_rms_px"]) >= {"TSAI", "PARK"}


def test_refinement_beats_the_linear_solution(session):
    data = session["data"]
    linear = solve_hand_eye(data.captures, BOARD, data.tof_intrinsics, data.sl_intrinsics,
                            refine=False)
    refined = solve_hand_eye(data.captures, BOARD, data.tof_intrinsics, data.sl_intrinsics)
    assert (pose_difference(refined.camera_to_flange_m, session["x"])[0]
            < pose_difference(linear.camera_to_flange_m, session["x"])[0])


def _blank(capture: HandEyeCapture) -> HandEyeCapture:
    """The view with a ToF amplitude image that shows no board (a smooth ramp)."""
    h, w = capture.tof_amplitude.shape
    ramp = np.tile(np.linspace(50.0, 60.0, w, dtype=np.float32), (h, 1))
    return HandEyeCapture(capture.index, capture.stamp_ns, capture.tcp_to_base_m, ramp,
                          capture.sl_image)


def test_failed_view_is_reported_not_dropped(session):
    data = session["data"]
    captures = list(data.captures)
    captures[3] = _blank(captures[3])
    result = solve_hand_eye(captures, BOARD, data.tof_intrinsics, data.sl_intrinsics)
    assert [(f.index, f.camera) for f in result.failures] == [(3, "tof")]
    assert "findChessboardCorners" in result.failures[0].reason
    assert 3 not in result.tof_views and 3 in result.sl_views
    assert pose_difference(result.camera_to_flange_m, session["x"])[0] < 1.0


def test_too_few_detectable_views_is_a_calibration_error(session, tmp_path):
    frames = [f if i < 3 else ToFFrame(f.range_mm, _blank(c).tof_amplitude, f.intrinsics,
                                       stamp_ns=f.stamp_ns)
              for i, (f, c) in enumerate(zip(session["frames"], session["captures"],
                                             strict=True))]
    path = tmp_path / "few"
    write_hand_eye_recording(path, frames, [c.tcp_to_base_m for c in session["captures"]],
                             [c.sl_image for c in session["captures"]], BOARD,
                             default_sl_intrinsics())
    data = read_hand_eye_recording(path)
    with pytest.raises(CalibrationError, match=r"at least 4 views .* ToF amplitude image, got 3"
                                               r".*view 3 tof: findChessboardCorners"):
        solve_hand_eye(data.captures, data.board, data.tof_intrinsics, data.sl_intrinsics)
    # The CLI turns it into one line and exit code 2.
    assert main(["calibrate", "hand-eye", str(path)]) == 2


def test_cli_writes_transforms_and_residuals(session, tmp_path, capsys):
    out = tmp_path / "hand_eye.json"
    assert main(["calibrate", "hand-eye", str(session["path"]), "-o", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary == json.loads(capsys.readouterr().out)
    matrix = np.array(summary["camera_to_flange"]["matrix_m"])
    assert pose_difference(matrix, session["x"])[0] < 1.0
    assert len(summary["camera_to_flange"]["ur_pose_vector"]) == 6
    assert summary["error_vs_sim_truth"]["sl_to_tof"]["translation_mm"] < 1.0
    assert summary["residuals"]["ax_xb"]["tof"]["rotation_rms_deg"] >= 0.0
    # The file feeds later recordings.
    camera_to_flange, sl_to_tof = load_hand_eye_json(out)
    np.testing.assert_allclose(camera_to_flange, matrix)
    assert pose_difference(sl_to_tof, session["s"])[0] < 1.0
    out.write_text("{}")
    with pytest.raises(CalibrationError, match="not a hand-eye result"):
        load_hand_eye_json(out)


def test_cli_simulate_records_then_calibrates(tmp_path, capsys):
    path = tmp_path / "simulated"
    assert main(["calibrate", "hand-eye", str(path), "--simulate", "--views", "5",
                 "--seed", "3"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["views"] == 5 and (path / "metadata.yaml").exists()
    error = summary["error_vs_sim_truth"]["camera_to_flange"]
    assert error["translation_mm"] < 1.0 and error["rotation_deg"] < 0.2
    # Refuses to overwrite the recording it made.
    assert main(["calibrate", "hand-eye", str(path), "--simulate", "--views", "5"]) == 2


def test_cli_help_says_what_it_reads_writes_and_how_long(capsys):
    with pytest.raises(SystemExit):
        main(["calibrate", "hand-eye", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Reads a calibration recording" in text and "JSON" in text and "second" in text


# ------------------------------------------------------------------------------------ plan


def test_plan_views_are_reachable_varied_and_show_the_board():
    board_to_base = HandEyeSimConfig().board_to_base_m
    poses = hand_eye_plan(board_to_base, 12, np.random.default_rng(3))
    assert len(poses) == 12
    config = HandEyePlanConfig()
    for tcp in poses:
        solve_ik(tcp)  # raises if unreachable
        camera = pose_m_to_mm(tcp @ DEFAULT_T_FLANGE_CAMERA_M)
        board_in_cam = invert_pose(camera) @ pose_m_to_mm(board_to_base)
        assert board_visible(board_in_cam, config) is None
        assert 240.0 <= np.linalg.norm(board_in_cam[:3, 3]) <= 420.0
        tilt = math.degrees(math.acos(abs(board_in_cam[2, 2])))
        assert tilt <= 32.0
    assert rotation_axis_spread_deg(poses) >= 15.0


def test_axis_spread_of_motions_about_one_axis_is_zero():
    poses = [make_pose(rot_z(0.2 * k), np.zeros(3)) for k in range(5)]
    assert rotation_axis_spread_deg(poses) == pytest.approx(0.0, abs=1e-6)
    poses = [make_pose(np.eye(3), np.zeros(3)), make_pose(rot_x(0.3), np.zeros(3)),
             make_pose(rot_x(0.3) @ rot_y(0.3), np.zeros(3))]
    assert rotation_axis_spread_deg(poses) == pytest.approx(90.0, abs=1e-6)


def test_unreachable_plan_is_a_calibration_error():
    far_away = make_pose(np.diag([1.0, -1.0, -1.0]), np.array([3.0, 0.0, 0.0]))
    with pytest.raises(CalibrationError, match="only 0 of 5 hand-eye views"):
        hand_eye_plan(far_away, 5, np.random.default_rng(0),
                      config=HandEyePlanConfig(max_candidates=20))


# --------------------------------------------------------------------------- linear solvers


def _exact_views(x: np.ndarray, n: int, rng: np.random.Generator):
    board = make_pose(rot_x(math.pi), np.array([0.45, 0.0, 0.0]))
    tcp, cams = [], []
    for _ in range(n):
        tilt = rot_x(rng.uniform(-0.4, 0.4)) @ rot_y(rng.uniform(-0.4, 0.4))
        g = make_pose(rot_x(math.pi) @ tilt @ rot_z(rng.uniform(-1.0, 1.0)),
                      np.array([0.45, 0.0, 0.35]) + rng.normal(0.0, 0.03, 3))
        tcp.append(g)
        cams.append(invert_pose(g @ x) @ board)
    return tcp, cams


@pytest.mark.parametrize("method", ["TSAI", "PARK"])
def test_linear_methods_are_exact_on_exact_poses(method):
    x = perturb_pose(DEFAULT_T_FLANGE_CAMERA_M, np.random.default_rng(5))
    tcp, cams = _exact_views(x, 6, np.random.default_rng(6))
    estimate = linear_hand_eye(tcp, cams, method)
    mm, deg = pose_difference(estimate, x)
    assert mm < 1e-6 and deg < 1e-6


def test_unknown_method_is_an_input_error():
    with pytest.raises(InputError, match="not one of"):
        linear_hand_eye([np.eye(4)] * 3, [np.eye(4)] * 3, "MAGIC")


# ------------------------------------------------------------------------------- detection


@pytest.mark.parametrize("roll_deg", [0.0, 90.0, 180.0, 270.0])
def test_detection_labels_the_board_the_same_way_at_any_roll(roll_deg):
    intr = default_sl_intrinsics()
    true = make_pose(rot_x(math.radians(15.0)) @ rot_z(math.radians(roll_deg)),
                     np.array([10.0, -5.0, 320.0]))
    image = render_sl_image(BOARD, true, intr, np.random.default_rng(0), supersample=2)
    det = detect_board(image, BOARD, intr)
    # A mislabelled board would be off by 90-180 degrees; one view's PnP is good to ~0.3 deg.
    mm, deg = pose_difference(det.board_to_camera_m, pose_mm_to_m(true))
    assert mm < 1.0 and deg < 0.5, (mm, deg)
    assert det.rms_px < 0.3


def test_symmetric_board_is_refused():
    with pytest.raises(InputError, match="180 degrees"):
        CalibrationBoard(n_cols=8, n_rows=6)


def test_object_points_follow_opencv_order():
    pts = BOARD.object_points_m() * 1000.0
    assert pts.shape == (8 * 5, 3)
    np.testing.assert_allclose(pts[0], [-70.0, -40.0, 0.0])
    np.testing.assert_allclose(pts[1] - pts[0], [20.0, 0.0, 0.0])
    np.testing.assert_allclose(pts[8] - pts[0], [0.0, 20.0, 0.0])
