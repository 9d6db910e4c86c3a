"""Exception hierarchy: one class per subsystem.

The library raises these; the CLI turns any :class:`TofMpdError` into a one-line message and a
non-zero exit code, and the ROS nodes turn them into logged, counted drops.
"""

from __future__ import annotations


class TofMpdError(Exception):
    """Base class of every error this package raises on purpose."""


class InputError(TofMpdError, ValueError):
    """An array or message does not have the shape, dtype, encoding or values expected."""


class RecordingError(TofMpdError):
    """A recording (rosbag2 MCAP directory) or NPZ interchange file is missing, corrupt or
    inconsistent."""


class WeightsError(TofMpdError):
    """A weights file is missing, corrupt, truncated or does not match this code/configuration."""


class SimulationError(TofMpdError):
    """The simulated cell was configured inconsistently (unknown effect, unreachable plan...)."""


class CalibrationError(TofMpdError):
    """A calibration could not be fitted or applied (too few captures, singular system...)."""


class ArmError(TofMpdError):
    """The robot arm backend failed: disconnected, protective stop, timeout, unreachable pose."""


class MismatchError(TofMpdError):
    """The sim-vs-real mismatch analysis could not run on the given data."""


class CaptureError(TofMpdError):
    """A synchronised capture (ToF + reference + pose) could not be taken in time."""
