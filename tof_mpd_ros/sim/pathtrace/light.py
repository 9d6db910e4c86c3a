"""The path tracer's light: a spot light at the camera centre, and its intensity profile in numpy.

Mitsuba 3's ``spot`` emitter (checked numerically against mitsuba 3.9.1 in
``test/sim/test_pathtrace.py``) has a radiant intensity that depends only on the angle θ between
the emission direction and its axis (here: the camera's optical axis, +z of the optical frame):

    I(θ) = I0                                   θ ≤ beam width β
    I(θ) = I0 (γ − θ) / (γ − β)                 β < θ < cutoff γ   (linear in the angle)
    I(θ) = 0                                    θ ≥ γ

so a Lambertian patch of albedo ρ at distance r lit at incidence cos θ_in reflects a radiance
``(ρ/π) I(θ) cos θ_in / r²`` back to the camera. With ``I0 = light_power`` this is the
simulator's direct return divided by π (the simulator's amplitude is π × radiance, see
``tof_mpd_ros/sim/tof/phasor.py``), i.e. inside the beam width the spot is exactly the simulator's
isotropic point source. The 180x140 crop of the DS325-like sensor reaches θ ≈ 28° in its corners
and the whole 320x240 sensor θ ≈ 43°, so with the defaults (β = 50°, γ = 60°) every visible
surface is lit at I0; the linear fall-off only dims surfaces outside the field of view, which
still send interreflected light into it. Any other transport that is compared with the path
tracer must weight the light leaving the source by :func:`spot_profile`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ..tof.config import DEFAULT_LIGHT_POWER, ToFConfig
from ..tof.world import spot_profile as world_spot_profile


@dataclass(frozen=True)
class SpotLight:
    """A spot light co-located with the camera centre, pointing along the optical axis.

    Attributes:
        cone_half_angle_deg: cutoff γ, degrees: no light beyond this angle from the axis.
        beam_width_deg: β, degrees: full intensity up to this angle, then a linear fall-off in
            the angle to 0 at the cutoff; 0 < β < γ.
        light_power: I0 in the simulator's amplitude·mm² (a ρ = 0.5 plane facing the camera at
            300 mm returns amplitude 0.5 · I0 / 300²): the rendered radiance × π × I0 is in the
            simulator's amplitude units.
    """

    cone_half_angle_deg: float = 60.0
    beam_width_deg: float = 50.0
    light_power: float = DEFAULT_LIGHT_POWER

    def __post_init__(self) -> None:
        if not 0.0 < self.beam_width_deg < self.cone_half_angle_deg <= 90.0:
            raise InputError("spot light: expected 0 < beam_width_deg < cone_half_angle_deg "
                             f"<= 90, got beam_width_deg={self.beam_width_deg}, "
                             f"cone_half_angle_deg={self.cone_half_angle_deg}")
        if not (math.isfinite(self.light_power) and self.light_power > 0.0):
            raise InputError(f"spot light: light_power must be > 0, got {self.light_power}")

    @classmethod
    def of_config(cls, config: ToFConfig) -> SpotLight:
        """The camera's light as ``config`` describes it (the ``multipath`` effect's cone and
        beam, the config's light power)."""
        p = config.params("multipath")
        return cls(cone_half_angle_deg=float(p["cutoff_deg"]),
                   beam_width_deg=float(p["beam_deg"]), light_power=config.light_power)

    def as_dict(self) -> dict[str, float]:
        """Plain-type description: the two angles (degrees) and the power (amplitude·mm²)."""
        return {"cone_half_angle_deg": float(self.cone_half_angle_deg),
                "beam_width_deg": float(self.beam_width_deg),
                "light_power": float(self.light_power)}


def spot_profile(cos_theta: np.ndarray | float, light: SpotLight | None = None) -> np.ndarray:
    """Relative radiant intensity I(θ)/I0 of the spot light (Mitsuba's ``spot`` emitter).

    Args:
        cos_theta: (...) float, cosine of the angle between the emission direction and the
            light's axis (the camera's optical axis); values are clipped to [-1, 1].
        light: the spot light (default :class:`SpotLight`).

    Returns:
        (...) float64 in [0, 1]: 1 up to the beam width, ``(γ − θ) / (γ − β)`` between the beam
        width and the cutoff (θ, β, γ in radians), 0 from the cutoff on.
    """
    spot = light if light is not None else SpotLight()
    # one falloff for both renderers: the built-in transport's
    return world_spot_profile(cos_theta, spot.cone_half_angle_deg, spot.beam_width_deg)
