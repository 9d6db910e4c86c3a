"""Each node's parameter table and its config/*.yaml agree, and descriptors are meaningful."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")

REPO = Path(__file__).resolve().parents[2]
NODES = {"corrector": "corrector_node", "collector": "collector_node",
         "sim_cell": "sim_cell_node"}


@pytest.mark.parametrize("node", sorted(NODES))
def test_config_yaml_mirrors_the_declared_defaults(node: str) -> None:
    module = importlib.import_module(f"tof_mpd_ros.nodes.{NODES[node]}")
    declared = {spec.name: spec.default for spec in module.PARAMETERS}
    config = yaml.safe_load((REPO / "config" / f"{node}.yaml").read_text())
    assert config[node]["ros__parameters"] == declared


@pytest.mark.parametrize("node", sorted(NODES))
def test_every_parameter_is_described_and_defaults_pass_their_checks(node: str) -> None:
    module = importlib.import_module(f"tof_mpd_ros.nodes.{NODES[node]}")
    for spec in module.PARAMETERS:
        assert len(spec.description) > 10, spec.name
        assert spec.check(spec.default) is None, spec.name
        if spec.choices:
            assert spec.check("definitely-not-a-choice") is not None
