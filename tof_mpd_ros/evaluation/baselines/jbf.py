"""JBF: amplitude-guided joint bilateral filter of the range image.

R̂(p) = Σ_q s(p,q) g(p,q) v(q) R(q) / Σ_q s(p,q) g(p,q) v(q), with a Gaussian spatial weight s
(``sigma_space``, pixels), a Gaussian range weight g on the amplitude *guide* (``sigma_color``,
same unit as the guide) and the validity v ∈ {0, 1}.

The guide is the float32 amplitude scaled to [0, 1] (:func:`.base.amplitude_guide`: divided by
the frame's 99th-percentile amplitude), so ``sigma_color`` is a fraction of the bright-end
amplitude. Float rather than 8-bit keeps dark pixels apart: ToF amplitude falls with the square of
distance, so much of a frame sits in the lowest few 8-bit levels.

NaN handling is exact, not a fill: the joint bilateral weights depend only on the guide, so the
filter is linear in its source and filtering ``v·R`` and ``v`` in one 3-channel call and
dividing gives the normalised-convolution result above. Invalid pixels get no weight.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import cv2
import numpy as np

from ...errors import InputError
from .base import Baseline, amplitude_guide, finish, prepare


def joint_bilateral(
    range_mm: np.ndarray,
    amplitude: np.ndarray,
    *,
    sigma_space: float = 2.0,
    sigma_color: float = 0.1,
    diameter: int = 0,
) -> np.ndarray:
    """Amplitude-guided joint bilateral filter.

    Args:
        range_mm: (H, W) float32 calibrated radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude, NaN = invalid.
        sigma_space: spatial Gaussian sigma in pixels (> 0).
        sigma_color: guide Gaussian sigma, fraction of the 99th-percentile amplitude (> 0).
        diameter: window side in pixels; 0 = 2·ceil(2·sigma_space) + 1.

    Returns:
        (H, W) float32 filtered range in mm, NaN where the input is invalid.

    Raises:
        InputError: bad shapes or non-positive sigmas.
    """
    if not (sigma_space > 0 and sigma_color > 0 and diameter >= 0):
        raise InputError(f"JBF needs sigma_space > 0, sigma_color > 0, diameter >= 0, got "
                         f"{sigma_space}, {sigma_color}, {diameter}")
    r, a, valid = prepare(range_mm, amplitude)
    if not valid.any():
        return r
    d = int(diameter) or 2 * math.ceil(2.0 * sigma_space) + 1
    guide = amplitude_guide(a, valid)
    # Subtract the mean so float32 sums keep sub-micrometre resolution.
    offset = float(np.mean(r[valid]))
    v = valid.astype(np.float32)
    src = np.dstack([np.where(valid, r - offset, 0.0).astype(np.float32), v, v])
    out = cv2.ximgproc.jointBilateralFilter(guide, src, d, float(sigma_color), float(sigma_space),
                                            borderType=cv2.BORDER_REFLECT)
    with np.errstate(invalid="ignore", divide="ignore"):
        est = out[..., 0] / out[..., 1] + offset
    est[out[..., 1] <= 1e-6] = np.nan
    return finish(est, valid, r)


class JBF(Baseline):
    """Registry wrapper of :func:`joint_bilateral` (unsupervised; ``fit`` is a no-op)."""

    name: ClassVar[str] = "JBF"
    param_grid: ClassVar[dict[str, list[Any]]] = {
        "sigma_space": [1.0, 2.0, 3.0, 5.0],
        "sigma_color": [0.02, 0.05, 0.1, 0.2, 0.5],
    }

    def apply(self, range_mm: np.ndarray, amplitude: np.ndarray, *, sigma_space: float = 2.0,
              sigma_color: float = 0.1, diameter: int = 0) -> np.ndarray:
        """See :func:`joint_bilateral`."""
        return joint_bilateral(range_mm, amplitude, sigma_space=sigma_space,
                               sigma_color=sigma_color, diameter=diameter)
