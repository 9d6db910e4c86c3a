"""The interface every physical effect of the ToF simulator implements.

An effect is a named, parameterised module that can be switched on or off. It acts at one stage
of the measurement pipeline (:mod:`.pipeline` holds the order of all steps):

* ``"geometry"``: ``apply(surface, params, ctx) -> SurfaceImage`` changes what the camera sees
  (pose errors; :class:`CameraMoveEffect` for those that move the camera);
* ``"footprint"``: ``apply(samples_phasor, params, ctx) -> phasor`` turns per-sample phasors into
  per-pixel phasors;
* ``"phasor"``: ``apply(phasor, params, ctx) -> phasor`` acts on the (H, W) complex128 pixel
  phasors (light transport, optics, noise);
* ``"readout"``: ``apply(phasor, params, ctx) -> range_mm`` turns phasors into range;
* ``"range"``: ``apply(range_mm, params, ctx) -> range_mm`` adds the camera's systematic errors
  to the (H, W) float64 range in mm (``ctx.amplitude`` holds the measured amplitude).

An effect switched off still has its step: :meth:`Effect.bypass` (the identity unless the effect
says what its stage does without it). Its parameters are a frozen dataclass (``Params``) whose
fields are declared with :func:`param`, which also gives each its realistic range
(:class:`ParamSpec`) so that the mismatch tool can fit them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ...pose import rotvec_to_matrix
from .warp import move_camera

if TYPE_CHECKING:
    from ..surface import SurfaceImage
    from .context import RenderContext

#: the stages an effect can act at, in pipeline order
STAGES = ("geometry", "footprint", "phasor", "readout", "range")

#: key of a parameter field's metadata holding (low, high, unit, doc, fit)
_SPEC_KEY = "tof_mpd_ros.param_spec"


def param(default: Any, low: float, high: float, unit: str, doc: str, *,
          fit: bool = True) -> Any:
    """A field of an effect's ``Params`` dataclass together with its :class:`ParamSpec`.

    Args:
        default: value used when a config does not give one (float, int, or a tuple of floats
            for per-material lists).
        low, high: realistic range (per element for tuples).
        unit: unit of the value; doc: one line saying what it does.
        fit: False for bookkeeping parameters a fitter should not touch (seeds).
    """
    return field(default=default, metadata={_SPEC_KEY: (low, high, unit, doc, fit)})


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    Attributes:
        name: keyword used in ``EffectConfig.params`` (the field of the effect's ``Params``).
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


def param_specs(params_type: type) -> tuple[ParamSpec, ...]:
    """The :class:`ParamSpec` of every field of a ``Params`` dataclass, in field order."""
    specs = []
    for f in fields(params_type):
        if _SPEC_KEY not in f.metadata:
            raise TypeError(f"{params_type.__name__}.{f.name}: declare it with param(...)")
        low, high, unit, doc, fit = f.metadata[_SPEC_KEY]
        specs.append(ParamSpec(f.name, f.default, low, high, unit, doc, fit))
    return tuple(specs)


@dataclass(frozen=True)
class NoParams:
    """The parameters of an effect that has none."""


class Effect:
    """Base class: subclasses set the class attributes and implement :meth:`apply`.

    Attributes:
        name: key in the registry and in ``ToFConfig.effects``.
        stage: one of :data:`STAGES`.
        nominal: on in the nominal simulated cell.
        summary: one line for reports.
        Params: frozen dataclass of the parameters (fields declared with :func:`param`).
        params: the :class:`ParamSpec` of each field of ``Params`` (derived from it).
        stochastic: only draws noise: the expected measurement (the mismatch predictor) skips
            it.
        replaces: names of effects this one stands in for while it is on (their step is
            skipped).
        light_transport: part of the light transport that an external renderer's phasor
            (``render_tof(transport=...)``) already holds: skipped then.
        mixes_pixels: moves light between pixels after the indirect light is added, so every
            pixel's indirect light is needed (``render_tof(receivers=...)`` is then ignored).
    """

    name: ClassVar[str]
    stage: ClassVar[str]
    nominal: ClassVar[bool] = False
    summary: ClassVar[str] = ""
    Params: ClassVar[type[Any]] = NoParams
    params: ClassVar[tuple[ParamSpec, ...]] = ()
    stochastic: ClassVar[bool] = False
    replaces: ClassVar[tuple[str, ...]] = ()
    light_transport: ClassVar[bool] = False
    mixes_pixels: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.params = param_specs(cls.Params)
        stage = getattr(cls, "stage", None)
        if stage is not None and stage not in STAGES:
            raise TypeError(f"{cls.__name__}: stage {stage!r} is not one of {STAGES}")

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

    def parse(self, params: Mapping[str, Any]) -> Any:
        """The ``Params`` instance of a config's parameter mapping (``EffectConfig.params``)."""
        return self.Params(**params)

    def apply(self, x: Any, params: Any, ctx: RenderContext) -> Any:
        """Apply the effect at its stage (see the module docstring for ``x`` and the result);
        ``params`` is an instance of ``Params``."""
        raise NotImplementedError

    def bypass(self, x: Any, ctx: RenderContext) -> Any:
        """What the effect's step does while the effect is off: nothing, unless its stage needs
        a stand-in (see :class:`.effects.mixed_pixels.MixedPixels`,
        :class:`.effects.phase_wrapping.PhaseWrapping`)."""
        return x

    def __repr__(self) -> str:
        return f"<effect {self.name} ({self.stage})>"


class CameraMoveEffect(Effect):
    """A geometry effect that moves the camera by a small rigid motion: the surface is seen
    from the moved camera (:func:`.warp.move_camera`, nearest-pixel). Subclasses implement
    :meth:`camera_move`, which the mismatch predictor also reads to move the camera sub-pixel
    exactly."""

    stage = "geometry"

    def camera_move(self, params: Any, ctx: RenderContext
                    ) -> tuple[np.ndarray, np.ndarray] | None:
        """(rotation vector (3,) float64 rad, translation (3,) float64 mm) of the true camera
        in the assumed camera's optical frame, or None when the camera does not move."""
        raise NotImplementedError

    def apply(self, x: SurfaceImage, params: Any, ctx: RenderContext) -> SurfaceImage:
        move = self.camera_move(params, ctx)
        return x if move is None else moved_surface(x, *move, ctx)


def moved_surface(surface: SurfaceImage, rotvec: np.ndarray, translation_mm: np.ndarray,
                  ctx: RenderContext) -> SurfaceImage:
    """``surface`` from a camera moved by (rotvec rad, translation mm); unchanged when zero.

    The move is also composed into ``ctx.camera_shift``, so light transport places the moved
    camera (and its pixels) where it really is in the world.
    """
    if not (np.any(rotvec) or np.any(translation_mm)):
        return surface
    shift = np.eye(4)
    shift[:3, :3] = rotvec_to_matrix(rotvec)
    shift[:3, 3] = translation_mm
    ctx.camera_shift = ctx.camera_shift @ shift
    return move_camera(surface, rotvec, translation_mm)
