"""Does the evaluation's ground truth transfer? Canny on a noisy reference vs on the true range.

The boundary region (≤ 5 px from an edge), the component analysis and G's precision/recall all
stand on edges found by Canny on the structured-light reference (the paper's labels, at
``GT_LOW_MM`` / ``GT_HIGH_MM`` of step height). A real reference is noisy and has holes; the
simulated cell also knows the true range. This study renders fresh test views of the cell and
measures (issue 16):

1. how well the reference's edges agree with the true range's (precision/recall, 2 px);
2. for a model (the shipped weights unless ``--weights``), the boundary-region accuracy within
   5 mm of calibrated / F / full, and G's precision/recall at its operating point, under four
   ground truths: Canny on the reference at the default thresholds, at half and at twice them,
   and Canny on the true range — does "full ≥ F at the boundary" hold under each?
3. the same accuracies scored against the true range instead of the reference (how much the
   reference's own noise caps the numbers).

Usage: ``python benchmarks/gt_edges_study.py OUT.json [--scenes 10] [--views 4]
[--weights W.npz]``. About 3 s per view on 2 cores (the structured-light scans dominate).
"""

from __future__ import annotations

import argparse
import json
import os
import time

from tof_mpd_ros.machine import cpu_model, set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

import numpy as np

from tof_mpd_ros.correction.default_weights import default_weights_path
from tof_mpd_ros.correction.edges import GT_HIGH_MM, GT_LOW_MM, ground_truth_edges
from tof_mpd_ros.correction.pipeline import correct, require_patch_kind
from tof_mpd_ros.correction.weights import load_weights
from tof_mpd_ros.evaluation.metrics import FrameAccumulator, boundary_region, edge_precision_recall
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.dataset import scene_rng
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import make_scene
from tof_mpd_ros.sim.viewpoints import ViewpointConfig, plan_viewpoints

STAGES = ("calibrated", "F", "full")


def render_views(n_scenes: int, n_views: int, seed: int) -> list[dict]:
    """Fresh test-split views: the ToF frame, its SL reference and the true range (mm)."""
    cell = SimCell()
    views = []
    for k in range(n_scenes):
        rng = scene_rng(k, "test", seed)
        scene = make_scene("test", rng)
        for vp in plan_viewpoints(scene, rng, ViewpointConfig(n_views=n_views)).viewpoints:
            frame = cell.capture(scene, vp.camera_to_base_mm, rng)
            truth = render_surface(scene, vp.camera_to_base_mm, cell.camera.intrinsics).range_mm
            views.append({"frame": frame, "truth": np.where(np.isfinite(frame.range_mm), truth,
                                                            np.nan)})
    return views


def ground_truths(reference: np.ndarray, truth: np.ndarray) -> dict[str, np.ndarray]:
    """The four edge definitions compared: (H, W) bool each."""
    return {"reference (default)": ground_truth_edges(reference)[0],
            "reference, half thresholds": ground_truth_edges(
                reference, low=GT_LOW_MM / 2, high=GT_HIGH_MM / 2)[0],
            "reference, double thresholds": ground_truth_edges(
                reference, low=2 * GT_LOW_MM, high=2 * GT_HIGH_MM)[0],
            "true range": ground_truth_edges(truth)[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out")
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--seed", type=int, default=7, help="scene seed (not the dataset's 0)")
    parser.add_argument("--weights", default=None)
    args = parser.parse_args()
    model = load_weights(args.weights or default_weights_path())
    require_patch_kind(model, "gt_edges_study.py (it studies G's edges and the geodesic step)")
    t0 = time.perf_counter()
    views = render_views(args.scenes, args.views, args.seed)
    render_s = time.perf_counter() - t0
    names = list(ground_truths(views[0]["frame"].reference_mm, views[0]["truth"]))
    acc = {(n, target): {s: FrameAccumulator((5.0,)) for s in STAGES}
           for n in names for target in ("reference", "true range")}
    g_maps, valids, gts = [], [], {n: [] for n in names}
    for v in views:
        f, truth = v["frame"], v["truth"]
        ref = f.reference_mm
        full = correct(model, f.range_mm, f.amplitude)
        est = {"calibrated": full.calibrated_mm, "F": full.range_f_mm, "full": full.range_mm}
        valid = np.isfinite(ref)
        g_maps.append(full.edges.astype(np.float32))
        valids.append(valid)
        for name, gt in ground_truths(ref, truth).items():
            gts[name].append(gt)
            for target, image in (("reference", ref), ("true range", truth)):
                # the same pixels in both: where the reference exists
                scored = np.where(valid, image, np.nan)
                mask = boundary_region(scored, edges=gt)
                for s in STAGES:
                    acc[(name, target)][s].add(est[s], scored, mask)
    agreement = edge_precision_recall([g.astype(np.float32) for g in gts["reference (default)"]],
                                      gts["true range"], [0.5], valid=valids)
    rows = {}
    for name in names:
        point = edge_precision_recall(g_maps, gts[name], [0.5], valid=valids)
        rows[name] = {
            "edge_pixels": int(sum(int(g.sum()) for g in gts[name])),
            "G_precision": point.precision[0], "G_recall": point.recall[0],
            **{f"{target}: {s}": [acc[(name, target)][s].result().whole.accuracy[0],
                                  acc[(name, target)][s].result().boundary.accuracy[0]]
               for target in ("reference", "true range") for s in STAGES}}
    result = {"machine": f"{cpu_model()}, {os.cpu_count()} cores", "views": len(views),
              "render_s": round(render_s, 1), "weights": str(args.weights or "shipped"),
              "reference_edges_vs_true_edges": {"precision": agreement.precision[0],
                                                "recall": agreement.recall[0]},
              "ground_truths": rows}
    print(f"machine: {result['machine']}; {len(views)} views rendered in {render_s:.0f} s")
    print(f"reference edges vs true-range edges (2 px): precision "
          f"{agreement.precision[0]:.3f}, recall {agreement.recall[0]:.3f}")
    print(f"{'ground truth':30s} {'edges':>7s}  G P/R       boundary within 5 mm, "
          "scored vs reference (vs true range): calibrated / F / full")
    for name, r in rows.items():
        b = "  ".join(f"{s} {100 * r[f'reference: {s}'][1]:5.1f} "
                      f"({100 * r[f'true range: {s}'][1]:5.1f})" for s in STAGES)
        print(f"{name:30s} {r['edge_pixels']:7d}  {r['G_precision']:.2f}/{r['G_recall']:.2f}"
              f"   {b}")
    with open(args.out, "w", encoding="utf-8") as fh:
        json.dump(result, fh, indent=2)


if __name__ == "__main__":
    main()
