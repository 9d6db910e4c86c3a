"""The machine a process runs on: what its CPU is, and the OpenMP wait policy entry points choose.

Nothing here runs at import: the entry points (``tof-mpd``, the node executables, the benchmark
scripts) call :func:`set_openmp_wait_policy` before numba or torch start OpenMP; reports and
benchmarks call :func:`cpu_model` / :func:`cpuinfo` to record where they ran.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

#: where Linux describes the CPUs
CPUINFO_PATH = Path("/proc/cpuinfo")
#: the OpenMP wait policy :func:`set_openmp_wait_policy` chooses
OMP_WAIT_POLICY = "PASSIVE"


def cpuinfo(path: Path = CPUINFO_PATH) -> dict[str, str]:
    """The first processor block of ``/proc/cpuinfo`` as ``{field: value}``; the package's one
    parser of that file.

    Args:
        path: the file (a test may pass a copy).

    Returns:
        Field names and values as written, stripped (``"model name"``, ``"flags"``,
        ``"cpu MHz"``, ...); empty off Linux or when the file cannot be read.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except OSError:
        return {}
    info: dict[str, str] = {}
    for line in text.split("\n\n")[0].splitlines():
        key, _, value = line.partition(":")
        info[key.strip()] = value.strip()
    return info


def cpu_model(path: Path = CPUINFO_PATH) -> str:
    """The CPU's model name (``/proc/cpuinfo``'s ``model name``), else
    :func:`platform.processor`, else the machine type, else ``"unknown"``."""
    return (cpuinfo(path).get("model name") or platform.processor() or platform.machine()
            or "unknown")


def set_openmp_wait_policy() -> None:
    """Let idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE``) unless the user chose a
    policy; the one place the package chooses it.

    numba's parallel kernels and torch share one OpenMP runtime (libgomp); under the default
    policy their idle threads spin and starve the other library's threads in the same process
    (measured: a full correction 4x slower right after a numba-parallel call). libgomp reads the
    variable once, when it loads (``import torch``, or numba's first parallel kernel), so an entry
    point calls this before either; processes it starts inherit the choice. An explicit user
    setting wins. The package does not call it on import.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", OMP_WAIT_POLICY)
