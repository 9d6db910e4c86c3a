"""Offline training: per-pixel calibration from checkerboard frames, and F + G from frames with
structured-light references. Pure numpy/torch; never imports rclpy."""

from __future__ import annotations

from .samples import TrainingData, prepare_training_data, sample_pixels
from .trainer import TrainConfig, fit_calibration, train

__all__ = ["TrainConfig", "TrainingData", "fit_calibration", "prepare_training_data",
           "sample_pixels", "train"]
