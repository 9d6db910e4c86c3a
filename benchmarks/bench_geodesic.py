"""Time the geodesic filter, the K-nearest search and the edge-map NMS on a 180x140 frame.

Prints median milliseconds per frame (numba's default thread count and 1 thread, wall clock,
plus the 1-thread CPU time, which load from other processes disturbs least), the share of
pixels served by the obstacle-free template, and the speed-up over a straightforward per-pixel
Dijkstra (Python ``heapq``, the same graph and K) measured side by side on a sample of pixels.

Usage: ``python benchmarks/bench_geodesic.py [--repeats 30] [--json out.json]``. Takes ~30 s
(the first run compiles the numba kernels, ~15 s, then they are cached on disk).
"""

from __future__ import annotations

import argparse
import heapq
import json
import math
import os
import platform
import statistics
import time

from tof_mpd_ros.machine import set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

import numba
import numpy as np

from tof_mpd_ros.correction import geodesic
from tof_mpd_ros.correction.edges import edge_map_from_responses, ground_truth_edges


def scene(h: int = 140, w: int = 180, seed: int = 0) -> np.ndarray:
    """(H, W) float32 radial range in mm: tilted table, two boxes, a cylinder, 2 mm noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    r = 420.0 + 0.6 * x + 0.4 * y
    r[30:80, 40:100] -= 90.0
    r[90:125, 115:165] -= 60.0
    r[(x - 60) ** 2 + (y - 110) ** 2 < 20**2] -= 120.0
    r[15:40, 130:170] -= 40.0 + 0.5 * (x[15:40, 130:170] - 130)
    return (r + rng.normal(0.0, 2.0, r.shape)).astype(np.float32)


def responses(edges: np.ndarray, groups: np.ndarray, seed: int = 0) -> np.ndarray:
    """(4, H, W) synthetic edge probabilities: blurred ground truth per group plus noise."""
    import cv2

    rng = np.random.default_rng(seed)
    out = np.empty((4, *edges.shape), np.float32)
    for g in range(4):
        ridge = cv2.GaussianBlur((groups == g).astype(np.float32), (0, 0), 1.2) * 2.5
        out[g] = np.clip(ridge + rng.uniform(0.0, 0.25, edges.shape), 0.0, 1.0)
    return out


def timed(fn, repeats: int, clock=time.perf_counter) -> float:
    """Median time of ``fn()`` in ms (after one warm-up call); wall clock unless told."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return 1e3 * statistics.median(times)


def heapq_knn(edges: np.ndarray, src: int, k: int) -> list[tuple[float, int]]:
    """Reference: textbook Dijkstra with a binary heap, same graph, first k settled."""
    h, w = edges.shape
    dist = {src: 0.0}
    heap = [(0.0, src)]
    done: list[tuple[float, int]] = []
    seen = set()
    while heap and len(done) < k:
        d, v = heapq.heappop(heap)
        if v in seen:
            continue
        seen.add(v)
        done.append((d, v))
        vy, vx = divmod(v, w)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                ny, nx = vy + dy, vx + dx
                if (dy, dx) == (0, 0) or not (0 <= ny < h and 0 <= nx < w) or edges[ny, nx]:
                    continue
                if dy and dx and edges[vy, nx] and edges[ny, vx]:
                    continue
                nd = d + (math.sqrt(2.0) if dy and dx else 1.0)
                u = ny * w + nx
                if nd < dist.get(u, math.inf):
                    dist[u] = nd
                    heapq.heappush(heap, (nd, u))
    return done


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--json", help="also write the numbers to this JSON file")
    args = parser.parse_args()

    r = scene()
    edges, groups = ground_truth_edges(r)
    valid = np.isfinite(r)
    scores = responses(edges, groups)
    threads = numba.get_num_threads()
    res: dict[str, float | int | str] = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs",
        "frame": f"{r.shape[1]}x{r.shape[0]}", "edge_pixels": int(edges.sum()),
        "numba_threads": threads, "load_average_1min": os.getloadavg()[0]}
    graph, _ = geodesic._prepare(edges, valid, 81, 1.0, None)
    res["template_share"] = round(float(graph.tmpl_ok.mean()), 3)

    res["geodesic_filter_ms"] = timed(lambda: geodesic.geodesic_filter(r, edges), args.repeats)
    res["geodesic_neighbours_ms"] = timed(
        lambda: geodesic.geodesic_neighbours(edges, valid), args.repeats)
    res["edge_map_from_responses_ms"] = timed(lambda: edge_map_from_responses(scores),
                                              args.repeats)
    res["ground_truth_edges_ms"] = timed(lambda: ground_truth_edges(r), args.repeats)
    numba.set_num_threads(1)
    res["geodesic_filter_1thread_ms"] = timed(lambda: geodesic.geodesic_filter(r, edges),
                                              args.repeats)
    # CPU time of the single-threaded run: the figure least disturbed by other processes.
    res["geodesic_filter_1thread_cpu_ms"] = timed(
        lambda: geodesic.geodesic_filter(r, edges), args.repeats, time.process_time)
    numba.set_num_threads(threads)

    sample = np.random.default_rng(1).choice(r.size, 300, replace=False)
    t0 = time.perf_counter()
    for p in sample:
        heapq_knn(edges, int(p), 81)
    per_px = (time.perf_counter() - t0) / sample.size
    res["heapq_reference_ms_per_frame"] = 1e3 * per_px * r.size
    res["speedup_vs_heapq"] = res["heapq_reference_ms_per_frame"] / res["geodesic_filter_ms"]

    for key, value in res.items():
        print(f"{key:32s} {value:.2f}" if isinstance(value, float) else f"{key:32s} {value}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(res, f, indent=2)


if __name__ == "__main__":
    main()
