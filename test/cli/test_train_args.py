"""``tof-mpd train --target-clip-mm``: mm or ``auto`` (from the data), comma-separated."""

from __future__ import annotations

import argparse

import pytest

from tof_mpd_ros.cli.train import _clip_arg


def test_target_clip_is_positive_numbers_or_auto() -> None:
    assert _clip_arg("auto") == (None,)
    assert _clip_arg("22.5") == (22.5,)
    assert _clip_arg("15, 30,auto") == (15.0, 30.0, None)
    for bad in ("0", "-3", "fifteen", "15,,30"):
        with pytest.raises(argparse.ArgumentTypeError):
            _clip_arg(bad)
