"""``EFFECTS``: every named effect of the ToF simulator, in pipeline order.

The order within a stage is the order in which the render applies them (:mod:`.pipeline`).
:func:`register_effect` adds an effect: the renderer, :class:`.config.ToFConfig` and the mismatch
tool's predictor then know it, with nothing else to edit.
"""

from __future__ import annotations

from types import MappingProxyType

from .effect import STAGES, Effect
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

_BUILT_IN: tuple[type[Effect], ...] = (
    HandEye, TimeOffset,                      # geometry
    MixedPixels,                              # footprint
    Multipath, Subsurface, LensScatter,       # phasor: light transport and optics
    Noise, NoiseModel,                        # phasor: sensor noise (noise_model replaces noise)
    PhaseWrapping,                            # readout
    Wiggling, AmplitudeBias, PixelOffset, TemperatureDrift,  # range: systematic errors
)

_REGISTRY: dict[str, Effect] = {cls.name: cls() for cls in _BUILT_IN}

#: name -> effect instance, in pipeline order (a read-only view: see :func:`register_effect`)
EFFECTS: MappingProxyType[str, Effect] = MappingProxyType(_REGISTRY)

#: the built-in effects that the nominal simulated cell switches on
NOMINAL_EFFECTS: tuple[str, ...] = tuple(n for n, e in EFFECTS.items() if e.nominal)


def effect_names(stage: str | None = None) -> tuple[str, ...]:
    """Names of all effects (or those of one stage), in pipeline order."""
    return tuple(n for n, e in EFFECTS.items() if stage is None or e.stage == stage)


def nominal_effects() -> tuple[str, ...]:
    """Names of the registered effects that the nominal cell switches on, in pipeline order."""
    return tuple(n for n, e in EFFECTS.items() if e.nominal)


def register_effect(cls: type[Effect], *, after: str | None = None) -> Effect:
    """Add effect ``cls`` to the registry (and so to every pipeline step list made afterwards).

    Args:
        cls: an :class:`Effect` subclass with a new ``name`` and a ``stage``.
        after: the effect of the same stage it follows; None = last of its stage.

    Returns:
        The registered instance.

    Raises:
        ValueError: a name already taken, an unknown stage, ``after`` or replaced effect.
    """
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise ValueError(f"expected an Effect subclass, got {cls!r}")
    if cls.name in _REGISTRY:
        raise ValueError(f"effect {cls.name!r} is already registered")
    if getattr(cls, "stage", None) not in STAGES:
        raise ValueError(f"effect {cls.name!r}: stage must be one of {STAGES}")
    unknown = set(cls.replaces) - set(_REGISTRY)
    if unknown:
        raise ValueError(f"effect {cls.name!r} replaces unknown effects {sorted(unknown)}")
    names = list(_REGISTRY)
    if after is None:
        rank = STAGES.index(cls.stage)
        index = sum(STAGES.index(e.stage) <= rank for e in _REGISTRY.values())
    elif after in _REGISTRY and _REGISTRY[after].stage == cls.stage:
        index = names.index(after) + 1
    else:
        raise ValueError(f"after={after!r}: not a registered {cls.stage} effect")
    effect = cls()
    items = list(_REGISTRY.items())
    items.insert(index, (cls.name, effect))
    _REGISTRY.clear()
    _REGISTRY.update(items)
    return effect


def unregister_effect(name: str) -> None:
    """Remove an effect added by :func:`register_effect` (the built-in ones stay).

    Raises:
        ValueError: a built-in or unknown effect.
    """
    if name in {cls.name for cls in _BUILT_IN} or name not in _REGISTRY:
        raise ValueError(f"{name!r} is not an added effect")
    del _REGISTRY[name]
