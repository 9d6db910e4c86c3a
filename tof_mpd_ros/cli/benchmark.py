"""``tof-mpd benchmark``: raw, calibrated, the six baselines, F alone and the full method (or a
model of the fcn kind, as ``fcn``) on the same test recordings, with the paper's figures, a
ranking and an HTML report."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .output import add_output


def register(subparsers: argparse._SubParsersAction) -> None:
    bench = subparsers.add_parser(
        "benchmark", help="the paper's comparison: every baseline vs the method, with a report",
        description="Reads training and test recordings / NPZ files with references and a "
                    "weights file. Calibrates every frame with the weights' intrinsic "
                    "calibration; fits RF-WF and RFD on the training frames minus a held-out "
                    "validation split (whole capture sessions) and grid-searches every "
                    "baseline (JBF, WMF, RF-WF, RFD, TV, PD) there; then runs raw, calibrated, "
                    "each baseline, F alone and the full method on the same test frames (weights "
                    "of the fcn kind: the network as method 'fcn' instead of F alone and the "
                    "full method). "
                    "Writes OUT/results.json (every number: curves, 2/5/10 mm table, MAE, "
                    "runtime per frame, grids searched and chosen, ranking vs the paper), "
                    "accuracy curves, qualitative panels, range profiles, edge P/R and "
                    "component-analysis PNGs and OUT/index.html. Time: about 1-2 s per test "
                    "frame plus tuning — minutes with --quick on a small dataset; the full "
                    "grids refit RFD per max_depth (several minutes each on 2 cores).")
    bench.add_argument("--train", type=Path, nargs="+", required=True, metavar="TRAIN",
                       help="training recordings / .npz (with references)")
    bench.add_argument("--test", type=Path, nargs="+", required=True, metavar="TEST",
                       help="test recordings / .npz (frames without a reference are skipped)")
    add_output(bench, "output directory")
    bench.add_argument("--weights", type=Path, help="weights file (default: shipped)")
    bench.add_argument("--quick", action="store_true",
                       help="small grids and forests (the demo's setting)")
    bench.add_argument("--methods", default=None,
                       help="comma-separated subset of the baselines (default: all six)")
    bench.add_argument("--val-fraction", type=float, default=0.25,
                       help="share of the training frames held out for the grid search")
    bench.add_argument("--max-val-frames", type=int, default=None,
                       help="at most this many validation frames (default: all; 4 with "
                            "--quick)")
    bench.add_argument("--examples", type=int, default=3,
                       help="test frames shown in the qualitative panels and profiles")
    bench.add_argument("--no-progress", action="store_true", help="no progress bars")
    bench.set_defaults(func=run_benchmark_command)


def run_benchmark_command(args: argparse.Namespace) -> int:
    from ..errors import InputError
    from ..evaluation.benchmark import BASELINE_NAMES, BenchmarkConfig, default_grids
    from ..evaluation.benchmark import run_benchmark as run
    from ..evaluation.report import write_benchmark_report
    from ..recordings import iter_frames
    from .correct import fit_to_frames, load_model

    model = load_model(args.weights)
    grids = default_grids(model, quick=args.quick)
    if args.methods:
        wanted = [m.strip() for m in args.methods.split(",") if m.strip()]
        unknown = sorted(set(wanted) - set(BASELINE_NAMES))
        if unknown:
            raise InputError(f"--methods: unknown {unknown}; choose from {list(BASELINE_NAMES)}")
        grids = {m: g for m, g in grids.items() if m in wanted}
    max_val = args.max_val_frames if args.max_val_frames is not None else (
        4 if args.quick else None)
    config = BenchmarkConfig(grids=grids, quick=args.quick, val_fraction=args.val_fraction,
                             max_val_frames=max_val, n_examples=args.examples,
                             progress=not args.no_progress)
    train, sources = [], []
    for i, path in enumerate(args.train):
        for frame in iter_frames(path):
            train.append(frame)
            sources.append(i)
    test = (f for path in args.test for f in iter_frames(path))
    if train:
        model = fit_to_frames(model, train[0].range_mm.shape)
    result = run(model, train, test, config, train_sources=sources,
                 on_stage=lambda msg: print(f"==> {msg}", flush=True))
    write_benchmark_report(result, args.output, extra={
        "train_recordings": [str(p) for p in args.train],
        "test_recordings": [str(p) for p in args.test],
        "weights": str(args.weights or "shipped")})
    table = result.table()
    print(json.dumps({"output": str(args.output), "model_kind": result.kind,
                      "n_test_frames": result.n_frames,
                      "ranking_5mm_whole": result.comparison["ranking_whole"],
                      "targets": result.comparison["targets"],
                      "within_5mm": {m: {"whole": round(r["whole_5mm"], 4),
                                         "boundary": round(r["boundary_5mm"], 4),
                                         "mae_mm": round(r["mae_mm"], 3),
                                         "ms_per_frame": round(r["ms_per_frame"], 1)}
                                     for m, r in table.items()},
                      "seconds": round(result.timings["total_s"], 1)}, indent=1))
    return 0
