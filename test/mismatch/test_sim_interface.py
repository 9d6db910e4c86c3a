"""The mismatch tool reaches the simulator only through ``tof_mpd_ros.sim.tof``'s public names
(its ``__all__``), never through its modules' internals."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import tof_mpd_ros.mismatch
import tof_mpd_ros.sim.tof

MISMATCH = Path(tof_mpd_ros.mismatch.__file__).parent
SOURCES = sorted(MISMATCH.glob("*.py"))


def _sim_tof_imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, names) of every import of ``tof_mpd_ros.sim.tof`` or below in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:  # relative to tof_mpd_ros.mismatch
                parent = ["tof_mpd_ros", "mismatch"][:2 - node.level + 1]
                module = ".".join([*parent, module] if module else parent)
            if module.startswith("tof_mpd_ros.sim.tof"):
                found.append((module, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.startswith("tof_mpd_ros.sim.tof")]
    return found


def test_the_parser_sees_the_imports():
    imports = dict(_sim_tof_imports(MISMATCH / "predict.py"))
    assert "FramePredictor" not in imports.get("tof_mpd_ros.sim.tof", [])
    assert "pipeline_steps" in imports["tof_mpd_ros.sim.tof"]


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: p.name)
def test_mismatch_imports_only_public_sim_tof_names(path):
    public = set(tof_mpd_ros.sim.tof.__all__)
    for module, names in _sim_tof_imports(path):
        assert module == "tof_mpd_ros.sim.tof", f"{path.name} imports from {module}"
        assert set(names) <= public, f"{path.name}: {sorted(set(names) - public)} not public"
