"""Speed of the AMCW ToF simulator at 180x140, side by side with the path tracer it is checked on.

For a few scenes — the golden 150 mm cube and random cell scenes of both object splits (first
planned viewpoint) — it times, in one run:

* the world of the scene (table across the light's cone, every object face; ``world_from_scene``);
* multipath with 1, 2 and 3 diffuse bounces (world + transport), and 2 bounces on 1 thread;
* a whole simulated capture (``SimCell.capture`` without the structured-light reference: ray cast
  of the 3x3-supersampled window, world, two bounces, noise and systematic errors);
* ``render_from_reference`` alone and with 3 other views fused (what ``sim predict`` and the
  mismatch tool call);
* when the ``[pathtrace]`` extra is installed, Mitsuba 3 + mitransient on the same scene and crop
  (all bounces, ``--spp`` samples per pixel), so the ratio is measured here, not quoted.

Prints the machine (CPU model, cores, numba threads) and median ms per frame; ``--json`` writes
the numbers. Usage: ``python benchmarks/bench_sim.py [--repeats 3] [--scenes 3] [--spp 1024]
[--json out.json]``. Takes ~1-2 min (numba kernels compile on the first run, then come from the
on-disk cache; the path tracer adds ~10 s per scene).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time

from tof_mpd_ros.machine import cpu_model, set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

import numba
import numpy as np

from tof_mpd_ros.pose import look_at
from tof_mpd_ros.sim.cell import CameraModel, SimCell
from tof_mpd_ros.sim.objects import ObjectSpec
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import PlacedObject, Scene, Table, make_scene
from tof_mpd_ros.sim.tof import ToFConfig, render_from_reference
from tof_mpd_ros.sim.tof.reference_world import ReferenceView
from tof_mpd_ros.sim.tof.transport import indirect_phasor
from tof_mpd_ros.sim.tof.world import world_from_scene
from tof_mpd_ros.sim.viewpoints import plan_viewpoints


def timed(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` in ms, after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def cube_case() -> tuple[str, Scene, np.ndarray, list[np.ndarray]]:
    """The issue's 150 mm cube (rotated 20°) on a table, camera 300 mm above its top."""
    box = PlacedObject(ObjectSpec(1, "box", (150.0, 150.0, 150.0), 0.5), 1, 450.0, 0.0, 0.0,
                       math.radians(20))
    target = np.array([450.0, 0.0, 60.0])
    pose = look_at(np.array([330.0, 0.0, 450.0]), target)
    others = [look_at(np.array(e), target) for e in ([570.0, 0.0, 450.0], [450.0, 120.0, 450.0],
                                                     [450.0, -120.0, 450.0])]
    return "cube 150 mm", Scene(Table(albedo=0.5), (box,)), pose, others


def cell_case(split: str, seed: int) -> tuple[str, Scene, np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    scene = make_scene(split, rng)
    views = plan_viewpoints(scene, rng).viewpoints
    return (f"cell {split} seed {seed} ({len(scene.objects)} objects)", scene,
            views[0].camera_to_base_mm, [v.camera_to_base_mm for v in views[1:4]])


def path_tracer(scene: Scene, pose: np.ndarray, spp: int):
    """A timing function for the path tracer, or None when the extra is not installed."""
    try:
        from tof_mpd_ros.sim.pathtrace import render_phasor
        from tof_mpd_ros.sim.pathtrace.render import load_mitsuba
        load_mitsuba()
    except Exception as err:
        print(f"  (path tracer not available: {err})")
        return None
    k = CameraModel().intrinsics
    f = ToFConfig.nominal().mod_freq_hz
    return lambda: render_phasor(scene, pose, k, mod_freq_hz=f, spp=spp, max_depth=-1, seed=0)


def bench_case(name, scene, pose, others, args) -> dict[str, float]:
    k = CameraModel().intrinsics
    cfg = ToFConfig.nominal()
    f, power = cfg.mod_freq_hz, cfg.light_power
    surface = render_surface(scene, pose, k)
    ref = surface.range_mm
    views = [ReferenceView(render_surface(scene, p, k).range_mm, p) for p in others]
    cell = SimCell()
    rows = {"world of the scene": timed(lambda: world_from_scene(scene, pose), args.repeats)}
    for b in (1, 2, 3):
        def multipath(b=b):
            return indirect_phasor(surface, world_from_scene(scene, pose), mod_freq_hz=f,
                                   light_power=power, bounces=b)
        rows[f"multipath, {b} bounce(s)"] = timed(multipath, args.repeats)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    rows["multipath, 2 bounces, 1 thread"] = timed(
        lambda: indirect_phasor(surface, world_from_scene(scene, pose), mod_freq_hz=f,
                                light_power=power), args.repeats)
    numba.set_num_threads(threads)
    rows["capture (no SL reference)"] = timed(
        lambda: cell.capture(scene, pose, np.random.default_rng(0), with_reference=False),
        args.repeats)
    rows["from reference, alone"] = timed(
        lambda: render_from_reference(ref, k, 0.5, cfg), args.repeats)
    rows[f"from reference, {len(views)} views fused"] = timed(
        lambda: render_from_reference(ref, k, 0.5, cfg, camera_to_world_mm=pose,
                                      other_views=views), args.repeats)
    pt = path_tracer(scene, pose, args.spp) if args.spp else None
    if pt is not None:
        rows[f"path tracer, {args.spp} spp, all bounces"] = timed(pt, 1)
    print(f"{name}:")
    for label, ms in rows.items():
        print(f"  {label:<44s} {ms:9.1f} ms")
    if pt is not None:
        ratio = rows[f"path tracer, {args.spp} spp, all bounces"] / rows["multipath, 2 bounce(s)"]
        print(f"  path tracer / two-bounce multipath: {ratio:.1f}x")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenes", type=int, default=3, help="random cell scenes besides the cube")
    parser.add_argument("--spp", type=int, default=1024,
                        help="path-tracer samples per pixel (0 = skip the path tracer)")
    parser.add_argument("--json", help="also write the numbers to this JSON file")
    args = parser.parse_args()

    machine = {"cpu": cpu_model(), "cores": os.cpu_count(), "numba_threads":
               numba.get_num_threads(), "python": platform.python_version(),
               "numpy": np.__version__, "numba": numba.__version__}
    print(f"machine: {machine['cpu']}, {machine['cores']} cores, numba {machine['numba']} "
          f"({machine['numba_threads']} threads); frame 180x140 (the paper's crop)")
    cases = [cube_case()] + [cell_case(("train", "test")[i % 2], i) for i in range(args.scenes)]
    results = {name: bench_case(name, scene, pose, others, args)
               for name, scene, pose, others in cases}
    medians = {label: statistics.median(r[label] for r in results.values())
               for label in next(iter(results.values()))}
    print("median over the scenes:")
    for label, ms in medians.items():
        print(f"  {label:<44s} {ms:9.1f} ms")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "median_ms": medians, "per_scene_ms": results}, f,
                      indent=2)


if __name__ == "__main__":
    main()
