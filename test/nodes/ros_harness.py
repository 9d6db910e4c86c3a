"""Helpers for node tests: start node executables in their own processes, listen on loopback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def domain_id(offset: int) -> int:
    """ROS domain ID number ``offset`` of this test run's block (test/conftest.py claims the
    block, so a concurrent run on the same host uses other IDs). Each test file keeps its own
    offsets, so the files' nodes never see each other either."""
    base = int(os.environ["TOF_MPD_TEST_DOMAIN_BASE"])
    if not 0 < offset < int(os.environ["TOF_MPD_TEST_DOMAINS_PER_RUN"]):
        raise ValueError(f"domain offset {offset} is outside this run's block")
    return base + offset


def node_env(domain_id: int) -> dict[str, str]:
    """Environment for a node process: loopback-only DDS, its own domain and log directory."""
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id),
               PYTHONPATH=str(REPO) + os.pathsep + env.get("PYTHONPATH", ""))
    env.setdefault("ROS_LOG_DIR", tempfile.gettempdir())
    return env


def start_node(executable: str, params: dict[str, object], domain_id: int,
               log_path: Path, *, script: Path | None = None,
               preexec_fn: Callable[[], None] | None = None,
               remap: Sequence[str] = ()) -> subprocess.Popen:
    """``python -m tof_mpd_ros.nodes.<executable> --ros-args -p k:=v ... -r from:=to ...``.

    With ``script``, ``python <script> --ros-args ...`` instead (a node with injected faults);
    ``preexec_fn`` runs in the child before it starts (e.g. a resource limit).
    """
    program = [str(script)] if script else ["-m", f"tof_mpd_ros.nodes.{executable}"]
    args = [sys.executable, *program, "--ros-args"]
    for key, value in params.items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        args += ["-p", f"{key}:={text}"]
    for rule in remap:  # remapping rules, "__ns:=/tof" or "from:=to"
        args += ["-r", rule]
    with open(log_path, "w") as log:  # the child keeps its own descriptor
        return subprocess.Popen(args, env=node_env(domain_id), stdout=log,
                                stderr=subprocess.STDOUT, preexec_fn=preexec_fn)


def stop_node(process: subprocess.Popen, timeout: float = 60.0,
              signum: int = signal.SIGINT) -> int:
    """``signum`` (default SIGINT, like Ctrl-C), then kill if it does not exit."""
    if process.poll() is None:
        process.send_signal(signum)
        try:
            process.wait(timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
    return process.returncode


def spin_until(node, executor, condition: Callable[[], bool], timeout: float) -> bool:
    """Spin ``executor`` until ``condition()`` holds or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        if condition():
            return True
    return condition()
