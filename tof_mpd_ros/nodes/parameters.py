"""Declare a node's parameters once, from one table, with descriptors and validation.

Each node module holds a tuple of :class:`ParameterSpec`; ``config/<node>.yaml`` lists the same
defaults for ``--params-file`` users (a test keeps the two identical). Values are validated in an
on-set callback, so ``ros2 param set`` with a bad value is refused with a reason.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node

from ..errors import InputError


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: name, default, description and optional constraints."""

    name: str
    default: Any
    description: str
    choices: tuple[str, ...] = ()
    min_value: float | None = None
    max_value: float | None = None
    read_only: bool = False

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(name=self.name, description=self.description,
                                read_only=self.read_only)
        if self.choices:
            d.additional_constraints = f"one of: {', '.join(self.choices)}"
        if self.min_value is not None and self.max_value is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                d.integer_range = [IntegerRange(from_value=int(self.min_value),
                                                to_value=int(self.max_value), step=0)]
            elif isinstance(self.default, float):
                d.floating_point_range = [FloatingPointRange(
                    from_value=float(self.min_value), to_value=float(self.max_value), step=0.0)]
        return d

    def check(self, value: Any) -> str | None:
        """The reason ``value`` is refused, or None when it is acceptable."""
        if self.choices and value not in self.choices:
            return f"{self.name} must be one of {self.choices}, got {value!r}"
        if self.min_value is not None and value < self.min_value:
            return f"{self.name} must be >= {self.min_value}, got {value!r}"
        if self.max_value is not None and value > self.max_value:
            return f"{self.name} must be <= {self.max_value}, got {value!r}"
        return None


def declare(node: Node, specs: Sequence[ParameterSpec], *,
            check: Callable[[list], str | None] | None = None) -> dict[str, Any]:
    """Declare ``specs`` on ``node``, install the validation callback, return current values.

    Args:
        node: the node.
        specs: its parameter table.
        check: a further validation of a change (``rclpy.parameter.Parameter`` list), called
            only when every value passed its spec's check; returns the reason to refuse it, or
            None to accept. For checks that need the values together or cost work (loading a
            file), which a single spec cannot express.

    Raises:
        ValueError: a value given at start-up (``--params-file``, ``-p``) is out of bounds.
    """
    by_name = {s.name: s for s in specs}
    for spec in specs:
        node.declare_parameter(spec.name, spec.default, spec.descriptor())

    def validate(parameters: list) -> SetParametersResult:
        for p in parameters:
            spec = by_name.get(p.name)
            reason = spec.check(p.value) if spec is not None else None
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        reason = check(parameters) if check is not None else None
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(validate)
    values = {s.name: node.get_parameter(s.name).value for s in specs}
    for spec in specs:
        reason = spec.check(values[spec.name])
        if reason:
            raise ValueError(reason)
    return values


def refuse_retired_parameters(node: Node, retired: Mapping[str, str]) -> None:
    """Stop at start-up if a retired topic parameter is set (``-p``, a params file).

    ``retired`` maps each former parameter to the node's relative topic name it selected. rclpy
    ignores values for undeclared parameters, so an old launch file would silently leave the
    node on its default topics; instead the error names the remapping that replaces it.

    Raises:
        InputError: one of ``retired`` was given a value.
    """
    # rclpy keeps the start-up values of every parameter, declared or not, in this mapping;
    # it has no public accessor for undeclared ones.
    overrides = getattr(node, "_parameter_overrides", {})
    for name, topic in retired.items():
        if name in overrides:
            value = overrides[name].value
            raise InputError(f"parameter {name} was removed: remap the topic instead, "
                             f"--ros-args -r {topic}:={value} (launch: remappings=[("
                             f"'{topic}', '{value}')])")
