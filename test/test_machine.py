"""tof_mpd_ros.machine: the one /proc/cpuinfo parser, and the OpenMP wait policy the entry
points (not the package's import) choose."""

from __future__ import annotations

import os
import platform
from collections.abc import Callable
from pathlib import Path

import pytest

from tof_mpd_ros.machine import cpu_model, cpuinfo, set_openmp_wait_policy, slow_precision

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


def test_the_wait_policy_is_passive_unless_the_user_chose_one(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    set_openmp_wait_policy()
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    set_openmp_wait_policy()
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"


def _cli_help() -> None:
    from tof_mpd_ros.cli.main import main

    main(["--help"])


def _node_help() -> None:
    from tof_mpd_ros.nodes.corrector import main

    main(["--help"])


@pytest.mark.parametrize("entry", [_cli_help, _node_help], ids=["tof-mpd", "corrector"])
def test_entry_points_choose_the_wait_policy_first(monkeypatch: pytest.MonkeyPatch,
                                                   entry: Callable[[], None]) -> None:
    """``tof-mpd`` and the node executables set it before anything else (even ``--help``)."""
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    with pytest.raises(SystemExit):
        entry()
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"


def _cpuinfo_with(tmp_path: Path, flags: str) -> Path:
    path = tmp_path / "cpuinfo"
    path.write_text(f"processor\t: 0\nmodel name\t: AMD EPYC 7B13\nflags\t\t: {flags}\n",
                    encoding="utf-8")
    return path


def test_a_reduced_precision_without_its_instructions_is_slow(tmp_path: Path) -> None:
    zen3 = _cpuinfo_with(tmp_path, "fpu sse2 avx avx2 fma")         # AVX2, no VNNI, no BF16
    for precision, flag in (("int8", "avx512_vnni"), ("bfloat16", "avx512_bf16")):
        why = slow_precision(precision, zen3)
        assert why is not None and repr(precision) in why
        assert flag in why and "AMD EPYC 7B13" in why and "float32" in why
    assert slow_precision("float32", zen3) is None


def test_a_precision_with_its_instructions_is_not(tmp_path: Path) -> None:
    zen4 = _cpuinfo_with(tmp_path, "avx2 fma avx512f avx512_vnni avx512_bf16")
    assert slow_precision("int8", zen4) is None
    assert slow_precision("bfloat16", zen4) is None
    sapphire = _cpuinfo_with(tmp_path, "avx2 avx512f amx_int8 amx_tile")   # AMX, no BF16 flag
    assert slow_precision("int8", sapphire) is None
    assert slow_precision("bfloat16", sapphire) is not None
    # a flag's name inside another's must not count ("avx512_vnnix" is not avx512_vnni)
    assert slow_precision("int8", _cpuinfo_with(tmp_path, "avx2 avx512_vnnix")) is not None


def test_where_it_cannot_be_told_nothing_is_said(tmp_path: Path) -> None:
    arm = tmp_path / "arm"
    arm.write_text("processor\t: 0\nFeatures\t: fp asimd bf16 i8mm\n", encoding="utf-8")
    assert slow_precision("int8", arm) is None
    assert slow_precision("bfloat16", tmp_path / "absent") is None
