"""Per-stage timing of the full correction: straightforward reference vs production, side by side.

For each frame size (180x140 and 320x240 by default) prints the median and p90 in ms of every
stage (calibration, encoding, F, G, NMS + hysteresis, geodesic filter) and of the whole
correction, for

* the **fast path**: ``pipeline.correct`` itself. The total is timed on un-instrumented calls;
  the stages are timed in separate calls with timing wrappers around the functions
  ``correct`` calls (see :class:`StageTimer`: calibration, plane preparation, the threaded
  band loop of row encoding + F+G GEMM and kernel, whose time is split between encoding and
  F+G in proportion to their summed per-thread CPU times, NMS + hysteresis, geodesic filter;
  F and G share their first-layer GEMM, so they are one row); the rest is "other" (glue);
* the **reference path**: the test oracle ``test/oracles/reference_pipeline.py`` (per-pixel
  loops, per-pixel numpy matrix-vector products, per-pixel heapq Dijkstra). It is too slow to
  run whole frames repeatedly (~8 s of CPU per 180x140 frame), so encoding, F, G and the
  geodesic search are timed on a random sample of pixels per frame and extrapolated to the
  frame's pixel count; calibration,
  the padded planes and the edge snapping run on the full frame. NMS + hysteresis is the same
  function in both paths. The sampled pixels are also checked against the fast path's output.

Plus: achieved GFLOP/s of the networks against the CPU's nominal peak (cores x GHz x FLOPs per
cycle of the detected SIMD, explained in the output) and against a large float32 GEMM measured
now; the paper's 165 ms (GPU) and the targets as reference lines; the machine (CPU model, cores,
torch / numba threads, load average at start and end). ``--json PATH`` writes everything.

Frames: the recording ``--frames`` (e.g. ``md_test`` of ``tof-mpd sim dataset --small``) with the
model ``--weights`` (default: the shipped weights); a synthetic scene and an untrained model when
no recording is given.
The 320x240 frames and calibration are the 180x140 ones upscaled (nearest neighbour), with the
same networks: the timing depends on the size and on the edge density, not on the exact scene.

Usage: ``python benchmarks/bench_pipeline.py [--repeats 30] [--ref-frames 3] [--ref-pixels 400]
[--threads N] [--json out.json]``. Takes ~1-2 min on an idle 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numba
import numpy as np
import torch

from tof_mpd_ros.calibration import IntrinsicCalibration
from tof_mpd_ros.correction import edges as edges_module
from tof_mpd_ros.correction import geodesic as geodesic_module
from tof_mpd_ros.correction import networks as networks_module
from tof_mpd_ros.correction import pipeline as pipeline_module
from tof_mpd_ros.correction.pipeline import PRECISIONS, CorrectionModel, correct
from tof_mpd_ros.evaluation.components import g_probabilities
from tof_mpd_ros.machine import PRECISION_FLAGS, cpu_model, cpuinfo

# The reference path is a test oracle (test/oracles, not in the wheel).
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
from oracles import reference_pipeline as ref

PAPER_MS = 165.0                       # the paper, per frame, with a GPU
TARGETS_MS = {"180x140": 25.0, "320x240": 60.0}   # issue 8 (docs/performance.md)
STAGES = ("calibration", "encoding", "F", "G", "F+G", "NMS+hysteresis", "geodesic", "other")
PRECISION = {"value": "float32"}        # --precision: the fast path's first-layer GEMMs


def fast_correct(model: CorrectionModel, range_mm: np.ndarray, amplitude: np.ndarray
                 ) -> pipeline_module.CorrectionResult:
    """The production path, at the precision chosen on the command line."""
    return correct(model, range_mm, amplitude, precision=PRECISION["value"])


# ---------------------------------------------------------------------------------------------
# machine


def cpu_peak(n_cores: int) -> dict[str, Any]:
    """Nominal float32 peak: cores x GHz x FLOPs per cycle per core, with the reasoning.

    FLOPs per cycle per core = 2 (an FMA is a multiply and an add) x float32 lanes of the widest
    FMA (16 for AVX-512, 8 for AVX2) x FMA pipes (2 on every x86 core with FMA listed here; AMD
    Zen 4 runs 512-bit FMAs on 256-bit pipes, so AVX-512 gives it no extra width). The clock is
    /proc/cpuinfo's "cpu MHz", which under a hypervisor is the nominal (TSC) clock, not boost.
    """
    info = cpuinfo()
    flags = set(info.get("flags", "").split())
    vendor, family = info.get("vendor_id", ""), int(info.get("cpu family", "0") or 0)
    ghz = float(info.get("cpu MHz", "0") or 0) / 1e3
    if "avx512f" in flags and not (vendor == "AuthenticAMD" and family < 26):
        simd, per_cycle = "AVX-512 (2 x 512-bit FMA pipes)", 2 * 16 * 2
    elif "avx512f" in flags:
        simd, per_cycle = "AVX-512 on 2 x 256-bit FMA pipes (Zen 4)", 2 * 8 * 2
    elif "fma" in flags and "avx2" in flags:
        simd, per_cycle = "AVX2 (2 x 256-bit FMA pipes)", 2 * 8 * 2
    elif "sse2" in flags:
        simd, per_cycle = "SSE2 (4-lane add + mul pipes)", 4 * 2
    else:
        simd, per_cycle = "unknown (scalar)", 2
    if vendor == "AuthenticAMD" and family >= 26 and "avx512f" in flags:
        simd += ", Zen 5"
    return {"cores": n_cores, "ghz": round(ghz, 3), "simd": simd, "flops_per_cycle": per_cycle,
            "peak_gflops": round(n_cores * ghz * per_cycle, 1),
            "bf16": bool(flags & set(PRECISION_FLAGS["bfloat16"])),
            "int8": bool(flags & set(PRECISION_FLAGS["int8"])),
            "how": f"{n_cores} cores x {ghz:.3f} GHz (cpuinfo 'cpu MHz', nominal: a core "
                   f"boosting above it can exceed 100 %) x {per_cycle} float32 FLOPs/cycle = "
                   f"2 (FMA) x lanes x pipes for {simd}"}


def gemm_ceiling(n: int = 1536, repeats: int = 5) -> float:
    """GFLOP/s of a float32 n x n x n torch GEMM, best of ``repeats`` (what is reachable now)."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    torch.mm(a, b)
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        torch.mm(a, b)
        best = min(best, time.perf_counter() - t0)
    return 2 * n ** 3 / best / 1e9


def machine() -> dict[str, Any]:
    """CPU model, cores, threads, load."""
    info = cpuinfo()
    extra = f" (family {info.get('cpu family')}, model {info.get('model')})" if info else ""
    return {"cpu": cpu_model() + extra, "cpus": os.cpu_count(),
            "affinity_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
            else os.cpu_count(),
            "torch_threads": torch.get_num_threads(), "numba_threads": numba.get_num_threads(),
            "torch": torch.__version__, "python": platform.python_version(),
            "load_average_start": [round(x, 2) for x in os.getloadavg()]}


# ---------------------------------------------------------------------------------------------
# data


def _resize(x: np.ndarray, h: int, w: int) -> np.ndarray:
    """Nearest-neighbour resize of an (H, W) array (keeps NaNs and sharp steps)."""
    ys = (np.arange(h) * x.shape[0] / h).astype(int)
    xs = (np.arange(w) * x.shape[1] / w).astype(int)
    return x[ys][:, xs]


def _synthetic(h: int = 140, w: int = 180, n: int = 4) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(0)
    out = []
    for _ in range(n):
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        r = 420.0 + 0.6 * x + 0.4 * y
        r[30:80, 40:100] -= 90.0
        r[(x - 60) ** 2 + (y - 110) ** 2 < 20 ** 2] -= 120.0
        r += rng.normal(0, 2.0, r.shape).astype(np.float32)
        a = (300.0 * (400.0 / r) ** 2).astype(np.float32)
        out.append((r.astype(np.float32), a))
    return out


def load_inputs(frames_path: Path | None, weights_path: Path | None
                ) -> tuple[CorrectionModel, list[tuple[np.ndarray, np.ndarray]], str]:
    """(model, [(range, amplitude)], description) at the model's native size."""
    if frames_path is not None:
        from tof_mpd_ros.correction.default_weights import default_weights_path

        weights_path = weights_path or default_weights_path()
        from tof_mpd_ros.correction.weights import load_weights
        from tof_mpd_ros.recordings import RecordingReader

        model = load_weights(weights_path)
        pipeline_module.require_patch_kind(model, "bench_pipeline.py (it times and checks the "
                                                  "patch kind's engine, F, G and the filter)")
        frames = [(f.range_mm, f.amplitude) for f in RecordingReader(frames_path).frames()]
        return model, frames, f"{frames_path} ({len(frames)} frames), weights {weights_path}"
    frames = _synthetic()
    model = CorrectionModel.untrained(IntrinsicCalibration.identity(140, 180), seed=0)
    return model, frames, "synthetic scene, untrained model (no --frames given)"


def at_size(model: CorrectionModel, frames: list[tuple[np.ndarray, np.ndarray]], h: int,
            w: int) -> tuple[CorrectionModel, list[tuple[np.ndarray, np.ndarray]]]:
    """The model and frames resized to (h, w) (nearest neighbour); unchanged at native size."""
    if model.shape == (h, w):
        return model, frames
    c = model.calibration
    calib = IntrinsicCalibration(_resize(c.c0, h, w), _resize(c.c1, h, w), _resize(c.c2, h, w),
                                 _resize(c.fitted, h, w), c.amplitude_term)
    resized = CorrectionModel(calib, model.encoding, model.range_net, model.boundary_nets,
                              model.geodesic)
    return resized, [(_resize(r, h, w), _resize(a, h, w)) for r, a in frames]


# ---------------------------------------------------------------------------------------------
# timing helpers


def summary(ms: list[float]) -> dict[str, float]:
    """Median and p90 (nearest rank) of a list of milliseconds."""
    if not ms:
        return {"median": math.nan, "p90": math.nan, "n": 0}
    s = sorted(ms)
    p90 = s[min(len(s) - 1, math.ceil(0.9 * len(s)) - 1)]
    return {"median": statistics.median(s), "p90": p90, "n": len(s)}


CLOCKS = ("wall", "cpu")


def now() -> tuple[float, float]:
    """(wall, process CPU) clocks in seconds; CPU time sums every thread of this process."""
    return time.perf_counter(), time.process_time()


def since(t0: tuple[float, float], scale: float = 1.0) -> tuple[float, float]:
    """Milliseconds elapsed on both clocks since ``t0``, times ``scale``."""
    t1 = now()
    return 1e3 * (t1[0] - t0[0]) * scale, 1e3 * (t1[1] - t0[1]) * scale


class Record:
    """Per-stage lists of (wall, cpu) milliseconds, one entry per frame."""

    def __init__(self) -> None:
        self.ms: dict[str, list[tuple[float, float]]] = defaultdict(list)

    def add(self, stage: str, ms: tuple[float, float]) -> None:
        self.ms[stage].append(ms)

    def summaries(self, stages: tuple[str, ...] | list[str]) -> dict[str, Any]:
        """{clock: {stage: summary or None}}."""
        return {c: {s: summary([m[i] for m in self.ms[s]]) if self.ms.get(s) else None
                    for s in stages} for i, c in enumerate(CLOCKS)}


class StageTimer:
    """Wraps what ``correct`` calls so that every call adds its duration to a stage.

    Three kinds of hook:

    * ``seq``: called on the caller's thread; adds wall and process CPU time to its stage;
    * ``container``: a sequential call that runs several stages on worker threads (the fast
      path's ``_Engine.networks``: per band, row encoding then the F+G GEMM and kernel);
    * ``inner``: what runs inside a container on the workers; only the CPU time of the calling
      thread (``time.thread_time``, blind to preemption) is summed over threads, to split the
      container's wall and CPU time between encoding and F+G in that proportion.

    Hooks whose target does not exist (another version of the pipeline) are skipped; a stage
    nothing was hooked for shows as missing and its time lands in "other".
    """

    HOOKS = (  # (stage, owner, attribute, kind)
        ("calibration", IntrinsicCalibration, "apply", "seq"),
        # pipeline._Engine
        ("encoding", pipeline_module, "frame_planes", "seq"),
        ("encoding+F+G", pipeline_module._Engine, "networks", "container"),
        ("encoding", pipeline_module, "encode_band", "inner"),
        ("encoding", pipeline_module, "encode_band_int8", "inner"),
        ("F+G", networks_module.PatchNets, "first_layer", "inner"),
        ("F+G", networks_module.PatchNets, "heads", "inner"),
        ("NMS+hysteresis", edges_module, "edge_map_from_best", "seq"),
        ("geodesic", geodesic_module, "geodesic_filter", "seq"),
    )

    def __init__(self) -> None:
        self.seq: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])
        self.inner: dict[str, float] = defaultdict(float)
        self.lock = threading.Lock()

    def reset(self) -> None:
        self.seq.clear()
        self.inner.clear()

    def wrap(self, stage: str, kind: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            t0, thread0 = now(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                wall, cpu = since(t0)
                thread_ms = 1e3 * (time.thread_time() - thread0)
                with self.lock:
                    if kind == "inner":
                        self.inner[stage] += thread_ms
                    else:
                        self.seq[stage][0] += wall
                        self.seq[stage][1] += cpu
        return timed

    def stages(self) -> dict[str, tuple[float, float]]:
        """(wall, cpu) ms per stage of the last call(s), containers split between stages."""
        out = {k: (v[0], v[1]) for k, v in self.seq.items() if k != "encoding+F+G"}
        if "encoding+F+G" in self.seq:
            wall, cpu = self.seq["encoding+F+G"]
            enc, nets = self.inner.get("encoding", 0.0), self.inner.get("F+G", 0.0)
            share = enc / (enc + nets) if enc + nets > 0 else 0.0
            e0, e1 = out.get("encoding", (0.0, 0.0))
            f0, f1 = out.get("F+G", (0.0, 0.0))
            out["encoding"] = (e0 + share * wall, e1 + share * cpu)
            out["F+G"] = (f0 + (1 - share) * wall, f1 + (1 - share) * cpu)
        return out

    @contextmanager
    def installed(self) -> Iterator[list[str]]:
        """Install the wrappers; yields the stages that could be hooked."""
        saved = []
        hooked: set[str] = set()
        for stage, owner, name, kind in self.HOOKS:
            if owner is None:
                continue
            original = owner.__dict__.get(name) if isinstance(owner, type) else getattr(
                owner, name, None)
            if original is None:
                continue
            saved.append((owner, name, original))
            hooked.update(("encoding", "F+G") if kind == "container" else (stage,))
            setattr(owner, name, self.wrap(stage, kind, original))
        try:
            yield sorted(hooked)
        finally:
            for owner, name, original in reversed(saved):
                setattr(owner, name, original)


def time_fast(model: CorrectionModel, frames: list[tuple[np.ndarray, np.ndarray]],
              repeats: int) -> dict[str, Any]:
    """Fast path: un-instrumented totals, then the same calls with the stages instrumented."""
    fast_correct(model, *frames[0])                              # warm-up (numba, allocs)
    rec = Record()
    for i in range(repeats):
        t0 = now()
        fast_correct(model, *frames[i % len(frames)])
        rec.add("total", since(t0))
    timer = StageTimer()
    with timer.installed() as hooked:
        for i in range(repeats):
            timer.reset()
            t0 = now()
            fast_correct(model, *frames[i % len(frames)])
            whole = since(t0)
            stages = timer.stages()
            for stage in hooked:
                rec.add(stage, stages.get(stage, (0.0, 0.0)))
            rec.add("other", tuple(whole[c] - sum(stages.get(s, (0.0, 0.0))[c] for s in hooked)
                                   for c in range(2)))
    return {"stages": rec.summaries(STAGES), "total": rec.summaries(("total",)),
            "hooked": hooked, "scores": head_scores(model, frames[0])}


def head_scores(model: CorrectionModel, frame: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(4, H, W) G probabilities of a frame (the reference's NMS input), from the modules."""
    r, a = frame
    return g_probabilities(model, model.calibration.apply(r, a), a)


def time_reference(model: CorrectionModel, frames: list[tuple[np.ndarray, np.ndarray]],
                   n_frames: int, n_pixels: int, scores: np.ndarray | None, seed: int = 0
                   ) -> dict[str, Any]:
    """Reference path on sampled pixels of ``n_frames`` frames, extrapolated per frame."""
    rng = np.random.default_rng(seed)
    h, w = model.shape
    n = h * w
    weights = ref.ReferenceWeights.from_model(model)
    g = model.geodesic
    rec = Record()
    diffs = {"range_f_mm": 0.0, "confidence": 0.0, "range_mm": 0.0}
    for fi in range(n_frames):
        r, a = frames[fi % len(frames)]
        fast = fast_correct(model, r, a)
        flat = np.sort(rng.choice(n, size=min(n_pixels, n), replace=False))
        pts = [(int(p // w), int(p % w)) for p in flat]
        scale = n / len(pts)
        stage: dict[str, tuple[float, float]] = {}

        t0 = now()
        calibrated = ref.reference_calibration(model.calibration, r, a)
        stage["calibration"] = since(t0)

        t0 = now()
        planes = ref.reference_planes(calibrated, a, model.encoding)
        t_planes = since(t0)
        t0 = now()
        feats = np.stack([ref.reference_encode_pixel(planes, y, x, model.encoding)
                          for y, x in pts])
        t_pixels = since(t0, scale)
        stage["encoding"] = (t_planes[0] + t_pixels[0], t_planes[1] + t_pixels[1])

        t0 = now()
        f_mm = ref.reference_range_net(weights, feats)
        stage["F"] = since(t0, scale)
        t0 = now()
        probs = ref.reference_boundary_nets(weights, feats)
        stage["G"] = since(t0, scale)
        stage["F+G"] = (stage["F"][0] + stage["G"][0], stage["F"][1] + stage["G"][1])

        # Same function as the fast path: time it on the scores the fast path fed it.
        if scores is not None and scores.shape[-2:] == (h, w):
            t0 = now()
            ref.edge_map_from_responses(scores)
            stage["NMS+hysteresis"] = since(t0)

        # Geodesic: the per-pixel search on the sample, snapping on the whole frame, both on
        # the fast path's R_F and edges (the tests check they equal the reference's).
        t0 = now()
        raw = ref.reference_geodesic_raw(fast.range_f_mm, fast.edges, k=g.k, sigma=g.sigma,
                                         step=g.step, pixels=pts)
        t_search = since(t0, scale)
        t0 = now()
        ref.reference_snap(raw, fast.range_f_mm, fast.edges)
        t_snap = since(t0)
        stage["geodesic"] = (t_search[0] + t_snap[0], t_search[1] + t_snap[1])
        for name, ms in stage.items():
            rec.add(name, ms)
        parts = [stage[s] for s in ("calibration", "encoding", "F+G", "NMS+hysteresis",
                                    "geodesic") if s in stage]
        rec.add("total", (sum(p[0] for p in parts), sum(p[1] for p in parts)))

        # Agreement on the sampled pixels.
        ys, xs = np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
        ok = fast.valid[ys, xs]
        rf = calibrated[ys, xs] + f_mm
        diffs["range_f_mm"] = max(diffs["range_f_mm"], float(np.max(
            np.abs(rf[ok] - fast.range_f_mm[ys, xs][ok]), initial=0.0)))
        conf = 1.0 - probs.max(axis=1)
        diffs["confidence"] = max(diffs["confidence"], float(np.max(
            np.abs(conf[ok] - fast.confidence[ys, xs][ok]), initial=0.0)))
        inner = ok & ~fast.edges[ys, xs] & np.isfinite(raw[ys, xs])
        diffs["range_mm"] = max(diffs["range_mm"], float(np.max(
            np.abs(raw[ys, xs][inner] - fast.range_mm[ys, xs][inner]), initial=0.0)))
    return {"stages": rec.summaries(STAGES), "total": rec.summaries(("total",)),
            "pixels_per_frame": min(n_pixels, n), "frames": n_frames,
            "sample_agreement_max_abs": diffs}


def network_flops_per_pixel(model: CorrectionModel) -> int:
    """2 x multiply-adds of F and the 4 G heads as defined (dense layers, one-hot included)."""
    f = sum(layer.in_features * layer.out_features for layer in model.range_net.layers)
    g = model.boundary_nets
    h1, h2 = g.hidden
    return 2 * (f + g.n_heads * (g.n_features * h1 + h1 * h2 + h2 * 2))


# ---------------------------------------------------------------------------------------------
# report


def _fmt(x: float | None) -> str:
    return "      -" if x is None or not math.isfinite(x) else f"{x:9.2f}"


def print_size(label: str, fast: dict[str, Any], slow: dict[str, Any]) -> None:
    print(f"\n== {label}: ms per frame (reference: {slow['pixels_per_frame']} sampled pixels "
          f"x {slow['frames']} frames, extrapolated to the whole frame) ==")
    print(f"{'':16s} {'--------- wall clock ---------':^39s}   "
          f"{'------- process CPU time -------':^39s}")
    head = f"{'ref med':>9s} {'ref p90':>9s} {'fast med':>9s} {'fast p90':>9s}  {'ratio':>6s}"
    print(f"{'stage':16s} {head}   {head}")
    notes = {"F": "fast: fused into F+G", "G": "fast: fused into F+G",
             "NMS+hysteresis": "ref: edge_map_from_responses",
             "other": "fast: glue outside stages",
             "total": "fast: un-instrumented correct()"}
    for s in (*STAGES, "total"):
        cells = []
        for clock in CLOCKS:
            src_f = fast["total" if s == "total" else "stages"][clock].get(s)
            src_r = slow["total" if s == "total" else "stages"][clock].get(s)
            fm, fp = (src_f["median"], src_f["p90"]) if src_f else (None, None)
            rm, rp = (src_r["median"], src_r["p90"]) if src_r else (None, None)
            ratio = f"{rm / fm:5.0f}x" if rm and fm and fm > 0 else "     -"
            cells.append(f"{_fmt(rm)} {_fmt(rp)} {_fmt(fm)} {_fmt(fp)}  {ratio}")
        note = f"  ({notes[s]})" if s in notes else ""
        print(f"{s:16s} {cells[0]}   {cells[1]}{note}")
    agree = slow["sample_agreement_max_abs"]
    print("reference vs fast on the sampled pixels, max |diff|: "
          + ", ".join(f"{k} {v:.2e}" for k, v in agree.items()))


def full_check(model: CorrectionModel, frames: list[tuple[np.ndarray, np.ndarray]], n: int
               ) -> dict[str, Any]:
    """Whole-frame reference_correct vs correct on n frames: edge and range agreement."""
    worst = {"edge_pixels_differing": 0, "range_mm_max_abs": 0.0, "nan_pattern_equal": True,
             "frames": n, "edge_pixels": 0}
    h, w = model.shape
    print(f"\n== full-frame check at {w}x{h}: reference_correct vs correct on {n} frames ==")
    for i in range(n):
        r, a = frames[i % len(frames)]
        t0 = now()
        slow = ref.reference_correct(model, r, a)
        ms = since(t0)
        fast = fast_correct(model, r, a)
        differing = int((slow.edges != fast.edges).sum())
        diff = float(np.nanmax(np.abs(slow.range_mm - fast.range_mm), initial=0.0))
        same_nan = bool(np.array_equal(np.isnan(slow.range_mm), np.isnan(fast.range_mm)))
        worst["edge_pixels_differing"] += differing
        worst["edge_pixels"] += int(fast.edges.sum())
        worst["range_mm_max_abs"] = max(worst["range_mm_max_abs"], diff)
        worst["nan_pattern_equal"] &= same_nan
        print(f"frame {i}: {int(fast.edges.sum())} edge pixels, {differing} differ; max |range "
              f"diff| {diff:.2e} mm; NaN pattern equal {same_nan}; reference took "
              f"{ms[0] / 1e3:.1f} s wall, {ms[1] / 1e3:.1f} s CPU")
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=Path, help="recording (default: a synthetic scene)")
    parser.add_argument("--weights", type=Path, help="weights (default: the shipped ones)")
    parser.add_argument("--sizes", default="180x140,320x240", help="WxH list")
    parser.add_argument("--repeats", type=int, default=30, help="fast-path calls per size")
    parser.add_argument("--ref-frames", type=int, default=3)
    parser.add_argument("--ref-pixels", type=int, default=1000, help="sampled pixels per frame")
    parser.add_argument("--full-check", type=int, default=0, metavar="N",
                        help="also run the whole reference on N native-size frames and compare "
                             "(~20 s CPU each at 180x140)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch intra-op threads (default: torch's own choice)")
    parser.add_argument("--precision", choices=PRECISIONS, default="float32",
                        help="fast path's first-layer GEMMs (bfloat16: AVX512-BF16/AMX; "
                             "int8: VNNI/AMX-INT8)")
    parser.add_argument("--json", type=Path, help="also write the numbers to this JSON file")
    args = parser.parse_args()
    PRECISION["value"] = args.precision
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    mach = machine()
    peak = cpu_peak(mach["affinity_cpus"])
    model0, frames0, source = load_inputs(args.frames, args.weights)
    print(f"machine: {mach['cpu']}, {mach['cpus']} CPUs ({mach['affinity_cpus']} usable), "
          f"torch {mach['torch']} with {mach['torch_threads']} threads, numba "
          f"{mach['numba_threads']} threads, python {mach['python']}")
    print(f"load average at start (1/5/15 min): {mach['load_average_start']}"
          + ("  ** machine busy: wall times are inflated **"
             if mach["load_average_start"][0] > 0.5 * (mach["cpus"] or 1) else ""))
    print(f"inputs: {source}; fast path precision {args.precision}")
    print(f"nominal peak: {peak['peak_gflops']} GFLOP/s float32 = {peak['how']}")
    ceiling = gemm_ceiling()
    print(f"measured now: float32 1536^3 torch GEMM {ceiling:.0f} GFLOP/s "
          f"({100 * ceiling / peak['peak_gflops']:.0f} % of nominal peak)")
    print(f"reference line: the paper, {PAPER_MS:.0f} ms per frame with a GPU; targets "
          + ", ".join(f"{k} <= {v:.0f} ms" for k, v in TARGETS_MS.items()))

    results: dict[str, Any] = {"machine": mach, "peak": peak, "gemm_ceiling_gflops": ceiling,
                               "paper_ms": PAPER_MS, "targets_ms": TARGETS_MS, "inputs": source,
                               "precision": args.precision, "sizes": {}}
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.lower().split("x"))
        model, frames = at_size(model0, frames0, h, w)
        fast = time_fast(model, frames, args.repeats)
        slow = time_reference(model, frames, args.ref_frames, args.ref_pixels, fast["scores"])
        label = f"{w}x{h}" + ("" if model is model0 else " (upscaled frames and calibration)")
        print_size(label, fast, slow)
        flops = network_flops_per_pixel(model) * h * w
        fg_wall = fast["stages"]["wall"].get("F+G")
        fg_cpu = fast["stages"]["cpu"].get("F+G")
        gflops = (flops / (fg_wall["median"] * 1e-3) / 1e9 if fg_wall and fg_wall["median"] > 0
                  else math.nan)
        per_cpu_s = (flops / (fg_cpu["median"] * 1e-3) / 1e9 if fg_cpu and fg_cpu["median"] > 0
                     else math.nan)
        core_peak = peak["peak_gflops"] / max(peak["cores"], 1)
        print(f"networks: {flops / 1e9:.2f} GFLOP per frame "
              f"({network_flops_per_pixel(model)} FLOPs/pixel); fast F+G {gflops:.1f} GFLOP/s "
              f"wall = {100 * gflops / peak['peak_gflops']:.1f} % of the nominal peak, "
              f"{100 * gflops / ceiling:.0f} % of the GEMM measured now; "
              f"{per_cpu_s:.1f} GFLOP per CPU-second = {100 * per_cpu_s / core_peak:.1f} % of "
              "one core's peak")
        total = fast["total"]["wall"]["total"]["median"]
        total_cpu = fast["total"]["cpu"]["total"]["median"]
        target = TARGETS_MS.get(f"{w}x{h}")
        verdict = "" if target is None else (
            f"; target {target:.0f} ms {'met' if total <= target else 'NOT met'} (wall)")
        print(f"fast total: {total:.1f} ms wall ({PAPER_MS / total:.2f}x the paper's speed), "
              f"{total_cpu:.1f} ms CPU{verdict}")
        fast.pop("scores")
        results["sizes"][f"{w}x{h}"] = {"fast": fast, "reference": slow,
                                        "upscaled": model is not model0,
                                        "network_gflop_per_frame": flops / 1e9,
                                        "network_gflops_wall": gflops,
                                        "network_gflop_per_cpu_second": per_cpu_s,
                                        "fraction_of_peak": gflops / peak["peak_gflops"]}
    if args.full_check:
        results["full_check"] = full_check(model0, frames0, args.full_check)
    results["machine"]["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    print(f"\nload average at end: {results['machine']['load_average_end']}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=float), encoding="utf-8")
        print(f"wrote {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
