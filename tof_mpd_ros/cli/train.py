"""``tof-mpd train``: fit F and G, or the fcn kind (after the intrinsic calibration), on
recordings."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from .output import add_output

MODEL_KINDS = ("patch", "fcn")


def register(subparsers: argparse._SubParsersAction) -> None:
    train = subparsers.add_parser(
        "train", help="train the correction networks (F and G, or the fcn kind)",
        description="Train the correction networks on recordings (or NPZ files) whose frames "
                    "carry a structured-light reference; missing reference pixels are excluded. "
                    "--model patch (default): the paper's range-recovery net F and boundary "
                    "nets G; --model fcn: the fully-convolutional network with a per-pixel "
                    "sigma (trained on random crops, Gaussian likelihood). The intrinsic "
                    "calibration comes from --calibration (a file from `tof-mpd calibrate "
                    "intrinsic`) or is fitted from --calibration-captures. Writes the weights "
                    "file and WEIGHTS.json with the loss history. The paper's schedule (40 "
                    "epochs, batch 500) on MD-Train-sized data takes tens of minutes on 2 "
                    "cores; --epochs and --max-samples-per-frame shorten it. Resumable with "
                    "--checkpoint-dir.")
    train.add_argument("recordings", type=Path, nargs="+", help="training recordings / .npz")
    add_output(train, "weights .npz to write")
    source = train.add_mutually_exclusive_group(required=True)
    source.add_argument("--calibration", type=Path, help="calibration .npz")
    source.add_argument("--calibration-captures", type=Path,
                        help="checkerboard capture recording to fit the calibration from")
    train.add_argument("--model", choices=MODEL_KINDS, default="patch",
                       help="what to train: patch = F and G (default), fcn = the "
                            "fully-convolutional network with per-pixel sigma")
    train.add_argument("--epochs", type=int, help="default 40 (patch) / 60 (fcn)")
    train.add_argument("--batch-size", type=int,
                       help="patches (patch, default 500) or crops (fcn, default 8) per step")
    train.add_argument("--lr", type=float, help="learning rate: of F and G's SGD (patch, "
                       "default 0.05) or of Adam (fcn, default 0.001)")
    train.add_argument("--crop-px", type=int,
                       help="fcn: side of the square training crops, px (default 96)")
    train.add_argument("--max-samples-per-frame", type=int, default=4000,
                       help="patch: pixels drawn afresh per frame and epoch (default 4000; 0 = "
                            "every usable pixel, the paper's ~10 M patches at MD scale)")
    train.add_argument("--target-clip-mm", type=_clip_arg, metavar="MM|auto[,...]",
                       help="truncation T of the target. patch: one value (15 = the paper's), "
                            "'auto' (the training data's 99th percentile of |distortion| away "
                            "from edges, at least 15), or several = one F each on the same "
                            "patches, the best on the validation frames kept (default "
                            "15,30,auto); fcn: one value (default 100)")
    train.add_argument("--edge-thresholds", choices=("tune", "paper"), default="tune",
                       help="patch: G's hysteresis thresholds: chosen on the validation frames "
                            "by the full pipeline's boundary accuracy (default), or the "
                            "paper's 0.3 / 0.6")
    train.add_argument("--val-split", choices=("frame", "session"), default="frame",
                       help="fcn: what the validation frames (and the sigma gain fitted on them) "
                            "hold out: single frames (default), or whole recording sessions, "
                            "i.e. scenes (frames when there is one session); measured in "
                            "docs/method.md section 9: holding scenes out cost accuracy and did "
                            "not calibrate sigma better on unseen scenes")
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
    return load_reference_frames(paths, lambda ref: ref is not None)[0]


def load_reference_frames(paths: list[Path], has_reference: Callable[[Any], bool]
                          ) -> tuple[list, int]:
    """The frames of ``paths`` whose ``reference_mm`` passes ``has_reference``, and how many
    did not.

    Raises:
        InputError: no frame passes.
    """
    from ..errors import InputError
    from ..recordings import iter_frames

    frames = [f for path in paths for f in iter_frames(path)]
    usable = [f for f in frames if has_reference(f.reference_mm)]
    if not usable:
        raise InputError(f"no frame with a reference in {', '.join(map(str, paths))}")
    return usable, len(frames) - len(usable)


def _train_patch(args: argparse.Namespace, frames: list, calibration: Any
                 ) -> tuple[Any, list[dict[str, Any]], dict[str, Any]]:
    """F and G: (model, history, the summary entries of this kind)."""
    from ..training.trainer import TrainConfig, train

    given = {"epochs": args.epochs, "batch_size": args.batch_size, "lr_range": args.lr,
             "lr_boundary": args.lr, "target_clip_mm": args.target_clip_mm}
    config = TrainConfig(max_samples_per_frame=args.max_samples_per_frame or None,
                         tune_edge_thresholds=args.edge_thresholds == "tune",
                         **{k: v for k, v in given.items() if v is not None})
    model, history = train(frames, calibration, config, seed=args.seed,
                           checkpoint_dir=args.checkpoint_dir, weights_path=args.output,
                           overwrite=args.overwrite)
    return model, history, {key: model.metadata.get(key) for key in (
        "target_clip_mm", "edge_thresholds", "target_clip_validation")}


def _train_fcn(args: argparse.Namespace, frames: list, calibration: Any
               ) -> tuple[Any, list[dict[str, Any]], dict[str, Any]]:
    """The fcn kind: (model, history, the summary entries of this kind)."""
    from ..errors import InputError
    from ..evaluation.benchmark.split import session_groups
    from ..training.fcn_trainer import FCNTrainConfig, train_fcn

    clip = args.target_clip_mm
    if clip is not None and (len(clip) != 1 or clip[0] is None):
        raise InputError("--model fcn takes one --target-clip-mm value in mm, got "
                         f"{','.join('auto' if c is None else f'{c:g}' for c in clip)}")
    given = {"epochs": args.epochs, "batch_size": args.batch_size, "lr": args.lr,
             "crop_px": args.crop_px, "target_clip_mm": None if clip is None else clip[0]}
    config = FCNTrainConfig(**{k: v for k, v in given.items() if v is not None})
    groups = (session_groups([f.stamp_ns for f in frames])
              if args.val_split == "session" else None)
    if groups is not None and len(set(groups)) < 2:
        # one session cannot be held out whole without leaving nothing to train on
        logging.getLogger(__name__).info("one recording session: validation frames are "
                                         "held out one by one")
        groups = None
    model, history = train_fcn(frames, calibration, config, seed=args.seed, groups=groups,
                               checkpoint_dir=args.checkpoint_dir, weights_path=args.output,
                               overwrite=args.overwrite)
    return model, history, {"train_config": model.metadata.get("train_config"),
                            "max_sigma_mm": model.max_sigma_mm}


def run_train(args: argparse.Namespace) -> int:
    from ..calibration import load_calibration
    from .calibrate import fit_from_file

    calibration = (load_calibration(args.calibration) if args.calibration is not None
                   else fit_from_file(args.calibration_captures)[0])
    frames = load_training_frames(args.recordings)
    run = _train_fcn if args.model == "fcn" else _train_patch
    model, history, extra = run(args, frames, calibration)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if int(os.environ.get("RANK", "0")) != 0:
        return 0  # under torchrun, rank 0 writes the summary (and the weights)
    summary = {"weights": str(args.output), "model": model.kind, "frames": len(frames),
               "epochs": len(history), "world": world,
               "final": history[-1] if history else {}, "history": history, **extra}
    write_summary(summary, args.output.with_suffix(".json"), sys.stdout)
    return 0


def write_summary(summary: dict, path: Path, stream: TextIO) -> None:
    """Write the whole ``summary`` to ``path`` and the summary without its history to
    ``stream`` — unless the stream is that very file (``tof-mpd train ... -o W.npz >
    W.json``), which would then hold two documents; the file keeps the whole one and a note
    goes to stderr."""
    path.write_text(json.dumps(summary, indent=2))
    if _same_file(stream, path):
        print(f"the summary is in {path} (stdout is that file)", file=sys.stderr)
        return
    print(json.dumps({k: v for k, v in summary.items() if k != "history"}), file=stream)


def _same_file(stream: TextIO, path: Path) -> bool:
    try:
        fd_stat, path_stat = os.fstat(stream.fileno()), path.stat()
    except (OSError, ValueError, AttributeError):
        return False  # no file behind the stream (a pipe, a test's StringIO)
    return (fd_stat.st_dev, fd_stat.st_ino) == (path_stat.st_dev, path_stat.st_ino)
