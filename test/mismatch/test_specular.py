"""Specular surfaces: a point brighter from one view than another is flagged, a Lambertian
scene is not, and a recording without motion or poses flags nothing."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import ndimage

from tof_mpd_ros.mismatch.analysis import analyse
from tof_mpd_ros.mismatch.specular import (
    FALLOFF_PER_DEG,
    SPECULAR_LOG_RATIO,
    incidence_deg,
    incidence_falloff,
    reference_surfaces,
    specular_masks,
    view_dependence,
)


def _box(frame) -> np.ndarray:
    """(H, W) bool pixels of the box (its top stands well above the table)."""
    ref = frame.reference_mm
    return ref < np.nanmedian(ref) - 40.0


def test_a_lambertian_sweep_looks_alike_from_every_view(sweep):
    frames = sweep({}, n_frames=4)
    spread = view_dependence(frames)
    seen = np.concatenate([np.isfinite(s).ravel() for s in spread])
    assert seen.mean() > 0.6                      # the views overlap: most points compared
    values = np.concatenate([s[np.isfinite(s)] for s in spread])
    assert np.median(values) < 0.05               # shot noise and shading only
    flagged = np.concatenate([m.ravel() for m in specular_masks(frames)])
    assert flagged.mean() < 0.01


def test_a_surface_three_times_brighter_from_one_view_is_specular(sweep):
    frames = list(sweep({}, n_frames=4))
    box = _box(frames[2])
    assert 0.05 < box.mean() < 0.6
    frames[2] = replace(frames[2], amplitude=np.where(box, 3.0, 1.0) * frames[2].amplitude)
    masks = specular_masks(frames)
    # from the bright view the box differs from all three others by ln 3; from the others,
    # from one in three (RMS ln 3 / √3 = 0.63): both over the threshold
    assert np.log(3.0) / np.sqrt(3.0) > SPECULAR_LOG_RATIO
    for frame, mask in zip(frames, masks, strict=True):
        box = _box(frame)
        assert mask[box].mean() > 0.7
        assert mask[~box].mean() < 0.02


def test_a_surface_mostly_view_dependent_is_left_out_whole(sweep):
    """Specularity belongs to a material: a dim metal face shows the mirror image of the table
    at about the same brightness from every view, so only part of it is told apart by its
    brightness, and its rim lies in the edge band the test cannot judge. Measured on
    path-traced sweeps (session 37): the pixel test alone took 51 % of the metal pixels, the
    whole surfaces 98 %."""
    frames = list(sweep({}, n_frames=4))
    box = _box(frames[2])
    columns = np.nonzero(box.any(axis=0))[0]
    left = box & (np.arange(box.shape[1]) < columns.mean())[None, :]
    frames[2] = replace(frames[2], amplitude=np.where(left, 3.0, 1.0) * frames[2].amplitude)
    bright = np.nan_to_num(view_dependence(frames)[2], nan=0.0) > SPECULAR_LOG_RATIO
    mask = specular_masks(frames)[2]
    assert bright[box].mean() < 0.6                # the pixels' own test: about half the top
    ref = frames[2].reference_mm
    top = box & (np.abs(ref - np.median(ref[box])) < 10.0)  # not the pixels the jump mixes
    assert mask[top].mean() > 0.99                 # the whole top, its rim included
    table = ~ndimage.binary_dilation(box, iterations=3) & np.isfinite(frames[2].range_mm)
    assert mask[table].mean() < 0.005              # not the table beside it


def test_one_view_tells_a_lobe_from_a_texture(sweep):
    """From one view: a table whose brightness follows a retro-reflection lobe (cos⁸ of the
    incidence angle, a glossy finish) is specular; the same table under a texture (a fifth to
    five times as bright, in 4-pixel patches) is not, nor is the unchanged one."""
    frame = sweep({}, n_frames=2)[0]
    table = ~_box(frame) & np.isfinite(frame.reference_mm)
    theta = np.radians(incidence_deg(frame))
    assert np.nanmax(np.degrees(theta)[table]) > 30.0       # the table spans the incidences
    lobe = replace(frame, amplitude=np.where(table, np.cos(theta) ** 8, 1.0) * frame.amplitude)
    rng = np.random.default_rng(1)
    patches = np.kron(rng.uniform(np.log(0.2), np.log(5.0), (64, 64)), np.ones((4, 4)))
    texture = np.exp(patches[:frame.range_mm.shape[0], :frame.range_mm.shape[1]])
    textured = replace(frame, amplitude=np.where(table, texture, 1.0) * frame.amplitude)
    assert np.nanmedian(incidence_falloff(lobe)[table]) < -FALLOFF_PER_DEG
    for still in ([frame, frame], [textured, textured]):
        assert not any(m.any() for m in specular_masks(still))
    masks = specular_masks([lobe, lobe])
    assert masks[0][table].mean() > 0.9
    assert masks[0][_box(frame)].mean() < 0.05


def test_the_reference_surfaces_end_at_depth_edges(sweep):
    frame = sweep({}, n_frames=2)[0]
    labels = reference_surfaces(frame)
    box = _box(frame)
    top = np.bincount(labels[box & (labels > 0)]).argmax()
    assert np.mean(labels[box] == top) > 0.7       # the box's top is one surface (the rest:
    #                                                its edge band, on none) ...
    assert not np.any(labels[~box] == top)         # ... and the table is another
    assert np.all(labels[box & ndimage.binary_dilation(~box)] == 0)  # its outline on none


def test_a_brighter_frame_a_still_camera_or_no_poses_flag_nothing(sweep):
    frames = list(sweep({}, n_frames=3))
    # a whole frame twice as bright (exposure, warm-up) is no surface's doing
    brighter = [frames[0], replace(frames[1], amplitude=2.0 * frames[1].amplitude), frames[2]]
    assert not any(m.any() for m in specular_masks(brighter))
    # a still camera sees every point from one view only
    still = [frames[0], replace(frames[0], amplitude=0.5 * frames[0].amplitude), frames[0]]
    assert not any(m.any() for m in specular_masks(still))
    no_pose = [replace(f, pose=None) for f in frames]
    assert all(np.isnan(d).all() for d in view_dependence(no_pose))


def test_the_report_counts_the_specular_pixels_it_leaves_out(sweep):
    frames = list(sweep({}, n_frames=4))
    box = _box(frames[2])
    frames[2] = replace(frames[2], amplitude=np.where(box, 3.0, 1.0) * frames[2].amplitude)
    analysis = analyse(frames, max_effects=0)
    share = analysis.profile_facts["specular_share"]
    measured = sum(np.isfinite(f.range_mm).sum() for f in frames)
    boxes = sum((_box(f) & np.isfinite(f.range_mm)).sum() for f in frames)
    assert 0.7 * boxes / measured < share < boxes / measured + 0.02
    assert any("brighter from some views" in w and "like a lobe" in w and "left out" in w
               for w in analysis.profile_words)
