"""The simulator's multipath against the path tracer (Mitsuba 3 + mitransient golden frames).

The golden frames (``test/sim/data/golden/``, made by ``benchmarks/render_golden_frames.py``)
hold converged path-traced ranges of the cell's own scenes; no Mitsuba is needed here. The
comparison is on the multipath field, the 5×5 median of range − truth, over every lit pixel:

* the cell's production path (``SimCell.capture``: the scene's world, three bounces) within
  1.5 mm RMSE and correlation ≥ 0.9 of the all-bounce render;
* its one-bounce variant against the exactly-one-bounce render (the kernel itself);
* the prediction from the reference image alone (no scene description: the support plane is
  inferred and extended, objects extruded down to it) within 2.0 mm RMSE and correlation
  ≥ 0.8.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from tof_mpd_ros.sim.cell import CameraModel, SimCell
from tof_mpd_ros.sim.pathtrace.golden import compare_fields, load_golden, multipath_field
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.tof import ToFConfig, render_from_reference

GOLDEN_DIR = Path(__file__).parent / "data" / "golden"
GOLDEN = sorted(GOLDEN_DIR.glob("*.npz"))


def _config(golden, bounces: int | None = None) -> ToFConfig:
    """Pure light transport as the path tracer renders it: multipath (the cell's default
    bounces unless given) and the pixel footprint, no noise or systematic errors, the golden
    frame's light and modulation frequency."""
    extra = {} if bounces is None else {"bounces": bounces}
    cfg = ToFConfig.ideal().with_effect(
        "multipath", enabled=True, cutoff_deg=golden.light.cone_half_angle_deg,
        beam_deg=golden.light.beam_width_deg, **extra).with_effect("mixed_pixels", enabled=True)
    return ToFConfig.from_dict({**cfg.to_dict(), "mod_freq_hz": golden.mod_freq_hz,
                                "light_power": golden.light.light_power})


@lru_cache(maxsize=64)
def _captured(name: str, bounces: int | None) -> np.ndarray:
    """The cell's capture of a golden scene (cached: several tests compare the same one)."""
    golden = load_golden(GOLDEN_DIR / f"{name}.npz")
    cell = SimCell(camera=CameraModel(), tof=_config(golden, bounces))
    assert cell.camera.intrinsics == golden.intrinsics
    frame = cell.capture(golden.scene, golden.camera_to_base_mm, np.random.default_rng(0),
                         with_reference=False)
    return frame.range_mm


def _capture(golden, bounces: int | None = None) -> np.ndarray:
    return _captured(golden.name, bounces)


def test_there_are_golden_frames():
    assert len(GOLDEN) >= 8


@pytest.fixture(scope="module", params=GOLDEN, ids=[p.stem for p in GOLDEN])
def golden(request):
    return load_golden(request.param)


def test_cell_matches_the_path_tracer(golden):
    ours = multipath_field(_capture(golden), golden.true_range_mm)
    ref = multipath_field(golden.range_all_mm, golden.true_range_mm)
    c = compare_fields(ours, ref)
    assert c.n_pixels > 0.8 * golden.true_range_mm.size
    assert c.rmse_mm <= 1.5, c
    assert c.correlation >= 0.9, c


def test_one_bounce_kernel_matches_the_one_bounce_render(golden):
    ours = multipath_field(_capture(golden, 1), golden.true_range_mm)
    ref = multipath_field(golden.range_one_bounce_mm, golden.true_range_mm)
    c = compare_fields(ours, ref)
    assert c.rmse_mm <= 1.5, c
    assert c.correlation >= 0.9, c


def test_prediction_from_the_reference_alone(golden):
    """The crop's true range as the reference, its albedo image (the mismatch tool infers
    albedo from the measured amplitude) and the camera's pose (the robot's: it says which way
    is up), nothing else about the scene."""
    albedo = render_surface(golden.scene, golden.camera_to_base_mm, golden.intrinsics).albedo
    m = render_from_reference(golden.true_range_mm, golden.intrinsics, albedo, _config(golden),
                              camera_to_world_mm=golden.camera_to_base_mm)
    c = compare_fields(multipath_field(m.range_mm, golden.true_range_mm),
                       multipath_field(golden.range_all_mm, golden.true_range_mm))
    assert c.rmse_mm <= 2.0, c
    assert c.correlation >= 0.8, c


def test_one_bounce_is_not_enough():
    """On the scenes with clear multipath, one bounce alone is further from the all-bounce
    render than two, and two further than the default three."""
    checked = 0
    for path in GOLDEN:
        g = load_golden(path)
        ref = multipath_field(g.range_all_mm, g.true_range_mm)
        if np.nanpercentile(np.abs(ref), 90) < 1.0:
            continue
        rmse = [compare_fields(multipath_field(_capture(g, b), g.true_range_mm),
                               ref).rmse_mm for b in (1, 2, None)]
        assert rmse[2] <= rmse[1] < rmse[0], (g.name, rmse)
        checked += 1
    assert checked >= 4
