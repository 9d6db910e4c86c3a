"""``tof-mpd mismatch`` and ``tof-mpd mismatch-benchmark``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ..errors import InputError, MismatchError
from .output import add_output


def register(subparsers: Any) -> None:
    """Add the ``mismatch`` and ``mismatch-benchmark`` commands."""
    p = subparsers.add_parser(
        "mismatch", help="locate and name the physics a simulator leaves out of a recording",
        description="Reads REAL (a recording directory / .mcap, or an interchange .npz; every "
                    "frame needs its reference range image) and optionally a simulator config "
                    "(JSON, ToFConfig.to_dict; default: the nominal cell). Predicts every frame "
                    "from its reference, locates where the residual exceeds the noise model, "
                    "fits every candidate effect on alternate frames and scores it on the "
                    "others, and writes into OUT: report.json (selected, ranking, parameters, "
                    "rmse_before_mm, rmse_after_mm, localisation), fitted_config.json, PNG "
                    "plots and index.html. Takes about 2-5 min for 6 frames of 96x72 (one-shot, "
                    "two cores; the light transport of each frame's world about half of it), "
                    "a few minutes for the 160x144 Azure Kinect frame.",
        epilog="example: tof-mpd mismatch real.npz -o mismatch_report/")
    p.add_argument("real", help="recording directory, .mcap or .npz with references, or the "
                                "Azure Kinect sample folder or the ADI ToF folder (plane-fit "
                                "reference)")
    p.add_argument("--sim-config", help="simulator config JSON to diagnose (default nominal)")
    p.add_argument("--workflow", choices=("one-shot", "monitor"),
                   help="one-shot: fit the camera's profile first, then name the physics "
                        "on top of it (default without --sim-config); monitor: name what "
                        "changed since the run that wrote --sim-config (default with it)")
    p.add_argument("--mode", type=int, default=3,
                   help="camera mode of an ADI ToF folder (3, long range; 2, short range)")
    add_output(p, "output directory (created)")
    p.add_argument("--max-effects", type=int, default=2, help="most effects to select (2)")
    p.add_argument("--reference-noise-mm", type=float, default=0.5,
                   help="std of the reference range in mm (0.5, structured light)")
    p.set_defaults(func=_mismatch)

    b = subparsers.add_parser(
        "mismatch-benchmark", help="score the mismatch tool on concealed-effect cases",
        description="Generates N 'real' 6-frame sweeps of random scenes in the simulated cell "
                    "(ray-cast, supersampled, structured-light reference), each carrying a "
                    "random concealed effect with random parameters, nothing (controls, 20%%) "
                    "or two effects (15%%); runs the tool blind on each .npz; writes OUT/"
                    "cases/*.npz, OUT/labels.json (hidden truth, read only for scoring), "
                    "OUT/results/*.json, OUT/benchmark.json and OUT/benchmark.txt (top-1, false "
                    "alarms, parameter error, RMSE reduction). Takes about 4-6 min per case on "
                    "two busy cores (generation ~15 s, the tool's analysis, then the oracle's: "
                    "the same frames predicted with the true effects).")
    b.add_argument("--cases", type=int, default=8, help="number of cases (8)")
    b.add_argument("--seed", type=int, default=0, help="seed of the whole benchmark (0)")
    b.add_argument("--frames", type=int, default=6, help="frames per case (6)")
    b.add_argument("--base", choices=("nominal", "profile", "pathtrace"), default="nominal",
                   help="the camera the concealed effects sit on: the nominal cell, a random "
                        "camera profile per case (noise, level, pixel pattern, wiggle, "
                        "amplitude bias and units, modulation frequency), or such a camera "
                        "with path-traced light transport ([pathtrace] extra)")
    b.add_argument("--resume", action="store_true",
                   help="keep the cases an interrupted run with the same --cases, --seed and "
                        "--base answered in OUT, run the others")
    b.add_argument("--shard", metavar="I/N", default=None,
                   help="run only every N-th case of the plan from the I-th (0-based), into "
                        "OUT; N such runs in their own directories share one benchmark, "
                        "scored together with --merge")
    b.add_argument("--merge", nargs="+", metavar="RUN_DIR",
                   help="instead of running: score finished benchmark directories together")
    add_output(b, "output directory (created)")
    b.set_defaults(func=_benchmark)


def _load_config(path: str | None) -> Any:
    from ..sim.tof import ToFConfig
    if path is None:
        return None
    try:
        return ToFConfig.from_dict(json.loads(Path(path).read_text()))
    except (OSError, ValueError) as err:
        raise MismatchError(f"{path}: cannot read the simulator config: {err}") from err


def _mismatch(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..mismatch import analyse, load_frames, write_report
    from ..mismatch.fit import CANDIDATES
    from ..mismatch.realdata import (
        adi_config,
        adi_frame,
        azure_kinect_config,
        is_adi_dir,
        is_azure_kinect_dir,
    )

    # the arguments first: a wrong combination costs no reading of the recording
    config = _load_config(args.sim_config)
    monitor = (config is not None) if args.workflow is None else args.workflow == "monitor"
    if monitor and config is None:
        raise MismatchError("--workflow monitor needs --sim-config (an earlier run's "
                            "fitted_config.json)")
    adi = is_adi_dir(args.real)
    frames = [adi_frame(args.real, args.mode)] if adi else load_frames(args.real)
    # the stand-ins of the shared real cameras are where a one-shot run starts from
    if config is None and is_azure_kinect_dir(args.real):
        config = azure_kinect_config()
    if config is None and adi:
        config = adi_config()
    total = len(CANDIDATES) * max(args.max_effects, 1)
    with tqdm(total=total, desc="fitting candidates", file=sys.stderr) as bar:
        analysis = analyse(frames, config, max_effects=args.max_effects,
                           reference_noise_mm=args.reference_noise_mm,
                           progress=lambda name: bar.update(1), monitor=monitor)
    paths = write_report(analysis, args.output)
    summary = {"selected": analysis.selected, "parameters": analysis.parameters,
               "rmse_before_mm": analysis.metrics["rmse_before_mm"],
               "rmse_after_mm": analysis.metrics["rmse_after_mm"],
               "report": str(paths["report"]), "html": str(paths["html"])}
    print(json.dumps(summary, indent=2))
    return 0


def _benchmark(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..mismatch import run_benchmark
    from ..mismatch.benchmark import merge_runs, text_table

    if args.merge:
        doc = merge_runs(args.merge, args.output)
        print(text_table(doc["cases"], doc["summary"]))
        print(json.dumps(doc["summary"], indent=2))
        return 0
    from ..sim.dataset import Shard

    try:
        shard = Shard() if args.shard is None else Shard.parse(args.shard)
    except ValueError as err:
        raise InputError(f"--shard: {err}") from err
    with tqdm(total=len(shard.take(list(range(args.cases)))), desc="benchmark cases",
              file=sys.stderr) as bar:
        doc = run_benchmark(args.cases, args.seed, args.output, n_frames=args.frames,
                            base=args.base, resume=args.resume, shard=shard,
                            progress=lambda msg: bar.update(1))
    print(text_table(doc["cases"], doc["summary"]))
    print(json.dumps(doc["summary"], indent=2))
    return 0
