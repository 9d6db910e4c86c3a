"""Judge a spatially concentrated effect where its correction is large.

A lens's halo, subsurface scattering, a blur at depth edges and a hand–eye misregistration
change few pixels much and most pixels little. Scored per pixel over the whole image (the mean
held-out likelihood gain of :mod:`.fit`), such an effect is diluted by the pixels it leaves
alone, and its score overlaps what a camera's own misspecification gives a spurious fit on a
control (measured in session 9: 5–17 mnats/px for the missed effects, 11–31 for the controls'
best fits). What separates them is *where* the fit acts. Where the true effect's correction is
large, it is most of the residual, and the fit trained on other frames predicts it. A
spurious fit bends a correction of the wrong shape towards a diffuse misfit, and where that
correction is large it explains only part of the residual.

So the held-out pixels where the fitted correction is large are cut into groups: per frame,
per tile of ``TILE_PX``, and per sign of the correction (a blur at a depth edge pulls one
side up and the other down; one tile mean would cancel them). Each group's residual level is
measured before and after the candidate, with its standard error, as :mod:`.frame_levels`
does for whole frames. The candidate explains the residual there when it gains a χ² of at
least ``MIN_CHI2_GAIN`` and leaves at most ``MAX_CHI2_LEFT`` of it.

This alone does not separate an effect from a control's misfit (session 12: on the controls of
session 11 a halo, a blur or a misregistration fitted to the camera's or the path tracer's
unmodelled residual left 0.1–0.4 of the groups' χ², as the true effects did). When several
concentrated corrections explain the residual where they act, it is a misfit they all bend
to, not one effect's signature; so the analysis also asks that no rival explains its own
region (``RIVAL_LEFT``, :meth:`.analysis._Search._by_concentration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..sim.tof import ToFConfig
from .fit import Problem
from .frame_levels import levels_chi2
from .likelihood import CORRELATION_PX, best_shift, total_sigma

#: effects that act on few pixels much (edges, dim pixels beside bright ones, a misregistered
#: object's outline): judged where their correction is large
CONCENTRATED_EFFECTS: tuple[str, ...] = ("lens_scatter", "subsurface", "mixed_pixels",
                                         "hand_eye")
#: effects of the whole scene whose correction still has a place of its own: interreflection
#: is largest at concave corners and where objects meet the table. Named as physics, a fit
#: of one must explain the residual there as a concentrated effect does (``MAX_CHI2_LEFT``):
#: measured on already-scored blind cases (docs/mismatch.md, session 28), true changes of
#: the multipath gain left 0.02-0.21 of the groups' chi2, gains fitted to path-traced metal
#: and glossy parts 0.49-1.08 (one extra name passed at 0.25)
SIGNATURE_EFFECTS: tuple[str, ...] = ("multipath",)
#: the correction is "large" on held-out pixels where |correction| is at least this share of
#: its 95th percentile (the percentile, not the maximum: a few edge pixels must not set it)
LARGE_SHARE = 0.5
#: ...and at least this many mm: below it the correction is within any camera's calibration
MIN_CORRECTION_MM = 0.5
#: side of the square tiles that group the large-correction pixels of a frame (px)
TILE_PX = 16
#: a group needs this many pixels (one effective sample is CORRELATION_PX pixels)
MIN_GROUP_PX = 32
#: the groups' χ² must gain at least this much (about 4σ of evidence, as for the frames'
#: levels)...
MIN_CHI2_GAIN = 16.0
#: ...and the candidate must leave at most this share of the groups' χ²: where it acts, it is
#: most of what the model misses
MAX_CHI2_LEFT = 0.3
#: another concentrated candidate that gains as much and leaves at most this share of its
#: own groups' χ² is a rival: the residual is then one any of several corrections of the
#: same kind bends to (measured on the controls of session 11: a halo, a blur and a
#: misregistration each leaving 0.1–0.4), not the signature of one of them
RIVAL_LEFT = 0.5
#: fewer groups than this say nothing about where a correction acts
MIN_GROUPS = 3


@dataclass(frozen=True)
class GroupLevels:
    """The residual levels of the held-out pixel groups where a candidate's correction is
    large, before and after it (mm).

    Attributes:
        before_mm, after_mm: per group, the residual's level under the current model and with
            the candidate (each judged at its own level, :meth:`.fit.Problem.level`).
        se_mm: per group, the level's standard error.
        correction_mm: per group, the mean correction the candidate predicts.
        pixels: held-out pixels where the correction is large (all groups').
    """

    before_mm: tuple[float, ...]
    after_mm: tuple[float, ...]
    se_mm: tuple[float, ...]
    correction_mm: tuple[float, ...]
    pixels: int

    @property
    def chi2_before(self) -> float:
        return levels_chi2(self.before_mm, self.se_mm)

    @property
    def chi2_after(self) -> float:
        return levels_chi2(self.after_mm, self.se_mm)

    @property
    def share_left(self) -> float:
        """Share of the groups' χ² the candidate leaves (1 = explains nothing)."""
        return self.chi2_after / self.chi2_before if self.chi2_before > 0 else 1.0

    @property
    def explained(self) -> bool:
        """Whether the candidate explains the residual where its correction is large."""
        return self._explains(MAX_CHI2_LEFT)

    @property
    def rival(self) -> bool:
        """Whether the candidate explains that residual well enough to stand beside another
        (see ``RIVAL_LEFT``)."""
        return self._explains(RIVAL_LEFT)

    def _explains(self, max_left: float) -> bool:
        if len(self.se_mm) < MIN_GROUPS:
            return False
        return (self.chi2_before - self.chi2_after >= MIN_CHI2_GAIN
                and self.share_left <= max_left)

    def as_dict(self) -> dict[str, object]:
        return {"groups": len(self.se_mm), "pixels": self.pixels,
                "chi2_before": round(self.chi2_before, 2),
                "chi2_after": round(self.chi2_after, 2),
                "share_left": round(self.share_left, 3),
                "mean_abs_correction_mm": round(float(np.mean(np.abs(self.correction_mm))), 3),
                "explained": self.explained, "rival": self.rival}


def large_cut(correction_mm: np.ndarray, share: float = LARGE_SHARE) -> float:
    """The |correction| (mm) from which a correction is large: ``share`` of the 95th
    percentile of ``correction_mm`` ((N,) float64 mm, finite), at least
    ``MIN_CORRECTION_MM``."""
    if correction_mm.size == 0:
        return float("inf")
    return max(share * float(np.percentile(np.abs(correction_mm), 95.0)), MIN_CORRECTION_MM)


def group_ids(shape: tuple[int, int], correction_mm: np.ndarray) -> np.ndarray:
    """(H, W) int64 group of each pixel of a frame: its tile and the sign of the correction
    ((H, W) float64 mm)."""
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    tiles_across = -(-shape[1] // TILE_PX)
    tile = (v // TILE_PX) * tiles_across + (u // TILE_PX)
    return 2 * tile + (correction_mm > 0)


def group_levels(problem: Problem, config: ToFConfig,
                 share: float = LARGE_SHARE) -> GroupLevels | None:
    """The held-out pixel groups' levels where ``config`` (a fitted candidate) changes the
    current model's prediction most (``share``: see :func:`large_cut`); None without held-out
    frames or large corrections."""
    masks = problem.masks("test")
    frames = problem.frames_of("test")
    corrections = []
    for i in frames:
        before = problem.model_range(i, None)
        after = problem.model_range(i, config)
        corrections.append(np.where(masks[i], after - before, np.nan))
    if not corrections:
        return None
    cut = large_cut(np.concatenate([c[np.isfinite(c)] for c in corrections]), share)
    rows: list[tuple[float, float, float, float]] = []
    pixels = 0
    for i, c in zip(frames, corrections, strict=True):
        large = np.isfinite(c) & (np.abs(c) >= cut)
        pixels += int(large.sum())
        rows += _frame_groups(problem, i, config, c, large)
    if not rows:
        return None
    before, after, se, corr = zip(*rows, strict=True)
    return GroupLevels(before, after, se, corr, pixels)


def _frame_groups(problem: Problem, i: int, config: ToFConfig, correction: np.ndarray,
                  large: np.ndarray) -> list[tuple[float, float, float, float]]:
    """Per group of frame ``i``'s ``large`` pixels ((H, W) bool): (level before, level after,
    standard error, mean correction), in mm."""
    before = problem.predictors[i].predict(None)
    r_before = problem.residual(i, None)
    r_after = problem.residual(i, config)
    sigma = total_sigma(before.noise_mm, problem.reference_noise_mm)
    ids = group_ids(large.shape, correction)
    rows = []
    for g in np.unique(ids[large]):
        m = large & (ids == g) & np.isfinite(r_before) & np.isfinite(r_after)
        n = int(m.sum())
        if n < MIN_GROUP_PX:
            continue
        rb = r_before[m]
        spread = 1.4826 * float(np.median(np.abs(rb - np.median(rb))))
        se = spread / float(np.sqrt(max(n / CORRELATION_PX, 1.0)))
        if se <= 0:
            continue
        rows.append((best_shift(rb, sigma[m]), best_shift(r_after[m], sigma[m]), se,
                     float(np.mean(correction[m]))))
    return rows


__all__ = ["CONCENTRATED_EFFECTS", "SIGNATURE_EFFECTS", "GroupLevels", "group_ids", "group_levels",
           "large_cut"]
