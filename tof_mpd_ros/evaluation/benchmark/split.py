"""The frames the baselines see (calibrated) and the train/validation split of the training
frames (whole capture sessions held out)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ...correction.fcn import FCNCorrectionModel
from ...correction.pipeline import CorrectionModel, check_frame_pair
from ...errors import InputError
from ...frame import ToFFrame


@dataclass
class CalibratedFrame:
    """What a baseline sees: the calibrated range, amplitude and the reference.

    Attributes:
        range_mm: (H, W) float32 calibrated radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude.
        reference_mm: (H, W) float32 reference in mm, NaN = missing; or None.
    """

    range_mm: np.ndarray
    amplitude: np.ndarray
    reference_mm: np.ndarray | None


def calibrate_frames(model: CorrectionModel | FCNCorrectionModel, frames: Iterable[ToFFrame]
                     ) -> list[CalibratedFrame]:
    """Apply the model's intrinsic calibration (either kind) to every frame.

    Raises:
        InputError: a frame is not the model's crop.
    """
    out = []
    for frame in frames:
        r, a = check_frame_pair(model.shape, frame.range_mm, frame.amplitude)
        out.append(CalibratedFrame(model.calibration.apply(r, a), a.astype(np.float32),
                                   frame.reference_mm))
    return out


@dataclass(frozen=True)
class TrainValSplit:
    """Indices into the training frames.

    Attributes:
        fit: frames the learned baselines are fitted on.
        val: frames the grids are searched on.
        n_groups: capture sessions found (1 = none could be told apart).
        how: ``"sessions"`` (whole sessions held out) or ``"tail"`` (the last frames).
    """

    fit: tuple[int, ...]
    val: tuple[int, ...]
    n_groups: int
    how: str

    def to_dict(self) -> dict:
        return {"fit_frames": list(self.fit), "val_frames": list(self.val),
                "n_sessions": self.n_groups, "how": self.how}


def session_groups(stamps_ns: Sequence[int], sources: Sequence[int] | None = None, *,
                   gap_s: float = 300.0) -> list[int]:
    """Session id per frame: a new session starts at a new source (recording) or where the stamp
    jumps by more than ``gap_s`` seconds (either direction) from the previous frame's."""
    groups, current = [], 0
    for i, stamp in enumerate(stamps_ns):
        if i > 0 and (abs(int(stamp) - int(stamps_ns[i - 1])) > gap_s * 1e9
                      or (sources is not None and sources[i] != sources[i - 1])):
            current += 1
        groups.append(current)
    return groups


def split_train_val(stamps_ns: Sequence[int], val_fraction: float = 0.25, *,
                    sources: Sequence[int] | None = None, gap_s: float = 300.0,
                    max_val_frames: int | None = None) -> TrainValSplit:
    """Hold out about ``val_fraction`` of the training frames for the grid search.

    With several sessions, whole sessions are held out, taken evenly across the sequence (at
    least one, never all). With one session, the last ``ceil(val_fraction * N)`` frames. At most
    ``max_val_frames`` validation frames are kept (evenly spaced); the others are not used.

    Args:
        stamps_ns: (N,) capture stamps in ns, in frame order.
        val_fraction: target share of frames in validation.
        sources: (N,) recording index per frame (a new recording starts a session).
        gap_s: session gap in seconds.
        max_val_frames: cap on validation frames.

    Raises:
        InputError: fewer than 2 frames.
    """
    n = len(stamps_ns)
    if n < 2:
        raise InputError(f"the benchmark needs at least 2 training frames (fit + validation), "
                         f"got {n}")
    groups = np.asarray(session_groups(stamps_ns, sources, gap_s=gap_s))
    n_groups = int(groups.max()) + 1
    if n_groups >= 2:
        n_val_groups = int(np.clip(round(val_fraction * n_groups), 1, n_groups - 1))
        # Evenly spaced sessions, the last one always included.
        chosen = [(i + 1) * n_groups // n_val_groups - 1 for i in range(n_val_groups)]
        is_val = np.isin(groups, chosen)
        how = "sessions"
    else:
        n_val = int(np.clip(np.ceil(val_fraction * n), 1, n - 1))
        is_val = np.arange(n) >= n - n_val
        how = "tail"
    val = np.flatnonzero(is_val)
    if max_val_frames is not None and val.size > max_val_frames:
        val = val[np.round(np.linspace(0, val.size - 1, max_val_frames)).astype(int)]
    return TrainValSplit(tuple(np.flatnonzero(~is_val).tolist()), tuple(val.tolist()),
                         n_groups, how)

