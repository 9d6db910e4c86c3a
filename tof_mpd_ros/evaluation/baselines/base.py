"""What every baseline shares: the interface, input checking and NaN bookkeeping.

A baseline corrects one *calibrated* ToF frame (the caller applies the intrinsic calibration
first, as the paper does for every method):

* ``range_mm``: (H, W) float32 radial range in millimetres, NaN = invalid;
* ``amplitude``: (H, W) float32 amplitude in sensor units, NaN = invalid;
* result: (H, W) float32 corrected radial range in mm, NaN exactly where the input is invalid.

A pixel is *valid* when its range and amplitude are finite and > 0, the same rule as the patch
encoding of the networks (:mod:`tof_mpd_ros.correction.encoding`), so every method sees the same
pixels. Invalid pixels never contribute to a valid pixel's estimate.

Free parameters come in two kinds, both grid-searched by :func:`.grid.grid_search`:

* *apply* parameters (``param_grid``): keyword arguments of :meth:`Baseline.apply`, cheap to vary;
* *fit* parameters (``fit_param_grid``): constructor arguments of the learned methods; varying
  them means refitting on the training frames.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any, ClassVar, Protocol

import numpy as np
from scipy import ndimage

from ...errors import InputError
from ...validation import check_array, check_same_shape


class FrameLike(Protocol):
    """What the baselines read from a frame (:class:`tof_mpd_ros.frame.ToFFrame` fits).

    Attributes:
        range_mm: (H, W) float32 calibrated radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude, NaN = invalid.
        reference_mm: (H, W) float32 reference radial range in mm, NaN = missing; or None.
    """

    range_mm: np.ndarray
    amplitude: np.ndarray
    reference_mm: np.ndarray | None


class Baseline(ABC):
    """One competing method of the paper's evaluation (§V "Baseline Methods").

    Subclasses set ``name``, ``param_grid`` (apply-time grid), optionally ``fit_param_grid``
    (constructor-time grid) and ``supervised``; they store their constructor arguments in
    ``self.fit_params`` so :func:`.grid.grid_search` can rebuild them with other values.
    """

    name: ClassVar[str]
    param_grid: ClassVar[dict[str, list[Any]]]
    fit_param_grid: ClassVar[dict[str, list[Any]]] = {}
    supervised: ClassVar[bool] = False

    def __init__(self) -> None:
        self.fit_params: dict[str, Any] = {}

    def fit(self, frames: Sequence[FrameLike]) -> Baseline:
        """Learn from frames with ``reference_mm``; unsupervised methods return ``self``."""
        return self

    @abstractmethod
    def apply(self, range_mm: np.ndarray, amplitude: np.ndarray, **params: Any) -> np.ndarray:
        """Correct one frame: (H, W) float32 mm in, (H, W) float32 mm out (see module doc)."""

    @classmethod
    def apply_param_names(cls) -> tuple[str, ...]:
        """Names of the keyword parameters :meth:`apply` accepts."""
        sig = inspect.signature(cls.apply)
        return tuple(p.name for p in sig.parameters.values() if p.kind is p.KEYWORD_ONLY)

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.fit_params.items())
        return f"{type(self).__name__}({args})"


def prepare(range_mm: object, amplitude: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check one frame's inputs and return them as float32 with the validity mask.

    Args:
        range_mm: (H, W) numeric radial range in mm, NaN = invalid.
        amplitude: (H, W) numeric amplitude, NaN = invalid.

    Returns:
        ``(range_mm, amplitude, valid)``: (H, W) float32 copies with NaN wherever invalid, and
        the (H, W) bool mask of valid pixels (both finite and > 0).

    Raises:
        InputError: not 2-D, not numeric, or shapes differ.
    """
    r = check_array("range_mm", range_mm, ndim=2, dtype_kind="fiu").astype(np.float32)
    a = check_array("amplitude", amplitude, ndim=2, dtype_kind="fiu").astype(np.float32)
    check_same_shape(range_mm=r, amplitude=a)
    if min(r.shape) < 1:
        raise InputError(f"range_mm: expected a non-empty image, got shape {r.shape}")
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(r) & np.isfinite(a) & (r > 0) & (a > 0)
    r[~valid] = np.nan
    a[~valid] = np.nan
    return r, a, valid


def finish(estimate: np.ndarray, valid: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Final (H, W) float32 range in mm: NaN where invalid, ``fallback`` where the method
    produced no finite value for a valid pixel (e.g. an isolated pixel with no valid support)."""
    out = np.where(np.isfinite(estimate), estimate, fallback).astype(np.float32)
    out[~valid] = np.nan
    return out


def fill_nearest(image: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Copy of ``image`` with every invalid pixel set to its nearest valid pixel's value.

    Filters that cannot skip pixels need finite input; callers still mask the filled pixels out
    of the result (or out of the weights), so the fill value only has to be finite and plausible.

    Args:
        image: (H, W) float array, any unit.
        valid: (H, W) bool; must contain at least one True.
    """
    if valid.all():
        return image.copy()
    idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    return image[idx[0], idx[1]]


def amplitude_guide(amplitude: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Amplitude scaled to [0, 1] for use as a filter guide.

    Divided by the 99th percentile of the valid amplitudes (so one specular pixel does not
    compress the rest of the scale) and clipped to [0, 1]; invalid pixels get 0. ``sigma_color``
    of the guided filters is therefore a fraction of the frame's bright-end amplitude and does
    not depend on the sensor's amplitude unit.

    Returns:
        (H, W) float32 in [0, 1].
    """
    scale = float(np.percentile(amplitude[valid], 99.0)) if valid.any() else 1.0
    guide = np.zeros(amplitude.shape, np.float32)
    guide[valid] = np.clip(amplitude[valid] / max(scale, 1e-12), 0.0, 1.0)
    return guide
