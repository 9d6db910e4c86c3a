"""What an approximate geodesic filter would cost in accuracy, and what it would save (issue 17
item 4: "measure what an approximation costs in accuracy before choosing it").

Every candidate filters the same R_F with the same edge map of G (the patch kind's pipeline,
``pipeline.correct``), frame by frame:

* **exact** -- the product's :func:`~tof_mpd_ros.correction.geodesic.geodesic_filter` (K = 81
  geodesically nearest pixels, Gaussian of the path length, edges as barriers);
* **domain transform** -- OpenCV's ``ximgproc.dtFilter`` (Gastal & Oliveira, SIGGRAPH 2011),
  an O(1)-per-pixel edge-aware filter (separable passes of a recursive filter, ``RF``, or of a
  normalized box, ``NC``). The guide is the edge map times 1e4, so a step onto an edge pixel is
  an (almost) infinite domain distance: the barrier of the exact filter. The values are
  filtered as a normalized convolution (R_F x w and w, w = 0 on edge and missing pixels) and
  the edge pixels then take their most similar neighbour's value as in the product. Its
  spatial sigma is the product's sigma (2 px): matched by definition, not tuned on these frames;
* **F alone** -- no filter, for scale.

This is not the paper's K-nearest propagation (Liu et al., CVPR 2013), which docs/method.md
argues costs more than the exact search on two cores; the domain transform is the cheapest
edge-aware filter a well-kept library offers, so it bounds what any approximation can save.

Prints, side by side: within 2 / 5 / 10 mm of the reference (whole image and boundary region),
MAE and RMSE, the share of pixels within 0.5 mm of the exact filter, and the median ms per
frame of each filter at the frames' size and at 320x240 (the frames upscaled, nearest
neighbour), with the CPU (model name, family, model) and the load average.

Frames: ``--frames DIR ...`` recordings with a reference (e.g. ``md_test`` of ``tof-mpd sim
dataset --small``, or of ``--renderer pathtrace``); by default it renders ``tof-mpd sim dataset
--small`` into a temporary directory first (1-2 min on 2 cores). Weights: ``--weights``
(default: the shipped patch-kind weights).

Usage: ``python benchmarks/bench_geodesic_approximation.py [--frames DIR ...] [--repeats 15]
[--json out.json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from tof_mpd_ros.machine import set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

import cv2
import numpy as np

from tof_mpd_ros.cli.correct import fit_to_frames, load_model
from tof_mpd_ros.correction import geodesic
from tof_mpd_ros.correction.pipeline import CorrectionModel, correct
from tof_mpd_ros.evaluation.metrics import evaluate_frames
from tof_mpd_ros.machine import cpu_model, cpuinfo
from tof_mpd_ros.recordings import iter_frames

#: guide value of an edge pixel: a domain distance of 1e4 / sigma_r per step is a barrier
BARRIER = 1.0e4
THRESHOLDS_MM = (2.0, 5.0, 10.0)
AGREEMENT_MM = 0.5
#: (R_F mm, edge map, reference mm) of one frame, each (H, W): float32, bool, float
Inputs = list[tuple[np.ndarray, np.ndarray, np.ndarray]]
Filters = dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]


def domain_transform(range_f: np.ndarray, edges: np.ndarray, sigma: float, mode: int
                     ) -> np.ndarray:
    """(H, W) float32 R_F (mm, NaN = missing) filtered by the domain transform with ``edges``
    ((H, W) bool) as barriers, spatial ``sigma`` in pixels; edge pixels snapped as the exact
    filter does. Returns (H, W) float32 mm, NaN where no usable pixel is near."""
    valid = np.isfinite(range_f)
    weight = (valid & ~edges).astype(np.float32)
    stack = np.dstack([np.where(valid, range_f, 0.0).astype(np.float32) * weight, weight])
    guide = edges.astype(np.float32) * BARRIER
    out = cv2.ximgproc.dtFilter(guide, stack, sigma, 1.0, mode=mode, numIters=3)
    with np.errstate(invalid="ignore", divide="ignore"):
        filtered = np.where(out[..., 1] > 1e-6, out[..., 0] / out[..., 1], np.nan)
    filtered[edges] = np.nan
    return geodesic._snap_edge_pixels(filtered.astype(np.float64), range_f, edges, True)


def candidates(sigma: float, k: int) -> Filters:
    """name -> filter(range_f, edges) -> (H, W) float32 mm."""
    return {
        "exact": lambda r, e: geodesic.geodesic_filter(r, e, k=k, sigma=sigma),
        "domain transform RF": lambda r, e: domain_transform(r, e, sigma, cv2.ximgproc.DTF_RF),
        "domain transform NC": lambda r, e: domain_transform(r, e, sigma, cv2.ximgproc.DTF_NC),
        "F alone": lambda r, e: r.copy(),
    }


def render_default_frames(out: Path) -> list[Path]:
    """``tof-mpd sim dataset --small`` into ``out``; its md_test recording."""
    print(f"rendering tof-mpd sim dataset --small into {out} (1-2 min) ...", flush=True)
    subprocess.run([sys.executable, "-m", "tof_mpd_ros.cli.main", "sim", "dataset", "--small",
                    "-o", str(out)], check=True)
    return [out / "md_test"]


def corrected_inputs(model: CorrectionModel, paths: list[Path]) -> Inputs:
    """(R_F, edge map, reference) of every frame with a reference, all (H, W)."""
    rows = []
    fitted: dict[tuple[int, int], CorrectionModel] = {}  # one window cut per frame size
    for path in paths:
        for frame in iter_frames(path):
            if frame.reference_mm is None:
                continue
            shape = frame.range_mm.shape
            if shape not in fitted:
                fitted[shape] = fit_to_frames(model, shape)
            res = correct(fitted[shape], frame.range_mm, frame.amplitude)
            rows.append((res.range_f_mm, res.edges, frame.reference_mm))
    return rows


def median_ms(fn: Callable[[np.ndarray, np.ndarray], np.ndarray], r: np.ndarray,
              e: np.ndarray, repeats: int) -> float:
    fn(r, e)  # compile / warm up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn(r, e)
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def upscale(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    iy = np.arange(shape[0]) * a.shape[0] // shape[0]
    ix = np.arange(shape[1]) * a.shape[1] // shape[1]
    return a[iy][:, ix]


def accuracy_rows(inputs: Inputs, filters: Filters) -> dict[str, dict[str, float]]:
    rows = {}
    exact = [filters["exact"](r, e) for r, e, _ in inputs]
    for name, fn in filters.items():
        est = exact if name == "exact" else [fn(r, e) for r, e, _ in inputs]
        ev = evaluate_frames(est, [ref for _, _, ref in inputs], THRESHOLDS_MM)
        both = [np.isfinite(a) & np.isfinite(b) for a, b in zip(est, exact, strict=True)]
        agree = sum(int((np.abs(a - b)[m] <= AGREEMENT_MM).sum())
                    for a, b, m in zip(est, exact, both, strict=True))
        row = {f"whole <{t:g}": ev.whole.at(t) for t in THRESHOLDS_MM}
        row |= {f"boundary <{t:g}": ev.boundary.at(t) for t in THRESHOLDS_MM}
        row |= {"MAE mm": ev.whole.mae_mm, "RMSE mm": ev.whole.rmse_mm,
                f"within {AGREEMENT_MM:g} mm of exact": agree / max(1, sum(int(m.sum())
                                                                          for m in both))}
        rows[name] = row
    return rows


def timing_rows(inputs: Inputs, filters: Filters, repeats: int) -> dict[str, dict[str, float]]:
    r, e, _ = max(inputs, key=lambda x: int(x[1].sum()))  # the frame with the most edge pixels
    big = (upscale(r, (240, 320)), upscale(e, (240, 320)))
    return {name: {f"ms {r.shape[1]}x{r.shape[0]}": median_ms(fn, r, e, repeats),
                   "ms 320x240": median_ms(fn, *big, repeats)}
            for name, fn in filters.items() if name != "F alone"}


def print_table(rows: dict[str, dict[str, float]]) -> None:
    cols = list(next(iter(rows.values())))
    width = {c: max(12, len(c) + 2) for c in cols}
    print(f"{'filter':22s}" + "".join(f"{c:>{width[c]}s}" for c in cols))
    for name, row in rows.items():
        cells = "".join(f"{row[c]:>{width[c]}.4f}" if "<" in c or "within" in c
                        else f"{row[c]:>{width[c]}.2f}" for c in cols)
        print(f"{name:22s}{cells}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", nargs="+", type=Path,
                        help="recordings with a reference (default: render --small md_test)")
    parser.add_argument("--weights", type=Path, help="patch-kind weights (default: shipped)")
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    info = cpuinfo()
    machine = {"cpu": cpu_model(), "family": info.get("cpu family"), "model": info.get("model"),
               "cores": os.cpu_count(), "load_average": os.getloadavg()}
    model = load_model(args.weights)
    if not isinstance(model, CorrectionModel):
        parser.error("the geodesic filter belongs to the patch kind; --weights is an fcn file")
    with tempfile.TemporaryDirectory() as tmp:
        paths = args.frames or render_default_frames(Path(tmp) / "dataset")
        inputs = corrected_inputs(model, paths)
    if not inputs:
        parser.error("no frame with a reference in --frames")
    filters = candidates(model.geodesic.sigma, model.geodesic.k)
    accuracy = accuracy_rows(inputs, filters)
    timing = timing_rows(inputs, filters, args.repeats)
    machine["load_average_after"] = os.getloadavg()
    print(f"CPU: {machine['cpu']} (family {machine['family']} model {machine['model']}), "
          f"{machine['cores']} cores, load {machine['load_average']} -> "
          f"{machine['load_average_after']}; {len(inputs)} frames of {[str(p) for p in paths]}")
    print("\naccuracy against the reference (fractions; whole image, boundary region):")
    print_table(accuracy)
    print(f"\nmedian ms per frame ({args.repeats} repeats, the frame with the most edge pixels):")
    print_table(timing)
    if args.json:
        args.json.write_text(json.dumps({"machine": machine, "frames": [str(p) for p in paths],
                                         "n_frames": len(inputs), "accuracy": accuracy,
                                         "timing": timing}, indent=2))


if __name__ == "__main__":
    main()
