"""Evaluation figures: each writes a non-empty PNG."""

from __future__ import annotations

import numpy as np
import pytest

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.evaluation import edge_precision_recall, evaluate_frames
from tof_mpd_ros.evaluation.plots import (
    plot_accuracy_curves,
    plot_error_map,
    plot_precision_recall,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _is_png(path) -> bool:
    data = path.read_bytes()
    return data.startswith(PNG_MAGIC) and len(data) > 2000


def _scene():
    ref = np.full((1, 30, 40), 400.0, np.float32)
    ref[0, 10:20, 10:25] = 340.0
    ref[0, :3, :] = np.nan
    return ref


def test_accuracy_curves_png(tmp_path):
    ref = _scene()
    rng = np.random.default_rng(0)
    methods = {name: evaluate_frames(ref + rng.normal(0, s, ref.shape), ref)
               for name, s in (("raw", 8.0), ("proposed", 2.0))}
    out = plot_accuracy_curves(methods, tmp_path / "sub" / "acc.png", title="test")
    assert _is_png(out)
    with pytest.raises(InputError):
        plot_accuracy_curves({}, tmp_path / "none.png")


def test_precision_recall_png(tmp_path):
    gt = np.zeros((30, 30), bool)
    gt[15, :] = True
    score = np.random.default_rng(1).random((30, 30)) * 0.5
    score[15, :] = 0.9
    curves = {"G": edge_precision_recall(score, gt, np.linspace(0.1, 0.9, 9)),
              "Canny": edge_precision_recall(score[::-1], gt, np.linspace(0.1, 0.9, 9))}
    assert _is_png(plot_precision_recall(curves, tmp_path / "pr.png"))


def test_error_map_png(tmp_path):
    ref = _scene()[0]
    est = ref + 5.0
    est[25, 5] = np.nan
    assert _is_png(plot_error_map(est, ref, tmp_path / "err.png", limit_mm=10))
    with pytest.raises(InputError, match="estimate"):
        plot_error_map(est[:, :5], ref, tmp_path / "bad.png")
