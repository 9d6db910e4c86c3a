"""``tof-mpd calibrate``: fit the per-pixel intrinsic calibration and the hand–eye calibration
(both implemented in :mod:`tof_mpd_ros.calibration`; this module only reads files and reports)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..calibration import IntrinsicCalibration, fit_calibration, save_calibration
from ..errors import CalibrationError, RecordingError
from ..frame import ToFFrame
from .output import add_output


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
    add_output(intrinsic, "calibration .npz to write")
    intrinsic.add_argument("--amplitude-term", choices=("linear", "inverse"), default="linear",
                           help="how amplitude enters the model (default linear)")
    intrinsic.set_defaults(func=run_intrinsic)
    _register_install(commands)
    _register_sigma(commands)
    _register_hand_eye(commands)


def _register_install(commands: argparse._SubParsersAction) -> None:
    install = commands.add_parser(
        "install", help="put an intrinsic calibration into a weights file (networks kept)",
        description="Replace the per-pixel intrinsic calibration of a weights file (either "
                    "kind) by CALIBRATION (from `tof-mpd calibrate intrinsic`), keeping the "
                    "networks: the calibration is the camera's own, the networks are learnt "
                    "physics that work on any calibrated frame. The weights' frame becomes "
                    "the calibration's (e.g. the whole 320x240 sensor for weights trained on "
                    "the 180x140 crop). Measure the result on test frames of that size "
                    "(`tof-mpd evaluate`).",
        epilog="example: tof-mpd calibrate install full_sensor.npz --weights weights.npz "
               "-o weights_full.npz")
    install.add_argument("calibration", type=Path, help="calibration .npz")
    install.add_argument("--weights", type=Path, help="weights file (default: shipped weights)")
    add_output(install, "weights .npz to write")
    install.add_argument("--overwrite", action="store_true")
    install.set_defaults(func=run_install)


def run_install(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..calibration import load_calibration
    from ..correction.weights import save_weights
    from .correct import load_model

    model = load_model(args.weights)
    calibration = load_calibration(args.calibration)
    before = model.shape
    weights = "shipped" if args.weights is None else str(args.weights)
    installed = replace(model, calibration=calibration, metadata={
        **model.metadata, "calibration_installed": {
            "from": str(args.calibration), "into": weights,
            "frame_before": [before[1], before[0]]}})
    save_weights(args.output, installed, overwrite=args.overwrite)
    print(json.dumps({"output": str(args.output), "kind": model.kind,
                      "frame_before": [before[1], before[0]],
                      "frame": [calibration.shape[1], calibration.shape[0]]}))
    return 0


def _register_sigma(commands: argparse._SubParsersAction) -> None:
    sigma = commands.add_parser(
        "sigma", help="refit an fcn weights file's sigma on reference frames of your camera",
        description="Refit the per-pixel uncertainty (sigma) of an fcn-kind weights file on "
                    "recordings with a reference, e.g. a few scenes of the camera and the kind "
                    "of scene it will run on that were not used for training. One gain on "
                    "sigma is fitted so that 95.45 % of those pixels lie within 2 sigma; the "
                    "threshold above which a pixel takes a neighbour's side (max_sigma_mm) "
                    "moves with it, so the corrected range is unchanged. The trainer fits "
                    "the same gain on its own validation frames, which come from the training "
                    "scenes: on another renderer or camera the errors outgrow that sigma "
                    "(docs/method.md section 9). Use scenes other than those you evaluate on.",
        epilog="example: tof-mpd calibrate sigma site_scenes/ --weights fcn.npz "
               "-o fcn_site.npz")
    sigma.add_argument("recordings", type=Path, nargs="+",
                       help="recordings / .npz whose frames carry a reference")
    sigma.add_argument("--weights", type=Path, required=True, help="fcn-kind weights file")
    add_output(sigma, "weights .npz to write")
    sigma.add_argument("--overwrite", action="store_true")
    sigma.set_defaults(func=run_sigma)


def run_sigma(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..correction.weights import save_weights
    from ..errors import InputError
    from ..training.fcn_trainer import recalibrate_sigma_on_frames
    from .correct import fit_to_frames, load_model
    from .train import load_reference_frames

    model = load_model(args.weights)
    if model.kind != "fcn":
        raise InputError(f"{args.weights}: a {model.kind!r} model predicts no sigma; "
                         "`calibrate sigma` recalibrates the fcn kind's")
    # an NPZ keeps a missing reference as NaN
    frames, skipped = load_reference_frames(
        args.recordings, lambda ref: ref is not None and bool(np.isfinite(ref).any()))
    window = fit_to_frames(model, frames[0].range_mm.shape)
    fitted, summary = recalibrate_sigma_on_frames(
        window, frames, source=", ".join(map(str, args.recordings)))
    # the network is the whole sensor's; only the gain came from the window
    recalibrations = fitted.metadata["sigma_recalibrations"]
    save_weights(args.output, replace(model, net=fitted.net, max_sigma_mm=fitted.max_sigma_mm,
                                      metadata={**model.metadata,
                                                "sigma_recalibrations": recalibrations}),
                 overwrite=args.overwrite)
    print(json.dumps({"output": str(args.output), **summary,
                      "frames_without_reference": skipped}))
    return 0


def fit_from_file(path: Path, amplitude_term: str = "linear"
                  ) -> tuple[IntrinsicCalibration, list[ToFFrame]]:
    """Fit an IntrinsicCalibration (:func:`~tof_mpd_ros.calibration.fit_calibration`) from every
    frame of a recording or NPZ that has a reference; returns it and those frames."""
    from ..recordings import iter_frames

    frames = [f for f in iter_frames(path) if f.reference_mm is not None]
    if not frames:
        raise CalibrationError(f"{path}: no frame with a reference (true range) to fit against")
    return fit_calibration(frames, amplitude_term=amplitude_term), frames


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


# ------------------------------------------------------------------------------ hand-eye


def _register_hand_eye(commands: argparse._SubParsersAction) -> None:
    hand_eye = commands.add_parser(
        "hand-eye", help="camera-to-flange and ToF-to-SL transforms from checkerboard views",
        description="Hand-eye calibration as the paper does before collecting. Reads a "
                    "calibration recording (ToF amplitude, SL image /sl/image_raw + "
                    "/sl/camera_info, TCP pose per view, board in custom_data), finds the board "
                    "in both cameras, solves A X = X B and refines X, the SL offset and the "
                    "board pose on all corners. Prints (and with -o writes) JSON: the "
                    "transforms as 4x4 matrices in metres and UR pose vectors, residuals "
                    "(px, mm, deg) and the views left out with the reason. Solving takes about "
                    "a second; --simulate first records a simulated session into RECORDING "
                    "(about 1-2 s per view).")
    hand_eye.add_argument("recording", type=Path, help="calibration recording directory")
    add_output(hand_eye, "also write the JSON here", required=False)
    hand_eye.add_argument("--simulate", action="store_true",
                          help="first write a simulated calibration recording to RECORDING "
                               "(true hand-eye = default moved by a few mm and ~1 deg)")
    hand_eye.add_argument("--views", type=int, default=12, help="simulated views (default 12)")
    hand_eye.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    hand_eye.add_argument("--min-views", type=int, default=4,
                          help="fewest views with the board detected per camera (default 4)")
    hand_eye.add_argument("--no-refine", action="store_true",
                          help="report the linear hand-eye solution without the joint "
                               "reprojection refinement")
    hand_eye.set_defaults(func=run_hand_eye)


def run_hand_eye(args: argparse.Namespace) -> int:
    from ..calibration.hand_eye import pose_difference, solve_hand_eye
    from ..calibration.hand_eye_io import read_hand_eye_recording

    if args.simulate:
        _simulate_hand_eye(args.recording, args.views, args.seed)
    data = read_hand_eye_recording(args.recording)
    result = solve_hand_eye(data.captures, data.board, data.tof_intrinsics, data.sl_intrinsics,
                            min_views=args.min_views, refine=not args.no_refine)
    summary = {"recording": str(args.recording), "views": len(data.captures),
               "board": data.board.as_dict(), **result.as_dict()}
    truth = data.sim_truth()
    if truth is not None:
        estimates = {"camera_to_flange": result.camera_to_flange_m,
                     "sl_to_tof": result.sl_to_tof_m}
        summary["error_vs_sim_truth"] = {
            name: dict(zip(("translation_mm", "rotation_deg"),
                           pose_difference(estimates[name], truth[name]), strict=True))
            for name in estimates if name in truth}
    text = json.dumps(summary, indent=2)
    if args.output is not None:
        args.output.write_text(text)
    print(text)
    return 0


def _simulate_hand_eye(path: Path, views: int, seed: int) -> None:
    from ..arm.tool import DEFAULT_T_FLANGE_CAMERA_M
    from ..sim.hand_eye import HandEyeSimConfig, perturb_pose, simulate_hand_eye_recording

    if path.exists():
        raise RecordingError(f"{path} exists; --simulate refuses to overwrite a recording")
    rng = np.random.default_rng(seed)
    config = HandEyeSimConfig(n_views=views,
                              t_flange_camera_m=perturb_pose(DEFAULT_T_FLANGE_CAMERA_M, rng))
    simulate_hand_eye_recording(path, rng, config)
