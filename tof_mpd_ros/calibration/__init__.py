"""Calibration, in one place.

* :mod:`.intrinsic` — the per-pixel ToF range calibration (the paper's linear model from
  observed range and amplitude to true range): :class:`IntrinsicCalibration`, its one fit
  (:meth:`IntrinsicCalibration.fit`, :func:`fit_calibration` from checkerboard frames) and its
  ``.npz`` file (:func:`save_calibration`, :func:`load_calibration`). ``tof-mpd calibrate
  intrinsic`` fits it; the correction pipeline applies it first.
* :mod:`.hand_eye` — the hand–eye calibration (ToF camera in the flange frame, SL camera in the
  ToF frame) from checkerboard views; :mod:`.hand_eye_board` the printed board and its
  detection; :mod:`.hand_eye_io` calibration recordings and result files. ``tof-mpd calibrate
  hand-eye`` solves it.

Not here, on purpose: the hand–eye *capture plan* (:mod:`tof_mpd_ros.collection.hand_eye_plan`,
where the arm goes; the collector runs it like any other plan) and the *simulated* captures
(:mod:`tof_mpd_ros.sim.hand_eye`, the graded checkerboard of :mod:`tof_mpd_ros.sim.checkerboard`).
The hand–eye modules load OpenCV and SciPy, so this package imports only :mod:`.intrinsic`.

Pure numpy/OpenCV/SciPy; never imports rclpy or the simulator.
"""

from __future__ import annotations

from .intrinsic import IntrinsicCalibration, fit_calibration, load_calibration, save_calibration

__all__ = ["IntrinsicCalibration", "fit_calibration", "load_calibration", "save_calibration"]
