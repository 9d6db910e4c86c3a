"""The world light travels through: scene tessellation, the support plane a range image implies,
and fusion of other views — checked against the scene's exact world with numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import median_filter

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.pose import look_at
from tof_mpd_ros.sim.cell import CameraModel
from tof_mpd_ros.sim.objects import ObjectSpec
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import PlacedObject, Scene, Table
from tof_mpd_ros.sim.tof import ToFConfig, render_from_reference, render_tof
from tof_mpd_ros.sim.tof.reference import surface_from_reference
from tof_mpd_ros.sim.tof.reference_world import (
    Plane,
    ReferenceView,
    border_extension,
    extruded_objects,
    fit_support_plane,
    fusion_views,
    world_from_surface,
)
from tof_mpd_ros.sim.tof.transport import MAX_SPREAD, _bounce_cut
from tof_mpd_ros.sim.tof.world import build_tree, spot_profile, world_from_scene

K = CameraModel().intrinsics
TARGET = np.array([450.0, 0.0, 60.0])
MULTIPATH = ToFConfig.ideal().with_effect("multipath", enabled=True)


def _cube_scene(x: float = 450.0, y: float = 0.0) -> Scene:
    box = PlacedObject(ObjectSpec(1, "box", (150.0, 150.0, 150.0), 0.5), 1, x, y, 0.0,
                       math.radians(20))
    return Scene(Table(albedo=0.5), (box,))


def _pose(eye) -> np.ndarray:
    return look_at(np.asarray(eye, float), TARGET)


@pytest.fixture(scope="module")
def cube():
    scene = _cube_scene()
    pose = _pose([330.0, 0.0, 450.0])
    surf = render_surface(scene, pose, K)
    truth = render_tof(surf, MULTIPATH, np.random.default_rng(0), supersample=1,
                       world=world_from_scene(scene, pose))
    field = median_filter(truth.range_mm - surf.range_mm, 5)
    return scene, pose, surf, field


@pytest.mark.parametrize("kind,dims,area", [
    ("box", (100.0, 60.0, 40.0), 100 * 60 + 2 * (100 * 40 + 60 * 40)),
    ("cylinder", (80.0, 80.0, 50.0), math.pi * 40 ** 2 + 2 * math.pi * 40 * 50),
    ("sphere", (90.0, 90.0, 90.0), 4 * math.pi * 45 ** 2),
    ("prism", (120.0, 70.0, 60.0), 120 * 60 + 2 * 70 * math.hypot(60, 60)),
])
def test_object_faces_have_their_area_and_face_outwards(kind, dims, area):
    spec = ObjectSpec(1, kind, dims, 0.5)
    obj = PlacedObject(spec, 1, 450.0, 0.0, 0.0, 0.3)
    world = world_from_scene(Scene(Table(), (obj,)), _pose([400.0, 0.0, 400.0]))
    tree = world.tree
    leaves = slice(0, tree.n_leaves)
    on_obj = tree.centre[leaves, 2] > 1e-6  # the table is the plane z = 0
    centre, _ = obj.bounding_sphere()
    if kind == "prism":  # the apex is at x = 0 (apex_offset 0): the solid's centroid height
        centre = np.array([450.0, 0.0, dims[2] / 3.0])
    outward = np.einsum("ij,ij->i", tree.centre[leaves][on_obj] - centre,
                        tree.normal[leaves][on_obj])
    assert np.all(outward > 0)
    # the bottom rests on the table and is not a surface; everything else is, with its area
    assert tree.area[leaves][on_obj].sum() == pytest.approx(area, rel=0.01)


def test_table_reaches_across_the_light_cone_and_shadows_are_unlit(cube):
    scene, pose, _, _ = cube
    world = world_from_scene(scene, pose)
    tree = world.tree
    table = tree.centre[:tree.n_leaves, 2] < 1e-6
    # the cone (60°) from 450 mm above the table reaches ~600-800 mm out: far beyond the crop
    reach = np.linalg.norm(tree.centre[:tree.n_leaves][table, :2] - pose[:3, 3][:2], axis=1)
    assert reach.max() > 600.0
    # table just behind the box (seen from the light) is in its shadow: unlit (the light at
    # x = 330 over the box's far top edge, 150 mm high, reaches the table beyond x = 610)
    x = tree.centre[:tree.n_leaves, 0]
    behind = table & (x > 560) & (x < 600) & (np.abs(tree.centre[:tree.n_leaves, 1]) < 40)
    assert behind.sum() > 50 and not world.lit[behind].any()
    assert world.lit[table & (tree.centre[:tree.n_leaves, 0] < 350)].all()


def test_spot_profile_is_flat_in_the_beam_and_linear_to_the_cutoff():
    angles = np.radians([0.0, 44.0, 45.0, 52.5, 60.0, 70.0])
    np.testing.assert_allclose(spot_profile(np.cos(angles), 60.0, 45.0),
                               [1.0, 1.0, 1.0, 0.5, 0.0, 0.0], atol=1e-9)


def test_support_plane_is_the_table(cube):
    _, pose, surf, _ = cube
    plane = fit_support_plane(surf.points_mm().reshape(-1, 3))
    assert plane is not None
    true_n = pose[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # table normal in the camera frame
    assert math.degrees(math.acos(min(1.0, plane.normal @ true_n))) < 0.1
    assert -plane.offset_mm == pytest.approx(pose[2, 3], abs=0.5)  # camera height above it
    assert plane.inlier_fraction > 0.5


def test_no_support_plane_in_a_cloud_without_one():
    rng = np.random.default_rng(3)
    cloud = rng.normal(size=(5000, 3)) * 50.0 + np.array([0.0, 0.0, 400.0])
    assert fit_support_plane(cloud) is None


def test_hidden_faces_are_inferred_by_extrusion_or_seen_by_other_views(cube):
    """The table's second bounce comes partly from box faces the target camera cannot see.
    Without them (carving only, nothing extruded) the table is about a mm short; objects
    extruded down to the support plane put walls there, and other views of the scene see them."""
    scene, pose, surf, truth = cube
    table = surf.object_id == 0

    def table_rmse(m) -> float:
        f = median_filter(m.range_mm - surf.range_mm, 5)
        ok = table & np.isfinite(f) & np.isfinite(truth)
        return float(np.sqrt(np.mean((f - truth)[ok] ** 2)))

    without = render_tof(surf, MULTIPATH, np.random.default_rng(0), supersample=1,
                         world=world_from_surface(surf, extend_plane=True, extrude=False))
    alone = render_from_reference(surf.range_mm, K, 0.5, MULTIPATH, camera_to_world_mm=pose)
    views = [ReferenceView(render_surface(scene, p, K).range_mm, p, 0.5)
             for p in (_pose([570.0, 0.0, 450.0]), _pose([450.0, 120.0, 450.0]),
                       _pose([450.0, -120.0, 450.0]))]
    fused = render_from_reference(surf.range_mm, K, 0.5, MULTIPATH, camera_to_world_mm=pose,
                                  other_views=views)
    assert np.nanmedian(truth[table]) > 0.8  # the exact world: about a mm on the table
    assert table_rmse(without) > 0.7
    assert table_rmse(alone) < 0.5 * table_rmse(without)
    assert table_rmse(fused) < 0.5 * table_rmse(without)


@pytest.mark.parametrize("coarse", [1, 4])
def test_extruded_walls_stand_for_the_hidden_faces_at_any_pixel_size(coarse):
    """The cube's two faces turned away from the camera (2 × 150 × 150 mm²) come back as
    extruded walls — also when the pixels are 4× coarser than the height field's cells (each
    pixel then fills several cells; left as isolated columns they grew walls around every gap:
    5× the area and 100× the transport time)."""
    k = Intrinsics(K.fx / coarse, K.fy / coarse, (K.cx + 0.5) / coarse - 0.5,
                   (K.cy + 0.5) / coarse - 0.5, K.width // coarse, K.height // coarse)
    pose = _pose([330.0, 0.0, 450.0])
    world = world_from_surface(render_surface(_cube_scene(), pose, k), camera_to_world=pose,
                               world_up=np.array([0.0, 0.0, 1.0]), border_fraction=0.0)
    hidden_mm2 = 2 * 150.0 * 150.0
    assert 0.8 * hidden_mm2 <= world.notes["extruded_wall_mm2"] <= 1.6 * hidden_mm2


def test_a_surface_cut_by_the_border_continues_on_its_plane():
    """A tilted plane filling the image: the margin's rays meet the same plane (to the
    normals' accuracy), every margin pixel is filled, and as the support plane (exact
    elsewhere) it is not continued at all."""
    n = np.array([0.3, 0.2, -1.0]) / np.linalg.norm([0.3, 0.2, -1.0])
    d = -400.0  # n·p = d, the camera on the side n points to
    range_mm = d / (K.ray_directions() @ n)
    surface = surface_from_reference(range_mm, K, 0.5)
    wide, beyond = border_extension(surface, 20, None)
    assert wide.intrinsics.shape == (K.height + 40, K.width + 40)
    np.testing.assert_array_equal(wide.range_mm[20:-20, 20:-20], surface.range_mm)
    margin = np.ones(wide.intrinsics.shape, bool)
    margin[20:-20, 20:-20] = False
    assert beyond[margin].mean() > 0.99 and not beyond[~margin].any()
    off_plane = wide.points_mm()[beyond] @ n - d
    assert np.max(np.abs(off_plane)) < 0.05
    _, none = border_extension(surface, 20, Plane(n, d, 1.0))
    assert not none.any()


def test_fusion_picks_views_of_the_same_scene_only():
    """Two scenes share the table plane; only views whose objects agree are fused."""
    eyes = ([330.0, 0.0, 450.0], [570.0, 0.0, 450.0], [450.0, 150.0, 450.0])
    refs, poses = [], []
    for scene in (_cube_scene(), _cube_scene(450.0, 60.0)):
        for eye in eyes:
            p = _pose(eye)
            refs.append(render_surface(scene, p, K).range_mm)
            poses.append(p)
    assert sorted(fusion_views(refs, poses, K, 0, max_views=5)) == [1, 2]
    assert sorted(fusion_views(refs, poses, K, 4, max_views=5)) == [3, 5]
    assert fusion_views(refs, poses, K, 0, max_views=1) in ([1], [2])


def test_world_from_a_range_image_without_a_plane_keeps_its_pixels():
    scene = _cube_scene()
    surf = render_surface(scene, _pose([330.0, 0.0, 450.0]), K)
    world = world_from_surface(surf, extend_plane=False, border_fraction=0.0)
    assert world.tree.n_leaves == int(surf.valid.sum())
    assert world.support_plane is None and world.lit.all()


def test_extruded_walls_merge_into_patches_along_each_object():
    """Two boxes side by side: the walls facing one way lie on both, at the same positions
    along the wall. Each wall is its own run of columns, so grid neighbours are neighbours in
    space and the hierarchy merges them into bounce patches (interleaved, every leaf stayed
    its own patch: 5× the transport time on a tabletop)."""
    xs, ys = np.meshgrid(np.arange(0.0, 60.0, 2.0), np.arange(0.0, 60.0, 2.0))
    top = [np.stack([xs.ravel(), ys.ravel() + dy, np.full(xs.size, 50.0)], axis=1)
           for dy in (0.0, 200.0)]
    points = np.concatenate(top)
    _, walls = extruded_objects(np.array([0.0, 0.0, 1.0, 0.0]), points,
                                np.full(len(points), 0.5), [], cell_mm=2.0, leaf_mm=4.0)
    for face in (f for f in walls if len(f.centre) > 1):
        gaps = np.linalg.norm(np.diff(face.centre[:, 0], axis=0), axis=1)
        # neighbouring outline cells (a few apart where a run turns a corner), never the
        # other box 200 mm away
        assert gaps.max() <= 6 * 2.0
    tree = build_tree(walls)
    patch, _ = _bounce_cut(tree.radius, tree.spread, tree.child, tree.n_leaves,
                           4.04 * 8.0 / math.sqrt(2.0), MAX_SPREAD)
    # a 32 mm patch of 2 × 4 mm leaves holds up to 128; corners and ends hold fewer
    assert np.median(np.unique(patch, return_counts=True)[1]) >= 32
