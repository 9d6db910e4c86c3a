"""``tof-mpd train`` arguments: ``--target-clip-mm`` (mm or ``auto``, comma-separated) and the
per-kind defaults of ``--model patch|fcn``."""

from __future__ import annotations

import argparse
import io
import json
from pathlib import Path

import pytest

from tof_mpd_ros.cli.train import _clip_arg, write_summary


def test_target_clip_is_positive_numbers_or_auto() -> None:
    assert _clip_arg("auto") == (None,)
    assert _clip_arg("22.5") == (22.5,)
    assert _clip_arg("15, 30,auto") == (15.0, 30.0, None)
    for bad in ("0", "-3", "fifteen", "15,,30"):
        with pytest.raises(argparse.ArgumentTypeError):
            _clip_arg(bad)


@pytest.mark.parametrize(("line", "kind", "expected"), [
    ("", "patch", {"epochs": 40, "batch_size": 500, "lr_range": 0.05,
                   "target_clip_mm": (15.0, 30.0, None)}),
    ("--lr 0.01 --batch-size 200 --epochs 3 --target-clip-mm 15", "patch",
     {"epochs": 3, "batch_size": 200, "lr_range": 0.01, "lr_boundary": 0.01,
      "target_clip_mm": (15.0,)}),
    ("--model fcn", "fcn", {"epochs": 60, "batch_size": 8, "lr": 1e-3, "crop_px": 96,
                            "target_clip_mm": 100.0}),
    ("--model fcn --lr 0.002 --batch-size 4 --crop-px 64 --target-clip-mm 50", "fcn",
     {"batch_size": 4, "lr": 0.002, "crop_px": 64, "target_clip_mm": 50.0}),
])
def test_model_kind_picks_the_trainer_and_its_defaults(
        line: str, kind: str, expected: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--batch-size``, ``--epochs``, ``--lr`` and ``--target-clip-mm`` default to the chosen
    kind's own (500 patches / 8 crops...)."""
    from tof_mpd_ros.cli import train as cli_train
    from tof_mpd_ros.cli.main import build_parser
    from tof_mpd_ros.training import fcn_trainer, trainer

    seen = {}

    def fake(frames, calibration, config, **kwargs):
        seen["config"] = config
        raise SystemExit(0)

    monkeypatch.setattr(trainer, "train", fake)
    monkeypatch.setattr(fcn_trainer, "train_fcn", fake)
    args = build_parser().parse_args(["train", "in.npz", "--calibration", "c.npz", "-o",
                                      "w.npz", *line.split()])
    assert args.model == kind
    run = cli_train._train_fcn if kind == "fcn" else cli_train._train_patch
    with pytest.raises(SystemExit):
        run(args, [], None)
    config = seen["config"]
    assert type(config).__name__ == ("FCNTrainConfig" if kind == "fcn" else "TrainConfig")
    assert {k: getattr(config, k) for k in expected} == expected


def test_summary_on_stdout_redirected_to_its_own_file_stays_one_document(tmp_path: Path) -> None:
    """``tof-mpd train ... -o W.npz > W.json``: the file is the whole summary, parseable."""
    summary = {"weights": "W.npz", "final": {"epoch": 2}, "history": [{"epoch": 1}, {"epoch": 2}]}
    path = tmp_path / "W.json"
    with path.open("w") as stdout:           # the shell's redirection, opened first
        write_summary(summary, path, stdout)
    assert json.loads(path.read_text()) == summary
    other = io.StringIO()                    # stdout elsewhere: the short form is printed
    write_summary(summary, tmp_path / "V.json", other)
    assert json.loads(other.getvalue()) == {"weights": "W.npz", "final": {"epoch": 2}}
    assert json.loads((tmp_path / "V.json").read_text()) == summary
