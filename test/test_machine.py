"""tof_mpd_ros.machine: the one /proc/cpuinfo parser."""

from __future__ import annotations

import platform
from pathlib import Path

from tof_mpd_ros.machine import cpu_model, cpuinfo

# Two processors, as Linux writes them (tab before the colon, blank line between blocks).
CPUINFO_TEXT = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 26
model name\t: AMD EPYC 9B45
cpu MHz\t\t: 2600.000
flags\t\t: fpu sse2 avx2 fma avx512f

processor\t: 1
vendor_id\t: AuthenticAMD
model name\t: another name that must not be read
"""


def test_cpuinfo_reads_the_first_processor_block(tmp_path: Path) -> None:
    path = tmp_path / "cpuinfo"
    path.write_text(CPUINFO_TEXT, encoding="utf-8")
    info = cpuinfo(path)
    assert info["processor"] == "0"
    assert info["model name"] == "AMD EPYC 9B45"
    assert info["cpu MHz"] == "2600.000"
    assert info["cpu family"] == "26"
    assert info["flags"].split() == ["fpu", "sse2", "avx2", "fma", "avx512f"]
    assert cpu_model(path) == "AMD EPYC 9B45"


def test_without_cpuinfo_the_model_falls_back_to_platform(tmp_path: Path) -> None:
    missing = tmp_path / "absent"
    assert cpuinfo(missing) == {}
    assert cpu_model(missing) == (platform.processor() or platform.machine() or "unknown")


def test_a_block_without_model_name_falls_back_too(tmp_path: Path) -> None:
    path = tmp_path / "cpuinfo"
    path.write_text("processor\t: 0\nfeatures\t: fp asimd\n", encoding="utf-8")
    assert cpu_model(path) == (platform.processor() or platform.machine() or "unknown")
