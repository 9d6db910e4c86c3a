"""The ready-made views (views/: an RViz2 config and a Foxglove layout) parse, show what they
promise, and name only topics the nodes publish, resolved where the demo launch file puts them.

The published names come from the node modules' own tables (``corrector_node.PUBLISHED``,
``sim_cell_node.PUBLISHED``, whose publishers are created from them) and the namespaces from
``launch/sim_demo.launch.py``, read statically like test_launch_files.py does (``launch`` is
not installable from PyPI); nothing here lists topics by hand but what a view must show.
"""

from __future__ import annotations

import ast
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

pytest.importorskip("rclpy")

from tof_mpd_ros.nodes import corrector_node, sim_cell_node
from tof_mpd_ros.nodes.cell_topics import CELL_TOPICS

REPO = Path(__file__).resolve().parents[1]
VIEWS = REPO / "views"
RVIZ = VIEWS / "corrector.rviz"
FOXGLOVE = VIEWS / "corrector.foxglove.json"
LAUNCH = REPO / "launch" / "sim_demo.launch.py"
# What each view must show, as output keys of the nodes: input depth | corrected | correction |
# confidence side by side, and both clouds.
IMAGES = (("sim_cell", "depth"), ("corrector", "output"), ("corrector", "correction"),
          ("corrector", "confidence"))
CLOUDS = (("corrector", "input_points"), ("corrector", "points"))


def launch_namespaces(path: Path) -> dict[str, str]:
    """executable -> the namespace its ``Node(...)`` in the launch file gives it ("" = root)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = {}
    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call)):
        kw = {k.arg: k.value for k in call.keywords if isinstance(k.value, ast.Constant)}
        if "executable" in kw:
            out[kw["executable"].value] = kw["namespace"].value if "namespace" in kw else ""
    return out


def resolve(namespace: str, topic: str) -> str:
    """A relative topic name in ``namespace``, as rcl resolves it (absolute names stay)."""
    if topic.startswith("/"):
        return topic
    return "/" + "/".join(part for part in (namespace.strip("/"), topic) if part)


@pytest.fixture(scope="module")
def published() -> dict[tuple[str, str], str]:
    """(node, output key) -> resolved topic, for every publisher of the demo's two nodes."""
    ns = launch_namespaces(LAUNCH)
    assert set(ns) == {"sim_cell", "corrector"}, ns
    out = {("corrector", k): resolve(ns["corrector"], corrector_node.TOPICS[k])
           for k in corrector_node.PUBLISHED}
    out.update({("sim_cell", k): resolve(ns["sim_cell"], CELL_TOPICS[k])
                for k in sim_cell_node.PUBLISHED})
    return out


def rviz_displays(displays: list[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    """Every display, groups' members included."""
    for display in displays:
        yield display
        yield from rviz_displays(display.get("Displays", []))


def rviz_topic(display: dict[str, Any]) -> str | None:
    topic = display.get("Topic")
    return topic.get("Value") if isinstance(topic, dict) else topic


def foxglove_topics(config: Any) -> Iterator[str]:
    """Every topic a Foxglove panel config names: ``...Topic`` values, ``topics`` keys."""
    if isinstance(config, dict):
        for key, value in config.items():
            if key.lower().endswith("topic") and isinstance(value, str):
                yield value
            elif key == "topics" and isinstance(value, dict):
                yield from value
            yield from foxglove_topics(value)
    elif isinstance(config, list):
        for item in config:
            yield from foxglove_topics(item)


def layout_leaves(node: Any) -> list[str]:
    """Panel ids of a Foxglove layout tree, left to right / top to bottom."""
    if isinstance(node, str):
        return [node]
    assert set(node) >= {"first", "second", "direction"}, node
    return layout_leaves(node["first"]) + layout_leaves(node["second"])


def sim_cell_frame_id() -> str:
    return next(p.default for p in sim_cell_node.PARAMETERS if p.name == "frame_id")


def test_the_launch_file_namespaces_are_read() -> None:
    assert launch_namespaces(LAUNCH) == {"sim_cell": "", "corrector": "tof"}
    assert resolve("tof", "depth_corrected/points") == "/tof/depth_corrected/points"
    assert resolve("", "tof/depth/image_raw") == "/tof/depth/image_raw"


def test_rviz_config_shows_the_four_images_and_both_clouds(
        published: dict[tuple[str, str], str]) -> None:
    config = yaml.safe_load(RVIZ.read_text())
    manager = config["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == sim_cell_frame_id()
    displays = list(rviz_displays(manager["Displays"]))
    assert all(d["Class"].startswith("rviz_default_plugins/") for d in displays)
    named = [(d["Class"], rviz_topic(d)) for d in displays if rviz_topic(d) is not None]
    for _, topic in named:  # every topic it names is one the nodes publish
        assert topic in published.values(), f"{RVIZ.name} names {topic}, which nobody publishes"
    images = [t for c, t in named if c == "rviz_default_plugins/Image"]
    clouds = [t for c, t in named if c == "rviz_default_plugins/PointCloud2"]
    assert images == [published[k] for k in IMAGES]
    assert clouds == [published[k] for k in CLOUDS]
    for display in displays:
        if isinstance(display.get("Topic"), dict):  # the nodes publish reliably (image_pipeline)
            assert display["Topic"]["Reliability Policy"] in ("Reliable", "Best Effort")
    cloud = next(d for d in displays if rviz_topic(d) == published[("corrector", "points")])
    assert cloud["Channel Name"] == "intensity"  # a field of the published cloud


def test_foxglove_layout_shows_the_four_images_side_by_side_and_both_clouds(
        published: dict[tuple[str, str], str]) -> None:
    layout = json.loads(FOXGLOVE.read_text())
    panels = layout["configById"]
    leaves = layout_leaves(layout["layout"])
    assert sorted(leaves) == sorted(panels)  # every panel placed, nothing placed twice
    topics = list(foxglove_topics(panels))
    assert topics
    for topic in topics:
        assert topic in published.values(), f"{FOXGLOVE.name} names {topic}, which nobody " \
            "publishes"
    images = [p for p in leaves if p.startswith("Image!")]
    assert [panels[p]["imageMode"]["imageTopic"] for p in images] == \
        [published[k] for k in IMAGES]
    # The four images in one row, above the 3-D panel.
    row = layout["layout"]["first"]
    assert layout["layout"]["direction"] == "column" and layout_leaves(row) == images
    assert all(n["direction"] == "row" for n in (row, row["first"], row["second"]))
    [three_d] = [p for p in leaves if p.startswith("3D!")]
    assert panels[three_d]["followTf"] == sim_cell_frame_id()
    assert list(panels[three_d]["topics"]) == [published[k] for k in CLOUDS]
    assert panels[three_d]["topics"][published[("corrector", "points")]]["colorField"] == \
        "intensity"


def test_every_named_topic_check_would_catch_a_stray_name(
        published: dict[tuple[str, str], str]) -> None:
    """The check above is not vacuous: the views' names are found, a typo is not published."""
    assert published[("corrector", "points")] == "/tof/depth_corrected/points"
    assert published[("sim_cell", "depth")] == "/tof/depth/image_raw"
    assert "/tof/depth_corrected/pointz" not in published.values()
    assert set(foxglove_topics({"a": {"imageTopic": "/x"}, "topics": {"/y": {}}})) == {"/x",
                                                                                      "/y"}
