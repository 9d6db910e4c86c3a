"""Offline training of F + G from frames with structured-light references (the per-pixel
calibration they start from is fitted by :mod:`tof_mpd_ros.calibration`). Pure numpy/torch;
never imports rclpy."""

from __future__ import annotations

from .samples import TrainingData, prepare_training_data, sample_pixels
from .trainer import TrainConfig, train

__all__ = ["TrainConfig", "TrainingData", "prepare_training_data", "sample_pixels", "train"]
