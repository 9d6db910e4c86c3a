"""Run an arm session in a child process, with a timeout on every call.

ur_rtde's constructors can block forever (holding the GIL) against an unresponsive controller,
and a protocol error in the native client can abort the whole process. Isolating the session in
its own process means a hang becomes a timeout and a crash becomes an :class:`ArmError`, while
the collector and its open recording carry on.
"""

from __future__ import annotations

import importlib
import multiprocessing as mp
import traceback
from typing import Any

import numpy as np

from ..errors import ArmError
from ..pose import matrix_to_pose_vector, pose_vector_to_matrix

SESSIONS = {
    "ur_rtde": "tof_mpd_ros.arm.sessions:UrRtdeSession",
    "sim": "tof_mpd_ros.arm.sessions:SimulatedSession",
}


def _serve(conn, target: str, kwargs: dict[str, Any]) -> None:
    """Child process: build the session, then answer ``(method, args)`` requests."""
    try:
        module, name = target.split(":")
        session = getattr(importlib.import_module(module), name)(**kwargs)
        conn.send(("ok", None))
    except BaseException as err:  # report any failure to connect to the parent, then exit
        conn.send(("error", f"{type(err).__name__}: {err}"))
        return
    while True:
        try:
            method, args = conn.recv()
        except EOFError:
            return
        if method == "__stop__":
            _safe_close(session)
            conn.send(("ok", None))
            return
        try:
            conn.send(("ok", getattr(session, method)(*args)))
        except BaseException as err:  # the parent decides what a failed call means
            conn.send(("error", f"{type(err).__name__}: {err}"))
            if not isinstance(err, Exception):
                traceback.print_exc()
                return


def _safe_close(session: object) -> None:
    try:
        session.close()  # type: ignore[attr-defined]
    except Exception:  # closing a broken connection must not mask the original problem
        pass


class IsolatedArm:
    """An arm session in a child process.

    Args:
        backend: ``"ur_rtde"`` or ``"sim"`` (or ``"module:Class"`` of another session type).
        connect_timeout_s: how long connecting may take.
        call_timeout_s: how long one call (a move included) may take.
        **session_kwargs: passed to the session constructor (``host=...`` for ur_rtde).

    Raises:
        ArmError: the child failed to connect in time, died, or a call failed or timed out.
            After a timeout or a death the child is killed and the arm is unusable
            (:attr:`alive` is False); a failed call leaves it usable.
    """

    def __init__(self, backend: str = "sim", *, connect_timeout_s: float = 10.0,
                 call_timeout_s: float = 60.0, **session_kwargs: Any) -> None:
        target = SESSIONS.get(backend, backend)
        if ":" not in target:
            raise ArmError(f"unknown arm backend {backend!r}; expected one of {sorted(SESSIONS)}")
        self.call_timeout_s = call_timeout_s
        ctx = mp.get_context("spawn")  # never fork a process that runs DDS threads
        self._conn, child_conn = ctx.Pipe()
        self._process = ctx.Process(target=_serve, args=(child_conn, target, session_kwargs),
                                    daemon=True, name=f"arm-{backend}")
        self._process.start()
        child_conn.close()
        self._receive("connect", connect_timeout_s)

    @property
    def alive(self) -> bool:
        return self._process.is_alive()

    def _receive(self, what: str, timeout_s: float) -> Any:
        if not self._conn.poll(timeout_s):
            if self._process.is_alive():
                self._kill()
                raise ArmError(f"arm {what} timed out after {timeout_s:.1f} s; the arm client "
                               "was stopped")
        try:
            status, value = self._conn.recv()
        except (EOFError, OSError) as err:
            self._process.join(1.0)
            code = self._process.exitcode
            self._kill()
            raise ArmError(f"arm client process died during {what} (exit code {code})") from err
        if status == "error":
            raise ArmError(f"arm {what} failed: {value}")
        return value

    def call(self, method: str, *args: Any) -> Any:
        if not self._process.is_alive():
            raise ArmError(f"arm client is not running (exit code {self._process.exitcode}); "
                           "reconnect the arm")
        try:
            self._conn.send((method, args))
        except (BrokenPipeError, OSError) as err:
            self._kill()
            raise ArmError(f"arm client process died before {method}") from err
        return self._receive(method, self.call_timeout_s)

    def move_to(self, tcp_to_base_m: np.ndarray, *, speed: float = 0.1,
                accel: float = 0.5) -> None:
        """Linear move of the TCP to a (4, 4) pose in the base frame (metres)."""
        self.call("move_l", matrix_to_pose_vector(tcp_to_base_m).tolist(), speed, accel)

    def tcp_pose(self) -> np.ndarray:
        """(4, 4) float64 actual TCP-to-base pose, metres."""
        return pose_vector_to_matrix(np.asarray(self.call("tcp_pose")))

    def status(self) -> dict[str, object]:
        return self.call("status")

    def _kill(self) -> None:
        if self._process.is_alive():
            self._process.kill()
        self._process.join(5.0)

    def close(self) -> None:
        if self._process.is_alive():
            try:
                self._conn.send(("__stop__", ()))
                self._conn.poll(5.0)
            except OSError:
                pass
        self._kill()
        self._conn.close()

    def __enter__(self) -> IsolatedArm:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
