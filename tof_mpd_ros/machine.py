"""The machine a process runs on: what its CPU is (reports and benchmarks record it)."""

from __future__ import annotations

import platform
from pathlib import Path

#: where Linux describes the CPUs
CPUINFO_PATH = Path("/proc/cpuinfo")


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

