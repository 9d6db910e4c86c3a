"""``tof-mpd train``: fit F and G (after the intrinsic calibration) on recordings."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from .output import add_output


def register(subparsers: argparse._SubParsersAction) -> None:
    train = subparsers.add_parser(
        "train", help="train the range-recovery net F and the boundary nets G",
        description="Train F and G on recordings (or NPZ files) whose frames carry a "
                    "structured-light reference; missing reference pixels are excluded. The "
                    "intrinsic calibration comes from --calibration (a file from `tof-mpd "
                    "calibrate intrinsic`) or is fitted from --calibration-captures. Writes the "
                    "weights file (calibration + F + G + constants) and WEIGHTS.json with the "
                    "loss history. The paper's schedule (40 epochs, batch 500) on MD-Train-sized "
                    "data takes tens of minutes on 2 cores; --epochs and "
                    "--max-samples-per-frame shorten it. Resumable with --checkpoint-dir.")
    train.add_argument("recordings", type=Path, nargs="+", help="training recordings / .npz")
    add_output(train, "weights .npz to write")
    source = train.add_mutually_exclusive_group(required=True)
    source.add_argument("--calibration", type=Path, help="calibration .npz")
    source.add_argument("--calibration-captures", type=Path,
                        help="checkerboard capture recording to fit the calibration from")
    train.add_argument("--epochs", type=int, default=40)
    train.add_argument("--batch-size", type=int, default=500)
    train.add_argument("--max-samples-per-frame", type=int, default=4000,
                       help="pixels drawn afresh per frame and epoch (default 4000; 0 = every "
                            "usable pixel, the paper's ~10 M patches at MD scale)")
    train.add_argument("--target-clip-mm", type=_clip_arg, default=(15.0, 30.0, None),
                       metavar="MM|auto[,...]",
                       help="truncation T of F's target: one value (15 = the paper's), 'auto' "
                            "(the training data's 99th percentile of |distortion| away from "
                            "edges, at least 15), or several = one F each on the same patches, "
                            "the best on the validation frames kept (default 15,30,auto)")
    train.add_argument("--edge-thresholds", choices=("tune", "paper"), default="tune",
                       help="G's hysteresis thresholds: chosen on the validation frames by the "
                            "full pipeline's boundary accuracy (default), or the paper's "
                            "0.3 / 0.6")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--checkpoint-dir", type=Path, help="checkpoint after every epoch; "
                       "an interrupted run resumes from it")
    train.add_argument("--overwrite", action="store_true", help="replace an existing output")
    train.set_defaults(func=run_train)


def _clip_arg(text: str) -> tuple[float | None, ...]:
    """``15`` / ``auto`` / ``15,30,auto`` -> the truncation candidates (None = from the data)."""
    out: list[float | None] = []
    for part in text.split(","):
        part = part.strip()
        if part == "auto":
            out.append(None)
            continue
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected numbers of mm or 'auto', comma-separated, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {part}")
        out.append(value)
    return tuple(out)


def load_training_frames(paths: list[Path]) -> list:
    from ..errors import InputError
    from ..recordings import iter_frames

    frames = [f for path in paths for f in iter_frames(path)]
    usable = [f for f in frames if f.reference_mm is not None]
    if not usable:
        raise InputError(f"no frame with a reference in {', '.join(map(str, paths))}")
    return usable


def run_train(args: argparse.Namespace) -> int:
    from ..calibration import load_calibration
    from ..training.trainer import TrainConfig, train
    from .calibrate import fit_from_file

    calibration = (load_calibration(args.calibration) if args.calibration is not None
                   else fit_from_file(args.calibration_captures)[0])
    frames = load_training_frames(args.recordings)
    config = TrainConfig(epochs=args.epochs, batch_size=args.batch_size,
                         max_samples_per_frame=args.max_samples_per_frame or None,
                         target_clip_mm=args.target_clip_mm,
                         tune_edge_thresholds=args.edge_thresholds == "tune")
    model, history = train(frames, calibration, config, seed=args.seed,
                           checkpoint_dir=args.checkpoint_dir, weights_path=args.output,
                           overwrite=args.overwrite)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if int(os.environ.get("RANK", "0")) != 0:
        return 0  # under torchrun, rank 0 writes the summary (and the weights)
    summary = {"weights": str(args.output), "frames": len(frames), "epochs": len(history),
               "world": world,
               "final": history[-1] if history else {}, "history": history,
               "target_clip_mm": model.metadata.get("target_clip_mm"),
               "edge_thresholds": model.metadata.get("edge_thresholds"),
               "target_clip_validation": model.metadata.get("target_clip_validation")}
    args.output.with_suffix(".json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({k: v for k, v in summary.items() if k != "history"}))
    return 0
