"""A toy effect known only to the tests, for registering a new effect (sim and mismatch tests)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tof_mpd_ros.sim.tof import Effect, param


@dataclass(frozen=True)
class ToyOffsetParams:
    offset_mm: float = param(3.0, -10.0, 10.0, "mm", "added to every range")


class ToyOffset(Effect):
    """A range-stage effect known only to the tests: adds ``offset_mm`` to every range."""

    name = "toy_offset"
    stage = "range"
    Params = ToyOffsetParams

    def apply(self, x: np.ndarray, params: ToyOffsetParams, ctx) -> np.ndarray:
        return x + params.offset_mm
