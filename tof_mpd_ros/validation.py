"""One small input-validation helper used by every public entry point.

Modelled on kornia's ``KORNIA_CHECK_SHAPE``: check first, fail with a typed error that says what
was expected and what arrived.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import InputError


def check_array(
    name: str,
    value: object,
    *,
    ndim: int | Sequence[int] | None = None,
    shape: Sequence[int | None] | None = None,
    dtype_kind: str | None = None,
    error: type[Exception] = InputError,
) -> np.ndarray:
    """Return ``value`` as an ndarray after checking its dimensions, shape and dtype kind.

    Args:
        name: what the argument is called, for the message (``"range_mm"``).
        value: the array-like to check.
        ndim: allowed number(s) of dimensions.
        shape: expected shape; ``None`` entries match any size. Aligned to the trailing axes
            when ``ndim`` allows more dimensions than ``len(shape)``.
        dtype_kind: allowed numpy dtype kinds, e.g. ``"f"`` (float), ``"fiu"`` (numeric).
        error: the exception class to raise.

    Raises:
        error: with a message naming the argument, what was expected and what arrived.
    """
    if not isinstance(value, np.ndarray):
        try:
            value = np.asarray(value)
        except Exception as err:  # any conversion failure is an input error
            raise error(f"{name}: expected an array, got {type(value).__name__}") from err
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if value.ndim not in allowed:
            raise error(f"{name}: expected {' or '.join(map(str, allowed))} dimensions, "
                        f"got shape {value.shape}")
    if shape is not None:
        expected = tuple(shape)
        actual = value.shape[-len(expected):] if len(expected) <= value.ndim else value.shape
        if len(actual) != len(expected) or any(
            e is not None and e != a for e, a in zip(expected, actual, strict=True)
        ):
            shown = tuple("*" if e is None else e for e in expected)
            raise error(f"{name}: expected shape (..., {', '.join(map(str, shown))}), "
                        f"got {value.shape}")
    if dtype_kind is not None and value.dtype.kind not in dtype_kind:
        raise error(f"{name}: expected dtype kind in {dtype_kind!r}, got {value.dtype}")
    return value


def check_same_shape(**arrays: np.ndarray) -> None:
    """Raise :class:`InputError` unless all the named arrays share one shape."""
    shapes = {name: np.shape(a) for name, a in arrays.items()}
    if len(set(shapes.values())) > 1:
        listed = ", ".join(f"{n} {s}" for n, s in shapes.items())
        raise InputError(f"arrays must have the same shape: {listed}")
