"""``tof-mpd demo``: the whole pipeline on the embedded simulated cell, end to end."""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    demo = subparsers.add_parser(
        "demo", help="simulate a small cell, correct it and evaluate against baselines",
        description="End to end on the simulated cell: render a small MD-Train/MD-Test-like "
                    "dataset with checkerboard captures (OUT/data), fit the intrinsic "
                    "calibration, use the shipped weights (or train F and G with --train), "
                    "correct the test frames and evaluate them against the baselines. Writes "
                    "OUT/report/index.html and OUT/report/results.json and prints a summary. "
                    "About 5-15 minutes on 2 cores.")
    demo.add_argument("-o", "--output", type=Path, default=Path("demo_out"),
                      help="output directory (default ./demo_out)")
    demo.add_argument("--train", action="store_true",
                      help="train F and G on the simulated data instead of using the shipped "
                           "weights (adds a few minutes)")
    demo.add_argument("--epochs", type=int, default=10, help="epochs with --train")
    demo.add_argument("--seed", type=int, default=1, help="seed of the simulated scenes")
    demo.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    demo.set_defaults(func=run_demo)


def _step(message: str) -> float:
    print(f"==> {message}", flush=True)
    return time.perf_counter()


def run_demo(args: argparse.Namespace) -> int:
    from ..correction.default_weights import default_weights_path
    from ..correction.weights import load_weights, save_weights
    from ..recordings import RecordingReader
    from ..sim.dataset import DatasetSpec, generate_dataset
    from ..training.trainer import TrainConfig, train
    from .calibrate import fit_from_file

    out = args.output
    data = out / "data"
    timings: dict[str, float] = {}
    start = _step(f"simulating a small cell into {data}")
    if not (data / "dataset.json").is_file():
        generate_dataset(data, DatasetSpec.small(seed=args.seed), workers=args.workers)
    timings["simulate_s"] = time.perf_counter() - start

    if args.train:
        start = _step("fitting the per-pixel calibration on the checkerboard captures")
        calibration, _ = fit_from_file(data / "calibration")
        start = _step(f"training F and G ({args.epochs} epochs)")
        with RecordingReader(data / "md_train") as reader:
            frames = list(reader.frames())
        model, _ = train(frames, calibration, TrainConfig(epochs=args.epochs), seed=args.seed)
        save_weights(out / "weights.npz", model, overwrite=True)
        weights_used = f"trained here ({args.epochs} epochs on {len(frames)} frames)"
        timings["train_s"] = time.perf_counter() - start
    else:
        model = load_weights(default_weights_path())
        weights_used = f"shipped ({default_weights_path().name})"

    start = _step("correcting and evaluating the test frames")
    summary = _evaluate(model, data, out / "report")
    timings["evaluate_s"] = time.perf_counter() - start
    summary.update({"weights": weights_used, "timings_s": {k: round(v, 1)
                                                            for k, v in timings.items()}})
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    _print_summary(summary, out)
    return 0


def _evaluate(model, data: Path, report_dir: Path) -> dict:
    from ..evaluation.components import evaluate_model
    from ..evaluation.report import write_component_report
    from ..recordings import RecordingReader

    with RecordingReader(data / "md_test") as reader:
        evaluation = evaluate_model(model, reader.frames())
    write_component_report(evaluation, report_dir, title="tof_mpd_ros demo (simulated cell)")
    result = evaluation.to_dict()
    return {"n_test_frames": evaluation.n_frames, "summary_5mm": result["summary_5mm"],
            "relative_improvement_5mm": result["relative_improvement_5mm"],
            "edges_max_f1": {k: c.max_f1 for k, c in evaluation.edges.items()},
            "ms_per_frame": 1e3 * evaluation.seconds_per_frame}


def _print_summary(summary: dict, out: Path) -> None:
    print(f"\nweights: {summary['weights']}; {summary['n_test_frames']} test frames; "
          f"{summary['ms_per_frame']:.0f} ms per frame")
    print(f"{'method':<14}{'<5 mm whole':>13}{'<5 mm boundary':>16}{'MAE mm':>9}")
    for name, row in summary["summary_5mm"].items():
        print(f"{name:<14}{row['whole']:>13.1%}{row['boundary']:>16.1%}{row['mae_mm']:>9.2f}")
    edges = ", ".join(f"{k} {v:.3f}" for k, v in summary["edges_max_f1"].items())
    print(f"edge max F1: {edges}")
    print(f"report: {out / 'report' / 'index.html'}")
