"""Correct a live depth/amplitude stream: conventions, crop and validation around ``correct``.

The corrector node is a thin ROS shell over :class:`DepthStreamCorrector`: it decodes messages
into millimetre arrays and intrinsics, calls :meth:`DepthStreamCorrector.correct`, and encodes the
result. Everything here is plain numpy and testable without ROS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from ..validation import check_array, check_same_shape
from .pipeline import CorrectionModel, correct

CONVENTIONS = ("z", "radial")


@dataclass
class StreamResult:
    """Corrected output for one input pair, in the input's depth convention.

    Attributes:
        depth_mm: (h, w) float32 corrected depth in mm (z-depth or radial range, like the
            input), NaN = invalid; h, w = the crop.
        edges: (h, w) bool boundary map from G.
        confidence: (h, w) float32 in [0, 1].
        intrinsics: intrinsics of the cropped output images.
        valid_fraction: fraction of input pixels in the crop that were valid.
    """

    depth_mm: np.ndarray
    edges: np.ndarray
    confidence: np.ndarray
    intrinsics: Intrinsics
    valid_fraction: float


class DepthStreamCorrector:
    """Applies a :class:`CorrectionModel` to full camera frames.

    Args:
        model: the loaded correction model (its crop defines the processed window).
        input_convention: ``"z"`` when inputs are REP 118 z-depth, ``"radial"`` when they are
            radial ToF range; outputs follow the same convention.
        device: torch device for the networks (``"cpu"`` by default).
    """

    def __init__(self, model: CorrectionModel, *, input_convention: str = "z",
                 device: str = "cpu") -> None:
        if input_convention not in CONVENTIONS:
            raise InputError(f"input_convention must be one of {CONVENTIONS}, "
                             f"got {input_convention!r}")
        self.model = model
        self.input_convention = input_convention
        self.device = device
        self.crop_height, self.crop_width = model.shape

    def correct(self, depth_mm: np.ndarray, amplitude: np.ndarray,
                intrinsics: Intrinsics) -> StreamResult:
        """Correct one frame.

        Args:
            depth_mm: (H, W) float32 depth in mm in ``input_convention``, NaN = invalid.
            amplitude: (H, W) float32 amplitude, NaN = invalid.
            intrinsics: intrinsics of the H x W input images.

        Raises:
            InputError: shapes differ, the crop does not fit, or the crop has no valid pixel.
        """
        depth_mm = check_array("depth_mm", depth_mm, ndim=2, dtype_kind="fiu")
        amplitude = check_array("amplitude", amplitude, ndim=2, dtype_kind="fiu")
        check_same_shape(depth_mm=depth_mm, amplitude=amplitude)
        if depth_mm.shape != intrinsics.shape:
            raise InputError(f"image is {depth_mm.shape[1]}x{depth_mm.shape[0]} but CameraInfo "
                             f"says {intrinsics.width}x{intrinsics.height}")
        rows, cols = intrinsics.crop_window(self.crop_width, self.crop_height)
        crop_intrinsics = intrinsics.crop(self.crop_width, self.crop_height)
        depth = depth_mm[rows, cols].astype(np.float32)
        amp = amplitude[rows, cols].astype(np.float32)
        valid = np.isfinite(depth) & (depth > 0) & np.isfinite(amp)
        if not valid.any():
            raise InputError("no valid pixel in the processed window")
        range_mm = (crop_intrinsics.z_to_radial(depth) if self.input_convention == "z"
                    else depth)
        result = correct(self.model, range_mm, amp, device=self.device)
        out = result.range_mm
        if self.input_convention == "z":
            out = crop_intrinsics.radial_to_z(out)
        return StreamResult(out.astype(np.float32), result.edges, result.confidence,
                            crop_intrinsics, float(valid.mean()))
