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
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.lifecycle import LifecycleNode, State, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from ..arm.isolated import IsolatedArm
from ..arm.ur_pose import pose_vector_to_matrix
from ..collection import session
from ..collection.plan import PlannedView, load_plan, sim_plan
from ..collection.runner import RunResult, run_plan
from ..errors import CaptureError, TofMpdError
from ..frame import ToFFrame
from ..image_encoding import amplitude_to_float, depth_to_mm, image_to_array
from .parameters import ParameterSpec as P
from .parameters import declare
from .ros_messages import intrinsics_of, pose_message, stamp_ns

# The node's parameters; config/collector.yaml mirrors these defaults (a test keeps them equal).
PARAMETERS = (
    P("arm_backend", "sim", "sim: the simulated UR5e; ur_rtde: a real UR over RTDE.",
      choices=("sim", "ur_rtde"), read_only=True),
    P("robot_ip", "192.168.1.10", "UR controller address (ur_rtde only).", read_only=True),
    P("session_path", "recordings/session", "Session directory; parts part_NNN are "
      "recordings. Existing parts are kept and the plan resumes.", read_only=True),
    P("plan_file", "", "YAML plan (views: [[x y z rx ry rz], ...] TCP poses, m/rad); empty = "
      "the simulated scene's plan.", read_only=True),
    P("seed", 0, "Simulated scene seed (same as the sim_cell node's).", read_only=True),
    P("split", "test", "Simulated scene's object split.", choices=("train", "test"),
      read_only=True),
    P("scene", 0, "Simulated scene index.", min_value=0, max_value=100000, read_only=True),
    P("views", 18, "Views of the simulated plan to visit.", min_value=1, max_value=18,
      read_only=True),
    P("hand_eye", [0.0, 0.0, 0.06, 0.0, 0.0, 0.0], "Camera pose in the flange frame, UR pose "
      "vector [x y z rx ry rz] (m, rad).", read_only=True),
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
    P("depth_topic", "/tof/depth/image_raw", "ToF depth (z-depth, REP 118).", read_only=True),
    P("amplitude_topic", "/tof/amplitude/image_raw", "ToF amplitude.", read_only=True),
    P("camera_info_topic", "/tof/camera_info", "ToF CameraInfo.", read_only=True),
    P("reference_topic", "/sl/depth/image_raw", "Structured-light reference in the ToF frame "
      "(z-depth).", read_only=True),
    P("tcp_pose_topic", "/arm/tcp_pose", "Published TCP pose after each move (base frame, m).",
      read_only=True),
    P("autostart", True, "Configure and activate at start-up.", read_only=True),
    P("exit_when_done", True, "Shut down when the plan is finished or the arm failed.",
      read_only=True),
)


class TopicCapture:
    """Latest messages per topic, and a blocking wait for a set stamped after a time."""

    def __init__(self, tolerance_ns: int, require_reference: bool) -> None:
        self._cond = threading.Condition()
        self._latest: dict[str, object] = {}
        self.tolerance_ns = tolerance_ns
        self.require_reference = require_reference

    def put(self, key: str, msg: object) -> None:
        with self._cond:
            self._latest[key] = msg
            self._cond.notify_all()

    def wait(self, after_ns: int, camera_to_base_m: np.ndarray, timeout_s: float) -> ToFFrame:
        with self._cond:
            if not self._cond.wait_for(lambda: self._ready(after_ns), timeout_s):
                have = sorted(k for k, m in self._latest.items() if stamp_ns(m) > after_ns)
                raise CaptureError(f"no synchronised set within {timeout_s:.1f} s "
                                   f"(fresh: {have or 'nothing'})")
            latest = dict(self._latest)
        return _frame(latest, camera_to_base_m)

    def _ready(self, after_ns: int) -> bool:
        keys = ("depth", "amplitude", "info") + (("reference",) if self.require_reference
                                                  else ())
        if any(k not in self._latest for k in keys):
            return False
        stamps = [stamp_ns(self._latest[k]) for k in keys]
        depth = stamp_ns(self._latest["depth"])
        return depth > after_ns and all(abs(s - depth) <= self.tolerance_ns for s in stamps)


def _decode_mm(msg: Image) -> np.ndarray:
    pixels = image_to_array(msg.encoding, msg.height, msg.width, msg.step,
                            bool(msg.is_bigendian), msg.data)
    return depth_to_mm(pixels, msg.encoding)


def _frame(latest: dict[str, object], camera_to_base_m: np.ndarray) -> ToFFrame:
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
        self.params = declare(self, PARAMETERS)
        p = self.params
        self.hand_eye_m = pose_vector_to_matrix(np.asarray(p["hand_eye"], dtype=np.float64))
        self.capture = TopicCapture(int(p["sync_tolerance_s"] * 1e9), p["require_reference"])
        qos = qos_profile_sensor_data
        for key, topic, kind in (("depth", "depth_topic", Image),
                                 ("amplitude", "amplitude_topic", Image),
                                 ("info", "camera_info_topic", CameraInfo),
                                 ("reference", "reference_topic", Image)):
            self.create_subscription(kind, p[topic], lambda m, k=key: self.capture.put(k, m),
                                     qos)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_pose = self.create_publisher(PoseStamped, p["tcp_pose_topic"], latched)
        self.arm: IsolatedArm | None = None
        self.writer = None
        self.pending: list[PlannedView] = []
        self.result: RunResult | None = None
        self._stop = threading.Event()
        self._close_lock = threading.Lock()
        self._worker: threading.Thread | None = None
        if p["autostart"]:
            self.create_timer(0.0, self._autostart_once)
        self._autostarted = False

    def _autostart_once(self) -> None:
        if self._autostarted:
            return
        self._autostarted = True
        if self.trigger_configure() == TransitionCallbackReturn.SUCCESS:
            self.trigger_activate()
        elif self.params["exit_when_done"]:
            rclpy.try_shutdown()

    # -- lifecycle -----------------------------------------------------------------------
    def on_configure(self, state: State) -> TransitionCallbackReturn:
        p = self.params
        try:
            plan = (load_plan(p["plan_file"]) if p["plan_file"]
                    else sim_plan(p["seed"], p["split"], p["scene"], p["views"], self.hand_eye_m))
            done = session.completed_views(p["session_path"], plan, self.hand_eye_m)
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
            self.writer = RecordingWriter(session.next_part(p["session_path"])).open()
        except TofMpdError as err:
            self.get_logger().error(f"cannot configure: {err}")
            self._close()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        self._stop.clear()
        self._worker = threading.Thread(target=self._run, daemon=True)
        self._worker.start()
        return super().on_activate(state)

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._stop.set()
        if self._worker is not None and self._worker is not threading.current_thread():
            self._worker.join()
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._close()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        self._stop.set()
        self._close()
        return TransitionCallbackReturn.SUCCESS

    # -- the plan (worker thread) --------------------------------------------------------
    def _run(self) -> None:
        p = self.params
        if self.pending:
            self.result = run_plan(
                self.pending, self.arm,
                lambda after, pose: self.capture.wait(after, pose, p["capture_timeout_s"]),
                self.writer, self.hand_eye_m, settle_s=p["settle_time_s"], speed=p["speed"],
                accel=p["accel"], publish_pose=self._publish_pose,
                should_stop=self._stop.is_set,
                on_view=lambda done, total: self.get_logger().info(
                    f"recorded {done}/{total} views"))
            r = self.result
            summary = (f"recorded views {r.recorded}; skipped {r.skipped}" +
                       (f"; stopped at view {r.failed_view}: {r.error}" if not r.ok else ""))
            (self.get_logger().info if r.ok and not r.skipped else
             self.get_logger().error)(summary)
        self._close()
        if p["exit_when_done"]:
            rclpy.try_shutdown()

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
