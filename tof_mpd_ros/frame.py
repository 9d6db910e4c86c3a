"""The ToF frame: what recordings hold, the simulator produces and the corrector consumes."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .camera import Intrinsics
from .errors import InputError
from .validation import check_array

# Default AMCW modulation frequency of the simulated DS325-like camera, in Hz.
DEFAULT_MOD_FREQ_HZ = 30e6


@dataclass
class ToFFrame:
    """One ToF capture with its optional structured-light reference and arm pose.

    Attributes:
        range_mm: (H, W) float32 radial range in millimetres, NaN = invalid.
        amplitude: (H, W) float32 amplitude (arbitrary sensor units, >= 0), NaN = invalid.
        intrinsics: pinhole intrinsics of these H x W images.
        mod_freq_hz: AMCW modulation frequency in Hz.
        reference_mm: (H, W) float32 reference radial range in mm, NaN = missing; or None.
        stamp_ns: capture time, integer nanoseconds since the epoch.
        pose: (4, 4) float64 camera-to-base transform in metres, or None.
        albedo: (H, W) float32 per-pixel albedo in [0, 1] when known (simulation), or None.
    """

    range_mm: np.ndarray
    amplitude: np.ndarray
    intrinsics: Intrinsics
    mod_freq_hz: float = DEFAULT_MOD_FREQ_HZ
    reference_mm: np.ndarray | None = None
    stamp_ns: int = 0
    pose: np.ndarray | None = None
    albedo: np.ndarray | None = None

    def __post_init__(self) -> None:
        shape = self.intrinsics.shape
        self.range_mm = check_array("range_mm", self.range_mm, ndim=2, shape=shape,
                                    dtype_kind="fiu").astype(np.float32, copy=False)
        self.amplitude = check_array("amplitude", self.amplitude, ndim=2, shape=shape,
                                     dtype_kind="fiu").astype(np.float32, copy=False)
        if self.reference_mm is not None:
            self.reference_mm = check_array("reference_mm", self.reference_mm, ndim=2,
                                            shape=shape, dtype_kind="fiu"
                                            ).astype(np.float32, copy=False)
        if self.albedo is not None:
            self.albedo = check_array("albedo", self.albedo, ndim=2, shape=shape,
                                      dtype_kind="fiu").astype(np.float32, copy=False)
        if self.pose is not None:
            self.pose = check_array("pose", self.pose, shape=(4, 4), ndim=2,
                                    dtype_kind="fiu").astype(np.float64, copy=False)
        if not (self.mod_freq_hz > 0):
            raise InputError(f"mod_freq_hz must be > 0, got {self.mod_freq_hz}")
        self.stamp_ns = int(self.stamp_ns)

    def cropped(self, width: int, height: int) -> ToFFrame:
        """The central ``width`` x ``height`` window of this frame (the window the corrector
        node processes, :meth:`Intrinsics.crop_window`): every image cropped, intrinsics of the
        window, the rest kept.

        Raises:
            InputError: the window does not fit in the frame.
        """
        rows, cols = self.intrinsics.crop_window(width, height)

        def window(image: np.ndarray | None) -> np.ndarray | None:
            return None if image is None else image[rows, cols].copy()

        return replace(self, range_mm=window(self.range_mm), amplitude=window(self.amplitude),
                       intrinsics=self.intrinsics.crop(width, height),
                       reference_mm=window(self.reference_mm), albedo=window(self.albedo))
