"""Object library and scene arrangement of the simulated cell."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tof_mpd_ros.errors import InputError, SimulationError
from tof_mpd_ros.sim.objects import KINDS, ObjectSpec, library_split, object_library
from tof_mpd_ros.sim.scene import (
    SceneConfig,
    footprints_separated,
    make_box_scene,
    make_scene,
)


def test_library_size_sizes_albedo_and_materials() -> None:
    lib = object_library()
    assert len(lib) >= 60
    assert [o.library_id for o in lib] == list(range(1, len(lib) + 1))
    assert all(100.0 <= o.largest_extent_mm <= 200.0 for o in lib)
    assert all(0.1 <= o.albedo <= 0.9 for o in lib)
    assert {o.kind for o in lib} == set(KINDS)
    materials = [o.material_id for o in lib]
    assert 0 < sum(m != 0 for m in materials) < len(lib) // 3


def test_splits_are_disjoint_halves_with_every_kind() -> None:
    train, test = library_split("train"), library_split("test")
    train_ids, test_ids = {o.library_id for o in train}, {o.library_id for o in test}
    assert not train_ids & test_ids
    assert train_ids | test_ids == {o.library_id for o in object_library()}
    assert len(train) == len(test)
    assert {o.kind for o in train} == {o.kind for o in test} == set(KINDS)
    with pytest.raises(InputError, match="split"):
        library_split("validation")


def test_prism_planes_contain_its_vertices() -> None:
    spec = ObjectSpec(0, "prism", (120.0, 80.0, 60.0), 0.5, apex_offset_mm=20.0)
    normals, offsets = spec.polyhedron_planes()
    vertices = np.array([[x, y, 0.0] for x in (-60, 60) for y in (-40, 40)]
                        + [[20.0, y, 60.0] for y in (-40, 40)])
    slack = vertices @ normals.T - offsets
    assert np.all(slack <= 1e-9)
    # Each of the 5 faces touches at least 3 vertices (a face, not a loose bound).
    assert np.all((np.abs(slack) < 1e-9).sum(axis=0) >= 3)


def test_footprint_separation_by_hand() -> None:
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    assert footprints_separated(square, square + np.array([15.0, 0.0]), gap_mm=5.0)
    assert not footprints_separated(square, square + np.array([14.0, 0.0]), gap_mm=5.0)
    assert not footprints_separated(square, square + np.array([5.0, 5.0]), gap_mm=0.0)
    # The brute-force distance used below agrees with the hand values.
    assert _min_distance(square, square + np.array([20.0, 0.0])) == pytest.approx(10.0)
    assert _min_distance(square, square + np.array([13.0, 14.0])) == pytest.approx(5.0)
    assert _min_distance(square, square + np.array([5.0, 5.0])) == 0.0


def _outline(poly: np.ndarray, per_edge: int = 50) -> np.ndarray:
    """(K * per_edge, 2) points densely sampled along a polygon's edges."""
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)[:, None, None]
    return (poly + t * (np.roll(poly, -1, axis=0) - poly)).reshape(-1, 2)


def _inside(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: inside a counter-clockwise convex polygon."""
    edges = np.roll(poly, -1, axis=0) - poly
    rel = points[:, None, :] - poly[None]
    return np.all(edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0] >= 0, axis=1)


def _vertex_segment_distance(vertices: np.ndarray, poly: np.ndarray) -> float:
    """Smallest distance from any of ``vertices`` to any edge of ``poly`` (exact), mm."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(((vertices[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return float(np.linalg.norm(vertices[:, None] - closest, axis=-1).min())


def _min_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between two disjoint convex polygons (0 if they overlap), mm."""
    if _inside(_outline(a), b).any() or _inside(_outline(b), a).any():
        return 0.0
    return min(_vertex_segment_distance(a, b), _vertex_segment_distance(b, a))


@pytest.mark.parametrize("split", ["train", "test"])
def test_scenes_are_deterministic_valid_arrangements(split: str) -> None:
    config = SceneConfig()
    allowed = {o.library_id for o in library_split(split)}
    for seed in range(8):
        scene = make_scene(split, np.random.default_rng(seed), config)
        again = make_scene(split, np.random.default_rng(seed), config)
        assert [(o.spec.library_id, o.x_mm, o.yaw_rad) for o in scene.objects] == \
               [(o.spec.library_id, o.x_mm, o.yaw_rad) for o in again.objects]
        assert 2 <= len(scene.objects) <= 5
        assert 0.5 <= scene.table.albedo <= 0.7
        assert {o.spec.library_id for o in scene.objects} <= allowed
        assert len({o.spec.library_id for o in scene.objects}) == len(scene.objects)
        assert [o.scene_index for o in scene.objects] == list(range(1, len(scene.objects) + 1))
        centre = np.array(config.workspace_centre_mm)
        for i, a in enumerate(scene.objects):
            assert a.z_mm == scene.table.height_mm  # resting on the table
            fp = a.footprint_base()
            assert np.all(np.abs(fp - centre) <= config.placement_half_size_mm + 1e-9)
            for b in scene.objects[i + 1:]:
                assert _min_distance(fp, b.footprint_base()) >= config.min_gap_mm - 0.5


def test_impossible_arrangement_raises_simulation_error() -> None:
    cramped = SceneConfig(n_objects=(5, 5), placement_half_size_mm=120.0, max_tries=20,
                          max_arrangements=3)
    with pytest.raises(SimulationError, match="could not arrange 5 objects"):
        make_scene("train", np.random.default_rng(0), cramped)
    with pytest.raises(InputError, match="n_objects"):
        make_scene("train", np.random.default_rng(0), SceneConfig(n_objects=(3, 2)))


def test_box_scene() -> None:
    scene = make_box_scene((150.0, 120.0, 100.0), albedo=0.4, table_albedo=0.65)
    (box,) = scene.objects
    assert box.spec.kind == "box" and box.spec.albedo == 0.4 and box.scene_index == 1
    assert scene.top_height_mm() == pytest.approx(100.0)
    np.testing.assert_allclose(scene.objects_centroid_mm(), [450.0, 0.0, 50.0])
    _, radius = box.bounding_sphere()
    assert radius == pytest.approx(np.linalg.norm([75.0, 60.0, 50.0]))
    described = json.loads(json.dumps(scene.as_dict()))
    assert described["objects"][0]["dims_mm"] == [150.0, 120.0, 100.0]
    assert described["table"]["albedo"] == 0.65
