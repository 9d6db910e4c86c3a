"""The paper's experiments (§V) side by side: raw, calibrated, the six baselines, F alone and the
full method on the same test frames. A model of the fcn kind takes the full method's place under
its own name, ``fcn`` (no F alone, no edge curves, no reference-edge ablation; its σ coverage in
the component analysis).

Protocol (what :func:`run_benchmark` does):

1. Every frame — training and test — is cropped to the model's shape by the caller and calibrated
   with the model's per-pixel intrinsic calibration; every baseline works on the calibrated range,
   as in the paper.
2. The training frames are split into a *fit* part and a *validation* part
   (:func:`split_train_val`: whole capture sessions — runs of frames separated by a stamp gap,
   i.e. scenes in the simulated layout — go to validation, so validation views are of scenes the
   forests never saw). RF-WF and RFD are fitted on the fit part; every baseline's free
   parameters are grid-searched on the validation part with the paper's score (fraction of
   pixels within 5 mm). The grid, the chosen values and every combination's score are recorded.
   F and G are whatever the weights file holds (trained on all training frames by ``tof-mpd
   train``).
3. On each test frame with a reference: every method runs, timed per frame (calibration
   included for everything after raw); the accuracy curves (whole image, 5 px boundary region),
   MAE/RMSE, the component analysis (raw / calibrated / F / geodesic+G / full, through the one
   per-frame loop of :class:`~tof_mpd_ros.evaluation.components.ComponentTally`) and G-vs-Canny
   edge precision/recall are pooled over pixels of all frames.
4. Methods are ranked at 5 mm and the ranking is compared with the paper's (proposed first, RFD
   second, the other baselines marginally above calibrated, calibrated above raw); every
   difference carries the evidence measured here that explains it.

:func:`tof_mpd_ros.evaluation.report.write_benchmark_report` turns the result into
``results.json``, PNGs and ``index.html``.

Modules: :mod:`.config` (methods, grids, settings), :mod:`.split` (calibrated training frames
and the session split), :mod:`.tuning` (fit and grid-search one baseline), :mod:`.run`
(:func:`run_benchmark`), :mod:`.result` (:class:`BenchmarkResult`), :mod:`.paper` (ranking and
the comparison with the paper), :mod:`.context` (machine and settings of a run).
"""

from __future__ import annotations

from ..profiles import ProfileLine
from .config import (
    BASELINE_NAMES,
    F_ALONE,
    FCN,
    METHODS,
    PAPER_METHODS,
    PROPOSED,
    RANK_THRESHOLD_MM,
    REFERENCE_EDGES,
    SMOOTHING_BASELINES,
    TABLE_THRESHOLDS_MM,
    BenchmarkConfig,
    GridSpec,
    default_grids,
    methods_for,
    own_method,
)
from .context import machine_info
from .paper import PAPER_WITHIN_5MM, compare_with_paper, rank_methods
from .result import BenchmarkResult
from .run import run_benchmark
from .split import CalibratedFrame, TrainValSplit, calibrate_frames, session_groups, split_train_val
from .tuning import TunedBaseline, tune_baseline

__all__ = [
    "BASELINE_NAMES", "FCN", "F_ALONE", "METHODS", "PAPER_METHODS", "PAPER_WITHIN_5MM",
    "PROPOSED",
    "RANK_THRESHOLD_MM", "REFERENCE_EDGES", "SMOOTHING_BASELINES", "TABLE_THRESHOLDS_MM",
    "BenchmarkConfig", "BenchmarkResult", "CalibratedFrame", "GridSpec", "ProfileLine",
    "TrainValSplit", "TunedBaseline", "calibrate_frames", "compare_with_paper", "default_grids",
    "machine_info", "methods_for", "own_method", "rank_methods", "run_benchmark",
    "session_groups", "split_train_val", "tune_baseline",
]
