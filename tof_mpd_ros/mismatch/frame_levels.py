"""Judge an effect whose correction is one range offset per frame on the frames' levels.

A warm-up drift moves every pixel of a frame by the same amount. Scored per pixel (the mean
held-out likelihood gain of :mod:`.fit`), a drift of a few millimetres over a recording is
worth little beside a camera whose per-pixel noise is 3–5 mm, and it sits below the score
that guards against the residual's structure (measured in session 9: a −11 mm drift over
6 frames scored 11 mnats/px against the 20 a later round asks). But each frame's *level* is
known to a few tenths of a millimetre from thousands of pixels, and there the drift is plain:
the held-out frames' levels step by 1–2 mm per frame, where a recording without a drift moves
0.1–0.2 mm (session 10, the blind cases of session 9). So such an effect is judged where its
signature is: its fit on the training frames must predict the held-out frames' levels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..sim.tof import ToFConfig
from .fit import Problem

#: effects whose correction is one range offset per frame, the same for every pixel
FRAME_LEVEL_EFFECTS: tuple[str, ...] = ("temperature_drift",)
#: the held-out frames' levels must gain at least this χ² (in their standard errors: ~4σ
#: of evidence)...
MIN_CHI2_GAIN = 16.0
#: ...and the effect must leave at most this share of their χ² (explain three quarters of
#: how the levels move)
MAX_CHI2_LEFT = 0.25
#: fewer held-out frames than this say nothing about a change over time
MIN_FRAMES = 2


@dataclass(frozen=True)
class FrameLevels:
    """The held-out frames' residual levels before and after a candidate (mm).

    Attributes:
        frames: held-out frame indices.
        before_mm, after_mm: per frame, the residual's level beyond the model's own level,
            under the current model and with the candidate.
        se_mm: per frame, the level's standard error.
    """

    frames: tuple[int, ...]
    before_mm: tuple[float, ...]
    after_mm: tuple[float, ...]
    se_mm: tuple[float, ...]

    @property
    def chi2_before(self) -> float:
        return levels_chi2(self.before_mm, self.se_mm)

    @property
    def chi2_after(self) -> float:
        return levels_chi2(self.after_mm, self.se_mm)

    @property
    def explained(self) -> bool:
        """Whether the candidate explains how the held-out frames' levels move."""
        if len(self.frames) < MIN_FRAMES:
            return False
        gain = self.chi2_before - self.chi2_after
        return gain >= MIN_CHI2_GAIN and self.chi2_after <= MAX_CHI2_LEFT * self.chi2_before

    def as_dict(self) -> dict[str, object]:
        return {"frames": list(self.frames),
                "before_mm": [round(x, 3) for x in self.before_mm],
                "after_mm": [round(x, 3) for x in self.after_mm],
                "se_mm": [round(x, 3) for x in self.se_mm],
                "chi2_before": round(self.chi2_before, 2),
                "chi2_after": round(self.chi2_after, 2), "explained": self.explained}


def levels_chi2(levels_mm: tuple[float, ...], se_mm: tuple[float, ...]) -> float:
    """Σ (level / standard error)² over groups of pixels (frames here, tiles in
    :mod:`.concentration`); both (G,) in mm."""
    return float(np.sum((np.array(levels_mm) / np.array(se_mm)) ** 2))


def frame_levels(problem: Problem, config: ToFConfig) -> FrameLevels | None:
    """The held-out frames' levels under the current model and under ``config`` (a fitted
    candidate); None when the split is not by frames (one frame split into tiles)."""
    if problem.split.how != "frames":
        return None
    rows = []
    for i in problem.frames_of("test"):
        before, se = problem.frame_level(i, None)
        after, _ = problem.frame_level(i, config)
        if np.isfinite(before) and np.isfinite(after) and se > 0:
            rows.append((i, before, after, se))
    if not rows:
        return None
    frames, before, after, se = zip(*rows, strict=True)
    return FrameLevels(tuple(frames), tuple(before), tuple(after), tuple(se))


__all__ = ["FRAME_LEVEL_EFFECTS", "FrameLevels", "frame_levels"]
