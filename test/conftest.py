"""Test-wide setup: keep every ROS process on loopback in this run's own domains, before rclpy
loads."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest

from tof_mpd_ros.machine import set_openmp_wait_policy

#: ROS domain IDs a test run owns: a block of this many consecutive IDs. The test process's own
#: (``ROS_DOMAIN_ID``) is the block's first; node tests take theirs with
#: ``ros_harness.domain_id(offset)``, a fixed offset per test file.
DOMAINS_PER_RUN = 14
#: Blocks start at 1 + DOMAINS_PER_RUN * k and stay within 1..88: domain 0 is every ROS user's
#: default, 91 the corrector benchmark's, and IDs above 101 collide with ephemeral ports on Linux.
N_BLOCKS = 6


def _claim_domain_block() -> int:
    """First domain ID of a block no other test run on this host holds.

    Each block has a lock file in the temporary directory, held (``flock``) for the life of this
    process, so concurrent runs never share a block; the search starts at a block derived from
    the pid. Should every block be taken (more than ``N_BLOCKS`` runs at once) or locking be
    unavailable, the pid's block is used unlocked.
    """
    start = os.getpid() % N_BLOCKS
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return 1 + DOMAINS_PER_RUN * start
    for i in range(N_BLOCKS):
        block = (start + i) % N_BLOCKS
        path = Path(tempfile.gettempdir()) / f"tof_mpd_ros_test_domains_{block}.lock"
        try:
            handle = open(path, "a")  # held open (locked) until the process exits
        except OSError:  # e.g. created by another user
            continue
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        _HELD.append(handle)
        return 1 + DOMAINS_PER_RUN * block
    return 1 + DOMAINS_PER_RUN * start


_HELD: list = []  # the lock file of this run's block, open (and locked) until exit

# DDS discovery must never leave loopback on this machine, and this run's domains are its own.
# These must be set before rclpy is imported anywhere in the test session; node processes inherit
# them (ros_harness.node_env sets each one's domain).
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ["TOF_MPD_TEST_DOMAIN_BASE"] = str(_claim_domain_block())
os.environ["TOF_MPD_TEST_DOMAINS_PER_RUN"] = str(DOMAINS_PER_RUN)
os.environ["ROS_DOMAIN_ID"] = os.environ["TOF_MPD_TEST_DOMAIN_BASE"]
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="tof_mpd_ros_log_"))
os.environ.setdefault("HOME", tempfile.gettempdir())
os.environ.setdefault("MPLBACKEND", "Agg")

# The test session is an entry point: like tof-mpd and the nodes, it chooses the OpenMP wait
# policy before torch loads OpenMP (the processes it starts inherit it).
set_openmp_wait_policy()

try:  # keep the 2-core machine usable by parallel test processes
    import torch

    torch.set_num_threads(1)
except ImportError:  # pragma: no cover - torch is a hard dependency, but keep conftest robust
    pass


def real_data_dir(name: str, env_var: str, is_layout: Callable[[Path], bool]) -> Path:
    """A folder of real frames: the repository's copy, ``data/realdata/NAME`` (MIT-licensed
    public frames, see its README and LICENSE), or wherever ``env_var`` points (another
    capture of the same layout). Committed, so the tests that need it run on every clone."""
    default = Path(__file__).resolve().parents[1] / "data" / "realdata" / name
    candidate = Path(os.environ.get(env_var, default))
    if not is_layout(candidate):
        pytest.fail(f"{candidate} does not hold the real frames' layout ({env_var} set to "
                    "another folder, or a checkout without data/realdata)")
    return candidate


@pytest.fixture(scope="session")
def azure_kinect_dir() -> Path:
    """The real Azure Kinect frame (depth, IR, factory calibration)."""
    from tof_mpd_ros.mismatch import realdata

    return real_data_dir("azure_kinect_mug", "TOF_MPD_AZURE_KINECT_DIR",
                         realdata.is_azure_kinect_dir)


@pytest.fixture(scope="session")
def adi_dir() -> Path:
    """The real Analog Devices frames (two modes of one office scene)."""
    from tof_mpd_ros.mismatch import realdata

    return real_data_dir("adi_tof_office", "TOF_MPD_ADI_DIR", realdata.is_adi_dir)
