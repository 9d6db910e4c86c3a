"""The measurement pipeline: the package's one ordered list of steps.

Both the renderer (:mod:`.render`) and the mismatch tool's expected-value predictor
(:class:`tof_mpd_ros.mismatch.predict.FramePredictor`) walk :func:`pipeline_steps`, so an effect
added with :func:`.registry.register_effect` is a step of both. The order is :data:`STAGE_ORDER`:

1. ``geometry``: the effects that change what the camera sees (a surface image);
2. :data:`DIRECT`: the pipeline's own step, the direct return of every surface sample;
3. ``footprint``: sample phasors to pixel phasors;
4. ``phasor``: light transport, optics and noise on the (H, W) pixel phasors;
5. ``readout``: phasor to range (the amplitude is read from the phasor first);
6. ``range``: the camera's systematic range errors.

Within a stage the effects run in registry order (:data:`.registry.EFFECTS`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

import numpy as np

from ...camera import Intrinsics
from ..surface import SurfaceImage
from .context import CameraMotion, RenderContext
from .effect import STAGES, Effect
from .effects.mixed_pixels import light_footprint_sigma_px
from .effects.noise import Noise
from .registry import EFFECTS

if TYPE_CHECKING:
    from .config import ToFConfig
    from .world import WorldModel

#: name and stage of the pipeline's own step between geometry and footprint: the direct return
DIRECT = "direct"
#: every stage of the pipeline in order: the effect stages with :data:`DIRECT` after geometry
STAGE_ORDER: tuple[str, ...] = (STAGES[0], DIRECT, *STAGES[1:])


class Action(Enum):
    """What a step does under a configuration."""

    #: the effect is on: :meth:`.effect.Effect.apply`
    APPLY = "apply"
    #: the effect is off: :meth:`.effect.Effect.bypass` (the identity for most effects)
    BYPASS = "bypass"
    #: another effect that is on stands in for it (``replaces``): nothing happens
    SKIP = "skip"


@dataclass(frozen=True)
class Step:
    """One step of the pipeline.

    Attributes:
        name: the effect's name, or :data:`DIRECT`.
        stage: the effect's stage, or :data:`DIRECT`.
        effect: the registered effect, None for :data:`DIRECT`.
        replaced_by: effects that stand in for this one while they are on.
    """

    name: str
    stage: str
    effect: Effect | None = None
    replaced_by: tuple[str, ...] = ()

    def action(self, config: ToFConfig) -> Action:
        """What the step does under ``config`` (:data:`DIRECT` always applies)."""
        if self.effect is None:
            return Action.APPLY
        if any(config.effects[other].enabled for other in self.replaced_by):
            return Action.SKIP
        return Action.APPLY if config.effects[self.name].enabled else Action.BYPASS

    def params(self, config: ToFConfig) -> Any:
        """The effect's typed ``Params`` under ``config``."""
        if self.effect is None:
            raise ValueError(f"step {self.name!r} has no parameters")
        return self.effect.parse(config.effects[self.name].params)


def pipeline_steps() -> tuple[Step, ...]:
    """The package's one ordered list of the measurement's steps (see the module docstring),
    from the registry as it is now."""
    replaced_by = {n: tuple(o for o, e in EFFECTS.items() if n in e.replaces) for n in EFFECTS}
    steps: list[Step] = []
    for stage in STAGE_ORDER:
        if stage == DIRECT:
            steps.append(Step(DIRECT, DIRECT))
        steps += [Step(n, stage, e, replaced_by[n]) for n, e in EFFECTS.items()
                  if e.stage == stage]
    return tuple(steps)


def run_step(step: Step, x: Any, config: ToFConfig, ctx: RenderContext) -> Any:
    """``x`` after effect ``step`` under ``config``: applied, bypassed (off) or skipped
    (replaced). ``x`` and the result are the stage's data (see :mod:`.effect`)."""
    if step.effect is None:
        raise ValueError(f"step {step.name!r} is the pipeline's own: its caller computes it")
    action = step.action(config)
    if action is Action.APPLY:
        return step.effect.apply(x, step.params(config), ctx)
    if action is Action.BYPASS:
        return step.effect.bypass(x, ctx)
    return x


def frame_context(config: ToFConfig, intrinsics: Intrinsics, samples: SurfaceImage, *,
                  rng: np.random.Generator, supersample: int = 1, frame_index: int = 0,
                  motion: CameraMotion | None = None,
                  world: WorldModel | None = None) -> RenderContext:
    """The :class:`.context.RenderContext` of one frame before its geometry stage.

    Args:
        config: camera and effect configuration.
        intrinsics: intrinsics of the output H x W pixel grid.
        samples: the surface image the pipeline starts from (``supersample`` samples per pixel
            and axis); also the context's ``surface`` until the geometry stage ends.
        rng: random generator for noise; frame_index, motion, world: see ``RenderContext``.
    """
    ctx = RenderContext(intrinsics=intrinsics, surface=samples, samples=samples,
                        supersample=supersample, mod_freq_hz=config.mod_freq_hz,
                        light_power=config.light_power, rng=rng, frame_index=int(frame_index),
                        motion=motion, noise_params=config.effect_params(Noise.name),
                        world=world)
    ctx.footprint_sigma_px = light_footprint_sigma_px(config)
    return ctx


__all__ = ["DIRECT", "STAGE_ORDER", "Action", "Step", "frame_context", "pipeline_steps",
           "run_step"]
