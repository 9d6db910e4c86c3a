"""Both model kinds and precisions side by side, per frame size (issue 17, item 4).

For 180x140 and 320x240 frames, times ``pipeline.correct`` end to end for

* the patch kind (calibration -> F -> G -> geodesic filter) in float32, bfloat16 and int8,
* the fcn kind (calibration -> U-Net) in float32 and bfloat16 under torch, and in float32
  under ONNX Runtime (``fcn/float32/ort``, the default executor where onnxruntime is installed;
  skipped, and said, where it is not),

all in one run, interleaved frame by frame so that a change of machine load hits every row
alike, and prints the median and p90 in ms, each row's ratio to the patch float32 path, the
targets (<= 15 ms at 180x140, <= 33 ms at 320x240 on 2 Zen 4 cores) and the paper's 165 ms
(GPU). For the fcn kind it also prints the convolutions' FLOPs per frame (counted from the
layer shapes), the GFLOP/s reached and its share of the CPU's nominal float32 peak
(``bench_pipeline.cpu_peak``, which explains the figure) and of a large GEMM measured in the
same run. For every row also the wall time per frame with two frames corrected at once, one
torch thread each (the corrector node's ``threads`` 1, ``parallel_frames`` 2): its frame rate,
where the median is its latency.

For each reduced-precision row, the agreement with the float32 output of the same kind (the
issue's bar: >= 99.9 % of the pixels within 0.5 mm, and accuracy within 5 mm does not drop):
measured on frames of a simulated test scene the script renders itself (``--agreement-views``
views, 7-10 s at 320x240) with trained weights (the shipped patch weights unless
``--weights-patch``; the fcn kind's only with ``--weights-fcn``, else untrained, as the output
says): the shares within 0.5 mm of the final range and of R_F, and the shares within 5 mm of
the scene's reference in float32 and in the reduced precision.

Inputs it makes itself: the synthetic scene of ``bench_pipeline`` (planes, a box, a disc, 2 mm
noise). The patch kind is timed with the shipped weights (or ``--weights-patch``): its reduced
precisions recompute G in float32 where an edge decision is unsure, and how many pixels that
is depends on the weights (untrained heads are unsure everywhere, and the recheck is skipped).
The fcn kind is timed untrained on an identity calibration unless ``--weights-fcn`` (its time
does not depend on the weights' values). A weights file is run on its central window of each
size (``pipeline.central_window``, as the node and ``tof-mpd correct`` run it), or on its own
frame where it is smaller (said in the output); the synthetic frames are resized to it.

The OpenMP threads wait passively (``OMP_WAIT_POLICY=PASSIVE`` unless set), as in the
corrector node: spinning workers make a 2-thread forward pass many times slower when another
process holds a core. Set ``OMP_WAIT_POLICY=ACTIVE GOMP_SPINCOUNT=20000`` to time a machine
given to the corrector alone (docs/performance.md has both).

Usage: ``python benchmarks/bench_kinds.py [--repeats 20] [--json out.json]``; ~1-2 min on an
idle 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

from tof_mpd_ros.machine import set_openmp_wait_policy

set_openmp_wait_policy()  # before torch loads OpenMP (it reads the policy once)

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import _resize, _synthetic, cpu_peak, gemm_ceiling, machine

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction import fcn_onnx
from tof_mpd_ros.correction.fcn import N_INPUTS, FCNCorrectionModel, ResidualFCN
from tof_mpd_ros.correction.pipeline import central_window, correct

PAPER_MS = 165.0
TARGETS_MS = {"180x140": 15.0, "320x240": 33.0}
SIZES = ((140, 180), (240, 320))
#: (kind, precision, fcn engine); the reference of each kind is its float32 row under torch
ROWS = (("patch", "float32", "torch"), ("patch", "bfloat16", "torch"),
        ("patch", "int8", "torch"), ("fcn", "float32", "torch"), ("fcn", "bfloat16", "torch"),
        ("fcn", "float32", "onnxruntime"))


def rows() -> list[tuple[str, str, str]]:
    """The rows this machine can run (ONNX Runtime's only where it is installed)."""
    return [r for r in ROWS if r[2] == "torch" or fcn_onnx.available()]


def row_name(row: tuple[str, str, str]) -> str:
    kind, precision, engine = row
    return f"{kind}/{precision}" + ("/ort" if engine == "onnxruntime" else "")


def conv_flops(net: ResidualFCN, h: int, w: int) -> int:
    """Multiply-add FLOPs (2 per MAC) of every convolution of ``net`` on an (h, w) frame,
    counted from the output shapes seen by forward hooks."""
    total = 0

    def hook(module: torch.nn.Conv2d, _inp: Any, out: torch.Tensor) -> None:
        nonlocal total
        k = module.kernel_size[0] * module.kernel_size[1] * module.in_channels
        total += 2 * k * out.numel()

    handles = [m.register_forward_hook(hook) for m in net.modules()
               if isinstance(m, torch.nn.Conv2d) and m is not net.head]
    m = net.architecture.multiple
    hp, wp = -(-h // m) * m, -(-w // m) * m
    with torch.no_grad():
        net.raw(torch.zeros(1, N_INPUTS, hp, wp))
    for handle in handles:
        handle.remove()
    # the 1 x 1 head runs as a matrix product (ResidualFCN.raw), which no hook sees
    return total + 2 * net.head.weight.numel() * hp * wp


def models(h: int, w: int, args: argparse.Namespace) -> dict[str, Any]:
    """One model of each kind at (h, w)."""
    from tof_mpd_ros.correction.default_weights import default_weights_path
    from tof_mpd_ros.correction.weights import load_weights

    calib = IntrinsicCalibration.identity(h, w)
    patch = window_of(load_weights(args.weights_patch or default_weights_path()), h, w)
    fcn = (window_of(load_weights(args.weights_fcn), h, w) if args.weights_fcn
           else FCNCorrectionModel.untrained(calib, seed=0))
    return {"patch": patch, "fcn": fcn}


def window_of(model: Any, h: int, w: int) -> Any:
    """``model`` on its central h x w window, or whole when its frame is smaller."""
    mh, mw = model.shape
    return central_window(model, min(w, mw), min(h, mh))


def frames_for(model: Any, base: list[tuple[np.ndarray, np.ndarray]]
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    h, w = model.shape
    return [(_resize(r, h, w), _resize(a, h, w)) for r, a in base]


def time_size(h: int, w: int, args: argparse.Namespace) -> dict[str, Any]:
    """Median / p90 ms of every row at (h, w), interleaved, plus the bf16 agreement."""
    base = _synthetic()
    kinds = models(h, w, args)
    frames = {k: frames_for(m, base) for k, m in kinds.items()}
    times: dict[tuple[str, str, str], list[float]] = {row: [] for row in rows()}
    for row in rows():                       # warm-up: engines, oneDNN primitives, sessions
        correct(kinds[row[0]], *frames[row[0]][0], precision=row[1], fcn_engine=row[2])
    for i in range(args.repeats):
        for kind, precision, engine in rows():
            r, a = frames[kind][i % len(frames[kind])]
            t0 = time.perf_counter()
            correct(kinds[kind], r, a, precision=precision, fcn_engine=engine)
            times[(kind, precision, engine)].append((time.perf_counter() - t0) * 1e3)
    out: dict[str, Any] = {}
    for row in rows():
        ms = sorted(times[row])
        out[row_name(row)] = {"median_ms": statistics.median(ms),
                              "p90_ms": ms[int(0.9 * (len(ms) - 1))]}
    trained = trained_models(h, w, args)
    scene = scene_frames(*trained["patch"].shape, args.agreement_views)
    for kind in ("patch", "fcn"):
        model = trained[kind]
        sized = scene if model.shape == trained["patch"].shape else scene_frames(
            *model.shape, args.agreement_views)
        others = [r for r in rows() if r[0] == kind and r[1:] != ("float32", "torch")]
        for row, numbers in agreement(model, sized, others).items():
            out[row_name(row)]["agreement"] = numbers
    out["agreement_weights"] = {"patch": str(args.weights_patch or "shipped"),
                                "fcn": str(args.weights_fcn or "untrained")}
    for row in rows():
        out[row_name(row)]["two_at_once_ms_per_frame"] = two_at_once(
            kinds[row[0]], frames[row[0]], row, args.repeats)
    out["fcn_gflop_per_frame"] = conv_flops(kinds["fcn"].net, *kinds["fcn"].shape) / 1e9
    out["frames"] = {kind: f"{m.shape[1]}x{m.shape[0]}" for kind, m in kinds.items()}
    return out


def two_at_once(model: Any, frames: list[tuple[np.ndarray, np.ndarray]],
                row: tuple[str, str, str], repeats: int) -> float:
    """Wall ms per frame when two threads correct ``repeats`` frames each side by side, one
    torch thread each: the corrector node's ``threads`` 1, ``parallel_frames`` 2 (its
    throughput; each frame's latency is longer)."""
    saved = torch.get_num_threads()
    torch.set_num_threads(1)

    def run(first: int) -> None:
        for i in range(repeats):
            correct(model, *frames[(first + i) % len(frames)], precision=row[1],
                    fcn_engine=row[2])

    try:
        run(0)                                        # warm-up on one thread
        workers = [threading.Thread(target=run, args=(k,)) for k in range(2)]
        t0 = time.perf_counter()
        for t in workers:
            t.start()
        for t in workers:
            t.join()
        return (time.perf_counter() - t0) * 1e3 / (2 * repeats)
    finally:
        torch.set_num_threads(saved)


def scene_frames(h: int, w: int, views: int) -> list[Any]:
    """``views`` frames of one simulated test scene on an (h, w) window of the sensor, with
    their references (the benchmark's own data: no file needed)."""
    from tof_mpd_ros.sim.cell import CameraModel, SimCell
    from tof_mpd_ros.sim.dataset import DatasetSpec, capture_scene

    return capture_scene("test", 0, DatasetSpec(views_per_scene=views, seed=5),
                         SimCell(camera=CameraModel(crop=(w, h)))).frames


def trained_models(h: int, w: int, args: argparse.Namespace) -> dict[str, Any]:
    """Trained weights of each kind on the (h, w) window where there are any; the fcn kind
    untrained unless ``--weights-fcn`` (the package ships no fcn weights)."""
    from tof_mpd_ros.correction.default_weights import default_weights_path
    from tof_mpd_ros.correction.weights import load_weights

    patch = window_of(load_weights(args.weights_patch or default_weights_path()), h, w)
    fcn = (window_of(load_weights(args.weights_fcn), h, w) if args.weights_fcn
           else FCNCorrectionModel.untrained(IntrinsicCalibration.identity(h, w), seed=0))
    return {"patch": patch, "fcn": fcn}


def agreement(model: Any, frames: list[Any], others: list[tuple[str, str, str]]
              ) -> dict[tuple[str, str, str], dict[str, float]]:
    """Per other row (a reduced precision, or another executor), against float32 under torch
    on ``frames`` (corrected that way once): shares of valid pixels within 0.5 mm (final range
    and R_F), and the shares within 5 mm of the reference in float32 and in that row."""
    counts = {p: np.zeros(3, np.int64) for p in others}     # near, near R_F, valid
    within = {p: 0 for p in ("float32", *others)}
    scored_total = 0
    for f in frames:
        ref = correct(model, f.range_mm, f.amplitude, fcn_engine="torch")
        scored = np.isfinite(f.reference_mm)
        scored_total += int(scored.sum())
        results: dict[Any, Any] = {"float32": ref}
        for p in others:
            low = results[p] = correct(model, f.range_mm, f.amplitude, precision=p[1],
                                       fcn_engine=p[2])
            ok = ref.valid & low.valid
            counts[p] += [(np.abs(ref.range_mm - low.range_mm)[ok] <= 0.5).sum(),
                          (np.abs(ref.range_f_mm - low.range_f_mm)[ok] <= 0.5).sum(), ok.sum()]
        for name, res in results.items():
            err = np.abs(res.range_mm - f.reference_mm)[scored]   # NaN (invalid): a miss
            within[name] += int((err <= 5.0).sum())
    scored_total = max(scored_total, 1)
    return {p: {"final_within_0.5mm": counts[p][0] / max(counts[p][2], 1),
                "range_f_within_0.5mm": counts[p][1] / max(counts[p][2], 1),
                "within_5mm_float32": within["float32"] / scored_total,
                "within_5mm_reduced": within[p] / scored_total} for p in others}


def print_size(label: str, res: dict[str, Any], peak: dict[str, Any], gemm: float) -> None:
    base = res["patch/float32"]["median_ms"]
    print(f"\n{label}  (target <= {TARGETS_MS[label]:.0f} ms; the paper: {PAPER_MS:.0f} ms "
          "on a GPU)")
    smaller = {k: f for k, f in res["frames"].items() if f != label}
    if smaller:
        print(f"  NOTE: timed on the weights' own smaller frame: {smaller}")
    print(f"  {'kind/precision':<18}{'median ms':>10}{'p90 ms':>9}{'vs patch f32':>14}"
          f"{'2 at once, ms/frame':>21}")
    for name in map(row_name, rows()):
        row = res[name]
        print(f"  {name:<18}{row['median_ms']:>10.1f}{row['p90_ms']:>9.1f}"
              f"{row['median_ms'] / base:>13.2f}x{row['two_at_once_ms_per_frame']:>21.1f}")
    if not fcn_onnx.available():
        print("  (fcn/float32/ort not timed: onnxruntime and onnx are not installed)")
    weights = res["agreement_weights"]
    print(f"  against float32 on a simulated scene (weights: patch {weights['patch']}, fcn "
          f"{weights['fcn']}); bar: >= 99.9 % within 0.5 mm, no drop within 5 mm")
    print(f"  {'kind/precision':<18}{'final <= 0.5 mm':>16}{'R_F <= 0.5 mm':>15}"
          f"{'within 5 mm: f32 -> reduced':>30}")
    for name in map(row_name, rows()):
        a = res[name].get("agreement")
        if a:
            print(f"  {name:<18}{100 * a['final_within_0.5mm']:>14.3f} %"
                  f"{100 * a['range_f_within_0.5mm']:>13.3f} %"
                  f"{100 * a['within_5mm_float32']:>19.2f} -> "
                  f"{100 * a['within_5mm_reduced']:.2f} %")
    gflop = res["fcn_gflop_per_frame"]
    for name in ("fcn/float32", "fcn/float32/ort"):
        if name not in res:
            continue
        rate = gflop / (res[name]["median_ms"] / 1e3)   # the whole correct(), not the U-Net alone
        print(f"  {name}: {gflop:.2f} GFLOP per frame -> {rate:.1f} GFLOP/s = "
              f"{100 * rate / peak['peak_gflops']:.0f} % of the nominal float32 peak "
              f"({peak['peak_gflops']} GFLOP/s), {100 * rate / gemm:.0f} % of a large GEMM now "
              f"({gemm:.0f} GFLOP/s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--weights-patch", type=Path)
    parser.add_argument("--weights-fcn", type=Path)
    parser.add_argument("--agreement-views", type=int, default=3,
                        help="views of the simulated scene the agreement is measured on")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    info = machine()
    cores = info["affinity_cpus"]
    peak = cpu_peak(cores)
    gemm = gemm_ceiling()
    print(f"CPU: {info['cpu']}, {cores} usable cores, torch {info['torch']} with "
          f"{info['torch_threads']} threads; load {info['load_average_start']}")
    info["openmp_wait"] = {k: os.environ.get(k) for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    print(f"OpenMP waits: {info['openmp_wait']} (docs/performance.md: spinning is faster on an "
          "idle machine, far slower on a busy one)")
    print(f"nominal float32 peak: {peak['how']} = {peak['peak_gflops']} GFLOP/s; "
          f"bf16 instructions: {peak['bf16']}, int8 dot-product instructions: {peak['int8']}"
          " (without them a reduced precision runs in a reference kernel)")
    results = {}
    for h, w in SIZES:
        label = f"{w}x{h}"
        results[label] = time_size(h, w, args)
        print_size(label, results[label], peak, gemm)
    info["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    print(f"\nload average at the end: {info['load_average_end']}")
    if args.json:
        args.json.write_text(json.dumps({"machine": info, "peak": peak, "gemm_gflops": gemm,
                                         "results": results}, indent=2))


if __name__ == "__main__":
    main()
