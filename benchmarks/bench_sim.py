"""Frames per second of the AMCW ToF simulator at 180x140, multipath on vs off, side by side.

Renders a random cell scene (table + 2-5 library objects, first planned viewpoint) three ways:

* ``render_tof`` on a 3x3-supersampled ray-cast surface of the 180x140 crop (mixed pixels from
  the real footprint), nominal config with and without ``multipath``;
* ``render_from_reference`` on the crop's centre-ray range image (what the mismatch tool calls);
* the one-bounce transport alone, with numba's default thread count and with 1 thread.

Prints the machine (CPU model, cores, numba threads), medians in ms and frames/s, and the
multipath on/off ratio; ``--json`` writes the same numbers. Usage:
``python benchmarks/bench_sim.py [--repeats 5] [--json out.json]``. Takes ~30 s (numba kernels
compile on the first run, ~10 s, then come from the on-disk cache).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numba
import numpy as np
from bench_machine import cpu_model

from tof_mpd_ros.camera import PAPER_CROP, Intrinsics
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import make_scene
from tof_mpd_ros.sim.tof import ToFConfig, render_from_reference, render_tof
from tof_mpd_ros.sim.tof.render import centre_samples
from tof_mpd_ros.sim.tof.transport import indirect_phasor
from tof_mpd_ros.sim.viewpoints import plan_viewpoints

SUPERSAMPLE = 3



def timed(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` in ms, after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="also write the numbers to this JSON file")
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    scene = make_scene("test", rng)
    view = plan_viewpoints(scene, rng).viewpoints[0]
    k = Intrinsics.ds325().crop(*PAPER_CROP)
    surface = render_surface(scene, view.camera_to_base_mm, k.scaled(SUPERSAMPLE))
    reference = centre_samples(surface, SUPERSAMPLE).range_mm
    on = ToFConfig.nominal()
    off = on.with_effect("multipath", enabled=False)

    def tof(cfg: ToFConfig):
        return lambda: render_tof(surface, cfg, np.random.default_rng(0),
                                  supersample=SUPERSAMPLE)

    def ref(cfg: ToFConfig):
        return lambda: render_from_reference(reference, k, config=cfg,
                                             rng=np.random.default_rng(0))

    pixel_surface = centre_samples(surface, SUPERSAMPLE)

    def transport() -> None:
        indirect_phasor(pixel_surface, mod_freq_hz=on.mod_freq_hz, light_power=on.light_power)

    default_threads = numba.get_num_threads()
    rows = {}
    for label, fn in (("render_tof, multipath on", tof(on)),
                      ("render_tof, multipath off", tof(off)),
                      ("render_from_reference, multipath on", ref(on)),
                      ("render_from_reference, multipath off", ref(off)),
                      (f"transport only, {default_threads} thread(s)", transport)):
        rows[label] = timed(fn, args.repeats)
    numba.set_num_threads(1)
    rows["transport only, 1 thread"] = timed(transport, args.repeats)
    rows["render_tof, multipath on, 1 thread"] = timed(tof(on), args.repeats)
    numba.set_num_threads(default_threads)

    m = render_tof(surface, on, np.random.default_rng(0), supersample=SUPERSAMPLE)
    over = (m.range_mm - m.true_range_mm)[np.isfinite(m.range_mm)]
    machine = {"cpu": cpu_model(), "cores": os.cpu_count(), "numba_threads": default_threads,
               "python": platform.python_version(), "numpy": np.__version__,
               "numba": numba.__version__}
    print(f"machine: {machine['cpu']}, {machine['cores']} cores, numba {machine['numba']} "
          f"({default_threads} threads)")
    print(f"frame: {k.width}x{k.height}, supersample {SUPERSAMPLE}, "
          f"{len(scene.objects)} objects, camera {view.height_mm:.0f} mm above the objects")
    for label, ms in rows.items():
        print(f"  {label:<42s} {ms:8.1f} ms   {1e3 / ms:7.2f} frames/s")
    ratio = rows["render_tof, multipath on"] / rows["render_tof, multipath off"]
    print(f"multipath on / off (render_tof): {ratio:.1f}x slower")
    print(f"nominal frame: median |range error| {np.median(np.abs(over)):.1f} mm, "
          f"95th percentile {np.percentile(np.abs(over), 95):.1f} mm")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "median_ms": rows, "multipath_ratio": ratio}, f,
                      indent=2)


if __name__ == "__main__":
    main()
