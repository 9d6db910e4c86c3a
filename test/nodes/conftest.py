"""Node tests need the ROS 2 wheels; the harness module sits beside them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "sim"))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if "nodes" in Path(str(item.fspath)).parts and "pairing" not in item.name:
            item.add_marker(pytest.mark.ros)
