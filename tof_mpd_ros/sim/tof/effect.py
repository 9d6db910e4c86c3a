"""The interface every physical effect of the ToF simulator implements.

An effect is a named, parameterised module that can be switched on or off. It acts at one stage
of the measurement pipeline (see :mod:`.render`):

* ``"geometry"``: ``apply(surface, params, ctx) -> SurfaceImage`` changes what the camera sees
  (pose errors);
* ``"footprint"``: ``apply(samples_phasor, params, ctx) -> phasor`` turns per-sample phasors into
  per-pixel phasors;
* ``"phasor"``: ``apply(phasor, params, ctx) -> phasor`` acts on the (H, W) complex128 pixel
  phasors (light transport, optics, noise);
* ``"readout"``: ``apply(phasor, params, ctx) -> range_mm`` turns phasors into range;
* ``"range"``: ``apply(range_mm, params, ctx) -> range_mm`` adds the camera's systematic errors
  to the (H, W) float64 range in mm (``ctx.amplitude`` holds the measured amplitude).

Parameters are described by :class:`ParamSpec` so that the mismatch tool can fit them within
realistic ranges.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from .context import RenderContext

STAGES = ("geometry", "footprint", "phasor", "readout", "range")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    Attributes:
        name: keyword used in ``EffectConfig.params``.
        default: value used when the config does not give one (float, int or tuple of floats
            for per-material lists).
        low, high: realistic range (per element for tuples); a fitter should stay inside it.
        unit: unit of the value (``"mm"``, ``"px"``, ``"rad"``, ``"1"`` ...).
        doc: one line saying what it does.
        fit: False for bookkeeping parameters a fitter should not touch (seeds).
    """

    name: str
    default: Any
    low: float
    high: float
    unit: str
    doc: str
    fit: bool = True


class Effect:
    """Base class: subclasses set the class attributes and implement :meth:`apply`."""

    name: ClassVar[str]
    stage: ClassVar[str]
    #: on in the nominal simulated cell
    nominal: ClassVar[bool] = False
    summary: ClassVar[str] = ""
    params: ClassVar[tuple[ParamSpec, ...]] = ()

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """``{parameter name: default value}``."""
        return {p.name: p.default for p in cls.params}

    @classmethod
    def spec(cls, name: str) -> ParamSpec:
        """The :class:`ParamSpec` called ``name`` (KeyError if none)."""
        for p in cls.params:
            if p.name == name:
                return p
        raise KeyError(name)

    def apply(self, x: Any, params: Mapping[str, Any], ctx: RenderContext) -> Any:
        """Apply the effect at its stage (see the module docstring for ``x`` and the result)."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"<effect {self.name} ({self.stage})>"
