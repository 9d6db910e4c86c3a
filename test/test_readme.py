"""README's two commands are the ones that CI and newcomers run."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    return re.findall(r"```(?:bash|sh)\n(.+?)\n```", text, flags=re.S)


def test_ci_runs_exactly_the_readme_test_command() -> None:
    commands = readme_commands()
    assert len(commands) >= 2, "README must start with the main command and the test command"
    test_command = commands[1].strip()
    ci_lines = [line for line in (REPO / ".ci/run").read_text().splitlines()
                if line and not line.startswith(("#", "set ", "cd "))]
    assert ci_lines == [test_command]


def test_both_commands_create_their_own_virtual_environment() -> None:
    main, tests = readme_commands()[:2]
    for command in (main, tests):
        assert "python3 -m venv" in command and "pip install" in command
    assert "tof-mpd demo" in main
    assert "pytest" in tests
