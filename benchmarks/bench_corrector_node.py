"""Corrector node latency and drops at 30 Hz and 60 Hz: publisher -> corrector -> listener.

Three processes on loopback, in their own ROS domain (``--domain-id``, default 91):

* a publisher (this script with ``--role publisher``) sends a depth (32FC1 z-depth, m) +
  amplitude (32FC1) + CameraInfo triple of ``--frame`` (180x140 by default; 320x240 is the
  whole DS325-like sensor) at the rate, every triple stamped just before it is published, from
  a paced loop;
* the ``corrector`` node executable with its default parameters (``queue_size`` 2, one CPU
  thread) and an untrained model of ``--kind`` (patch or fcn) covering ``--window`` (default:
  the frame; ``--weights`` to use a trained file: the per-frame cost does not depend on the
  weights' values; ``--window 32x24`` processes a small central window of the same frames, to
  see what the node itself sustains); ``--threads`` and ``--parallel-frames`` set the node's
  parameters of those names, ``--queue-size`` its ``queue_size``;
* the listener (this process) receives the corrected depth and ``/diagnostics``.

End-to-end latency = listener receive time - the input's header stamp (one host clock): it
includes both transports, pairing, queueing and the correction. Drops = frames sent in the
measured window without a corrected output; the node's own counters (``dropped_<reason>``,
``received_depth``) split them into drops in the node and losses in transport. The input frame is
a synthetic table-top (plane, box, cylinder, placed relative to the frame; DS325 optics) with
amplitude falloff and noise; the in-process ``DepthStreamCorrector.correct`` time of the same
frame is printed beside the node figures. The node is restarted for each rate.

Prints the machine (CPU model, cores, load average) and a side-by-side table; ``--json`` writes
the same numbers. Usage: ``python benchmarks/bench_corrector_node.py [--seconds 20]
[--rates 30 60] [--frame 320x240] [--kind fcn] [--window 180x140] [--json out.json]``. Takes
~2x(seconds + 15) s.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(REPO))
from tof_mpd_ros.cli.arguments import window_size  # noqa: E402  (no ROS: safe before rclpy)

OUTPUT = "/tof/depth_corrected/image"



def synthetic_frame(frame: tuple[int, int] = (180, 140), seed: int = 0
                    ) -> tuple[np.ndarray, np.ndarray, object]:
    """A table-top seen from 300 mm: plane + box + cylinder, with amplitude falloff and noise.

    Args:
        frame: (width, height) of the central window of the DS325-like sensor published.

    Returns:
        (depth_m, amplitude, intrinsics): (H, W) float32 z-depth in metres, (H, W) float32
        amplitude, and the window's :class:`~tof_mpd_ros.camera.Intrinsics`.
    """
    from tof_mpd_ros.camera import Intrinsics

    k = Intrinsics.ds325().crop(*frame)
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:k.height, 0:k.width].astype(np.float64)
    # objects placed as in the 180x140 frame, relative to its centre
    u, v = u - (k.width - 180) / 2, v - (k.height - 140) / 2
    z = 300.0 + 0.15 * (v - 69.5)                                  # tilted table, mm
    box = (np.abs(u - 60) < 25) & (np.abs(v - 70) < 30)
    z[box] -= 120.0
    cyl = (u - 125) ** 2 / 20.0 ** 2 + (v - 60) ** 2 / 45.0 ** 2 < 1
    z[cyl] -= 90.0 + 10.0 * np.sqrt(np.clip(1 - (u[cyl] - 125) ** 2 / 400.0, 0, 1))
    r = z / k.z_per_radial()
    amplitude = 4e7 / r ** 2 * (0.6 + 0.4 * (box | cyl))
    z = z + rng.normal(0.0, 1.5, z.shape)
    return ((z / 1000.0).astype(np.float32),
            (amplitude * (1 + rng.normal(0, 0.02, z.shape))).astype(np.float32), k)


def ros_env(domain_id: int, log_dir: str) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id),
               ROS_LOG_DIR=log_dir, PYTHONPATH=str(REPO) + os.pathsep
               + env.get("PYTHONPATH", ""))
    return env


# -- the publisher process --------------------------------------------------------------------
def run_publisher(rate: float, seconds: float, warmup_s: float, frame: tuple[int, int]) -> None:
    """Paced publishing: warm-up frames at 2 Hz, then ``seconds`` at ``rate``; prints JSON."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image

    from tof_mpd_ros.nodes.ros_messages import camera_info_message, image_message

    depth_m, amplitude, k = synthetic_frame(frame)
    rclpy.init()
    node = rclpy.create_node("bench_publisher")
    qos = qos_profile_sensor_data
    pubs = (node.create_publisher(Image, "/tof/depth/image_raw", qos),
            node.create_publisher(Image, "/tof/amplitude/image_raw", qos),
            node.create_publisher(CameraInfo, "/tof/depth/camera_info", qos))
    msgs = (image_message(depth_m, "32FC1", "tof_optical_frame"),
            image_message(amplitude, "32FC1", "tof_optical_frame"),
            camera_info_message(k, "tof_optical_frame"))
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not all(p.get_subscription_count() >= 1
                                                  for p in pubs):
        time.sleep(0.05)

    def send() -> int:
        stamp = node.get_clock().now().to_msg()
        for msg, pub in zip(msgs, pubs, strict=True):
            msg.header.stamp = stamp
            pub.publish(msg)
        return stamp.sec * 1_000_000_000 + stamp.nanosec

    end = time.monotonic() + warmup_s
    while time.monotonic() < end:
        send()
        time.sleep(0.5)
    time.sleep(1.0)
    period = 1.0 / rate
    n = round(seconds * rate)
    t0 = time.perf_counter() + 0.05
    stamps = []
    for i in range(n):
        delay = t0 + i * period - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        stamps.append(send())
    late = (time.perf_counter() - t0 - (n - 1) * period) * 1e3
    print(json.dumps({"sent": n, "first_ns": stamps[0], "last_ns": stamps[-1],
                      "late_ms": late}), flush=True)
    time.sleep(1.0)  # let the last frames reach the corrector before the writers leave
    node.destroy_node()
    rclpy.try_shutdown()


# -- the listener (this process) --------------------------------------------------------------
def measure(rate: float, args: argparse.Namespace, weights: Path, log_dir: str) -> dict:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    env = ros_env(args.domain_id, log_dir)
    log = open(Path(log_dir) / f"corrector_{rate:g}hz.log", "w")
    corrector = subprocess.Popen(
        [sys.executable, "-m", "tof_mpd_ros.nodes.corrector", "--ros-args",
         "-p", f"weights_path:={weights}", "-p", "diagnostics_period_s:=0.5",
         "-p", f"threads:={args.threads}", "-p", f"precision:={args.precision}",
         "-p", f"parallel_frames:={args.parallel_frames}",
         "-p", f"queue_size:={args.queue_size}",
         "-r", "__ns:=/tof"],  # its topics are relative
        env=env, stdout=log, stderr=subprocess.STDOUT)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=args.domain_id)
    node = rclpy.create_node("bench_listener", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    received: dict[int, int] = {}  # stamp -> receive time, ns
    diagnostics: list[dict[str, str]] = []

    def on_output(msg: Image) -> None:
        now = time.time_ns()
        received[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = now

    def on_diag(msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.name == "tof_mpd_ros: corrector":
                diagnostics.append({kv.key: kv.value for kv in s.values})

    deep = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT,
                      history=HistoryPolicy.KEEP_LAST, depth=1000)
    node.create_subscription(Image, OUTPUT, on_output, deep)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)

    def spin(seconds: float, until=lambda: False) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            executor.spin_once(timeout_sec=0.02)

    try:
        spin(90, lambda: bool(diagnostics) or corrector.poll() is not None)
        if corrector.poll() is not None:
            raise SystemExit(f"the corrector did not start:\n{Path(log.name).read_text()}")
        publisher = subprocess.Popen(
            [sys.executable, __file__, "--role", "publisher", "--rate", str(rate),
             "--seconds", str(args.seconds), "--frame", "{}x{}".format(*args.frame)], env=env,
            stdout=subprocess.PIPE, text=True)
        while publisher.poll() is None:
            spin(0.2)
        report = json.loads(publisher.stdout.read().strip().splitlines()[-1])
        n_diag = len(diagnostics)
        spin(3.0, lambda: len(diagnostics) >= n_diag + 3)
        final = diagnostics[-1]
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
        corrector.send_signal(2)
        try:
            corrector.wait(10)
        except subprocess.TimeoutExpired:
            corrector.kill()
        log.close()

    first, last = report["first_ns"], report["last_ns"]
    lat = np.array([(t - s) / 1e6 for s, t in received.items() if first <= s <= last])
    out = {"rate_hz": rate, "sent": report["sent"], "corrected": int(lat.size),
           "dropped": report["sent"] - int(lat.size),
           "publisher_late_ms": round(report["late_ms"], 1),
           "latency_p50_ms": float(np.percentile(lat, 50)) if lat.size else float("nan"),
           "latency_p99_ms": float(np.percentile(lat, 99)) if lat.size else float("nan"),
           "latency_max_ms": float(lat.max()) if lat.size else float("nan"),
           "node_received_depth": int(final.get("received_depth", 0)),
           "node_published": int(final.get("published", 0)),
           "node_dropped": {k[len("dropped_"):]: int(v) for k, v in final.items()
                            if k.startswith("dropped_") and k != "dropped_total" and int(v)},
           "node_latency_p50_ms": float(final.get("latency_p50_ms", "nan")),
           "node_latency_p99_ms": float(final.get("latency_p99_ms", "nan"))}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[30.0, 60.0])
    parser.add_argument("--seconds", type=float, default=20.0, help="measured time per rate")
    parser.add_argument("--domain-id", type=int, default=91)
    parser.add_argument("--weights", type=Path, help="weights file (default: untrained "
                        "model of --window)")
    parser.add_argument("--frame", type=window_size, default=(180, 140),
                        help="WxH of the published frames (the central window of the 320x240 "
                        "sensor; default the paper's 180x140)")
    parser.add_argument("--kind", choices=("patch", "fcn"), default="patch",
                        help="kind of the default untrained model")
    parser.add_argument("--window", type=window_size,
                        help="WxH processed by the default untrained model (default: the "
                        "frame): a small window shows what the node itself sustains")
    parser.add_argument("--threads", type=int, default=1, help="the node's threads parameter "
                        "(default 1, the node's default)")
    parser.add_argument("--parallel-frames", type=int, default=1,
                        help="the node's parallel_frames parameter (frames corrected at once)")
    parser.add_argument("--queue-size", type=int, default=2,
                        help="the node's queue_size parameter (pairs waiting for a worker)")
    parser.add_argument("--precision", choices=("float32", "bfloat16", "int8"), default="float32",
                        help="the node's precision parameter")
    parser.add_argument("--json", help="also write the numbers to this JSON file")
    parser.add_argument("--role", choices=("listener", "publisher"), default="listener",
                        help=argparse.SUPPRESS)
    parser.add_argument("--rate", type=float, default=30.0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    frame = args.frame
    if args.role == "publisher":
        run_publisher(args.rate, args.seconds, warmup_s=3.0, frame=frame)
        return

    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                      ROS_DOMAIN_ID=str(args.domain_id))
    log_dir = tempfile.mkdtemp(prefix="bench_corrector_")
    os.environ.setdefault("ROS_LOG_DIR", log_dir)
    import torch

    from tof_mpd_ros.calibration import IntrinsicCalibration
    from tof_mpd_ros.correction.depth_stream import DepthStreamCorrector
    from tof_mpd_ros.correction.fcn import FCNCorrectionModel
    from tof_mpd_ros.correction.pipeline import CorrectionModel
    from tof_mpd_ros.correction.weights import load_weights, save_weights
    from tof_mpd_ros.machine import cpu_model

    weights = args.weights
    if weights is None:
        win_w, win_h = args.window or args.frame
        build = CorrectionModel if args.kind == "patch" else FCNCorrectionModel
        weights = save_weights(Path(log_dir) / "untrained.npz", build.untrained(
            IntrinsicCalibration.identity(win_h, win_w)))
    # The same frame corrected in this process, with the node's thread count.
    depth_m, amplitude, k = synthetic_frame(frame)
    model = load_weights(weights)
    stream = DepthStreamCorrector(model, threads=args.threads, precision=args.precision)
    times = []
    for _ in range(12):
        t0 = time.perf_counter()
        stream.correct(depth_m * np.float32(1000.0), amplitude, k)
        times.append((time.perf_counter() - t0) * 1e3)
    offline_ms = float(np.median(times[2:]))

    machine = {"cpu": cpu_model(), "cores": os.cpu_count(),
               "load_average_1_5_15": [round(x, 2) for x in os.getloadavg()],
               "python": platform.python_version(), "torch": torch.__version__}
    results = [measure(rate, args, weights, log_dir) for rate in args.rates]
    machine["load_average_after"] = [round(x, 2) for x in os.getloadavg()]

    print(f"machine: {machine['cpu']}, {machine['cores']} cores, load average "
          f"{machine['load_average_1_5_15']} before / {machine['load_average_after']} after")
    window = stream.crop_width, stream.crop_height
    window = (min(window[0], frame[0]), min(window[1], frame[1]))
    print(f"frame: {frame[0]}x{frame[1]} 32FC1, {model.kind} kind, {args.precision}, window "
          f"{window[0]}x{window[1]}; node: threads {args.threads}, parallel_frames "
          f"{args.parallel_frames}, queue_size {args.queue_size}; in-process "
          f"DepthStreamCorrector.correct ({args.threads} thread(s), one frame at a time): median "
          f"{offline_ms:.1f} ms")
    rows = [("input rate (Hz)", "rate_hz", "{:g}"), ("frames sent", "sent", "{}"),
            ("corrected", "corrected", "{}"), ("dropped", "dropped", "{}"),
            ("  node: received depth", "node_received_depth", "{}"),
            ("  node: published", "node_published", "{}"),
            ("  node: drops by reason", "node_dropped", "{}"),
            ("end-to-end p50 (ms)", "latency_p50_ms", "{:.1f}"),
            ("end-to-end p99 (ms)", "latency_p99_ms", "{:.1f}"),
            ("end-to-end max (ms)", "latency_max_ms", "{:.1f}"),
            ("in node p50 (ms)", "node_latency_p50_ms", "{:.1f}"),
            ("in node p99 (ms)", "node_latency_p99_ms", "{:.1f}"),
            ("publisher late at end (ms)", "publisher_late_ms", "{}")]
    table = [(label, [fmt.format(r[key]) if not isinstance(r[key], dict)
                      else (", ".join(f"{k} {v}" for k, v in r[key].items()) or "none")
                      for r in results]) for label, key, fmt in rows]
    width = max(len(c) for _, cells in table for c in cells) + 2
    for label, cells in table:
        print(f"{label:<28}" + "".join(f"{c:>{width}}" for c in cells))
    if args.json:
        Path(args.json).write_text(json.dumps(
            {"machine": machine, "frame": list(frame), "kind": model.kind,
             "window": list(window), "node_parameters": {
                 "threads": args.threads, "parallel_frames": args.parallel_frames,
                 "queue_size": args.queue_size, "precision": args.precision},
             "offline_correct_ms": offline_ms, "results": results}, indent=2))


if __name__ == "__main__":
    main()
