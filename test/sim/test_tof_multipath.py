"""Diffuse interreflection (multipath) with numbers: over-shoot near concave creases, none on a
lone plane, and agreement with an independent brute-force one-bounce integration.

The analytic surfaces here are range images: the world light travels through is what the image
shows (``extend_plane=False, border_fraction=0``), unless a test says otherwise."""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracles.analytic_scenes import (
    ConvexSolid,
    box,
    box_on_table_scene,
    groove_scene,
    half_space,
    plane_scene,
    raycast,
)
from scipy.ndimage import binary_dilation, binary_erosion

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.errors import InputError
from tof_mpd_ros.sim.tof import (
    SPEED_OF_LIGHT_MM_S,
    ToFConfig,
    render_from_reference,
    render_tof,
)
from tof_mpd_ros.sim.tof.reference_world import world_from_surface
from tof_mpd_ros.sim.tof.transport import indirect_phasor

K = Intrinsics.ds325().crop(180, 140)
HALF = Intrinsics.ds325().crop(90, 70)  # same pixel scale, a quarter of the pixels
MULTIPATH = ToFConfig.ideal().with_effect("multipath", enabled=True)
F_MOD = MULTIPATH.mod_freq_hz
POWER = MULTIPATH.light_power


def _image_only(surface, config=MULTIPATH, **kw):
    """Render ``surface`` with the image as the whole world (no inferred support plane)."""
    world = world_from_surface(surface, extend_plane=False, border_fraction=0.0)
    return render_tof(surface, config, np.random.default_rng(0), supersample=1, world=world,
                      **kw)


def _indirect(surface, *, bounces: int = 1, open_ratio: float = 3.0) -> np.ndarray:
    return indirect_phasor(surface, world_from_surface(surface, extend_plane=False,
                                                      border_fraction=0.0),
                           mod_freq_hz=F_MOD, light_power=POWER, bounces=bounces,
                           open_ratio=open_ratio)


@pytest.fixture(scope="module")
def groove():
    surf = raycast(groove_scene(300.0, 0.5), K)
    return surf.range_mm, _image_only(surf)


def test_groove_overshoot_positive_peaks_near_crease_and_decays(groove):
    ref, m = groove
    err = (m.range_mm - ref)[40:100]  # rows around the centre; the crease is column ~89.5
    profile = np.mean(err, axis=0)  # (180,) over-shoot across the crease
    crease = int(np.argmax(ref[70]))
    dist = np.abs(np.arange(K.width) - crease)
    assert np.all(profile[dist >= 3] > 1.0)  # every pixel off the crease over-shoots
    left = profile[:crease - 2]
    peak = int(np.argmax(left))
    assert crease - peak < 30  # the largest over-shoot sits within 30 px (~35 mm) of the crease
    # it decays away from the crease, monotonically, to under 60 % of the peak at the border
    assert np.all(np.diff(left[:peak + 1]) > 0)
    assert left[0] < 0.6 * left[peak]
    # mm-to-cm: ~5 mm for albedo 0.5 at 300 mm
    assert 2.0 < float(np.max(profile)) < 20.0
    # right at the crease the indirect light arrives with almost no extra path
    assert profile[crease] < 0.7 * float(np.max(profile))


def test_groove_overshoot_scales_with_albedo():
    ref = raycast(groove_scene(300.0, 0.5), HALF).range_mm
    one = MULTIPATH.with_effect("multipath", bounces=1)
    bright = render_from_reference(ref, HALF, albedo=0.5, config=one)
    dark = render_from_reference(ref, HALF, albedo=0.1, config=one)
    e_bright = float(np.nanmean(bright.range_mm - ref))
    e_dark = float(np.nanmean(dark.range_mm - ref))
    # indirect/direct ∝ albedo of the sender; for small ratios the range error is ∝ too
    assert e_dark / e_bright == pytest.approx(0.2, rel=0.15)


def test_lone_plane_has_no_multipath():
    ref = raycast(plane_scene(300.0, 0.5, tilt_rad=0.3), HALF).range_mm
    m = render_from_reference(ref, HALF, config=MULTIPATH)
    assert float(np.max(np.abs(m.multipath_phasor))) == 0.0
    np.testing.assert_allclose(m.range_mm, ref, atol=1e-4)


def test_box_on_table_crease():
    scene = box_on_table_scene(300.0, 100.0, 40.0, 0.5)
    surf = raycast(scene, K)
    ref = surf.range_mm
    m = render_from_reference(ref, K, config=MULTIPATH)
    err = m.range_mm - ref
    face = surf.normal[..., 0] < -0.9  # the box face x = 40 looking at the camera side
    table = surf.object_id == 0
    top = (surf.object_id == 1) & ~face
    # the face, lit at grazing incidence, is dominated by light from the table: cm over-shoot
    assert 5.0 < float(np.median(err[face])) < 50.0
    # the table in front of the face over-shoots by about a mm (two bounces: table → face →
    # table doubles what the face's own direct light gives), fading away from it
    row = err[70]
    cols = np.nonzero(table[70])[0]
    assert np.all(row[cols] > 0.05)
    assert 0.5 < float(np.max(row[cols])) < 8.0
    # it grows from the far border towards the face, then falls again right at the crease,
    # where the light from the face arrives with almost no extra path
    peak = int(np.argmax(row[cols]))
    assert row[cols[0]] < 0.8 * row[cols[peak]] and row[cols[-1]] < 0.5 * row[cols[peak]]
    # the box top sees no other surface (convex edge): nothing (its edge pixels take their
    # normals from a range gradient that straddles the edge, so they are left out)
    inner = binary_erosion(top, iterations=2) & (np.abs(np.arange(K.width) - 140) < 20)
    assert inner.sum() > 1000
    assert float(np.max(np.abs(err[inner]))) < 1e-3


def _pixel_areas(scene: list[ConvexSolid], k: Intrinsics) -> np.ndarray:
    """Surface area of each pixel from its corner-ray hits (independent of the renderer)."""
    def pts(du: float, dv: float) -> np.ndarray:
        shifted = Intrinsics(k.fx, k.fy, k.cx - du, k.cy - dv, k.width, k.height)
        return raycast(scene, shifted).points_mm()
    eu = pts(0.5, 0.0) - pts(-0.5, 0.0)
    ev = pts(0.0, 0.5) - pts(0.0, -0.5)
    return np.linalg.norm(np.cross(eu, ev), axis=-1)


def _segment_blocked(x: np.ndarray, y: np.ndarray, solids: list[ConvexSolid]) -> np.ndarray:
    """(M,) bool: the open segment x→y[j] passes through the interior of a solid."""
    d = y - x
    blocked = np.zeros(len(y), bool)
    for s in solids:
        lo = np.full(len(y), 0.02)
        hi = np.full(len(y), 0.98)
        nd = d @ s.normals.T                      # (M, K)
        room = s.offsets - x @ s.normals.T        # (K,)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = room / nd
        lo = np.maximum(lo, np.where(nd < 0, t, -np.inf).max(axis=1))
        hi = np.minimum(hi, np.where(nd > 0, t, np.inf).min(axis=1))
        outside = ((nd == 0) & (room < 0)).any(axis=1)
        blocked |= (lo < hi - 1e-9) & ~outside
    return blocked


def brute_force_indirect(scene: list[ConvexSolid], k: Intrinsics,
                         visibility: bool) -> np.ndarray:
    """Plain one-bounce integral: every pixel sends to every other pixel."""
    surf = raycast(scene, k)
    rays = k.ray_directions()
    p = surf.points_mm().reshape(-1, 3)
    n = surf.normal.reshape(-1, 3)
    r = surf.range_mm.ravel()
    rho = surf.albedo.ravel()
    area = _pixel_areas(scene, k).ravel()
    cos_in = -np.einsum("ij,ij->i", n, rays.reshape(-1, 3))
    radiance = rho / math.pi * POWER * cos_in / r ** 2  # L_y of the lit sender
    kp = 2 * math.pi * F_MOD / SPEED_OF_LIGHT_MM_S
    out = np.zeros(len(r), complex)
    for i in range(len(r)):
        d = p - p[i]
        dist = np.linalg.norm(d, axis=1)
        dist[i] = 1.0  # the pixel itself: excluded below
        cx = d @ n[i] / dist
        cy = -np.einsum("ij,ij->i", n, d) / dist
        ok = (cx > 0) & (cy > 0)
        ok[i] = False
        if visibility:
            ok[ok] &= ~_segment_blocked(p[i], p[ok], scene)
        g = np.where(ok, cx * cy * area / (dist ** 2 + area / math.pi), 0.0)
        out[i] = rho[i] * np.sum(radiance * g * np.exp(1j * kp * (r + dist + r[i])))
    return out.reshape(k.shape)


def _relative_error(fast: np.ndarray, exact: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.abs(fast - exact) / np.abs(exact)


def test_fast_transport_matches_brute_force_on_groove():
    k = Intrinsics.from_fov(40, 30, 74.0)
    scene = groove_scene(300.0, 0.5)
    exact = brute_force_indirect(scene, k, visibility=False)
    surf = raycast(scene, k)
    away = np.abs(np.arange(k.width) - k.cx) > 2  # the crease column mixes both planes
    # every leaf on its own (the tree never aggregates), then the default hierarchy
    for open_ratio, tol in ((1e6, 0.01), (3.0, 0.04)):
        fast = _indirect(surf, open_ratio=open_ratio)
        rel = _relative_error(fast, exact)[:, away]
        assert float(np.median(rel)) < tol, open_ratio
        assert float(np.percentile(rel, 95)) < 2.5 * tol, open_ratio


def test_visibility_blocks_light_like_the_brute_force():
    # a table, a tall box face (x = 50) and a cube in front of it shadowing part of the table
    k = Intrinsics.from_fov(64, 48, 74.0)
    scene = [half_space((0.0, 0.0, -1.0), (0.0, 0.0, 300.0)),
             box((50.0, -1e4, 150.0), (1e4, 1e4, 301.0)),
             box((-15.0, -25.0, 240.0), (25.0, 25.0, 301.0))]
    exact = brute_force_indirect(scene, k, visibility=True)
    blind = brute_force_indirect(scene, k, visibility=False)
    surf = raycast(scene, k)
    fast = _indirect(surf)
    shadowed = (surf.object_id == 0) & (np.abs(blind) > 1.3 * np.abs(exact))
    assert shadowed.sum() >= 100  # the cube shadows part of the table from the face

    def shadow_error(z: np.ndarray) -> float:
        return float(np.abs(z - exact)[shadowed].sum() / np.abs(exact)[shadowed].sum())

    # screen-space marching recovers most of the shadow (sub-pixel clips of the cube's
    # corners are beyond a pixel-resolution depth image); ignoring visibility does not
    assert shadow_error(fast) < 0.25
    assert shadow_error(blind) > 3 * shadow_error(fast)
    lit = (np.abs(exact) > 0) & ~shadowed
    assert float(np.median(_relative_error(fast, exact)[lit])) < 0.08


def test_hierarchy_stays_close_to_every_leaf_on_its_own():
    surf = raycast(box_on_table_scene(300.0, 60.0, 10.0, 0.5), HALF)
    for bounces in (1, 2):
        tree = _indirect(surf, bounces=bounces)
        leaves = _indirect(surf, bounces=bounces, open_ratio=1e6)
        lit = np.abs(leaves) > 1e-3 * np.abs(leaves).max()
        assert lit.sum() > 500
        # later bounces are also gathered at ~8 mm patches rather than at every leaf
        tol = 0.03 if bounces == 1 else 0.05
        assert float(np.median(_relative_error(tree, leaves)[lit])) < tol, bounces


def test_multipath_never_shortens_a_single_ray_pixel():
    # the bounce path camera → y → x is never shorter than camera → x (triangle inequality)
    for scene in (box_on_table_scene(300.0, 60.0, 10.0, 0.8), groove_scene(250.0, 0.9)):
        surf = raycast(scene, HALF)
        m = render_tof(surf, MULTIPATH, np.random.default_rng(0), supersample=1)
        assert float(np.nanmin(m.range_mm - surf.range_mm)) > -1e-4
        m = _image_only(surf)
        assert float(np.nanmin(m.range_mm - surf.range_mm)) > -1e-4


def test_an_external_transport_phasor_runs_through_the_same_camera():
    """A path tracer's per-pixel phasor (here: the simulator's own direct + indirect) through
    ``render_tof(transport=...)`` gets the same noise, readout and systematic errors."""
    surf = raycast(box_on_table_scene(300.0, 60.0, 10.0, 0.5), HALF)
    cfg = ToFConfig.nominal()
    own = render_tof(surf, cfg, np.random.default_rng(5), supersample=1)
    z = own.direct_phasor.astype(np.complex128) + own.multipath_phasor
    ext = render_tof(surf, cfg, np.random.default_rng(5), supersample=1, transport=z)
    np.testing.assert_allclose(ext.range_mm, own.range_mm, atol=1e-3)
    assert ext.multipath_phasor is None
    with pytest.raises(InputError, match="transport"):
        render_tof(surf, cfg, np.random.default_rng(5), supersample=1, transport=z[1:])


def test_a_pixel_gathers_the_indirect_light_over_its_footprint():
    """A box-top pixel whose footprint reaches over the crease onto the side face gets part of
    that face's indirect light, as the direct light is mixed; pixels away from the crease keep
    theirs (the top sees no other surface: nothing)."""
    scene = box_on_table_scene(300.0, 100.0, 40.0, 0.5)
    surf = raycast(scene, K)
    centre = MULTIPATH.with_effect("mixed_pixels", enabled=False)
    footprint = MULTIPATH.with_effect("mixed_pixels", enabled=True)
    off = np.abs(render_from_reference(surf.range_mm, K, config=centre).multipath_phasor)
    on = np.abs(render_from_reference(surf.range_mm, K, config=footprint).multipath_phasor)
    face = surf.normal[..., 0] < -0.9
    top = (surf.object_id == 1) & ~face
    crease = top & binary_dilation(face, np.ones((3, 3), bool))
    inner = binary_erosion(top, iterations=3)
    assert crease.sum() > 50 and inner.sum() > 1000
    face_level = float(np.median(on[face]))
    # at the pixel centre the crease pixels are top face: (almost) nothing arrives there
    assert float(np.median(off[crease])) < 0.02 * face_level
    # over the footprint (σ ≈ 0.42 px: a neighbour weighs ~5 %) they get that much of the face
    assert 0.02 * face_level < float(np.median(on[crease])) < 0.15 * face_level
    np.testing.assert_array_equal(on[inner], off[inner])
