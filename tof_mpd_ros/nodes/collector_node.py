"""The collector node class: a lifecycle node that records a viewpoint plan.

* ``configure``: build the plan, find the views the session already holds, connect the arm (its
  client runs in a child process with timeouts) and open a new recording part;
* ``activate``: a worker thread moves the arm through the missing views, captures one
  synchronised set per view from the topics (ToF depth + amplitude + CameraInfo, the
  structured-light reference) and appends it, with the TCP pose and hand-eye transform;
* ``deactivate`` stops after the current view; ``cleanup`` closes the recording and the arm.

With ``autostart`` (default) the node configures and activates itself; with ``exit_when_done`` it
shuts down once the plan is finished or the arm failed (the session can be resumed by running
the collector again).

``plan:=hand_eye`` records a hand-eye calibration session instead: the arm visits
:func:`~tof_mpd_ros.collection.hand_eye_plan.hand_eye_plan_views` over the board at
``board_pose``, and each view (ToF depth + amplitude + CameraInfo and the SL camera's intensity
image + CameraInfo, synchronised, with the TCP pose) is written as
:mod:`~tof_mpd_ros.calibration.hand_eye_io` describes, so ``tof-mpd calibrate hand-eye SESSION``
(or ``SESSION/part_000``) solves it. Such a session resumes like any other (views are matched on
the TCP pose). With ``hand_eye_file`` (the JSON of ``tof-mpd calibrate hand-eye -o``) the
calibrated camera-to-flange replaces the ``hand_eye`` parameter, for the plan and in every
recorded frame.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.lifecycle import LifecycleNode, State, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from ..arm.isolated import IsolatedArm
from ..calibration.hand_eye_board import CalibrationBoard
from ..calibration.hand_eye_io import (
    KEY_CALIBRATION_FILE,
    KEY_SL_TO_TOF,
    hand_eye_custom_data,
    load_hand_eye_json,
    write_hand_eye_view,
)
from ..camera import Intrinsics
from ..collection import session
from ..collection.hand_eye_plan import hand_eye_plan_views
from ..collection.plan import PlannedView, load_plan
from ..collection.runner import CaptureFunction, RunResult, WriteFunction, run_plan
from ..errors import CaptureError, InputError, TofMpdError
from ..frame import ToFFrame
from ..image_encoding import amplitude_to_float, depth_to_mm, image_to_array
from ..pose import pose_vector_to_matrix
from .cell_topics import CELL_TOPICS, RETIRED_TOPIC_PARAMETERS
from .parameters import ParameterSpec as P
from .parameters import declare, refuse_retired_parameters
from .qos import overridable_publisher, overridable_subscription, subscription_qos
from .ros_messages import intrinsics_of, pose_message, stamp_ns

# The node's parameters; config/collector.yaml mirrors these defaults (a test keeps them equal).
PARAMETERS = (
    P("arm_backend", "sim", "sim: the simulated UR5e; ur_rtde: a real UR over RTDE.",
      choices=("sim", "ur_rtde"), read_only=True),
    P("robot_ip", "192.168.1.10", "UR controller address (ur_rtde only).", read_only=True),
    P("session_path", "recordings/session", "Session directory; parts part_NNN are "
      "recordings. Existing parts are kept and the plan resumes.", read_only=True),
    P("plan", "scene", "scene: record the scene's viewpoint plan (or plan_file); hand_eye: "
      "record a hand-eye calibration session over the board at board_pose (ToF + SL images, "
      "for `tof-mpd calibrate hand-eye`).", choices=("scene", "hand_eye"), read_only=True),
    P("plan_file", "", "YAML plan (views: [[x y z rx ry rz], ...] TCP poses, m/rad); empty = "
      "the simulated scene's plan (plan scene) or the hand-eye plan (plan hand_eye).",
      read_only=True),
    P("seed", 0, "Simulated scene seed (same as the sim_cell node's).", read_only=True),
    P("split", "test", "Simulated scene's object split.", choices=("train", "test"),
      read_only=True),
    P("scene", 0, "Simulated scene index.", min_value=0, max_value=100000, read_only=True),
    P("views", 18, "Views of the simulated plan to visit.", min_value=1, max_value=18,
      read_only=True),
    P("hand_eye", [0.0, 0.0, 0.06, 0.0, 0.0, 0.0], "Camera pose in the flange frame, UR pose "
      "vector [x y z rx ry rz] (m, rad); used when hand_eye_file is empty.", read_only=True),
    P("hand_eye_file", "", "JSON result of `tof-mpd calibrate hand-eye -o`; when set, its "
      "camera_to_flange replaces hand_eye for the plan and in every recorded frame.",
      read_only=True),
    P("hand_eye_views", 12, "Views of the hand-eye calibration plan.", min_value=4,
      max_value=60, read_only=True),
    P("board_pose", [0.45, 0.0, 0.0, 3.141592653589793, 0.0, 0.0], "Calibration board frame in "
      "the base frame (UR pose vector, m, rad; z into the table), for plan hand_eye.",
      read_only=True),
    P("board_cols", 9, "Squares across the calibration board (one of cols, rows odd).",
      min_value=3, max_value=50, read_only=True),
    P("board_rows", 6, "Squares down the calibration board.", min_value=3, max_value=50,
      read_only=True),
    P("board_square_mm", 20.0, "Side of a calibration board square, mm.", min_value=1.0,
      max_value=500.0, read_only=True),
    P("speed", 0.1, "TCP speed of moveL, m/s.", min_value=0.001, max_value=1.0),
    P("accel", 0.5, "TCP acceleration of moveL, m/s^2.", min_value=0.01, max_value=5.0),
    P("settle_time_s", 0.5, "Wait after a move before capturing.", min_value=0.0,
      max_value=30.0),
    P("capture_timeout_s", 15.0, "How long to wait for a synchronised ToF + reference set.",
      min_value=0.1, max_value=600.0),
    P("connect_timeout_s", 10.0, "Arm connection timeout.", min_value=0.1, max_value=600.0),
    P("move_timeout_s", 60.0, "Timeout of one arm call (a move included).", min_value=0.1,
      max_value=3600.0),
    P("sync_tolerance_s", 0.005, "Largest stamp difference within one captured set.",
      min_value=0.0, max_value=1.0),
    P("require_reference", True, "Capture only when a structured-light reference arrived.",
      read_only=True),
    P("autostart", True, "Configure and activate at start-up.", read_only=True),
    P("exit_when_done", True, "Shut down when the plan is finished or the arm failed.",
      read_only=True),
)


# Process exit codes (``exit_when_done``): the plan finished, could not start, or stopped early
# (arm failure or skipped views; run the collector again to resume).
EXIT_CONFIGURE_FAILED = 2
EXIT_PLAN_INCOMPLETE = 3

T = TypeVar("T")


class TopicCapture:
    """Latest messages per topic, and a blocking wait for a set stamped after a time.

    Args:
        tolerance_ns: largest stamp difference between the ``required`` messages and the depth.
        required: the keys a set needs (``depth`` among them).
    """

    def __init__(self, tolerance_ns: int, required: tuple[str, ...]) -> None:
        self._cond = threading.Condition()
        self._cancelled = False
        self._latest: dict[str, object] = {}
        self.tolerance_ns = tolerance_ns
        self.required = required

    def put(self, key: str, msg: object) -> None:
        """Store the newest message of ``key`` and wake waiters."""
        with self._cond:
            self._latest[key] = msg
            self._cond.notify_all()

    def cancel(self) -> None:
        """End every wait, now and later, with a CaptureError (the node is stopping)."""
        with self._cond:
            self._cancelled = True
            self._cond.notify_all()

    def wait_messages(self, after_ns: int, timeout_s: float) -> dict[str, object]:
        """The latest messages once the required ones are synchronised and newer than
        ``after_ns``.

        Raises:
            CaptureError: no such set within ``timeout_s``, or the capture was cancelled.
        """
        with self._cond:
            ready = self._cond.wait_for(lambda: self._cancelled or self._ready(after_ns),
                                        timeout_s)
            if self._cancelled:
                raise CaptureError("capture cancelled: the collector is stopping")
            if not ready:
                have = sorted(k for k, m in self._latest.items() if stamp_ns(m) > after_ns)
                raise CaptureError(f"no synchronised set within {timeout_s:.1f} s "
                                   f"(fresh: {have or 'nothing'})")
            return dict(self._latest)

    def wait(self, after_ns: int, camera_to_base_m: np.ndarray, timeout_s: float) -> ToFFrame:
        """A ToF frame (with the reference when present) at ``camera_to_base_m``.

        Raises:
            CaptureError: no such set in time, or its messages cannot be decoded.
        """
        messages = self.wait_messages(after_ns, timeout_s)
        return _decoded(lambda: _frame(messages, camera_to_base_m))

    def wait_hand_eye(self, after_ns: int, timeout_s: float) -> HandEyeView:
        """A calibration view: the ToF frame (no pose) and the SL image of the same instant."""
        messages = self.wait_messages(after_ns, timeout_s)
        return _decoded(lambda: _hand_eye_view(messages))

    def _ready(self, after_ns: int) -> bool:
        if any(k not in self._latest for k in self.required):
            return False
        stamps = [stamp_ns(self._latest[k]) for k in self.required]
        depth = stamp_ns(self._latest["depth"])
        return depth > after_ns and all(abs(s - depth) <= self.tolerance_ns for s in stamps)


def _decoded(decode: Callable[[], T]) -> T:
    """``decode()``; messages it cannot decode (a wrong encoding, a payload that does not
    match its size) are a failed capture, which the plan retries, then skips."""
    try:
        return decode()
    except InputError as err:
        raise CaptureError(f"cannot decode the captured messages: {err}") from err


@dataclass(frozen=True, eq=False)
class HandEyeView:
    """One captured calibration view.

    Attributes:
        frame: the ToF frame (radial range mm, amplitude; no pose, no reference).
        sl_image: (H, W) SL intensity image (uint8 for mono8, else float32).
        sl_intrinsics: of the SL image.
    """

    frame: ToFFrame
    sl_image: np.ndarray
    sl_intrinsics: Intrinsics


def _hand_eye_view(latest: dict[str, object]) -> HandEyeView:
    tof = {k: latest[k] for k in ("depth", "amplitude", "info")}
    image = latest["sl_image"]
    pixels = image_to_array(image.encoding, image.height, image.width, image.step,
                            bool(image.is_bigendian), image.data)
    if pixels.dtype != np.uint8:
        pixels = pixels.astype(np.float32)
    return HandEyeView(_frame(tof, None), pixels, intrinsics_of(latest["sl_info"]))


def _decode_mm(msg: Image) -> np.ndarray:
    pixels = image_to_array(msg.encoding, msg.height, msg.width, msg.step,
                            bool(msg.is_bigendian), msg.data)
    return depth_to_mm(pixels, msg.encoding)


def _frame(latest: dict[str, object], camera_to_base_m: np.ndarray | None) -> ToFFrame:
    """Messages -> a ToFFrame holding radial ranges (the topics hold z-depth)."""
    depth, amp, info = latest["depth"], latest["amplitude"], latest["info"]
    intr = intrinsics_of(info)
    amplitude = amplitude_to_float(image_to_array(amp.encoding, amp.height, amp.width,
                                                  amp.step, bool(amp.is_bigendian), amp.data))
    reference = None
    if "reference" in latest:
        reference = intr.z_to_radial(_decode_mm(latest["reference"]))
    return ToFFrame(range_mm=intr.z_to_radial(_decode_mm(depth)), amplitude=amplitude,
                    intrinsics=intr, reference_mm=reference, stamp_ns=stamp_ns(depth),
                    pose=camera_to_base_m)


class CollectorNode(LifecycleNode):
    def __init__(self) -> None:
        super().__init__("collector")
        refuse_retired_parameters(self, RETIRED_TOPIC_PARAMETERS)
        self.params = declare(self, PARAMETERS)
        p = self.params
        self.hand_eye_m = pose_vector_to_matrix(np.asarray(p["hand_eye"], dtype=np.float64))
        self.calibration = p["plan"] == "hand_eye"
        topics = [("depth", Image), ("amplitude", Image), ("info", CameraInfo)]
        required = ["depth", "amplitude", "info"]
        if self.calibration:
            topics += [("sl_image", Image), ("sl_info", CameraInfo)]
            required += ["sl_image", "sl_info"]
        else:
            topics.append(("reference", Image))
            required += ["reference"] if p["require_reference"] else []
        self.capture = TopicCapture(int(p["sync_tolerance_s"] * 1e9), tuple(required))
        qos = subscription_qos()
        for key, kind in topics:
            overridable_subscription(self, kind, CELL_TOPICS[key],
                                     lambda m, k=key: self.capture.put(k, m), qos)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_pose = overridable_publisher(self, PoseStamped, CELL_TOPICS["tcp_pose"], latched)
        self.arm: IsolatedArm | None = None
        self.writer = None
        self.pending: list[PlannedView] = []
        self.result: RunResult | None = None
        self._stop = threading.Event()
        self._close_lock = threading.Lock()
        self._worker: threading.Thread | None = None
        # Set to end the process (ros_runtime.spin_node), like a signal.
        self.stop_requested = threading.Event()
        self._autostart_timer = (self.create_timer(0.0, self._autostart_once)
                                 if p["autostart"] else None)
        self.exit_code = 0

    def _autostart_once(self) -> None:
        # A 0 s timer fires on every spin: cancel it, or it keeps a core busy.
        assert self._autostart_timer is not None
        if self._autostart_timer.is_canceled():
            return
        self._autostart_timer.cancel()
        if self.trigger_configure() == TransitionCallbackReturn.SUCCESS:
            self.trigger_activate()
        elif self.params["exit_when_done"]:
            self.exit_code = EXIT_CONFIGURE_FAILED
            self.stop_requested.set()

    # -- lifecycle -----------------------------------------------------------------------
    def on_configure(self, state: State) -> TransitionCallbackReturn:
        p = self.params
        try:
            custom = self._load_hand_eye_file()
            plan = self._plan()
            other = session.parts_of_other_kind(p["session_path"], self.calibration)
            if other:
                kind = "ordinary recordings" if self.calibration else "hand-eye calibrations"
                raise TofMpdError(f"{p['session_path']} holds {kind} ({other[0].name}); use "
                                  f"another session_path for plan {p['plan']}")
            done = (session.completed_calibration_views(p["session_path"], plan)
                    if self.calibration
                    else session.completed_views(p["session_path"], plan, self.hand_eye_m))
            self.pending = [v for v in plan if done[v.index] == 0]
            self.get_logger().info(f"plan: {len(plan)} views, {len(plan) - len(self.pending)} "
                                   f"already recorded in {p['session_path']}")
            if not self.pending:
                return TransitionCallbackReturn.SUCCESS
            kwargs = {"host": p["robot_ip"]} if p["arm_backend"] == "ur_rtde" else {}
            self.arm = IsolatedArm(p["arm_backend"], connect_timeout_s=p["connect_timeout_s"],
                                   call_timeout_s=p["move_timeout_s"], **kwargs)
            from ..recordings import RecordingWriter

            Path(p["session_path"]).mkdir(parents=True, exist_ok=True)
            if self.calibration:
                custom.update(hand_eye_custom_data(self._board()))
            self.writer = RecordingWriter(session.next_part(p["session_path"]),
                                          custom_data=custom).open()
        except TofMpdError as err:
            self.get_logger().error(f"cannot configure: {err}")
            self._close()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def _load_hand_eye_file(self) -> dict[str, str]:
        """Take camera-to-flange from ``hand_eye_file`` if set; the recording's custom_data."""
        path = self.params["hand_eye_file"]
        if not path:
            return {}
        camera_to_flange, sl_to_tof = load_hand_eye_json(path)
        self.hand_eye_m = camera_to_flange
        self.get_logger().info(f"hand-eye from {path}: camera at "
                               f"{np.round(camera_to_flange[:3, 3] * 1000.0, 2).tolist()} mm "
                               "in the flange frame")
        return {KEY_CALIBRATION_FILE: str(Path(path).resolve()),
                KEY_SL_TO_TOF: json.dumps(sl_to_tof.tolist())}

    def _board(self) -> CalibrationBoard:
        p = self.params
        return CalibrationBoard(p["board_cols"], p["board_rows"], p["board_square_mm"])

    def _plan(self) -> list[PlannedView]:
        p = self.params
        if p["plan_file"]:
            return load_plan(p["plan_file"])
        if self.calibration:
            board_m = pose_vector_to_matrix(np.asarray(p["board_pose"], dtype=np.float64))
            return hand_eye_plan_views(board_m, p["hand_eye_views"], p["seed"], self.hand_eye_m,
                                       self._board())
        # The simulator loads only for the plan of a simulated scene, never on a real cell.
        from ..sim.viewpoints import sim_plan

        return sim_plan(p["seed"], p["split"], p["scene"], p["views"], self.hand_eye_m)

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        self._stop.clear()
        self._worker = threading.Thread(target=self._run, daemon=True)
        self._worker.start()
        return super().on_activate(state)

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._stop_worker(timeout_s=None, cancel_capture=False)  # after the current view
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._close()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        self._stop_worker(timeout_s=self._worker_stop_s())
        self._close()
        return TransitionCallbackReturn.SUCCESS

    def destroy_node(self) -> None:
        # Called while the context is still valid (ros_runtime.spin_node, on a signal too): the
        # view in progress ends (a capture is cancelled, a move completes), then the recording
        # is finalised, before the node and the context go.
        self._stop_worker(timeout_s=self._worker_stop_s())
        try:
            self._close()
        except Exception as err:  # e.g. the disk is full: what was flushed stays readable
            self.get_logger().error(f"cannot close the recording: {err}")
        super().destroy_node()

    def _worker_stop_s(self) -> float:
        """The longest the view in progress can take to end: an arm move, then a margin."""
        return self.params["move_timeout_s"] + 30.0

    def _stop_worker(self, timeout_s: float | None, *, cancel_capture: bool = True) -> None:
        """Ask the worker to stop after its view and wait; ``cancel_capture`` also ends a
        capture in progress, for good (the node is going)."""
        self._stop.set()
        if cancel_capture:
            self.capture.cancel()
        if self._worker is not None and self._worker is not threading.current_thread():
            self._worker.join(timeout_s)

    # -- the plan (worker thread) --------------------------------------------------------
    def _run(self) -> None:
        """The worker: record the pending views, then close and finish. Whatever fails, it
        reports one line and finishes: a thread that died here would leave the node waiting
        forever with its recording open."""
        try:
            if self.pending:
                self._record_pending()
        except Exception as err:  # a failure nothing below foresaw: report it, never hang
            self.exit_code = EXIT_PLAN_INCOMPLETE
            self.get_logger().error(f"recording stopped: {type(err).__name__}: {err}; run the "
                                    "collector again to resume")
        finally:
            self._finish()

    def _record_pending(self) -> None:
        p = self.params
        if p["arm_backend"] == "sim":
            self._wait_for_arm_follower(p["connect_timeout_s"])
        capture, write = self._view_functions()
        self.result = run_plan(
            self.pending, self.arm, capture, self.writer, self.hand_eye_m,
            settle_s=p["settle_time_s"], speed=p["speed"], accel=p["accel"],
            publish_pose=self._publish_pose, should_stop=self._stop.is_set,
            on_view=lambda done, total: self.get_logger().info(
                f"recorded {done}/{total} views"), write_view=write)
        self._report(self.result)

    def _view_functions(self) -> tuple[CaptureFunction, WriteFunction | None]:
        """How a view is captured and written for this plan (None: the default writer)."""
        timeout = self.params["capture_timeout_s"]
        if not self.calibration:
            return (lambda after, pose: self.capture.wait(after, pose, timeout)), None

        def write(view: HandEyeView, tcp: np.ndarray) -> None:
            write_hand_eye_view(self.writer, view.frame, tcp, view.sl_image,
                                view.sl_intrinsics)

        return (lambda after, pose: self.capture.wait_hand_eye(after, timeout)), write

    def _report(self, r: RunResult) -> None:
        summary = (f"recorded views {r.recorded}; skipped {r.skipped}" +
                   (f"; stopped at view {r.failed_view}: {r.error}" if not r.ok else ""))
        # One call site per severity: rclpy raises ValueError when the severity logged from
        # one line changes between calls (a second activation would have killed the worker).
        if r.ok and not r.skipped:
            self.get_logger().info(summary)
        else:
            self.exit_code = EXIT_PLAN_INCOMPLETE
            self.get_logger().error(summary)
        if self.calibration and r.ok:
            self.get_logger().info(f"solve with: tof-mpd calibrate hand-eye "
                                   f"{self.params['session_path']} -o hand_eye.json")

    def _finish(self) -> None:
        try:
            self._close()
        except Exception as err:  # e.g. the disk is full: what was flushed stays readable
            self.exit_code = self.exit_code or EXIT_PLAN_INCOMPLETE
            self.get_logger().error(f"cannot close the recording: {err}")
        if self.params["exit_when_done"]:
            self.stop_requested.set()

    def _wait_for_arm_follower(self, timeout_s: float) -> None:
        """Wait until something (the sim_cell node) subscribes to the TCP pose.

        The simulated arm is seen only through a simulated camera that renders from the
        published pose. Until discovery has matched that subscriber, a first pose would reach
        it late, after frames rendered elsewhere were stamped as if taken at that pose.
        """
        deadline = time.monotonic() + timeout_s
        while self.pub_pose.get_subscription_count() == 0 and not self._stop.is_set():
            if time.monotonic() > deadline:
                self.get_logger().warn(f"nothing subscribes to {self.pub_pose.topic_name} "
                                       f"after {timeout_s:.1f} s: frames may not show the "
                                       "simulated arm's pose")
                return
            time.sleep(0.05)

    def _publish_pose(self, tcp_m: np.ndarray) -> None:
        msg = PoseStamped(pose=pose_message(tcp_m))
        msg.header.frame_id = "base"
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_pose.publish(msg)

    def _close(self) -> None:
        with self._close_lock:  # the worker and a shutdown transition may both close
            self._close_unlocked()

    def _close_unlocked(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        if self.arm is not None:
            self.arm.close()
            self.arm = None
