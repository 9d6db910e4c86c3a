"""The capture loop: move, settle, capture one synchronised set, append it to the recording."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ArmError, CaptureError, RecordingError
from .plan import PlannedView

log = logging.getLogger(__name__)

# capture(after_ns, camera_to_base_m) -> a frame stamped after ``after_ns`` at that pose (a
# ToFFrame, or whatever ``write_view`` takes, e.g. a ToF frame with its SL image)
CaptureFunction = Callable[[int, np.ndarray], Any]
# write_view(captured, tcp_to_base_m) appends one captured view to the recording
WriteFunction = Callable[[Any, np.ndarray], None]


@dataclass
class RunResult:
    """What one run of the plan did."""

    recorded: list[int] = field(default_factory=list)
    skipped: list[int] = field(default_factory=list)
    failed_view: int | None = None
    error: str = ""

    @property
    def ok(self) -> bool:
        return self.failed_view is None


def run_plan(pending: list[PlannedView], arm, capture: CaptureFunction, writer,
             hand_eye_m: np.ndarray, *, settle_s: float = 0.5, speed: float = 0.1,
             accel: float = 0.5, publish_pose: Callable[[np.ndarray], None] | None = None,
             should_stop: Callable[[], bool] = lambda: False,
             on_view: Callable[[int, int], None] | None = None,
             write_view: WriteFunction | None = None) -> RunResult:
    """Visit ``pending`` views in order and record one frame at each.

    An arm failure (disconnect, protective stop, timeout) or a recording that cannot be written
    (disk full) ends the run: everything recorded so far is already flushed, and a later run
    resumes from the next missing view. A capture that
    times out is retried once, then the view is skipped (reported, never silently dropped).

    Args:
        pending: views still to record.
        arm: an :class:`~tof_mpd_ros.arm.isolated.IsolatedArm` (``move_to``, ``tcp_pose``).
        capture: returns a frame stamped after the given time, taken at the given camera pose.
        writer: an open :class:`~tof_mpd_ros.recordings.RecordingWriter`.
        hand_eye_m: (4, 4) camera pose in the flange frame, metres.
        settle_s: wait after the move before capturing (vibration, exposure).
        publish_pose: called with the actual TCP pose after each move (ROS: /arm/tcp_pose).
        should_stop: polled between views; True ends the run cleanly.
        on_view: progress callback ``(views done in this run, views pending)``.
        write_view: appends a captured view with its TCP pose; default
            ``writer.write_frame(frame, tcp_pose=tcp, hand_eye=hand_eye_m)``.
    """
    result = RunResult()
    for view in pending:
        if should_stop():
            break
        try:
            arm.move_to(view.tcp_to_base_m, speed=speed, accel=accel)
            tcp = arm.tcp_pose()
        except ArmError as err:
            result.failed_view, result.error = view.index, str(err)
            log.error("view %d: arm failed: %s; stopping (resume later)", view.index, err)
            return result
        if publish_pose is not None:
            publish_pose(tcp)
        time.sleep(settle_s)
        frame = _capture_with_retry(capture, tcp @ hand_eye_m, view.index, should_stop)
        if frame is None:
            if should_stop():  # a capture cut short by a stop is not a skipped view
                break
            result.skipped.append(view.index)
            continue
        try:
            if write_view is None:
                writer.write_frame(frame, tcp_pose=tcp, hand_eye=hand_eye_m)
            else:
                write_view(frame, tcp)
        except RecordingError as err:  # e.g. the disk is full: what is written stays
            result.failed_view = view.index
            result.error = f"cannot write the recording: {err}; run again to resume"
            log.error("view %d: %s", view.index, result.error)
            return result
        result.recorded.append(view.index)
        if on_view is not None:
            on_view(len(result.recorded), len(pending))
    return result


def _capture_with_retry(capture: CaptureFunction, camera_to_base_m: np.ndarray,
                        index: int, should_stop: Callable[[], bool]) -> Any:
    for attempt in (1, 2):
        if should_stop():
            return None
        after_ns = time.time_ns()
        try:
            return capture(after_ns, camera_to_base_m)
        except CaptureError as err:
            log.warning("view %d: capture attempt %d failed: %s", index, attempt, err)
    return None
