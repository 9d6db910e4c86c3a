"""The paper's method on a camera it was not built on (issue 16), end to end as a user runs it.

The "new camera" is the path tracer (Mitsuba 3 + mitransient, the ``[pathtrace]`` extra): true
multi-bounce multipath, glossy, metal and translucent parts, 50 MHz instead of the cell's 30,
about 1 mm of noise on a mid-grey surface at 300 mm, and none of the cell's systematic errors.
Its scenes come from their own seed. The workflow is the user's:

1. ``tof-mpd sim dataset --renderer pathtrace`` equivalent (here with the new camera's config):
   train scenes x views, test scenes x views, checkerboard captures;
2. ``tof-mpd calibrate intrinsic`` on the checkerboard captures;
3. ``tof-mpd train`` with each variant below (same seed, same frames) and ``tof-mpd evaluate``
   of it on the test frames (every stage, per region by distance to the edges, G's edges);
4. ``tof-mpd benchmark`` of the first variant (``default``: ``tof-mpd train`` with nothing
   but the data) against the six baselines on the same frames (the baselines do not depend on
   the variant).

Variants (the ablations issue 16 asks for): ``paper`` (T = 15 mm, G thresholds 0.3 / 0.6),
``auto-T`` (T from the training data alone), ``default`` (the trainer's defaults: T chosen on
the validation frames among 15, 30 and the data's own, G's thresholds chosen there too).
Every number lands in OUT/summary.json; the table is printed with the CPU.

Usage: ``python benchmarks/bench_new_camera.py OUT [--train-scenes 30 --test-scenes 8 --views 4
--calibration 60 --spp 64 --epochs E --samples S --quick]`` (the training schedule defaults to
``tof-mpd train``'s). Rendering takes a few seconds
per frame on 2 cores; ``--reuse`` keeps an existing OUT/data.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

from tof_mpd_ros.machine import cpu_model, set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

from tof_mpd_ros.cli.main import main as cli
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.dataset import DatasetSpec, generate_dataset
from tof_mpd_ros.sim.tof import ToFConfig

VARIANTS = {
    "default": [],  # tof-mpd train as a user runs it: T and G thresholds chosen on validation
    "paper": ["--target-clip-mm", "15", "--edge-thresholds", "paper"],
    "auto-T": ["--target-clip-mm", "auto", "--edge-thresholds", "paper"],
}


def new_camera() -> ToFConfig:
    """50 MHz, ~1 mm noise at 300 mm on albedo 0.5, no systematic errors (wiggling, amplitude
    bias, fixed-pattern offsets off); multipath and pixel footprint come from the path tracer."""
    cfg = ToFConfig.nominal()
    for name in ("wiggling", "amplitude_bias", "pixel_offset"):
        cfg = cfg.with_effect(name, enabled=False)
    cfg = cfg.with_effect("noise", read_std=0.2, shot_gain=0.0015)
    return ToFConfig.from_dict({**cfg.to_dict(), "mod_freq_hz": 50e6})


def render(out: Path, args: argparse.Namespace) -> dict:
    spec = DatasetSpec(n_train_scenes=args.train_scenes, n_test_scenes=args.test_scenes,
                       views_per_scene=args.views, n_calibration=args.calibration,
                       seed=args.seed)
    cell = SimCell(tof=new_camera(), renderer="pathtrace", pathtrace_spp=args.spp)
    return generate_dataset(out, spec, workers=args.workers, cell=cell)


def print_table(name: str, table: dict) -> None:
    print(f"== {name}: within 5 mm, whole / boundary")
    for method, row in table.items():
        print(f"  {method:12s} {100 * row['whole_5mm']:5.1f} / {100 * row['boundary_5mm']:5.1f} %")


def print_stages(name: str, summary: dict) -> None:
    print(f"== {name}: within 5 mm, whole / boundary")
    for stage, row in summary.items():
        print(f"  {stage:12s} {100 * row['whole']:5.1f} / {100 * row['boundary']:5.1f} %")


def run(argv: list[str]) -> None:
    print("$ tof-mpd " + " ".join(argv), flush=True)
    code = cli(argv)
    if code != 0:
        raise SystemExit(f"tof-mpd {argv[0]} failed with exit code {code}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--train-scenes", type=int, default=30)
    parser.add_argument("--test-scenes", type=int, default=8)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--calibration", type=int, default=60)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--seed", type=int, default=16)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--epochs", type=int, default=None,
                        help="training epochs (default: tof-mpd train's)")
    parser.add_argument("--samples", type=int, default=None,
                        help="samples per frame and epoch (default: tof-mpd train's)")
    parser.add_argument("--quick", action="store_true", help="the baselines' quick grids")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--reuse", action="store_true", help="keep an existing OUT/data")
    args = parser.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    data = out / "data"
    t0 = time.perf_counter()
    if not (args.reuse and (data / "dataset.json").exists()):
        render(data, args)
    timings = {"render_s": time.perf_counter() - t0}
    run(["calibrate", "intrinsic", str(data / "calibration"), "-o", str(out / "calib.npz")])
    results = {}
    for k, name in enumerate(args.variants.split(",")):
        w = out / f"weights_{name}.npz"
        t = time.perf_counter()
        schedule = ([*(["--epochs", str(args.epochs)] if args.epochs else []),
                     *(["--max-samples-per-frame", str(args.samples)] if args.samples else [])])
        run(["train", str(data / "md_train"), "--calibration", str(out / "calib.npz"), "-o",
             str(w), *schedule, "--seed", "0", "--overwrite", *VARIANTS[name]])
        run(["evaluate", str(data / "md_test"), "--weights", str(w), "-o",
             str(out / f"eval_{name}")])
        trained = json.loads(w.with_suffix(".json").read_text())
        trained.pop("history", None)
        evaluation = json.loads((out / f"eval_{name}" / "results.json").read_text())
        results[name] = {"train": trained, "summary_5mm": evaluation["summary_5mm"],
                         "regions": evaluation["regions"],
                         "g_operating_point": evaluation["g_operating_point"]}
        if k == 0:  # the baselines do not depend on the variant: benchmarked once
            bench = out / "benchmark"
            run(["benchmark", "--train", str(data / "md_train"), "--test",
                 str(data / "md_test"), "--weights", str(w), "-o", str(bench), "--no-progress",
                 *(["--quick"] if args.quick else [])])
            doc = json.loads((bench / "results.json").read_text())
            results["baselines"] = {"table": doc["table"],
                                    "ranking": doc["comparison"]["statement"],
                                    "findings": doc["comparison"]["findings"]}
            print_table("benchmark with " + name, doc["table"])
        timings[name + "_s"] = time.perf_counter() - t
        print_stages(name, evaluation["summary_5mm"])
    summary = {"machine": {"cpu": cpu_model(), "cores": os.cpu_count(),
                           "python": platform.python_version()},
               "camera": new_camera().to_dict(), "args": {k: str(v) for k, v in
                                                          vars(args).items()},
               "timings": timings, "results": results}
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores; summary in {out / 'summary.json'}")


if __name__ == "__main__":
    main()
