"""``ToFConfig``: modulation, light power and the on/off switch and parameters of every effect.

Serialises to and from plain dicts (JSON/YAML) so that fitted configs can be written by the
mismatch tool::

    cfg = ToFConfig.nominal().with_effect("lens_scatter", enabled=True, fraction=0.03)
    ToFConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from ...errors import SimulationError
from ...frame import DEFAULT_MOD_FREQ_HZ
from .registry import EFFECTS, nominal_effects

#: P in amplitude·mm²: a ρ = 0.5 plane facing the camera at 300 mm returns amplitude ≈ 556
DEFAULT_LIGHT_POWER = 1e8
#: pixels whose amplitude is below this are invalid (NaN), as a camera's confidence threshold
DEFAULT_MIN_AMPLITUDE = 5.0


@dataclass(frozen=True)
class EffectConfig:
    """Switch and parameters of one effect (parameters not given take their defaults)."""

    enabled: bool
    params: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"enabled": bool(self.enabled),
                "params": {k: list(v) if isinstance(v, tuple) else v
                           for k, v in self.params.items()}}


def _normalise_value(effect: str, name: str, value: Any) -> Any:
    default = EFFECTS[effect].spec(name).default
    if isinstance(default, tuple):
        seq = tuple(float(v) for v in (value if isinstance(value, (list, tuple)) else [value]))
        if not seq or not all(math.isfinite(v) for v in seq):
            raise SimulationError(f"{effect}.{name}: expected finite numbers, got {value!r}")
        return seq
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SimulationError(f"{effect}.{name}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise SimulationError(f"{effect}.{name}: expected a finite number, got {value!r}")
    return int(value) if isinstance(default, int) else float(value)


def _effect_config(name: str, enabled: bool, params: Mapping[str, Any]) -> EffectConfig:
    if name not in EFFECTS:
        raise SimulationError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
    merged = EFFECTS[name].defaults()
    for key, value in params.items():
        if key not in merged:
            raise SimulationError(f"effect {name!r} has no parameter {key!r}; "
                                  f"parameters: {', '.join(merged) or 'none'}")
        merged[key] = _normalise_value(name, key, value)
    return EffectConfig(bool(enabled), merged)


def _default_effects(enabled: tuple[str, ...]) -> dict[str, EffectConfig]:
    return {n: _effect_config(n, n in enabled, {}) for n in EFFECTS}


@dataclass(frozen=True)
class ToFConfig:
    """Configuration of the simulated AMCW ToF camera.

    Attributes:
        mod_freq_hz: modulation frequency in Hz (30 MHz: ambiguity range c/2f ≈ 4997 mm, so the
            150–450 mm workspace never wraps).
        light_power: P in amplitude·mm² (direct amplitude a = P ρ cosθ / r²).
        min_amplitude: pixels below this amplitude are invalid (NaN).
        effects: effect name -> :class:`EffectConfig`; after construction every effect in
            ``EFFECTS`` is present (effects left out of a given mapping are off, with default
            parameters). The default is the nominal cell.
    """

    mod_freq_hz: float = DEFAULT_MOD_FREQ_HZ
    light_power: float = DEFAULT_LIGHT_POWER
    min_amplitude: float = DEFAULT_MIN_AMPLITUDE
    effects: Mapping[str, EffectConfig] = field(
        default_factory=lambda: _default_effects(nominal_effects()))

    def __post_init__(self) -> None:
        for key in ("mod_freq_hz", "light_power"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise SimulationError(f"{key} must be a finite number > 0, got {value!r}")
        if not (math.isfinite(self.min_amplitude) and self.min_amplitude >= 0):
            raise SimulationError(f"min_amplitude must be >= 0, got {self.min_amplitude!r}")
        effects = _default_effects(())
        for name, cfg in self.effects.items():
            if not isinstance(cfg, EffectConfig):
                raise SimulationError(f"effects[{name!r}] must be an EffectConfig")
            effects[name] = _effect_config(name, cfg.enabled, cfg.params)
        object.__setattr__(self, "effects", effects)

    # -- constructors -------------------------------------------------------------------------

    @classmethod
    def nominal(cls) -> ToFConfig:
        """The nominal cell: multipath, mixed pixels, wiggling, amplitude bias, pixel offset,
        noise and phase wrapping on; every other effect off."""
        return cls()

    @classmethod
    def ideal(cls) -> ToFConfig:
        """Every effect off: each pixel reads the direct range of the ray through its centre."""
        return cls(effects=_default_effects(()))

    # -- queries and edits ----------------------------------------------------------------------

    def enabled(self, name: str) -> bool:
        """Whether effect ``name`` is on."""
        return self._get(name).enabled

    def params(self, name: str) -> dict[str, Any]:
        """A copy of effect ``name``'s parameters."""
        return dict(self._get(name).params)

    def effect_params(self, name: str) -> Any:
        """Effect ``name``'s parameters as its typed, frozen ``Params`` dataclass (what its
        ``apply`` reads), e.g. ``config.effect_params("multipath").gain``."""
        return EFFECTS[name].parse(self._get(name).params)

    def enabled_effects(self) -> tuple[str, ...]:
        """Names of the effects that are on, in pipeline order."""
        return tuple(n for n in EFFECTS if self.effects[n].enabled)

    def with_effect(self, name: str, enabled: bool | None = None, **params: Any) -> ToFConfig:
        """A copy with effect ``name`` switched (``None`` keeps its state) and ``params`` set."""
        current = self._get(name)
        effects = dict(self.effects)
        effects[name] = _effect_config(
            name, current.enabled if enabled is None else enabled, {**current.params, **params})
        return replace(self, effects=effects)

    def with_only(self, *names: str) -> ToFConfig:
        """A copy in which exactly the effects ``names`` are on (parameters kept)."""
        for n in names:
            self._get(n)
        return replace(self, effects={n: EffectConfig(n in names, c.params)
                                      for n, c in self.effects.items()})

    def _get(self, name: str) -> EffectConfig:
        try:
            return self.effects[name]
        except KeyError:
            raise SimulationError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}") from None

    # -- serialisation --------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON/YAML-safe) of every field."""
        return {"mod_freq_hz": float(self.mod_freq_hz), "light_power": float(self.light_power),
                "min_amplitude": float(self.min_amplitude),
                "effects": {n: c.to_dict() for n, c in self.effects.items()}}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ToFConfig:
        """Inverse of :meth:`to_dict`. Effects left out are off with default parameters.

        Raises:
            SimulationError: unknown keys, effects or parameters, or invalid values.
        """
        if not isinstance(data, Mapping):
            raise SimulationError(f"ToF config must be a mapping, got {type(data).__name__}")
        known = {"mod_freq_hz", "light_power", "min_amplitude", "effects"}
        unknown = set(data) - known
        if unknown:
            raise SimulationError(f"unknown ToF config keys: {', '.join(sorted(unknown))}")
        effects = {}
        for name, entry in dict(data.get("effects", {})).items():
            if not isinstance(entry, Mapping) or set(entry) - {"enabled", "params"}:
                raise SimulationError(f"effects[{name!r}] must be {{enabled, params}}")
            effects[name] = EffectConfig(bool(entry.get("enabled", False)),
                                         dict(entry.get("params", {})))
        try:
            scalars = {k: float(data.get(k, d)) for k, d in (
                ("mod_freq_hz", DEFAULT_MOD_FREQ_HZ), ("light_power", DEFAULT_LIGHT_POWER),
                ("min_amplitude", DEFAULT_MIN_AMPLITUDE))}
        except (TypeError, ValueError) as err:
            raise SimulationError(f"ToF config: {err}") from err
        return cls(**scalars, effects=effects)
