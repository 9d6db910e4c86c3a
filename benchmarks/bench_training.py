"""Training throughput of F + G with the real trainer, and the projected time for MD-Train.

Runs :func:`tof_mpd_ros.training.train` (SGD, batch 500, F and G together, the trainer's
default threads: 1 torch thread + 1 prefetch thread) for a few epochs on a few recorded frames
and prints:

* data preparation time per frame (calibration, targets, ground-truth edges; once per run);
* patches/s per epoch (the trainer's own figure: wall clock of the epoch loop) and patches per
  CPU-second (process CPU time of the same loop, all threads: least disturbed by load);
* the validation time per epoch;
* the projected time of the paper's schedule on MD-Train (540 frames x ~18.5 k usable patches x
  40 epochs: every usable pixel each epoch, ``max_samples_per_frame=None``) and of the
  subsampled schedule (``--subsample`` pixels per frame and epoch, default the trainer's
  default ``TrainConfig.max_samples_per_frame``), both from the median epoch rate (measured
  with every usable pixel, for long steady epochs), plus preparation and validation (54
  validation frames x 4000 pixels, the defaults).

Frames: ``--frames`` (e.g. ``md_train`` of ``tof-mpd sim dataset --small``) with the calibration
of ``--weights`` (identity without); synthetic box scenes when no recording is given.

Usage: ``python benchmarks/bench_training.py [--n-frames 6] [--epochs 3] [--subsample 4000]
[--json out.json]``. Takes ~1 min on an idle 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.correction.encoding import EncodingConfig
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.training import TrainConfig, train
from tof_mpd_ros.training import trainer as trainer_module
from tof_mpd_ros.training.samples import auto_encoding, prepare_training_data

MD_TRAIN_FRAMES = 540
MD_PATCHES_PER_FRAME = 18_500          # ~10 M patches / 540 frames (the paper)
MD_EPOCHS = 40
TARGET_MIN = 30.0                      # issue 8: F + G on MD-scale data in <= 30 min

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import cpu_peak, machine  # noqa: E402


def synthetic_frames(n: int, h: int = 140, w: int = 180, seed: int = 0) -> list[ToFFrame]:
    """Tilted table + box scenes with a multipath-like bump near the box (learnable)."""
    rng = np.random.default_rng(seed)
    intr = Intrinsics.from_fov(w, h, 60.0)
    out = []
    for _ in range(n):
        xx = np.mgrid[0:h, 0:w][1].astype(np.float64)
        table = rng.uniform(380, 460) + rng.uniform(-0.5, 0.5) * (xx - w / 2)
        box = np.zeros((h, w), bool)
        top, left = rng.integers(10, 60), rng.integers(10, 90)
        box[top:top + 50, left:left + 60] = True
        ref = np.where(box, table - rng.uniform(60, 140), table)
        measured = ref + np.where(box, 0.0, 8.0 * np.exp(-np.abs(xx - left) / 3.0))
        measured += rng.normal(0, 0.5, (h, w))
        amp = 300.0 * (400.0 / ref) ** 2
        out.append(ToFFrame(measured.astype(np.float32), amp.astype(np.float32), intr,
                            reference_mm=ref.astype(np.float32)))
    return out


def load_frames(path: Path | None, weights: Path | None, n: int
                ) -> tuple[list[ToFFrame], IntrinsicCalibration, str]:
    """(frames with a reference, calibration, description)."""
    if path is not None:
        from tof_mpd_ros.recordings import RecordingReader

        frames = [f for f in RecordingReader(path).frames() if f.reference_mm is not None][:n]
        if weights is not None:
            from tof_mpd_ros.correction.weights import load_weights

            calib = load_weights(weights).calibration
            what = f"calibration of {weights}"
        else:
            calib = IntrinsicCalibration.identity(*frames[0].range_mm.shape)
            what = "identity calibration"
        if calib.shape == frames[0].range_mm.shape:
            return frames, calib, f"{len(frames)} frames of {path}, {what}"
    frames = synthetic_frames(n)
    return (frames, IntrinsicCalibration.identity(*frames[0].range_mm.shape),
            f"{n} synthetic frames (no --frames given), identity calibration")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=Path, help="recording (default: synthetic frames)")
    parser.add_argument("--weights", type=Path, help="its calibration (default: identity)")
    parser.add_argument("--n-frames", type=int, default=6)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--subsample", type=int,
                        default=TrainConfig().max_samples_per_frame or MD_PATCHES_PER_FRAME,
                        help="pixels per frame and epoch of the subsampled projection "
                             "(default: the trainer's default max_samples_per_frame)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()

    mach = machine()
    frames, calib, source = load_frames(args.frames, args.weights, args.n_frames)
    # Every usable pixel each epoch: the most patches per epoch for a steady rate.
    cfg = TrainConfig(epochs=args.epochs, val_fraction=1.0 / len(frames),
                      max_samples_per_frame=None)
    print(f"machine: {mach['cpu']}, {mach['cpus']} CPUs, torch {mach['torch']}; trainer "
          f"threads: {cfg.num_threads} torch + {'1 prefetch' if cfg.prefetch else 'no prefetch'}")
    print(f"load average at start (1/5/15 min): {mach['load_average_start']}"
          + ("  ** machine busy: wall times are inflated **"
             if mach["load_average_start"][0] > 0.5 * (mach["cpus"] or 1) else ""))
    print(f"inputs: {source}; {args.epochs} epochs, batch {cfg.batch_size}, all usable pixels")

    # Data preparation alone (the trainer does it once per run; 2 warm-ups for OpenCV/torch).
    t0 = time.perf_counter()
    data = prepare_training_data(frames, calib, auto_encoding(frames, calib, EncodingConfig()))
    prep_s = time.perf_counter() - t0
    usable_per_frame = float(data.usable.reshape(len(frames), -1).sum(1).float().mean())

    # Wrap the epoch loop (for its process CPU time) and the validation (for its wall time).
    epoch_cpu: list[float] = []
    val_wall: list[float] = []
    run_epoch, validate = trainer_module._run_epoch, trainer_module._validate

    def timed_epoch(*a: Any, **k: Any) -> dict[str, float]:
        c0 = time.process_time()
        out = run_epoch(*a, **k)
        epoch_cpu.append(time.process_time() - c0)
        return out

    def timed_validate(*a: Any, **k: Any) -> dict[str, float]:
        t0 = time.perf_counter()
        out = validate(*a, **k)
        val_wall.append(time.perf_counter() - t0)
        return out

    trainer_module._run_epoch, trainer_module._validate = timed_epoch, timed_validate
    try:
        t0 = time.perf_counter()
        _, history = train(frames, calib, cfg, seed=0, progress=False)
        total_s = time.perf_counter() - t0
    finally:
        trainer_module._run_epoch, trainer_module._validate = run_epoch, validate
    rates = [h["patches_per_s"] for h in history]
    cpu_rates = [h["patches"] / c for h, c in zip(history, epoch_cpu, strict=True)]
    rate = statistics.median(rates)
    cpu_rate = statistics.median(cpu_rates)
    val_s = statistics.median(val_wall) if val_wall else 0.0
    n_val = max(1, round(len(frames) * cfg.val_fraction))
    val_pixels = n_val * min(cfg.val_samples_per_frame or usable_per_frame, usable_per_frame)

    print(f"data preparation: {1e3 * prep_s / len(frames):.0f} ms per frame; "
          f"{usable_per_frame:.0f} usable pixels per frame")
    for h, c in zip(history, cpu_rates, strict=True):
        print(f"epoch {h['epoch']}: {h['patches']} patches in {h['seconds']:.1f} s = "
              f"{h['patches_per_s']:.0f} patches/s wall, {c:.0f} patches per CPU-second, "
              f"loss F {h['loss_range']:.4f} G {h['loss_boundary']:.4f}")
    print(f"validation: {val_s:.2f} s per epoch for {val_pixels:.0f} pixels; whole train() call "
          f"{total_s:.1f} s")

    # FLOPs per patch of a training step: forward 2 x MACs, backward ~2x that (grad w.r.t.
    # inputs of every layer but the first, and w.r.t. the weights).
    macs = (280 * 40 + 40 * 10 + 10 * 10 + 10) + 4 * (240 * 40 + 40 * 20 + 20 * 2)
    peak = cpu_peak(1)
    gflops = 6 * macs * rate / 1e9
    print(f"SGD step arithmetic: ~{6 * macs / 1e3:.0f} kFLOP per patch (forward + backward) -> "
          f"{gflops:.1f} GFLOP/s wall = {100 * gflops / peak['peak_gflops']:.1f} % of one "
          f"core's nominal peak ({peak['peak_gflops']} GFLOP/s)")

    projections = {}
    default = TrainConfig()
    md_val_frames = round(MD_TRAIN_FRAMES * default.val_fraction)
    md_val_pixels = md_val_frames * (default.val_samples_per_frame or MD_PATCHES_PER_FRAME)
    val_rate = val_pixels / val_s if val_s > 0 else math.inf
    sub_name = (f"{args.subsample} pixels/frame/epoch"
                + (" (trainer default)" if args.subsample == default.max_samples_per_frame
                   else ""))
    for name, per_frame in (("every usable pixel, ~18.5 k/frame (the paper)",
                             MD_PATCHES_PER_FRAME),
                            (sub_name, min(args.subsample, MD_PATCHES_PER_FRAME))):
        n_train = MD_TRAIN_FRAMES - md_val_frames
        patches = n_train * per_frame * MD_EPOCHS
        prep = prep_s / len(frames) * MD_TRAIN_FRAMES
        val = MD_EPOCHS * md_val_pixels / val_rate
        wall = prep + patches / rate + val
        cpu_based = prep + patches / cpu_rate + val
        projections[name] = {"patches": patches, "minutes_wall_rate": wall / 60,
                             "minutes_cpu_rate": cpu_based / 60, "prep_minutes": prep / 60,
                             "validation_minutes": val / 60}
        verdict = "met" if wall / 60 <= TARGET_MIN else "NOT met"
        print(f"MD-Train projection, {name}: {patches / 1e6:.0f} M patch steps over "
              f"{n_train} training frames x {MD_EPOCHS} epochs -> {wall / 60:.1f} min at the "
              f"wall rate ({cpu_based / 60:.1f} min at the CPU-second rate, i.e. with a core to "
              f"itself); prep "
              f"{prep / 60:.1f} min, validation {val / 60:.1f} min; target {TARGET_MIN:.0f} min "
              f"{verdict}")
    end_load = [round(x, 2) for x in os.getloadavg()]
    print(f"load average at end: {end_load}")
    if args.json:
        result = {"machine": {**mach, "load_average_end": end_load}, "inputs": source,
                  "config": {"epochs": args.epochs, "batch_size": cfg.batch_size,
                             "num_threads": cfg.num_threads, "prefetch": cfg.prefetch},
                  "prep_ms_per_frame": 1e3 * prep_s / len(frames),
                  "usable_pixels_per_frame": usable_per_frame,
                  "patches_per_s_wall": rate, "patches_per_cpu_second": cpu_rate,
                  "validation_s_per_epoch": val_s, "history": history,
                  "torch_threads_after": torch.get_num_threads(), "projections": projections}
        args.json.write_text(json.dumps(result, indent=2, default=float), encoding="utf-8")
        print(f"wrote {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
