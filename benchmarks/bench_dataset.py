"""Where the time of ``tof-mpd sim dataset`` goes, and how long MD-Train + MD-Test take.

Profiles the simulated cell stage by stage on a sample of dataset scenes, *on one core* (numba
limited to one thread), with the dataset's own seeds, cell and viewpoint plans:

* per capture: the supersampled ray cast of the ToF window, the ToF render with multipath (the
  cell's path: the scene's world built, the crop receives) and without it, the
  structured-light reference — each of its 30 scans, with its compiled camera-cast +
  projector-visibility kernel (on code before that kernel: the SL camera's ray cast and the
  projector visibility) — and the fusion of all scans; then the whole
  :meth:`SimCell.capture` as the dataset calls it;
* per scene: building the scene and planning its 18 viewpoints;
* per calibration capture: :meth:`SimCell.capture_checkerboard`;
* the parent process: writing a frame to the MCAP recording; a worker process's start-up.

Every stage is timed both as CPU time of this process (``time.process_time``, what a core
spends on it) and as wall time; on a busy machine the wall time is inflated by the load (printed
with the machine) and the CPU time somewhat by cache and hyper-thread contention, so the CPU
time is the better estimate of a quiet core. The projection adds up the CPU time of the full
dataset (``DatasetSpec()``: 30 + 20 scenes x 18 views, 770 calibration captures) and divides it
by the workers (default 2), assuming one free core per worker.

Usage: ``python benchmarks/bench_dataset.py [--scenes 2] [--views 6] [--calibration 20]
[--workers 2] [--json out.json]``. The defaults take ~1 min on a quiet 2-core machine. To time
another version of the code (e.g. the last commit), run it with that tree first on
``PYTHONPATH``: the script adapts to the older API.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tof_mpd_ros.machine import cpu_model, set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

import numba
import numpy as np

from tof_mpd_ros.pose import make_pose, transform_points
from tof_mpd_ros.sim import raycast
from tof_mpd_ros.sim import structured_light as sl
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.checkerboard import calibration_poses
from tof_mpd_ros.sim.dataset import DatasetSpec, scene_rng
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import make_scene
from tof_mpd_ros.sim.tof import render_tof
from tof_mpd_ros.sim.viewpoints import ViewpointConfig, plan_viewpoints


class Timer:
    """Accumulates CPU and wall seconds per stage label."""

    def __init__(self) -> None:
        self.cpu: dict[str, list[float]] = defaultdict(list)
        self.wall: dict[str, list[float]] = defaultdict(list)

    def __call__(self, label: str, fn: Callable[[], Any]) -> Any:
        """Run ``fn()``, record its CPU and wall time under ``label``, return its result."""
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        self.cpu[label].append(time.process_time() - c0)
        self.wall[label].append(time.perf_counter() - w0)
        return out

    def mean(self, label: str) -> tuple[float, float]:
        """(mean CPU s, mean wall s) of ``label``."""
        return statistics.fmean(self.cpu[label]), statistics.fmean(self.wall[label])


def _accepts(fn: Callable, name: str) -> bool:
    return name in inspect.signature(fn).parameters


def profile_capture(cell: SimCell, scene, pose: np.ndarray, view_index: int,
                    timer: Timer, stamp_ns: int) -> Any:
    """Time the stages of one :meth:`SimCell.capture` and then the call itself.

    Returns:
        The captured :class:`~tof_mpd_ros.frame.ToFFrame`.
    """
    cam = cell.camera
    surface = timer("ray cast (ToF window, 3x3 supersampled)", lambda: render_surface(
        scene, pose, cam.window.scaled(cam.supersample)))
    kwargs = {"receivers": cam.crop_mask} if _accepts(render_tof, "receivers") else {}
    off = cell.tof.with_effect("multipath", enabled=False)

    def multipath_on():
        # the cell's path: the scene's world (table across the light's cone, every face)
        if _accepts(render_tof, "world"):
            from tof_mpd_ros.sim.tof.world import world_from_scene
            kwargs["world"] = world_from_scene(scene, pose)
        return render_tof(surface, cell.tof, np.random.default_rng(0),
                          supersample=cam.supersample, **kwargs)

    timer("ToF render, multipath on", multipath_on)
    timer("ToF render, multipath off", lambda: render_tof(
        surface, off, np.random.default_rng(0), supersample=cam.supersample))
    sensor, rng = cell.structured_light, np.random.default_rng(1)
    points = []
    for scan_pose in sl.scan_poses(pose, sensor, cell.fusion):
        if hasattr(raycast, "sl_ranges"):  # one kernel: camera cast + projector visibility
            projector = scan_pose @ make_pose(np.eye(3), np.array(sensor.projector_in_sl_mm))
            timer("  SL cast + projector visibility kernel", lambda p=scan_pose, q=projector:
                  raycast.sl_ranges(scene, p, sensor.intrinsics, q,
                                    max_incidence_deg=sensor.max_incidence_deg,
                                    tol_mm=sensor.occlusion_tol_mm))
        else:  # the numpy path: a camera image, then the visibility of its points
            timer("  SL camera ray cast", lambda p=scan_pose: render_surface(
                scene, p, sensor.intrinsics))
            probe = render_surface(scene, scan_pose, sensor.intrinsics)
            ok = np.isfinite(probe.range_mm.reshape(-1))
            rays = sensor.intrinsics.ray_directions().reshape(-1, 3)[ok]
            pts = transform_points(scan_pose, rays * probe.range_mm.reshape(-1)[ok, None])
            timer("  SL projector visibility", lambda p=scan_pose, q=pts:
                  sl._lit_by_projector(scene, q, p, sensor))
        points.append(timer("SL scan (each)", lambda p=scan_pose: sl.sl_scan(
            scene, p, rng, sensor)))
    cloud = np.concatenate(points)
    timer("SL fusion (30 scans)", lambda: sl.fuse_points(cloud, pose, cam.intrinsics,
                                                         cell.fusion))
    timer("SL reference (30 scans + fusion)", lambda: sl.reference_range(
        scene, pose, cam.intrinsics, np.random.default_rng(2), sensor, cell.fusion))
    return timer("capture (as the dataset calls it)", lambda: cell.capture(
        scene, pose, np.random.default_rng(3), frame_index=view_index, stamp_ns=stamp_ns))


def worker_startup_s() -> float:
    """Wall seconds for a fresh interpreter to import the cell and run a tiny capture
    (numba kernels load from the on-disk cache), as a spawned dataset worker does."""
    code = ("import numpy as np; from tof_mpd_ros.sim.cell import SimCell; "
            "from tof_mpd_ros.sim.checkerboard import calibration_poses; "
            "SimCell().capture_checkerboard(calibration_poses(1, np.random.default_rng(0))[0], "
            "np.random.default_rng(0))")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, env=dict(os.environ))
    return time.perf_counter() - t0


def frame_write_s(frames: list) -> float:
    """CPU seconds per frame for the parent to write frames to an MCAP recording (zstd)."""
    from tof_mpd_ros.recordings.writer import RecordingWriter

    with tempfile.TemporaryDirectory() as tmp:
        c0 = time.process_time()
        with RecordingWriter(Path(tmp) / "rec", compression="zstd") as writer:
            for frame in frames:
                writer.write_frame(frame)
        return (time.process_time() - c0) / max(len(frames), 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", type=int, default=2,
                        help="sample scenes (alternately train and test)")
    parser.add_argument("--views", type=int, default=6,
                        help="views profiled per sample scene (spread over its 18)")
    parser.add_argument("--calibration", type=int, default=20,
                        help="calibration captures profiled")
    parser.add_argument("--workers", type=int, default=2, help="workers of the projection")
    parser.add_argument("--json", help="also write the numbers to this JSON file")
    args = parser.parse_args()

    numba.set_num_threads(1)  # one core per stage: the per-core cost
    load_start = os.getloadavg()
    spec = DatasetSpec()
    cell = SimCell()
    timer = Timer()

    # compile / load every numba kernel before timing
    warm_rng = scene_rng(spec.seed, "train", 0)
    warm_scene = make_scene("train", warm_rng)
    warm_plan = plan_viewpoints(warm_scene, warm_rng, ViewpointConfig(n_views=3))
    cell.capture(warm_scene, warm_plan.viewpoints[0].camera_to_base_mm,
                 np.random.default_rng(0))
    cell.capture_checkerboard(calibration_poses(1, np.random.default_rng(0))[0],
                              np.random.default_rng(0))

    frames = []
    for k in range(args.scenes):
        split, index = ("train", k // 2) if k % 2 == 0 else ("test", k // 2)
        rng = scene_rng(spec.seed, split, index)
        scene = timer("scene: build", lambda r=rng, s=split: make_scene(s, r))
        n_bands = 3 if spec.views_per_scene % 3 == 0 else 1
        plan_cfg = ViewpointConfig(n_views=spec.views_per_scene, n_height_bands=n_bands)
        plan = timer("scene: plan 18 viewpoints", lambda r=rng, s=scene, c=plan_cfg:
                     plan_viewpoints(s, r, c))
        step = max(1, len(plan.viewpoints) // max(args.views, 1))
        for view in plan.viewpoints[::step][:args.views]:
            frames.append(profile_capture(cell, scene, view.camera_to_base_mm, view.index,
                                          timer, stamp_ns=len(frames) + 1))
        print(f"  profiled {split} scene {index} ({len(scene.objects)} objects)", flush=True)
    board_poses = calibration_poses(args.calibration, np.random.default_rng(5))
    for i, board in enumerate(board_poses):
        timer("calibration capture", lambda b=board, j=i: cell.capture_checkerboard(
            b, np.random.default_rng(j), frame_index=j))
    write_s = frame_write_s(frames)
    startup_s = worker_startup_s()
    load_end = os.getloadavg()

    # ---- report
    machine = {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(),
               "numpy": np.__version__, "numba": numba.__version__,
               "load_average_1min": [round(load_start[0], 1), round(load_end[0], 1)]}
    print(f"machine: {machine['cpu']}, {machine['cores']} cores, python {machine['python']}, "
          f"numpy {machine['numpy']}, numba {machine['numba']} (1 thread for the stages)")
    print(f"load average (1 min) at start / end: {load_start[0]:.1f} / {load_end[0]:.1f} "
          f"on {os.cpu_count()} cores")
    n_captures = len(timer.cpu["capture (as the dataset calls it)"])
    print(f"sample: {args.scenes} scene(s), {n_captures} captures, "
          f"{args.calibration} calibration captures")
    print(f"{'stage':<44s} {'CPU ms':>9s} {'wall ms':>9s}   (mean per call)")
    stages = {}
    order = ["ray cast (ToF window, 3x3 supersampled)", "ToF render, multipath on",
             "ToF render, multipath off", "SL scan (each)", "  SL camera ray cast",
             "  SL projector visibility", "  SL cast + projector visibility kernel",
             "SL fusion (30 scans)",
             "SL reference (30 scans + fusion)", "capture (as the dataset calls it)",
             "scene: build", "scene: plan 18 viewpoints", "calibration capture"]
    for label in sorted(timer.cpu, key=lambda x: order.index(x) if x in order else len(order)):
        cpu, wall = timer.mean(label)
        stages[label] = {"cpu_ms": 1e3 * cpu, "wall_ms": 1e3 * wall, "calls": len(timer.cpu[label])}
        print(f"  {label:<42s} {1e3 * cpu:9.1f} {1e3 * wall:9.1f}")
    print(f"  {'write one frame (parent, MCAP zstd)':<42s} {1e3 * write_s:9.1f}")
    print(f"  {'worker start-up (spawn, imports)':<42s} {'':9s} {1e3 * startup_s:9.1f}")

    on_cpu, on_wall = timer.mean("ToF render, multipath on")
    off_cpu, off_wall = timer.mean("ToF render, multipath off")
    h, w = cell.camera.crop[1], cell.camera.crop[0]
    print(f"ToF frame {w}x{h} (+{cell.camera.margin_px} px margin), one core: multipath on "
          f"{1 / on_cpu:.2f} frames/s (CPU; {1 / on_wall:.2f} wall), off {1 / off_cpu:.1f} "
          f"frames/s (CPU; {1 / off_wall:.1f} wall)")

    capture_cpu, _ = timer.mean("capture (as the dataset calls it)")
    scene_cpu = timer.mean("scene: build")[0] + timer.mean("scene: plan 18 viewpoints")[0]
    cal_cpu, _ = timer.mean("calibration capture")
    n_scenes = spec.n_train_scenes + spec.n_test_scenes
    n_views = n_scenes * spec.views_per_scene
    total_frames = n_views + spec.n_calibration
    cpu_total = (n_views * capture_cpu + n_scenes * scene_cpu + spec.n_calibration * cal_cpu
                 + total_frames * write_s + args.workers * startup_s)
    wall = cpu_total / args.workers
    print(f"projection, MD-Train + MD-Test ({n_scenes} scenes x {spec.views_per_scene} views) "
          f"+ {spec.n_calibration} calibration captures: {cpu_total / 60:.1f} CPU-min -> "
          f"{wall / 60:.1f} min on {args.workers} quiet cores "
          f"({n_views} x {capture_cpu:.2f} s captures, {spec.n_calibration} x "
          f"{1e3 * cal_cpu:.0f} ms calibration)")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "stages": stages, "write_frame_ms": 1e3 * write_s,
                       "worker_startup_s": startup_s,
                       "frames_per_s_multipath_on_cpu": 1 / on_cpu,
                       "frames_per_s_multipath_off_cpu": 1 / off_cpu,
                       "projected_cpu_min": cpu_total / 60,
                       "projected_wall_min": wall / 60, "workers": args.workers}, f, indent=2)


if __name__ == "__main__":
    main()
