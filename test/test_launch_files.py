"""Launch files parse and name only executables and config files that exist.

The `launch` package is not installable from PyPI, so the files are checked statically.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
EXECUTABLES = {"corrector", "collector", "sim_cell"}
LAUNCH_FILES = sorted((REPO / "launch").glob("*.launch.py"))


def string_keywords(tree: ast.AST, name: str) -> list[str]:
    return [kw.value.value for node in ast.walk(tree) if isinstance(node, ast.Call)
            for kw in node.keywords
            if kw.arg == name and isinstance(kw.value, ast.Constant)]


def test_there_are_launch_files() -> None:
    assert {p.name for p in LAUNCH_FILES} >= {"corrector.launch.py", "sim_demo.launch.py",
                                              "collector.launch.py"}


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_parses_and_refers_to_real_things(path: Path) -> None:
    tree = ast.parse(path.read_text(), filename=str(path))
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert "generate_launch_description" in functions
    executables = string_keywords(tree, "executable")
    assert executables and set(executables) <= EXECUTABLES
    assert set(string_keywords(tree, "package")) == {"tof_mpd_ros"}
    for literal in (n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)):
        if isinstance(literal, str) and literal.endswith(".yaml"):
            config = REPO / "config" / literal
            assert config.is_file(), f"{path.name} refers to missing {literal}"
            yaml.safe_load(config.read_text())
