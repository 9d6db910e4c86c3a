"""Offline training of F + G (:mod:`.trainer`) and of the fcn kind (:mod:`.fcn_trainer`) from
frames with structured-light references (the per-pixel calibration they start from is fitted by
:mod:`tof_mpd_ros.calibration`). Pure numpy/torch; never imports rclpy."""

from __future__ import annotations

from .fcn_trainer import FCNTrainConfig, evaluate_fcn, train_fcn
from .samples import TrainingData, prepare_training_data, sample_pixels
from .trainer import TrainConfig, train

__all__ = ["FCNTrainConfig", "TrainConfig", "TrainingData", "evaluate_fcn",
           "prepare_training_data", "sample_pixels", "train", "train_fcn"]
