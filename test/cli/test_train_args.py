"""``tof-mpd train --target-clip-mm``: a number of mm or ``auto`` (from the data)."""

from __future__ import annotations

import argparse

import pytest

from tof_mpd_ros.cli.train import _clip_arg


def test_target_clip_is_a_positive_number_or_auto() -> None:
    assert _clip_arg("auto") is None
    assert _clip_arg("22.5") == 22.5
    for bad in ("0", "-3", "fifteen"):
        with pytest.raises(argparse.ArgumentTypeError):
            _clip_arg(bad)
