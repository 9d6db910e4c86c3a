"""``tof-mpd evaluate``: the paper's metrics and component analysis on test recordings."""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

from .output import add_output

# correction.pipeline.PRECISIONS, spelt out so that the CLI starts without torch (a test holds
# the two equal)
PRECISIONS = ("float32", "bfloat16", "int8")


def register(subparsers: argparse._SubParsersAction) -> None:
    evaluate = subparsers.add_parser(
        "evaluate", help="accuracy curves, component analysis and edge P/R on test data",
        description="Evaluate the correction on recordings / NPZ files with references: "
                    "fraction of pixels within 1..20 mm (whole image and within 5 px of "
                    "boundaries), MAE, RMSE for raw, calibrated, F alone, geodesic with G alone "
                    "and the full method; G's edge precision/recall against Canny on the raw ToF "
                    "image. Weights of the fcn kind: raw, calibrated and fcn, no edge numbers "
                    "(it has no G), and the 1/2/3-sigma coverage of its predicted sigma. Writes "
                    "OUT/results.json, PNG plots and OUT/index.html. About 0.1-0.3 s per frame.")
    evaluate.add_argument("recordings", type=Path, nargs="+", help="test recordings / .npz")
    add_output(evaluate, "output directory")
    evaluate.add_argument("--weights", type=Path, help="weights file (default: shipped)")
    evaluate.add_argument("--precision", choices=PRECISIONS, default="float32",
                          help="the networks' arithmetic (default float32; bfloat16 either "
                               "kind, int8 the patch kind: measure what it costs on your data)")
    evaluate.set_defaults(func=run_evaluate)


def run_evaluate(args: argparse.Namespace) -> int:
    from ..evaluation.components import evaluate_model
    from ..evaluation.report import write_component_report
    from ..recordings import iter_frames
    from .correct import fit_to_frames, load_model

    model = load_model(args.weights)
    frames = (f for path in args.recordings for f in iter_frames(path))
    first = next(frames, None)
    if first is not None:
        model = fit_to_frames(model, first.range_mm.shape)
        frames = itertools.chain([first], frames)
    evaluation = evaluate_model(model, frames, precision=args.precision)
    write_component_report(evaluation, args.output,
                           extra={"recordings": [str(p) for p in args.recordings],
                                  "weights": str(args.weights or "shipped"),
                                  "precision": args.precision})
    print(json.dumps({"output": str(args.output), "model_kind": evaluation.kind,
                      "n_frames": evaluation.n_frames, "summary_5mm": evaluation.summary(5.0),
                      "edges_max_f1": {k: c.max_f1 for k, c in evaluation.edges.items()},
                      "sigma_coverage": evaluation.coverage or None}))
    return 0
