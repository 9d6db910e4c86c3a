"""What a path-traced base leaves unexplained when the camera is known (issue 13).

The mismatch benchmark's path-traced bases carry the path tracer's own light transport (every
bounce, glossy and metal lobes, translucent media) under a drawn camera profile. Before any
concealed effect can stand out, the tool's predictor has to explain the base itself. This
study renders static controls (nothing concealed) of development seeds, predicts every frame
with the case's *true* camera profile and amplitude units (:func:`.cases.truth_config`), and
splits the systematic residual (the frames' mean of real − predicted, mm; the frames differ
only by noise) by the material each pixel sees, with pixels within 2 px of a reference depth
edge apart (split into the edge's near and far side). The same seeds on the built-in renderer
("profile" bases: same scenes, same camera draws, its one-bounce transport, every object
Lambertian or subsurface) are the comparison: what the path tracer adds is the difference.

Usage: ``python benchmarks/pathtrace_floor.py OUT.json [--seeds 2001:2013] [--frames 4]
[--bases pathtrace profile]``. Needs the ``[pathtrace]`` extra for the path-traced bases
(~35 s per path-traced control of 4 frames at 96 x 72 and 1024 samples per pixel on one
Xeon core, ~25 s per built-in one).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy import ndimage

from tof_mpd_ros.machine import cpu_model
from tof_mpd_ros.mismatch.analysis import build_problem
from tof_mpd_ros.mismatch.cases import generate_case, truth_config
from tof_mpd_ros.mismatch.profile import adopt_recording
from tof_mpd_ros.sim.objects import MATERIAL_NAMES

#: pixels this close to a reference depth edge (px) are counted as edge pixels
EDGE_PX = 2.0


def systematic_residual(seed: int, base: str, n_frames: int) -> dict[str, np.ndarray]:
    """One static control: its systematic residual under the true camera, and per pixel the
    material, the edge distance and the edge side.

    Returns:
        ``residual`` (H, W) float64 mm (NaN where unpredicted), ``material`` (H, W) int32,
        ``edge_px`` (H, W) float64 distance to a reference depth edge, ``near_side`` (H, W)
        bool: the pixel is on the near (foreground) side of its edge.
    """
    case = generate_case(np.random.default_rng(seed), [], base=base, static=True,
                         n_frames=n_frames)
    labels = case.labels
    truth, _ = adopt_recording(case.frames, truth_config(labels["effects"], labels["camera"]),
                               keep_units=True)
    problem, descriptors = build_problem(case.frames, truth)
    residuals = np.stack([np.asarray(f.range_mm, np.float64) - p.predict().range_mm
                          for f, p in zip(case.frames, problem.predictors, strict=True)])
    reference = np.asarray(case.frames[0].reference_mm, np.float64)
    filled = np.where(np.isfinite(reference), reference, np.nanmax(reference))
    nearest = ndimage.minimum_filter(filled, 5)
    farthest = ndimage.maximum_filter(filled, 5)
    return {"residual": residuals.mean(axis=0), "material": case.materials[0],
            "edge_px": descriptors[0]["edge_distance_px"],
            "near_side": farthest - filled > filled - nearest}


def pooled(controls: list[dict[str, np.ndarray]]) -> dict[str, dict[str, float]]:
    """Per material (interior pixels) and per edge side: pixel count, scene count, mean, RMS
    and median |residual| in mm, pooled over ``controls``."""
    groups: dict[str, list[np.ndarray]] = {}
    for c in controls:
        r, ok = c["residual"], np.isfinite(c["residual"])
        interior = ok & (c["edge_px"] > EDGE_PX)
        for m in np.unique(c["material"][interior & (c["material"] >= 0)]):
            groups.setdefault(MATERIAL_NAMES[int(m)], []).append(
                r[interior & (c["material"] == m)])
        groups.setdefault("interior, all", []).append(r[interior])
        edge = ok & (c["edge_px"] <= EDGE_PX)
        groups.setdefault("edge, near side", []).append(r[edge & c["near_side"]])
        groups.setdefault("edge, far side", []).append(r[edge & ~c["near_side"]])
    out = {}
    for name, parts in groups.items():
        v = np.concatenate(parts)
        out[name] = {"pixels": int(v.size), "scenes": sum(p.size > 0 for p in parts),
                     "mean_mm": float(v.mean()), "rms_mm": float(np.sqrt(np.mean(v ** 2))),
                     "median_abs_mm": float(np.median(np.abs(v)))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="JSON file for the pooled figures")
    ap.add_argument("--seeds", default="2001:2013", help="first:end of the case seeds")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--bases", nargs="+", default=["pathtrace", "profile"])
    args = ap.parse_args()
    first, end = (int(x) for x in args.seeds.split(":"))
    report = {"cpu": cpu_model(), "seeds": [first, end], "frames": args.frames, "bases": {}}
    print(f"CPU: {report['cpu']}")
    for base in args.bases:
        start = time.perf_counter()
        controls = [systematic_residual(s, base, args.frames) for s in range(first, end)]
        report["bases"][base] = pooled(controls)
        print(f"\n{base} bases, seeds {first}-{end - 1} ({time.perf_counter() - start:.0f} s):"
              f"\n  {'pixels of':18s} {'n':>7s} {'scenes':>6s} {'mean':>7s} {'RMS':>6s} "
              f"{'median |r|':>10s} (mm)")
        for name, g in report["bases"][base].items():
            print(f"  {name:18s} {g['pixels']:7d} {g['scenes']:6d} {g['mean_mm']:+7.1f} "
                  f"{g['rms_mm']:6.1f} {g['median_abs_mm']:10.1f}")
    with open(args.out, "w") as f:
        json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
