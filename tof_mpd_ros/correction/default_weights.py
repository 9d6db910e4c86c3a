"""The weights shipped inside the package (trained on the simulated MD-Train)."""

from __future__ import annotations

from pathlib import Path

from ..errors import WeightsError

SHIPPED_WEIGHTS = Path(__file__).resolve().parents[1] / "data" / "default_weights.npz"


def default_weights_path() -> Path:
    """Path of the shipped weights.

    Raises:
        WeightsError: the package was installed without them.
    """
    if not SHIPPED_WEIGHTS.is_file():
        raise WeightsError(f"the shipped weights {SHIPPED_WEIGHTS} are missing; reinstall the "
                           "package or pass a weights file (`tof-mpd train` makes one)")
    return SHIPPED_WEIGHTS
