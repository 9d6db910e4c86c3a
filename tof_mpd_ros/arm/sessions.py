"""Arm sessions: the objects that live in the isolated child process.

A session exposes ``move_l(pose, speed, accel) -> None``, ``tcp_pose() -> list[float]`` and
``status() -> dict`` and raises on failure. :class:`UrRtdeSession` drives a real UR through
ur_rtde; :class:`SimulatedSession` is the simulated UR5e, with optional injected faults so the
collector's failure handling is testable.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from ..errors import ArmError
from ..pose import matrix_to_pose_vector, pose_vector_to_matrix
from .ur5e import HOME_JOINTS, forward_kinematics, solve_ik


class UrRtdeSession:
    """A UR arm over ur_rtde (RTDEControlInterface + RTDEReceiveInterface).

    The constructors connect and can block indefinitely against an unresponsive controller;
    that is why this runs in a child process with a connect timeout.
    """

    def __init__(self, host: str, frequency_hz: float = -1.0) -> None:
        import rtde_control
        import rtde_receive

        self._receive = rtde_receive.RTDEReceiveInterface(host, frequency_hz)
        self._control = rtde_control.RTDEControlInterface(host, frequency_hz)

    def move_l(self, pose: list[float], speed: float, accel: float) -> None:
        self._check_ready()
        if not self._control.moveL(list(pose), speed, accel):
            state = self.status()
            raise ArmError(f"moveL failed: {state}")
        self._check_ready()

    def tcp_pose(self) -> list[float]:
        self._check_ready()
        return list(self._receive.getActualTCPPose())

    def status(self) -> dict[str, object]:
        return {"connected": bool(self._receive.isConnected() and self._control.isConnected()),
                "protective_stopped": bool(self._receive.isProtectiveStopped()),
                "emergency_stopped": bool(self._receive.isEmergencyStopped()),
                "safety_mode": int(self._receive.getSafetyMode()),
                "steady": bool(self._control.isSteady())}

    def _check_ready(self) -> None:
        if not (self._receive.isConnected() and self._control.isConnected()):
            raise ArmError("the UR controller disconnected")
        if self._receive.isProtectiveStopped():
            raise ArmError("the arm is in a protective stop")
        if self._receive.isEmergencyStopped():
            raise ArmError("the arm is emergency-stopped")

    def close(self) -> None:
        self._control.stopScript()
        self._control.disconnect()
        self._receive.disconnect()


class SimulatedSession:
    """The simulated UR5e: moves are checked with inverse kinematics and take simulated time.

    Args:
        speed_scale: wall-clock seconds slept per simulated second of motion (0 = instant).
        faults: injected failures for tests, e.g. ``{"hang_on_connect": True}``,
            ``{"crash_on_move": 3}`` (the process dies on the 3rd move, like a protocol
            error in a native client), ``{"protective_stop_on_move": 2}``,
            ``{"hang_on_move": 2}``.
    """

    def __init__(self, *, speed_scale: float = 0.0, faults: dict | None = None,
                 start_joints: list[float] | None = None) -> None:
        self._faults = dict(faults or {})
        if self._faults.get("hang_on_connect"):
            time.sleep(3600)
        self._joints = np.array(start_joints if start_joints is not None else HOME_JOINTS,
                                dtype=np.float64)
        self._speed_scale = speed_scale
        self._moves = 0
        self._protective_stop = False

    def move_l(self, pose: list[float], speed: float, accel: float) -> None:
        self._moves += 1
        if self._faults.get("crash_on_move") == self._moves:
            os._exit(134)  # what a native client's abort looks like to the parent
        if self._faults.get("hang_on_move") == self._moves:
            time.sleep(3600)
        if self._faults.get("protective_stop_on_move") == self._moves:
            self._protective_stop = True
        if self._protective_stop:
            raise ArmError("the arm is in a protective stop")
        target = pose_vector_to_matrix(pose)
        joints = solve_ik(target, self._joints)  # ArmError when unreachable
        distance = float(np.linalg.norm(target[:3, 3] - self.tcp_matrix()[:3, 3]))
        if self._speed_scale > 0 and speed > 0:
            time.sleep(self._speed_scale * (distance / speed + math.sqrt(2 * distance / accel)))
        self._joints = joints

    def tcp_matrix(self) -> np.ndarray:
        return forward_kinematics(self._joints)

    def tcp_pose(self) -> list[float]:
        return matrix_to_pose_vector(self.tcp_matrix()).tolist()

    def joints(self) -> list[float]:
        return self._joints.tolist()

    def status(self) -> dict[str, object]:
        return {"connected": True, "protective_stopped": self._protective_stop,
                "emergency_stopped": False, "safety_mode": 3 if self._protective_stop else 1,
                "steady": True}

    def close(self) -> None:
        pass
