"""The real-robot side (arm, capture plans, calibration) never loads the simulator."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

# Modules a real cell runs: they must not import tof_mpd_ros.sim (the simulator imports them).
REAL_CELL_MODULES = [
    "tof_mpd_ros.arm.isolated",
    "tof_mpd_ros.arm.sessions",
    "tof_mpd_ros.arm.tool",
    "tof_mpd_ros.arm.ur5e",
    "tof_mpd_ros.arm.viewpoints",
    "tof_mpd_ros.calibration",
    "tof_mpd_ros.calibration.hand_eye",
    "tof_mpd_ros.calibration.hand_eye_board",
    "tof_mpd_ros.calibration.hand_eye_io",
    "tof_mpd_ros.calibration.intrinsic",
    "tof_mpd_ros.cli.calibrate",
    "tof_mpd_ros.collection.hand_eye_plan",
    "tof_mpd_ros.collection.plan",
    "tof_mpd_ros.collection.runner",
    "tof_mpd_ros.collection.session",
]


def test_real_cell_modules_do_not_import_the_simulator() -> None:
    code = ("import importlib, json, sys\n"
            f"for name in {REAL_CELL_MODULES!r}:\n"
            "    importlib.import_module(name)\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('tof_mpd_ros.'))))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, cwd=Path(__file__).resolve().parents[2])
    loaded = json.loads(done.stdout)
    assert set(REAL_CELL_MODULES) <= set(loaded)
    assert [m for m in loaded if m.startswith("tof_mpd_ros.sim")] == []
