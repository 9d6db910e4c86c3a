"""``EFFECTS``: every named effect of the ToF simulator, in pipeline order.

The order within a stage is the order in which the render applies them.
"""

from __future__ import annotations

from types import MappingProxyType

from .effect import Effect
from .effects.amplitude_bias import AmplitudeBias
from .effects.hand_eye import HandEye
from .effects.lens_scatter import LensScatter
from .effects.mixed_pixels import MixedPixels
from .effects.multipath import Multipath
from .effects.noise import Noise
from .effects.noise_model import NoiseModel
from .effects.phase_wrapping import PhaseWrapping
from .effects.pixel_offset import PixelOffset
from .effects.subsurface import Subsurface
from .effects.temperature_drift import TemperatureDrift
from .effects.time_offset import TimeOffset
from .effects.wiggling import Wiggling

_ORDER: tuple[type[Effect], ...] = (
    HandEye, TimeOffset,                      # geometry
    MixedPixels,                              # footprint
    Multipath, Subsurface, LensScatter,       # phasor: light transport and optics
    Noise, NoiseModel,                        # phasor: sensor noise (noise_model replaces noise)
    PhaseWrapping,                            # readout
    Wiggling, AmplitudeBias, PixelOffset, TemperatureDrift,  # range: systematic errors
)

#: name -> effect instance, in pipeline order
EFFECTS: MappingProxyType[str, Effect] = MappingProxyType({cls.name: cls() for cls in _ORDER})

#: effects that the nominal simulated cell switches on
NOMINAL_EFFECTS: tuple[str, ...] = tuple(n for n, e in EFFECTS.items() if e.nominal)


def effect_names(stage: str | None = None) -> tuple[str, ...]:
    """Names of all effects (or those of one stage), in pipeline order."""
    return tuple(n for n, e in EFFECTS.items() if stage is None or e.stage == stage)
