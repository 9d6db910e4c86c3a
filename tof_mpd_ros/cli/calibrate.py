"""``tof-mpd calibrate``: the per-pixel intrinsic calibration (and, later, hand-eye)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..errors import CalibrationError


def register(subparsers: argparse._SubParsersAction) -> None:
    calibrate = subparsers.add_parser(
        "calibrate", help="fit calibrations from capture recordings",
        description="Fit calibrations from recordings of calibration captures.")
    commands = calibrate.add_subparsers(dest="calibrate_command", metavar="KIND", required=True)
    intrinsic = commands.add_parser(
        "intrinsic", help="per-pixel linear range calibration from checkerboard captures",
        description="Fit the paper's per-pixel linear model (true range from observed range "
                    "and amplitude) from checkerboard captures whose reference holds the true "
                    "range (e.g. OUT/calibration of `tof-mpd sim dataset`). Reads a recording "
                    "or NPZ; writes an .npz with the coefficients and a .json with the fit's "
                    "residuals. Seconds for hundreds of captures.")
    intrinsic.add_argument("captures", type=Path, help="recording directory or .npz")
    intrinsic.add_argument("-o", "--output", type=Path, required=True,
                           help="calibration .npz to write")
    intrinsic.add_argument("--amplitude-term", choices=("linear", "inverse"), default="linear",
                           help="how amplitude enters the model (default linear)")
    intrinsic.set_defaults(func=run_intrinsic)


def fit_from_file(path: Path, amplitude_term: str = "linear"):
    """Fit an IntrinsicCalibration from every frame of a recording or NPZ."""
    from ..correction.calibration import IntrinsicCalibration
    from .frame_files import iter_frames

    frames = [f for f in iter_frames(path) if f.reference_mm is not None]
    if not frames:
        raise CalibrationError(f"{path}: no frame with a reference (true range) to fit against")
    return IntrinsicCalibration.fit(np.stack([f.range_mm for f in frames]),
                                    np.stack([f.amplitude for f in frames]),
                                    np.stack([f.reference_mm for f in frames]),
                                    amplitude_term=amplitude_term), frames


def save_calibration(path: Path, calibration) -> None:
    np.savez(path, **calibration.to_arrays())


def load_calibration(path: Path):
    """Read a calibration .npz written by ``tof-mpd calibrate intrinsic`` (no pickle)."""
    from ..correction.calibration import IntrinsicCalibration

    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError) as err:
        raise CalibrationError(f"{path}: not a calibration file: {err}") from err
    return IntrinsicCalibration.from_arrays(arrays)


def run_intrinsic(args: argparse.Namespace) -> int:
    calibration, frames = fit_from_file(args.captures, args.amplitude_term)
    raw = np.stack([f.range_mm - f.reference_mm for f in frames])
    fixed = np.stack([calibration.apply(f.range_mm, f.amplitude) - f.reference_mm
                      for f in frames])
    summary = {"captures": len(frames), "shape": list(calibration.shape),
               "fitted_fraction": float(np.mean(calibration.fitted)),
               "rmse_before_mm": float(np.sqrt(np.nanmean(raw ** 2))),
               "rmse_after_mm": float(np.sqrt(np.nanmean(fixed ** 2))),
               "output": str(args.output)}
    save_calibration(args.output, calibration)
    args.output.with_suffix(".json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary))
    return 0
