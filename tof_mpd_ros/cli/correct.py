"""``tof-mpd correct``: run the full correction on a recording or an NPZ."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from .arguments import window_size
from .output import add_output


def register(subparsers: argparse._SubParsersAction) -> None:
    correct = subparsers.add_parser(
        "correct", help="correct every frame of a recording or NPZ",
        description="Apply calibration -> F -> G -> geodesic filtering (or, with weights of "
                    "the fcn kind, calibration -> the network) to every frame of a "
                    "recording (directory) or NPZ and write the same kind of file with the "
                    "corrected radial range (references, poses and stamps are kept); an NPZ "
                    "written with fcn weights also holds sigma_mm, the predicted standard "
                    "deviation per pixel (a recording has no topic for it). Frames "
                    "larger than the processed window (--crop; by default the weights' whole "
                    "frame, the full 320x240 sensor for the shipped weights) are cropped to "
                    "its central window, as the corrector node does: the output holds the "
                    "window, with its intrinsics; smaller frames are corrected whole, as the "
                    "central window of the weights' pixels. Tens of milliseconds per 180x140 "
                    "frame on a CPU.",
        epilog="example: tof-mpd correct my_recording/ -o corrected/ --weights weights.npz")
    correct.add_argument("input", type=Path, help="recording directory or .npz")
    add_output(correct, "output recording directory or .npz", was_positional=True)
    correct.add_argument("--weights", type=Path, help="weights file (default: shipped weights)")
    correct.add_argument("--device", default="cpu", help="torch device (default cpu)")
    correct.add_argument("--crop", metavar="WxH", type=window_size, default=None,
                         help="processed central window, e.g. 180x140 (the paper's crop); "
                              "default: the weights' whole frame")
    correct.add_argument("--overwrite", action="store_true")
    correct.set_defaults(func=run_correct)


def load_model(path: Path | None):
    from ..correction.default_weights import default_weights_path
    from ..correction.weights import load_weights

    return load_weights(path if path is not None else default_weights_path())


def fit_to_frames(model, frame_shape: tuple[int, int]):
    """``model`` on the central window of ``frame_shape`` (H, W) when the frames are smaller
    than its frame (full-sensor weights on 180x140 recordings, as the node does); unchanged
    otherwise, and a size that does not fit is reported where the frames are corrected."""
    from ..correction.pipeline import central_window, processed_window

    window = processed_window(model.shape, frame_shape)
    if window == tuple(frame_shape):  # smaller or equal: corrected whole on the central window
        return central_window(model, window[1], window[0])
    return model


def run_correct(args: argparse.Namespace) -> int:
    from ..recordings import is_npz, save_npz, write_frames

    model = load_model(args.weights)
    width, height = args.crop or model.shape[::-1]
    if width > model.shape[1] or height > model.shape[0]:
        from ..errors import InputError

        raise InputError(f"--crop {width}x{height} is larger than the weights' "
                         f"{model.shape[1]}x{model.shape[0]} frame")
    seconds: list[float] = []
    cropped_from: set[tuple[int, int]] = set()
    sigmas: list = []
    frames = _corrected_frames(args, model, seconds, cropped_from, sigmas)
    # An fcn model predicts sigma: an .npz has room for it beside the frames, a recording
    # directory has no topic for it.
    sigma_written = model.kind == "fcn" and is_npz(args.output)
    if sigma_written:
        import numpy as np

        frames = list(frames)
        count = save_npz(args.output, frames, overwrite=args.overwrite,
                         extra={"sigma_mm": np.stack(sigmas)} if frames else None)
    else:
        count = write_frames(args.output, frames, overwrite=args.overwrite)
    ms = sorted(1e3 * s for s in seconds)
    summary = {"output": str(args.output), "frames": count, "model_kind": model.kind,
               "median_ms_per_frame": ms[len(ms) // 2] if ms else None,
               "window": [width, height], "weights_frame": list(model.shape[::-1]),
               "cropped_from": [[w, h] for h, w in sorted(cropped_from)],
               "sigma_mm_written": sigma_written}
    print(json.dumps(summary))
    return 0


def _corrected_frames(args: argparse.Namespace, model, seconds: list[float],
                      cropped_from: set[tuple[int, int]], sigmas: list):
    """The corrected frames of ``args.input``, one at a time; appends each frame's correction
    time to ``seconds``, the sizes cropped from to ``cropped_from`` and (fcn kind) the
    predicted sigma, (H, W) mm, to ``sigmas``."""
    from dataclasses import replace

    from tqdm import tqdm

    from ..correction.pipeline import central_window, correct, processed_window
    from ..recordings import count_frames, iter_frames

    windows: dict = {}
    for frame in tqdm(iter_frames(args.input), total=count_frames(args.input),
                      desc="correcting", unit="frame"):
        k = frame.intrinsics
        h, w = processed_window(model.shape, k.shape, args.crop)  # the node's central window
        if k.shape != (h, w):
            cropped_from.add(k.shape)
            frame = frame.cropped(w, h)
        if (h, w) not in windows:
            windows[(h, w)] = central_window(model, w, h)
        start = time.perf_counter()
        result = correct(windows[(h, w)], frame.range_mm, frame.amplitude, device=args.device)
        seconds.append(time.perf_counter() - start)
        if result.sigma_mm is not None:
            sigmas.append(result.sigma_mm)
        yield replace(frame, range_mm=result.range_mm)
