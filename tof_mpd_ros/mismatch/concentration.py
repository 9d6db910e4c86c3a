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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..sim.tof import ToFConfig
from .fit import Problem
from .likelihood import CORRELATION_PX, best_shift, total_sigma

#: effects that act on few pixels much (edges, dim pixels beside bright ones, a misregistered
#: object's outline): judged where their correction is large
CONCENTRATED_EFFECTS: tuple[str, ...] = ("lens_scatter", "subsurface", "mixed_pixels",
                                         "hand_eye")
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
#: the scale (px, Gaussian σ) above which a misfit is "diffuse": the signature test compares
#: what the correction and the residual have at finer scales
SMOOTH_PX = 6.0


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
        z2_before, z2_after: over those pixels, the mean squared residual in units of the
            model's σ (clipped at 6σ) before and after the candidate: per pixel, not averaged
            over a group, so a correction that varies within a group (across an edge) counts.
    """

    before_mm: tuple[float, ...]
    after_mm: tuple[float, ...]
    se_mm: tuple[float, ...]
    correction_mm: tuple[float, ...]
    pixels: int
    z2_before: float = float("nan")
    z2_after: float = float("nan")
    fine_slope: float = float("nan")
    fine_se: float = float("nan")

    @property
    def chi2_before(self) -> float:
        return float(np.sum((np.array(self.before_mm) / np.array(self.se_mm)) ** 2))

    @property
    def chi2_after(self) -> float:
        return float(np.sum((np.array(self.after_mm) / np.array(self.se_mm)) ** 2))

    @property
    def share_left(self) -> float:
        """Share of the groups' χ² the candidate leaves (1 = explains nothing)."""
        return self.chi2_after / self.chi2_before if self.chi2_before > 0 else 1.0

    @property
    def excess_left(self) -> float:
        """Share of the pixels' excess over the noise (mean z² − 1) the candidate leaves."""
        excess = self.z2_before - 1.0
        return (self.z2_after - 1.0) / excess if excess > 0 else 1.0

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
                "z2_before": round(self.z2_before, 3), "z2_after": round(self.z2_after, 3),
                "excess_left": round(self.excess_left, 3),
                "fine_slope": round(self.fine_slope, 3), "fine_se": round(self.fine_se, 3),
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
    shift_before, shift_after = problem.level(None), problem.level(config)
    masks = problem.masks("test")
    frames = problem.frames_of("test")
    corrections = []
    for i in frames:
        before = problem.predictors[i].predict(None).range_mm + shift_before
        after = problem.predictors[i].predict(config).range_mm + shift_after
        corrections.append(np.where(masks[i], after - before, np.nan))
    if not corrections:
        return None
    cut = large_cut(np.concatenate([c[np.isfinite(c)] for c in corrections]), share)
    rows: list[tuple[float, float, float, float]] = []
    z2: list[np.ndarray] = []
    fine: list[np.ndarray] = []
    for i, c in zip(frames, corrections, strict=True):
        large = np.isfinite(c) & (np.abs(c) >= cut)
        rows += _frame_groups(problem, i, config, c, large, (shift_before, shift_after))
        z2.append(_pixel_z2(problem, i, config, large, (shift_before, shift_after)))
        r_before = problem.real_mm[i] - problem.predictors[i].predict(None).range_mm \
            - shift_before
        fine.append(_fine(np.where(masks[i], r_before, np.nan), c, large))
    if not rows:
        return None
    before, after, se, corr = zip(*rows, strict=True)
    z2_all = np.concatenate(z2, axis=0)
    return GroupLevels(before, after, se, corr, int(z2_all.shape[0]),
                       *map(float, np.mean(z2_all, axis=0)),
                       *fine_slope(np.concatenate(fine, axis=0)))


def _smooth(x: np.ndarray) -> np.ndarray:
    """(H, W) float64: ``x`` ((H, W) float64, NaN = missing) blurred by a Gaussian of
    ``SMOOTH_PX``, normalised over the pixels present."""
    ok = np.isfinite(x)
    num = ndimage.gaussian_filter(np.where(ok, x, 0.0), SMOOTH_PX, mode="nearest")
    den = ndimage.gaussian_filter(ok.astype(np.float64), SMOOTH_PX, mode="nearest")
    return num / np.maximum(den, 1e-6)


def _fine(residual: np.ndarray, correction: np.ndarray, large: np.ndarray) -> np.ndarray:
    """(N, 2) float64 mm: on the ``large`` pixels ((H, W) bool), the residual and the
    correction ((H, W) float64 mm, NaN = not usable) less their own smooth trend
    (:func:`_smooth`): what a diffuse misfit does not have."""
    ok = np.isfinite(residual) & np.isfinite(correction)
    r = np.where(ok, residual, np.nan)
    c = np.where(ok, correction, np.nan)
    out = np.stack([r - _smooth(r), c - _smooth(c)], axis=-1)[large & ok]
    return out[np.all(np.isfinite(out), axis=1)]


def fine_slope(pairs: np.ndarray) -> tuple[float, float]:
    """The least-squares slope of the fine residual on the fine correction ((N, 2) float64 mm,
    :func:`_fine`) and its standard error (the robust spread of what is left, pixels
    correlated over ``CORRELATION_PX``). A slope near 1 many errors from 0: the correction's
    fine structure is in the held-out residual at the predicted size."""
    if pairs.shape[0] < MIN_GROUP_PX:
        return float("nan"), float("nan")
    r, c = pairs[:, 0], pairs[:, 1]
    cc = float(np.sum(c * c))
    if cc <= 0:
        return float("nan"), float("nan")
    slope = float(np.sum(c * np.clip(r, -6 * np.std(r), 6 * np.std(r)))) / cc
    left = r - slope * c
    spread = 1.4826 * float(np.median(np.abs(left - np.median(left))))
    return slope, spread * float(np.sqrt(CORRELATION_PX / cc))


def _pixel_z2(problem: Problem, i: int, config: ToFConfig, large: np.ndarray,
              shifts: tuple[float, float]) -> np.ndarray:
    """(N, 2) float64 squared residuals before and after ``config`` in units of the current
    model's σ (clipped at 6σ: flying pixels must not decide) on frame ``i``'s ``large``
    pixels where both are predicted."""
    before = problem.predictors[i].predict(None)
    after = problem.predictors[i].predict(config)
    sigma = total_sigma(before.noise_mm, problem.reference_noise_mm)
    z = np.stack([(problem.real_mm[i] - before.range_mm - shifts[0]) / sigma,
                  (problem.real_mm[i] - after.range_mm - shifts[1]) / sigma], axis=-1)[large]
    z = z[np.all(np.isfinite(z), axis=1)]
    return np.clip(z, -6.0, 6.0) ** 2


def _frame_groups(problem: Problem, i: int, config: ToFConfig, correction: np.ndarray,
                  large: np.ndarray, shifts: tuple[float, float]
                  ) -> list[tuple[float, float, float, float]]:
    """Per group of frame ``i``'s ``large`` pixels ((H, W) bool): (level before, level after,
    standard error, mean correction), in mm."""
    before = problem.predictors[i].predict(None)
    after = problem.predictors[i].predict(config)
    r_before = problem.real_mm[i] - before.range_mm - shifts[0]
    r_after = problem.real_mm[i] - after.range_mm - shifts[1]
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


__all__ = ["CONCENTRATED_EFFECTS", "GroupLevels", "group_ids", "group_levels", "large_cut"]
