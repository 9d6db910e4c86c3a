"""Learning curves of the paper's method (issue 16): how the test accuracy moves with the number
of training frames, the epochs and the samples per frame and epoch.

Trains F and G with the trainer's defaults (truncation and G thresholds chosen on validation
frames) on a recording, varying one knob at a time from a base setting, and evaluates every
model on the test recording (F alone and the full pipeline, within 5 mm, whole image and
boundary region). Training frames are taken whole scenes at a time (the recording's order),
so the validation split never shares a scene with training.

Usage: ``python benchmarks/learning_curves.py TRAIN_REC TEST_REC CALIB.npz OUT.json
[--frames 36,120] [--epochs 10,20,40] [--samples 1000,2500,5000] [--base 120,20,2500]``.
Prints a table with the CPU; each run takes about a minute per 100 frames and 20 epochs on 2
cores.
"""

from __future__ import annotations

import argparse
import json
import os
import time

from tof_mpd_ros.machine import cpu_model, set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

from tof_mpd_ros.calibration import load_calibration
from tof_mpd_ros.evaluation.components import evaluate_model
from tof_mpd_ros.recordings import iter_frames
from tof_mpd_ros.training import TrainConfig, train


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x]


def run_one(frames: list, test: list, calibration, n_frames: int, epochs: int,
            samples: int) -> dict:
    t0 = time.perf_counter()
    model, history = train(frames[:n_frames], calibration,
                           TrainConfig(epochs=epochs, max_samples_per_frame=samples), seed=0,
                           progress=False)
    seconds = time.perf_counter() - t0
    summary = evaluate_model(model, test, n_examples=0).summary(5.0)
    return {"frames": n_frames, "epochs": epochs, "samples": samples,
            "train_s": round(seconds, 1), "target_clip_mm": model.range_net.target_clip_mm,
            "F": [summary["F"]["whole"], summary["F"]["boundary"]],
            "full": [summary["full"]["whole"], summary["full"]["boundary"]],
            "val_within_5mm": history[-1].get("val_within_5mm")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("train")
    parser.add_argument("test")
    parser.add_argument("calibration")
    parser.add_argument("out")
    parser.add_argument("--frames", type=_ints, default=[36, 120])
    parser.add_argument("--epochs", type=_ints, default=[10, 40])
    parser.add_argument("--samples", type=_ints, default=[1000, 5000])
    parser.add_argument("--base", type=_ints, default=[120, 20, 2500],
                        help="frames, epochs, samples of the base setting")
    args = parser.parse_args()
    frames = [f for f in iter_frames(args.train) if f.reference_mm is not None]
    test = [f for f in iter_frames(args.test) if f.reference_mm is not None]
    calibration = load_calibration(args.calibration)
    n0, e0, s0 = args.base
    settings = [(n0, e0, s0)] + [(n, e0, s0) for n in args.frames] + \
        [(n0, e, s0) for e in args.epochs] + [(n0, e0, s) for s in args.samples]
    rows = []
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores; {len(frames)} training frames, "
          f"{len(test)} test frames")
    print("frames epochs samples    T   F whole/bnd     full whole/bnd   train s")
    for n, e, s in dict.fromkeys(settings):
        row = run_one(frames, test, calibration, min(n, len(frames)), e, s)
        rows.append(row)
        print(f"{row['frames']:6d} {e:6d} {s:7d} {row['target_clip_mm']:4.0f}   "
              f"{100 * row['F'][0]:5.1f}/{100 * row['F'][1]:5.1f}   "
              f"{100 * row['full'][0]:5.1f}/{100 * row['full'][1]:5.1f}   {row['train_s']:7.1f}",
              flush=True)
    with open(args.out, "w", encoding="utf-8") as f:
        json.dump({"machine": cpu_model(), "rows": rows}, f, indent=2)


if __name__ == "__main__":
    main()
