"""What an effect may read while one frame renders."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ...camera import Intrinsics
from ..surface import SurfaceImage

if TYPE_CHECKING:
    from .effects.noise import NoiseParams
    from .world import WorldModel


@dataclass(frozen=True)
class CameraMotion:
    """Instantaneous camera motion during a frame, in the camera optical frame.

    Attributes:
        linear_mm_s: (3,) float64 velocity of the optical centre in mm/s.
        angular_rad_s: (3,) float64 angular velocity in rad/s.
    """

    linear_mm_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass
class RenderContext:
    """Per-frame state shared by the effects.

    Attributes:
        intrinsics: intrinsics of the output H x W pixel grid.
        surface: pixel-resolution surface (one sample per pixel, after geometry effects); its
            points, normals and albedo are the scene for light transport.
        samples: the supersampled surface (``supersample`` samples per pixel and axis) the
            footprint is integrated over; equal to ``surface`` when ``supersample == 1``.
        supersample: samples per pixel and axis (1 when rendering from a reference).
        mod_freq_hz: modulation frequency in Hz.
        light_power: P in amplitude·mm².
        rng: random generator for noise.
        frame_index: index of the frame in its sequence (temperature drift).
        motion: camera motion during the frame (time offset), or None when at rest.
        true_range_mm: (H, W) float64 range of the pixel-centre surface, mm, NaN = no hit.
        amplitude: (H, W) float64 measured amplitude, set before the ``range`` stage.
        noise_params: parameters of the ``noise`` effect (also read by ``noise_model``), or
            None (its defaults).
        multipath_phasor: (H, W) complex128 indirect phasor once ``multipath`` has run.
        receivers: (H, W) bool pixels the caller keeps, or None (all): ``multipath`` computes
            the indirect light only there (the others still send light). Set only when no later
            effect mixes neighbouring pixels, so the kept pixels are unchanged by it.
        world: the surfaces light travels through (:class:`.world.WorldModel`), or None:
            ``multipath`` then builds one from ``surface`` alone.
        camera_shift: (4, 4) float64 true camera → assumed camera frame (mm), composed by the
            geometry effects that move the camera (identity otherwise).
        footprint_sigma_px: σ in pixels by which light computed at the pixel centres (the
            indirect light) is mixed over each pixel's footprint; 0 with ``mixed_pixels`` off.
    """

    intrinsics: Intrinsics
    surface: SurfaceImage
    samples: SurfaceImage
    supersample: int
    mod_freq_hz: float
    light_power: float
    rng: np.random.Generator
    frame_index: int = 0
    motion: CameraMotion | None = None
    true_range_mm: np.ndarray | None = None
    amplitude: np.ndarray | None = None
    noise_params: NoiseParams | None = None
    multipath_phasor: np.ndarray | None = None
    receivers: np.ndarray | None = None
    world: WorldModel | None = None
    camera_shift: np.ndarray = field(default_factory=lambda: np.eye(4))
    footprint_sigma_px: float = 0.0
