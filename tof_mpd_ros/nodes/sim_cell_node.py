"""The sim_cell node class: the simulated cell's ToF camera and structured-light sensor on topics.

Frames are rendered on a worker thread (a multipath frame takes about a second) and published by
a timer at ``rate_hz`` with fresh stamps. Without an arm, the node cycles through frames of a
viewpoint plan rendered at start-up, once all of them are rendered (it stops as soon as a TCP
pose publisher is discovered, so no frame from elsewhere is stamped while the arm's first pose is
on its way); when the arm's TCP pose arrives on ``arm/tcp_pose`` (the collector publishes it
while it drives the simulated or real arm), the node renders from that pose and publishes nothing
stale in between, so every frame stamped after a pose message was rendered at that pose.

With ``target:=hand_eye_board`` the scene is replaced by the hand-eye calibration board lying
on the table at ``board_pose`` (:mod:`~tof_mpd_ros.sim.hand_eye`): the ToF frames
show the board through the full ToF physics (no structured-light reference), and the SL
camera's intensity image of the board is published on ``sl/image_raw`` with its CameraInfo,
rendered from the SL camera pose (``hand_eye`` then ``sl_to_tof``) with the same stamp. Before
an arm pose arrives the node cycles through views of the hand-eye plan.

Topics: :data:`~tof_mpd_ros.nodes.cell_topics.CELL_TOPICS` (relative; remap them).
"""

from __future__ import annotations

import threading
import time

import numpy as np
from geometry_msgs.msg import Pose, PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from ..arm.viewpoints import ViewpointConfig
from ..calibration.hand_eye_board import CalibrationBoard
from ..camera import Intrinsics
from ..collection.hand_eye_plan import default_sl_intrinsics, hand_eye_plan_views
from ..frame import ToFFrame
from ..image_encoding import mm_to_depth
from ..pose import invert_pose, pose_m_to_mm, pose_vector_to_matrix, rotation_angle
from ..sim.cell import CameraModel, SimCell
from ..sim.dataset import scene_rng
from ..sim.hand_eye import render_sl_image, simulate_tof_capture
from ..sim.scene import make_scene
from ..sim.structured_light import StructuredLightConfig
from ..sim.viewpoints import plan_viewpoints
from .cell_topics import CELL_TOPICS, RETIRED_TOPIC_PARAMETERS
from .parameters import ParameterSpec as P
from .parameters import declare, refuse_retired_parameters
from .qos import overridable_publisher, publisher_qos
from .ros_messages import camera_info_message, image_message, pose_matrix

# The node's parameters; config/sim_cell.yaml mirrors these defaults (a test keeps them equal).
PARAMETERS = (
    P("rate_hz", 30.0, "Publication rate of ToF frames.", min_value=0.1, max_value=200.0),
    P("reliability", "reliable", "Alias: default QoS reliability of every published image and "
      "CameraInfo (reliable, like image_pipeline); qos_overrides.<topic>.publisher.reliability "
      "overrides it per topic.",
      choices=("best_effort", "reliable"), read_only=True),
    P("seed", 0, "Seed of the scene, the plan and the sensor noise.", read_only=True),
    P("split", "test", "Object-library half the scene is drawn from.",
      choices=("train", "test"), read_only=True),
    P("scene", 0, "Scene index (with seed and split, the same scene as `tof-mpd sim dataset`).",
      min_value=0, max_value=100000, read_only=True),
    P("views", 3, "Views rendered at start-up (the scene's plan, or the hand-eye plan for "
      "target hand_eye_board) and cycled until an arm appears.", min_value=1, max_value=18,
      read_only=True),
    P("follow_arm", True, "Render from the TCP pose on arm/tcp_pose when it arrives."),
    P("hand_eye", [0.0, 0.0, 0.06, 0.0, 0.0, 0.0], "Camera pose in the flange frame as a UR "
      "pose vector [x y z rx ry rz] (metres, axis-angle).", read_only=True),
    P("publish_reference", True, "Render and publish the structured-light reference.",
      read_only=True),
    P("crop_width", 180, "Width of the published ToF image.", min_value=8, max_value=296,
      read_only=True),
    P("crop_height", 140, "Height of the published ToF image.", min_value=8, max_value=216,
      read_only=True),
    P("frame_id", "tof_optical_frame", "frame_id of the published images.", read_only=True),
    P("target", "scene", "scene: the simulated scene; hand_eye_board: the hand-eye calibration "
      "board on the table, plus the SL camera's intensity image.",
      choices=("scene", "hand_eye_board"), read_only=True),
    P("sl_to_tof", [-0.05, 0.0, 0.0, 0.0, 0.0, 0.0], "True SL camera pose in the ToF optical "
      "frame as a UR pose vector (m, axis-angle); used by the reference and the SL image.",
      read_only=True),
    P("board_pose", [0.45, 0.0, 0.0, 3.141592653589793, 0.0, 0.0], "Board frame in the base "
      "frame (UR pose vector, m, rad; z into the table) for target hand_eye_board.",
      read_only=True),
    P("board_cols", 9, "Squares across the board (one of cols, rows odd).", min_value=3,
      max_value=50, read_only=True),
    P("board_rows", 6, "Squares down the board.", min_value=3, max_value=50, read_only=True),
    P("board_square_mm", 20.0, "Side of a board square, mm.", min_value=1.0, max_value=500.0,
      read_only=True),
    P("sl_frame_id", "sl_optical_frame", "frame_id of the SL camera image.", read_only=True),
)

# What the node publishes, key of CELL_TOPICS -> message type: the ToF camera's three topics,
# and the SL reference (target scene) or the SL camera's image and CameraInfo (hand_eye_board).
PUBLISHED = {"depth": Image, "amplitude": Image, "info": CameraInfo, "reference": Image,
             "sl_image": Image, "sl_info": CameraInfo}

# How long a stop waits for the view being rendered.
WORKER_STOP_S = 60.0


class SimCellNode(Node):
    def __init__(self) -> None:
        super().__init__("sim_cell")
        refuse_retired_parameters(self, RETIRED_TOPIC_PARAMETERS)
        self.params = declare(self, PARAMETERS)
        p = self.params
        sl_to_tof_m = pose_vector_to_matrix(np.asarray(p["sl_to_tof"], dtype=np.float64))
        self.cell = SimCell(camera=CameraModel(crop=(p["crop_width"], p["crop_height"])),
                            structured_light=StructuredLightConfig(
                                sl_to_tof_mm=pose_m_to_mm(sl_to_tof_m)))
        self.rng = np.random.default_rng([p["seed"], 7])
        self.hand_eye_m = pose_vector_to_matrix(np.asarray(p["hand_eye"], dtype=np.float64))
        self.board_mode = p["target"] == "hand_eye_board"
        if self.board_mode:
            self.board = CalibrationBoard(p["board_cols"], p["board_rows"],
                                          p["board_square_mm"])
            board_m = pose_vector_to_matrix(np.asarray(p["board_pose"], dtype=np.float64))
            self.board_to_base_mm = pose_m_to_mm(board_m)
            self.sl_intrinsics = default_sl_intrinsics()
            views = hand_eye_plan_views(board_m, max(3, p["views"]), p["seed"],
                                        self.hand_eye_m, self.board)
            self.cycle_poses = [pose_m_to_mm(v.camera_to_base_m(self.hand_eye_m))
                                for v in views[:p["views"]]]
            what = (f"hand-eye board {self.board.n_cols}x{self.board.n_rows} x "
                    f"{self.board.square_mm:g} mm")
        else:
            scene_random = scene_rng(p["seed"], p["split"], p["scene"])
            self.scene = make_scene(p["split"], scene_random)
            plan = plan_viewpoints(self.scene, scene_random, ViewpointConfig())
            self.cycle_poses = [v.camera_to_base_mm for v in plan.viewpoints[:p["views"]]]
            what = (f"{p['split']} scene {p['scene']} (seed {p['seed']}), "
                    f"{len(self.scene.objects)} objects")
        qos = publisher_qos(p["reliability"])
        keys = ("depth", "amplitude", "info",
                *(("sl_image", "sl_info") if self.board_mode else ("reference",)))
        self.publishers_by_key = {
            key: overridable_publisher(self, PUBLISHED[key], CELL_TOPICS[key], qos)
            for key in keys}
        self._lock = threading.Lock()
        self._cycle: list[dict[str, Image | CameraInfo]] = []
        self._current: dict[str, Image | CameraInfo] | None = None
        self._tick = 0
        self._render_request = threading.Event()
        self._pending_pose_mm: np.ndarray | None = None
        self._rendered_pose_mm: np.ndarray | None = None
        self._stop = threading.Event()
        self.frames_rendered = 0
        self.render_failures = 0
        self._cycle_rendered = False
        self.tcp_pose_topic = self.create_subscription(
            PoseStamped, CELL_TOPICS["tcp_pose"], self._on_tcp_pose, 10).topic_name
        self._worker = threading.Thread(target=self._render_loop, daemon=True)
        self._worker.start()
        self.create_timer(1.0 / p["rate_hz"], self._publish)
        self.get_logger().info(f"simulated cell: {what}, publishing at {p['rate_hz']} Hz")

    # -- rendering (worker thread) -------------------------------------------------------
    def _render_loop(self) -> None:
        """The worker: the start-up views, then a view at each new arm pose. A view that
        fails to render is reported and skipped; the thread goes on."""
        start = time.monotonic()
        for camera_to_base_mm in self.cycle_poses:
            if self._stop.is_set():
                return
            messages = self._render_or_report(camera_to_base_mm)
            with self._lock:
                if messages is not None:
                    self._cycle.append(messages)
        with self._lock:
            self._cycle_rendered = True
        self.get_logger().info(f"rendered {len(self._cycle)} of the {len(self.cycle_poses)} "
                               f"start-up views in {time.monotonic() - start:.1f} s")
        while not self._stop.is_set():
            if not self._render_request.wait(0.1):
                continue
            with self._lock:
                pose = self._pending_pose_mm
                self._render_request.clear()
            messages = self._render_or_report(pose)
            with self._lock:
                if messages is not None and self._pending_pose_mm is pose:  # no newer pose
                    self._current = messages
                    self._rendered_pose_mm = pose

    def _render_or_report(self, camera_to_base_mm: np.ndarray
                          ) -> dict[str, Image | CameraInfo] | None:
        """The view's messages, or None (logged, counted) when rendering it failed."""
        try:
            return self._render(camera_to_base_mm)
        except Exception as err:  # one view must not end the renderer for good
            self.render_failures += 1
            self.get_logger().error(
                f"cannot render the view at {np.round(camera_to_base_mm[:3, 3], 1).tolist()} "
                f"mm: {type(err).__name__}: {err}")
            return None

    def _render(self, camera_to_base_mm: np.ndarray) -> dict[str, Image | CameraInfo]:
        self.frames_rendered += 1
        if self.board_mode:
            return self._render_board(camera_to_base_mm)
        frame = self.cell.capture(self.scene, camera_to_base_mm, self.rng,
                                  with_reference=self.params["publish_reference"])
        return self._messages(frame)

    def _render_board(self, camera_to_base_mm: np.ndarray) -> dict[str, Image | CameraInfo]:
        """The board in the ToF camera (full physics) and in the SL camera (intensity)."""
        board_in_tof = invert_pose(camera_to_base_mm) @ self.board_to_base_mm
        frame = simulate_tof_capture(self.cell, self.board, board_in_tof, self.rng)
        board_in_sl = invert_pose(self.cell.structured_light.sl_to_tof_mm) @ board_in_tof
        image = render_sl_image(self.board, board_in_sl, self.sl_intrinsics, self.rng,
                                supersample=2)
        out = self._messages(frame)
        fid = self.params["sl_frame_id"]
        out["sl_image"] = image_message(image, "mono8", fid)
        out["sl_info"] = camera_info_message(self.sl_intrinsics, fid)
        return out

    def _messages(self, frame: ToFFrame) -> dict[str, Image | CameraInfo]:
        intr: Intrinsics = frame.intrinsics
        fid = self.params["frame_id"]
        depth_m = mm_to_depth(intr.radial_to_z(frame.range_mm), "32FC1")
        out = {"depth": image_message(depth_m, "32FC1", fid),
               "amplitude": image_message(frame.amplitude.astype(np.float32), "32FC1", fid),
               "info": camera_info_message(intr, fid)}
        if frame.reference_mm is not None:
            ref_m = mm_to_depth(intr.radial_to_z(frame.reference_mm), "32FC1")
            out["reference"] = image_message(ref_m, "32FC1", fid)
        return out

    # -- callbacks -----------------------------------------------------------------------
    def _on_tcp_pose(self, msg: PoseStamped) -> None:
        if not self.params["follow_arm"]:
            return
        try:
            camera_mm = pose_m_to_mm(_valid_pose(msg.pose) @ self.hand_eye_m)
        except ValueError as err:  # an exception here would end the node's executor
            self.get_logger().warning(f"ignored a TCP pose on {self.tcp_pose_topic}: "
                                      f"{err}")
            return
        with self._lock:
            reference = self._pending_pose_mm if self._pending_pose_mm is not None else None
            if reference is not None and _same_pose(reference, camera_mm):
                return
            self._pending_pose_mm = camera_mm
            self._current = None  # never publish a frame rendered at the previous pose
            self._render_request.set()

    def _publish(self) -> None:
        arm_present = self._arm_present()
        with self._lock:
            if self._pending_pose_mm is not None:
                messages = self._current
            elif self._cycle_rendered and self._cycle and not arm_present:
                # Only once every view is rendered: a steady stream, not one that starts
                # while the renderer still takes the CPU from its consumers.
                messages = self._cycle[self._tick % len(self._cycle)]
            else:
                messages = None
            self._tick += 1
        if messages is None:
            return
        stamp = self.get_clock().now().to_msg()
        for key, publisher in self.publishers_by_key.items():
            if key in messages:
                messages[key].header.stamp = stamp
                publisher.publish(messages[key])

    def _arm_present(self) -> bool:
        """Whether this node follows an arm whose pose publisher has been discovered."""
        return bool(self.params["follow_arm"]) and \
            self.count_publishers(self.tcp_pose_topic) > 0

    def destroy_node(self) -> None:
        # The renderer checks _stop between views; one render can take seconds when loaded.
        self._stop.set()
        self._worker.join(WORKER_STOP_S)
        super().destroy_node()


def _valid_pose(pose: Pose) -> np.ndarray:
    """(4, 4) transform of a ``geometry_msgs/Pose``.

    Raises:
        ValueError: a zero quaternion or a non-finite value.
    """
    matrix = pose_matrix(pose)  # scipy: ValueError on a zero-norm quaternion
    if not np.isfinite(matrix).all():
        raise ValueError("the pose is not finite")
    return matrix


def _same_pose(a_mm: np.ndarray, b_mm: np.ndarray, tol_mm: float = 0.5,
               tol_rad: float = 1e-3) -> bool:
    """Whether two (4, 4) poses (mm) are within ``tol_mm`` and ``tol_rad`` of each other."""
    if np.linalg.norm(a_mm[:3, 3] - b_mm[:3, 3]) > tol_mm:
        return False
    return rotation_angle(a_mm, b_mm) <= tol_rad

