"""``tof-mpd demo``: the whole pipeline on the embedded simulated cell, end to end."""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

from .output import add_output

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    demo = subparsers.add_parser(
        "demo", help="simulate a small cell, correct it and evaluate against baselines",
        description="End to end on the simulated cell: render a small MD-Train/MD-Test-like "
                    "dataset with checkerboard captures (OUT/data), fit the intrinsic "
                    "calibration, use the shipped weights (or train F and G with --train), "
                    "correct the test frames and benchmark them against the six baselines "
                    "(`tof-mpd benchmark --quick`: small grids tuned on held-out training "
                    "scenes). Writes OUT/report/index.html and OUT/report/results.json and "
                    "prints a summary. "
                    "About 5-15 minutes on 2 cores.")
    add_output(demo, "output directory (default ./demo_out)", default=Path("demo_out"))
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

    start = _step("benchmarking: baselines tuned on held-out training scenes, every method on "
                  "the test frames")
    summary = _evaluate(model, data, out / "report")
    timings["evaluate_s"] = time.perf_counter() - start
    summary.update({"weights": weights_used, "timings_s": {k: round(v, 1)
                                                            for k, v in timings.items()}})
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    _print_summary(summary, out)
    return 0


def _evaluate(model, data: Path, report_dir: Path) -> dict:
    """``tof-mpd benchmark --quick`` on the simulated MD-Train / MD-Test: every baseline tuned
    on held-out training scenes, then every method on the test frames; writes the report."""
    from ..evaluation.benchmark import BenchmarkConfig, run_benchmark
    from ..evaluation.report import write_benchmark_report
    from ..recordings import RecordingReader
    from .correct import fit_to_frames

    with RecordingReader(data / "md_train") as reader:
        train = list(reader.frames())
    if train:  # the shipped weights cover the whole sensor; the demo's cell records 180x140
        model = fit_to_frames(model, train[0].range_mm.shape)
    with RecordingReader(data / "md_test") as reader:
        result = run_benchmark(model, train, reader.frames(),
                               BenchmarkConfig(quick=True, max_val_frames=4),
                               on_stage=lambda msg: print(f"    {msg}", flush=True))
    write_benchmark_report(result, report_dir, title="tof_mpd_ros demo (simulated cell)",
                           extra={"train_recordings": [str(data / "md_train")],
                                  "test_recordings": [str(data / "md_test")]})
    table = result.table()
    edges = result.components.edges
    return {"n_test_frames": result.n_frames, "proposed_method": result.proposed,
            "summary_5mm": {m: {"whole": r["whole_5mm"], "boundary": r["boundary_5mm"],
                                "mae_mm": r["mae_mm"], "ms_per_frame": r["ms_per_frame"]}
                            for m, r in table.items()},
            "ranking_5mm": result.comparison["ranking_whole"],
            "ranking_statement": result.comparison["statement"],
            "differences_from_paper": [f for f in result.comparison["findings"]
                                       if not f["agrees"]],
            "targets": result.comparison["targets"],
            "relative_improvement_5mm": _relative(table["raw"]["whole_5mm"],
                                                  table[result.proposed]["whole_5mm"]),
            "edges_max_f1": {k: c.max_f1 for k, c in edges.items()},
            "ms_per_frame": table[result.proposed]["ms_per_frame"],
            "benchmark_s": round(result.timings["total_s"], 1)}


def _relative(before: float, after: float) -> float | None:
    return (after - before) / before if before > 0 else None


def _print_summary(summary: dict, out: Path) -> None:
    """The summary on the terminal (the package template ``templates/demo_summary.txt``)."""
    from ..templates import render

    print(render("demo_summary.txt", s=summary, report=out / "report" / "index.html"))
