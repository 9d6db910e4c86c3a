"""Analytic ray casting: exact hits on every primitive, nearest-hit logic, visibility."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from oracles.raycast_reference import visible_from

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.pose import invert_pose, look_at, transform_points
from tof_mpd_ros.sim import raycast, structured_light
from tof_mpd_ros.sim.objects import ObjectSpec
from tof_mpd_ros.sim.raycast import cast_rays, render_surface
from tof_mpd_ros.sim.scene import PlacedObject, Scene, Table, make_box_scene

# Odd-sized grid with the principal point on the central pixel.
INTR = Intrinsics(fx=150.0, fy=150.0, cx=60.0, cy=45.0, width=121, height=91)


def _one_of_each() -> Scene:
    specs = [ObjectSpec(1, "box", (150.0, 110.0, 90.0), 0.3),
             ObjectSpec(2, "cylinder", (120.0, 120.0, 160.0), 0.5, material_id=1),
             ObjectSpec(3, "sphere", (130.0, 130.0, 130.0), 0.7),
             ObjectSpec(4, "prism", (160.0, 120.0, 110.0), 0.9, apex_offset_mm=-30.0)]
    spots = [(330.0, -110.0, 0.4), (560.0, -120.0, 0.0), (340.0, 120.0, 0.0), (570.0, 110.0, -0.7)]
    objects = tuple(PlacedObject(s, i + 1, x, y, 0.0, yaw)
                    for i, (s, (x, y, yaw)) in enumerate(zip(specs, spots, strict=True)))
    return Scene(Table(albedo=0.6), objects)


def _surface_residual(obj: PlacedObject, points_base: np.ndarray) -> np.ndarray:
    """(N,) signed distance-like residual of base-frame points to the object's surface, mm."""
    p = transform_points(invert_pose(obj.object_to_base_mm), points_base)
    spec = obj.spec
    if spec.kind in ("box", "prism"):
        normals, offsets = spec.polyhedron_planes()
        return (p @ normals.T - offsets).max(axis=1)
    if spec.kind == "cylinder":
        r, h = spec.dims_mm[0] / 2, spec.dims_mm[2]
        return np.maximum.reduce([np.hypot(p[:, 0], p[:, 1]) - r, p[:, 2] - h, -p[:, 2]])
    r = spec.dims_mm[0] / 2
    return np.linalg.norm(p - [0.0, 0.0, r], axis=1) - r


POSES = [look_at(np.array([450.0, 0.0, 520.0]), np.array([450.0, 0.0, 50.0]), 0.3),
         look_at(np.array([250.0, -200.0, 400.0]), np.array([450.0, 0.0, 40.0]), -1.0),
         look_at(np.array([700.0, 150.0, 300.0]), np.array([450.0, 0.0, 60.0]), 2.0)]


def test_straight_down_on_a_box_matches_closed_form() -> None:
    scene = make_box_scene((150.0, 120.0, 100.0), albedo=0.4, table_albedo=0.65)
    pose = look_at(np.array([450.0, 0.0, 500.0]), np.array([450.0, 0.0, 0.0]))
    surf = render_surface(scene, pose, INTR)
    assert surf.range_mm[45, 60] == pytest.approx(400.0, abs=1e-9)
    np.testing.assert_allclose(surf.normal[45, 60], [0.0, 0.0, -1.0], atol=1e-12)
    # From straight above the box centre only the top face and the table are visible.
    rays = INTR.ray_directions()
    on_top = rays * (400.0 / rays[..., 2])[..., None]
    top_base = transform_points(pose, on_top)
    in_top = (np.abs(top_base[..., 0] - 450.0) <= 75.0) & (np.abs(top_base[..., 1]) <= 60.0)
    expected = np.where(in_top, 400.0, 500.0) / rays[..., 2]
    np.testing.assert_allclose(surf.range_mm, expected, rtol=1e-12)
    np.testing.assert_array_equal(surf.object_id, np.where(in_top, 1, 0))
    np.testing.assert_allclose(surf.albedo, np.where(in_top, 0.4, 0.65))
    assert 0.1 < in_top.mean() < 0.9


@pytest.mark.parametrize("pose", POSES)
def test_hits_lie_on_surfaces_with_camera_facing_unit_normals(pose: np.ndarray) -> None:
    scene = _one_of_each()
    surf = render_surface(scene, pose, INTR)
    points = transform_points(pose, surf.points_mm())
    seen = set(np.unique(surf.object_id)) - {-1}
    assert seen == {0, 1, 2, 3, 4}
    table = surf.object_id == 0
    np.testing.assert_allclose(points[table][:, 2], 0.0, atol=1e-6)
    normals_base = surf.normal @ pose[:3, :3].T
    for obj in scene.objects:
        mask = surf.object_id == obj.scene_index
        assert np.abs(_surface_residual(obj, points[mask])).max() < 1e-6
        # The normal is the outward surface gradient (central differences, away from edges).
        grad = np.stack([(_surface_residual(obj, points[mask] + e)
                          - _surface_residual(obj, points[mask] - e)) / 2e-4
                         for e in 1e-4 * np.eye(3)], axis=1)
        smooth = np.abs(np.linalg.norm(grad, axis=1) - 1.0) < 1e-3
        assert smooth.mean() > 0.95
        np.testing.assert_allclose(normals_base[mask][smooth], grad[smooth], atol=1e-3)
        assert np.all(surf.albedo[mask] == obj.spec.albedo)
        assert np.all(surf.material_id[mask] == obj.spec.material_id)
    valid = surf.valid
    np.testing.assert_allclose(np.linalg.norm(surf.normal[valid], axis=-1), 1.0, atol=1e-9)
    rays = INTR.ray_directions()[valid]
    assert np.all(np.einsum("ij,ij->i", surf.normal[valid], rays) <= 1e-12)


@pytest.mark.parametrize("pose", POSES)
def test_nearest_hit_is_the_minimum_over_single_objects(pose: np.ndarray) -> None:
    scene = _one_of_each()
    combined = render_surface(scene, pose, INTR).range_mm
    singles = [render_surface(Scene(scene.table, (obj,)), pose, INTR).range_mm
               for obj in scene.objects]
    np.testing.assert_allclose(combined, np.fmin.reduce(singles), rtol=1e-12)


def test_sphere_and_cylinder_closed_forms() -> None:
    scene = _one_of_each()
    cyl, sphere = scene.objects[1], scene.objects[2]
    # Straight down onto the sphere's top: distance = height - diameter.
    hits = cast_rays(scene, np.array([sphere.x_mm, sphere.y_mm, 400.0]), np.array([[0, 0, -1.0]]))
    assert hits.t_mm[0] == pytest.approx(400.0 - 130.0, abs=1e-9)
    np.testing.assert_allclose(hits.normal[0], [0.0, 0.0, 1.0], atol=1e-12)
    # Horizontally at the cylinder's axis from 300 mm away: distance = 300 - radius.
    origin = np.array([cyl.x_mm + 300.0, cyl.y_mm, 80.0])
    hits = cast_rays(scene, origin, np.array([[-1.0, 0.0, 0.0]]))
    assert hits.t_mm[0] == pytest.approx(300.0 - 60.0, abs=1e-9)
    assert hits.object_id[0] == cyl.scene_index
    np.testing.assert_allclose(hits.normal[0], [1.0, 0.0, 0.0], atol=1e-12)
    # A grazing miss just outside the radius passes.
    hits = cast_rays(Scene(scene.table, (cyl,)), origin + np.array([0.0, 60.001, 0.0]),
                     np.array([[-1.0, 0.0, 0.0]]))
    assert math.isinf(hits.t_mm[0])


def test_supersampled_centres_match_the_coarse_grid() -> None:
    scene = _one_of_each()
    coarse = render_surface(scene, POSES[1], INTR)
    fine = render_surface(scene, POSES[1], INTR.scaled(3))
    assert fine.range_mm.shape == (3 * INTR.height, 3 * INTR.width)
    np.testing.assert_allclose(fine.range_mm[1::3, 1::3], coarse.range_mm, rtol=1e-12)


def test_rays_off_the_table_hit_nothing() -> None:
    scene = Scene(Table(half_extent_mm=(100.0, 100.0)))
    pose = look_at(np.array([450.0, 0.0, 300.0]), np.array([450.0, 0.0, 0.0]))
    surf = render_surface(scene, pose, INTR)
    missed = ~surf.valid
    assert missed[0, 0] and not missed[45, 60]
    assert np.all(surf.object_id[missed] == -1) and np.all(surf.albedo[missed] == 0.0)
    assert np.all(np.isnan(surf.normal[missed]))


def test_visibility_from_a_point() -> None:
    scene = make_box_scene((150.0, 150.0, 100.0))
    light = np.array([450.0 - 400.0, 0.0, 150.0])  # low, to the -x side of the box
    points = np.array([[450.0 + 100.0, 0.0, 0.0],   # table right behind the box: shadowed
                       [450.0 - 100.0, 0.0, 0.0],   # table in front of the box: lit
                       [450.0, 0.0, 100.0],         # box top centre: lit
                       [450.0 - 75.0, 0.0, 50.0],   # box face towards the light: lit
                       [450.0 + 75.0, 0.0, 50.0],   # box back face: self-occluded
                       [np.nan, 0.0, 0.0]])
    np.testing.assert_array_equal(visible_from(scene, points, light),
                                  [False, True, True, True, False, False])


def test_bad_inputs_raise_input_error() -> None:
    scene = make_box_scene()
    with pytest.raises(InputError, match="directions"):
        cast_rays(scene, np.zeros(3), np.zeros((4, 2)))
    with pytest.raises(InputError, match="origins_mm"):
        cast_rays(scene, np.zeros((3, 3)), np.ones((4, 3)) / math.sqrt(3))
    with pytest.raises(InputError, match="camera_to_base_mm"):
        render_surface(scene, np.eye(3), INTR)


def test_packed_scene_columns_are_named_by_the_index_constants() -> None:
    scene = _one_of_each()
    packed = raycast.pack_scene(scene)
    table = scene.table
    assert packed.table.shape == (raycast.N_TABLE,)
    np.testing.assert_array_equal(
        packed.table[[raycast.TABLE_Z, raycast.TABLE_CX, raycast.TABLE_CY, raycast.TABLE_HALF_X,
                      raycast.TABLE_HALF_Y, raycast.TABLE_ALBEDO]],
        [table.height_mm, *table.centre_xy_mm, *table.half_extent_mm, table.albedo])
    assert packed.geom.shape == (4, raycast.N_GEOM)
    for obj, g, kind, planes, n in zip(scene.objects, packed.geom, packed.kind, packed.planes,
                                       packed.n_planes, strict=True):
        centre, radius = obj.bounding_sphere()
        assert (g[raycast.GEOM_X], g[raycast.GEOM_Y], g[raycast.GEOM_Z]) == (
            obj.x_mm, obj.y_mm, obj.z_mm)
        assert g[raycast.GEOM_COS_YAW] == math.cos(obj.yaw_rad)
        assert g[raycast.GEOM_SIN_YAW] == math.sin(obj.yaw_rad)
        np.testing.assert_array_equal(
            g[[raycast.GEOM_BOUND_X, raycast.GEOM_BOUND_Y, raycast.GEOM_BOUND_Z]], centre)
        assert g[raycast.GEOM_BOUND_R] == radius and g[raycast.GEOM_BOUND_R2] == radius**2
        assert g[raycast.GEOM_SHAPE_R] == obj.spec.dims_mm[0] / 2.0
        assert g[raycast.GEOM_SHAPE_R2] == (obj.spec.dims_mm[0] / 2.0) ** 2
        expected_kind = {"box": raycast.KIND_POLYHEDRON, "prism": raycast.KIND_POLYHEDRON,
                         "cylinder": raycast.KIND_CYLINDER, "sphere": raycast.KIND_SPHERE}
        assert kind == expected_kind[obj.spec.kind]
        if kind == raycast.KIND_POLYHEDRON:
            normals, offsets = obj.spec.polyhedron_planes()
            assert n == len(offsets)
            np.testing.assert_array_equal(
                planes[:n, [raycast.PLANE_NX, raycast.PLANE_NY, raycast.PLANE_NZ]], normals)
            np.testing.assert_array_equal(planes[:n, raycast.PLANE_OFFSET], offsets)
        else:
            assert n == 0


def test_the_package_ships_one_ray_caster_and_no_oracle() -> None:
    # The numpy ray caster, the point-visibility cast and the step-by-step SL scan are test
    # oracles (test/oracles); the package keeps only the compiled kernels.
    for module in (raycast, structured_light):
        oracles = [name for name in vars(module)
                   if name.endswith("_reference") or name in ("visible_from", "_Rays")]
        assert oracles == [], module.__name__
    # the exact convex-polyhedron caster is a test oracle too (test/oracles/analytic_scenes.py)
    assert importlib.util.find_spec("tof_mpd_ros.sim.tof.analytic") is None
