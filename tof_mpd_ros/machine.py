"""The machine a process runs on: what its CPU is, and the OpenMP wait policy entry points choose.

Nothing here runs at import: the entry points (``tof-mpd``, the node executables, the benchmark
scripts) call :func:`set_openmp_wait_policy` before numba or torch start OpenMP; reports and
benchmarks call :func:`cpu_model` / :func:`cpuinfo` to record where they ran, and the correction
asks :func:`slow_precision` whether a reduced precision has this CPU's instructions.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

#: where Linux describes the CPUs
CPUINFO_PATH = Path("/proc/cpuinfo")
#: x86 ``/proc/cpuinfo`` flags of the instructions a reduced precision's GEMMs and convolutions
#: need; without any of them oneDNN falls back to a reference kernel (measured on AMD Zen 3,
#: AVX2 only, 320x240: patch int8 2.7 s and bfloat16 2.1 s per frame against float32's 0.11 s;
#: docs/performance.md). ``avx_vnni`` (client cores) is listed as the int8 dot product it is,
#: not measured here.
PRECISION_FLAGS = {"bfloat16": ("avx512_bf16", "amx_bf16"),
                   "int8": ("avx512_vnni", "avx_vnni", "amx_int8")}
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


class SlowPrecisionWarning(RuntimeWarning):
    """A reduced precision asked for on a CPU without its instructions: the output is right,
    only slow (:func:`slow_precision`; issued by ``correction.pipeline.correct``)."""


def slow_precision(precision: str, path: Path = CPUINFO_PATH) -> str | None:
    """Why ``precision`` would run slower than float32 on this CPU, or None.

    None for float32, for a precision whose instructions the CPU lists
    (:data:`PRECISION_FLAGS`), and where that cannot be told (no x86 ``flags`` line: another
    architecture, or no ``/proc/cpuinfo``): a warning there would be a guess.

    Args:
        precision: ``"float32"``, ``"bfloat16"`` or ``"int8"``.
        path: the cpuinfo file (a test may pass a copy).
    """
    wanted = PRECISION_FLAGS.get(precision)
    info = cpuinfo(path)
    flags = info.get("flags")
    if wanted is None or flags is None or set(wanted) & set(flags.split()):
        return None
    where = " ".join(f"{k.split()[-1]} {info[k]}" for k in ("cpu family", "model") if k in info)
    return (f"precision {precision!r} without its instructions: this CPU "
            f"({info.get('model name') or cpu_model(path)}{', ' + where if where else ''}) "
            f"has none of "
            f"{', '.join(wanted)}, so its GEMMs and convolutions run in a "
            f"reference kernel, many times slower than float32 (measured on AMD Zen 3: "
            f"6-24x); use float32 here")


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
