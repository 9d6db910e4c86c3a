"""Soak: sim_cell -> corrector at 30 Hz for 10 minutes; drops, latency and memory per minute.

Issue 15, item 3. Three processes on loopback, in their own ROS domain (``--domain-id``,
default 92: the test runs hold 1-85 and ``bench_corrector_node.py`` 91):

* the ``sim_cell`` node executable with its defaults (config/sim_cell.yaml: test scene 0, 3
  views with the structured-light reference, 180x140) at ``--rate`` Hz;
* the ``corrector`` node executable with its defaults (config/corrector.yaml: the shipped
  weights, ``queue_size`` 2, one CPU thread, best-effort sensor QoS) -- what
  ``sim_demo.launch.py`` starts;
* this process, which subscribes to sim_cell's CameraInfo (one per frame, same stamp as the
  frame's images, small enough never to be lost to fragmentation), the corrected depth and
  ``/diagnostics``, and reads both nodes' VmRSS from ``/proc/<pid>/status`` every second.

After the corrector has sent its first output back and ``--warmup`` seconds more (JIT, thread
pools, DDS discovery), ``--duration`` seconds are measured in rows of ``--minute-s`` (60) s. A
frame belongs to the row its stamp falls in. Per row: frames sent (CameraInfo stamps seen),
corrected (outputs received with such a stamp; one arriving more than GRACE_S after its row
ended counts as lost), lost = sent - corrected (node drops + transport losses), the node's own
drops by reason (differences of its ``dropped_<reason>`` counters on ``/diagnostics``), the
latency p50/p99/max (receipt of the corrected depth in this process - the input's stamp; one
host clock, so both transports, pairing, queueing and the correction are in it), both nodes' RSS
at the row's end (median of the once-a-second VmRSS samples in its last 10 s) and the 1-minute
load average.

Summary and criteria (exit status 1 when one fails, 2 when the run could not be made):

* memory growth of each node, MB per minute: least-squares slope of the end-of-minute RSS from
  the end of minute 1 on, so growth during minute 1 does not count (warm-up: caches and the
  node's bounded histories, e.g. its 1000-frame latency window, fill during it); fails above
  ``--max-growth`` (1 MB/min). A 2-minute run gives one difference only: judge growth on 10;
* p99 stability: the per-minute p99s' max/min is printed; **stable** means every minute has
  outputs and no minute's p99 is above ``--p99-limit`` (2) x the median of the per-minute p99s
  (with only 2 minutes this cannot fail: the median is their mean);
* drops: totals printed; checked only with ``--max-drops N`` (frames sent without an output).

The CPU model (``lscpu``) and the load average are printed with the figures, and ``--out``
writes the rows, the summary and the machine as JSON. The nodes are stopped with SIGINT at the
end; their exit codes and whether their logs hold a traceback are reported.

Usage: ``python benchmarks/soak.py [--duration 600] [--rate 30] [--out soak.json]``. Takes the
duration plus about a minute (sim_cell renders its views, the corrector warms up).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUTPUT = "/tof/depth_corrected/image"
CAMERA_INFO = "/tof/depth/camera_info"
DIAGNOSTICS_NAME = "tof_mpd_ros: corrector"
# An output arriving this long after its row ended is counted as lost, so a row can be printed.
GRACE_S = 5.0
# Wait this long for the corrector's first output (sim_cell renders 3 views of ~1 s each first;
# a busy machine takes several times longer).
FIRST_OUTPUT_TIMEOUT_S = 300.0
NS = 1_000_000_000
# A minute's RSS is the median of the once-a-second samples in its last RSS_WINDOW_S: a single
# sample can catch a frame's transient buffers (VmRSS swings by ~3 MB within seconds here).
RSS_WINDOW_S = 10.0


# -- pure parts (test/test_soak_summary.py exercises them on synthetic numbers) ---------------
def vmrss_mb(status_text: str) -> float | None:
    """VmRSS of a ``/proc/<pid>/status`` text in MB (10^6 bytes); None if absent (a zombie)."""
    for line in status_text.splitlines():
        if line.startswith("VmRSS:"):
            value, unit = line.split()[1:3]
            if unit.lower() != "kb":
                raise ValueError(f"unexpected VmRSS unit {unit!r}")
            return int(value) * 1024 / 1e6
    return None


def lscpu_model(lscpu_text: str) -> str | None:
    """The ``Model name`` field of ``lscpu`` output, or None."""
    for line in lscpu_text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "Model name":
            return value.strip()
    return None


def counters_at(diagnostics: Sequence[tuple[int, dict[str, str]]], t_ns: int) -> dict[str, int]:
    """The corrector's integer counters in the last ``/diagnostics`` received at or before
    ``t_ns`` ({} before the first). ``diagnostics`` = (receipt time ns, key/values), in order."""
    last: dict[str, str] = {}
    for received, values in diagnostics:
        if received > t_ns:
            break
        last = values
    return {k: int(v) for k, v in last.items() if v.isdigit()}


def drops_between(before: dict[str, int], after: dict[str, int]) -> dict[str, int]:
    """Drops by reason counted between two counter snapshots (reasons with none left out)."""
    out = {}
    for key, value in after.items():
        if key.startswith("dropped_") and key != "dropped_total":
            n = value - before.get(key, 0)
            if n:
                out[key[len("dropped_"):]] = n
    return out


def percentile(values: Sequence[float], q: float) -> float:
    """``q``-th percentile (numpy's linear interpolation); NaN for no values."""
    return float(np.percentile(values, q)) if len(values) else math.nan


@dataclass
class Samples:
    """What this process recorded; every time is ``time.time_ns()`` (the stamps' clock)."""

    sent: set[int] = field(default_factory=set)  # stamps of sim_cell's CameraInfo
    received: dict[int, int] = field(default_factory=dict)  # output stamp -> receipt
    diagnostics: list[tuple[int, dict[str, str]]] = field(default_factory=list)
    rss: list[tuple[int, float | None, float | None]] = field(default_factory=list)  # corr, sim


def minute_row(samples: Samples, start_ns: int, end_ns: int, index: int,
               load_1min: float | None = None) -> dict[str, object]:
    """The table row of the frames stamped in [start_ns, end_ns) (row ``index``, from 1).

    RSS: the median of the samples in the row's last RSS_WINDOW_S (``*_rss_mb``) and the
    largest sample in the row (``*_rss_peak_mb``)."""
    sent = [s for s in samples.sent if start_ns <= s < end_ns]
    late_ns = end_ns + round(GRACE_S * NS)
    latencies = [(samples.received[s] - s) / 1e6 for s in sent
                 if s in samples.received and samples.received[s] <= late_ns]
    before = counters_at(samples.diagnostics, start_ns)
    after = counters_at(samples.diagnostics, end_ns)
    in_row = [r for r in samples.rss if start_ns <= r[0] <= end_ns]
    window = [r for r in in_row if r[0] >= end_ns - RSS_WINDOW_S * NS] or in_row[-1:]
    corrector_mb, sim_mb = (_median([r[i] for r in window]) for i in (1, 2))
    peaks = [max((r[i] for r in in_row if r[i] is not None), default=None) for i in (1, 2)]
    return {"minute": index, "sent": len(sent), "corrected": len(latencies),
            "lost": len(sent) - len(latencies),
            "node_received": after.get("received_depth", 0) - before.get("received_depth", 0),
            "node_published": after.get("published", 0) - before.get("published", 0),
            "node_drops": drops_between(before, after),
            "p50_ms": percentile(latencies, 50), "p99_ms": percentile(latencies, 99),
            "max_ms": max(latencies) if latencies else math.nan,
            "corrector_rss_mb": corrector_mb, "sim_cell_rss_mb": sim_mb,
            "corrector_rss_peak_mb": peaks[0], "sim_cell_rss_peak_mb": peaks[1],
            "load_1min": load_1min}


def _median(values: Sequence[float | None]) -> float | None:
    """Median, or None when there is no value or one is missing (the process was gone)."""
    if not values or any(v is None for v in values):
        return None
    return float(np.median(values))


def growth_mb_per_min(rss_end_mb: Sequence[float | None], minute_s: float = 60.0,
                      warmup_rows: int = 1) -> float | None:
    """Least-squares slope of end-of-row RSS in MB per 60 s, warm-up rows excluded.

    ``rss_end_mb[k]`` is the RSS at the end of row k + 1. The end of the last warm-up row is the
    first point (the state once warm-up is over), so growth during the warm-up does not count.
    None with fewer than 2 points or a missing sample (the process was gone).
    """
    points = list(rss_end_mb[warmup_rows - 1:] if warmup_rows > 0 else rss_end_mb)
    if len(points) < 2 or any(p is None for p in points):
        return None
    x = np.arange(len(points), dtype=np.float64) * (minute_s / 60.0)
    slope, _ = np.polyfit(x, np.asarray(points, dtype=np.float64), 1)
    return float(slope)


def p99_stability(p99_ms: Sequence[float], limit: float = 2.0) -> dict[str, object]:
    """Spread of the per-minute p99s; ``stable`` = every minute has a p99 and none is above
    ``limit`` x their median."""
    finite = [p for p in p99_ms if math.isfinite(p)]
    if not finite:
        return {"max_over_min": math.nan, "worst_over_median": math.nan, "stable": False}
    median = float(np.median(finite))
    worst = max(finite) / median if median > 0 else math.inf
    return {"max_over_min": max(finite) / min(finite) if min(finite) > 0 else math.inf,
            "worst_over_median": worst,
            "stable": len(finite) == len(p99_ms) and worst <= limit}


def summarise(rows: Sequence[dict], minute_s: float = 60.0,
              p99_limit: float = 2.0) -> dict[str, object]:
    """Totals, memory growth of both nodes and p99 stability of the per-minute rows."""
    drops: dict[str, int] = {}
    for row in rows:
        for reason, n in row["node_drops"].items():
            drops[reason] = drops.get(reason, 0) + n
    return {"minutes": len(rows),
            "sent": sum(r["sent"] for r in rows),
            "corrected": sum(r["corrected"] for r in rows),
            "lost": sum(r["lost"] for r in rows),
            "node_drops": drops, "node_drops_total": sum(drops.values()),
            "corrector_growth_mb_per_min": growth_mb_per_min(
                [r["corrector_rss_mb"] for r in rows], minute_s),
            "sim_cell_growth_mb_per_min": growth_mb_per_min(
                [r["sim_cell_rss_mb"] for r in rows], minute_s),
            "p99": p99_stability([r["p99_ms"] for r in rows], p99_limit)}


def failures(summary: dict, max_growth: float = 1.0, max_drops: int | None = None
             ) -> list[str]:
    """The criteria that failed, each as a sentence ([] = the soak passed)."""
    out = []
    for node in ("corrector", "sim_cell"):
        growth = summary[f"{node}_growth_mb_per_min"]
        if growth is None:
            out.append(f"{node}: memory growth not measured (fewer than 2 minutes, or the "
                       "process was gone)")
        elif growth > max_growth:
            out.append(f"{node}: memory grows {growth:.2f} MB/min (limit {max_growth:g})")
    p99 = summary["p99"]
    if not p99["stable"]:
        out.append(f"p99 unstable: worst minute {p99['worst_over_median']:.2f}x the median "
                   "minute's (or a minute without output)")
    if max_drops is not None and summary["lost"] > max_drops:
        out.append(f"{summary['lost']} frames without a corrected output (limit {max_drops})")
    return out


def _num(value: float | None, fmt: str) -> str:
    return "-" if value is None or not math.isfinite(value) else format(value, fmt)


def format_row(row: dict) -> str:
    drops = ", ".join(f"{k} {v}" for k, v in sorted(row["node_drops"].items())) or "0"
    return (f"{row['minute']:>3} {row['sent']:>6} {row['corrected']:>6} {row['lost']:>5} "
            f"{row['node_received']:>6} {_num(row['p50_ms'], '.1f'):>7} "
            f"{_num(row['p99_ms'], '.1f'):>7} {_num(row['max_ms'], '.1f'):>7} "
            f"{_num(row['corrector_rss_mb'], '.1f'):>8} {_num(row['sim_cell_rss_mb'], '.1f'):>8} "
            f"{_num(row['load_1min'], '.2f'):>5}  {drops}")


TABLE_HEADER = (f"{'min':>3} {'sent':>6} {'corr':>6} {'lost':>5} {'nd rx':>6} {'p50 ms':>7} "
                f"{'p99 ms':>7} {'max ms':>7} {'corr MB':>8} {'sim MB':>8} {'load':>5}  "
                "node drops by reason")


def format_summary(summary: dict, fails: Sequence[str]) -> str:
    p99 = summary["p99"]
    drops = ", ".join(f"{k} {v}" for k, v in sorted(summary["node_drops"].items())) or "none"
    lines = [
        f"minutes {summary['minutes']}: sent {summary['sent']}, corrected "
        f"{summary['corrected']}, lost {summary['lost']} (node drops: {drops})",
        f"memory growth (end-of-minute RSS from the end of minute 1, least squares): corrector "
        f"{_num(summary['corrector_growth_mb_per_min'], '+.2f')} MB/min, sim_cell "
        f"{_num(summary['sim_cell_growth_mb_per_min'], '+.2f')} MB/min",
        f"p99 per minute: max/min {_num(p99['max_over_min'], '.2f')}, worst/median "
        f"{_num(p99['worst_over_median'], '.2f')} -> {'stable' if p99['stable'] else 'UNSTABLE'}",
        "verdict: " + ("PASS" if not fails else "FAIL: " + "; ".join(fails))]
    return "\n".join(lines)


# -- the run ----------------------------------------------------------------------------------
def machine() -> dict[str, object]:
    """CPU model (lscpu's Model name), cores and the load average now."""
    try:
        text = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
    except OSError:  # no util-linux
        text = ""
    model = lscpu_model(text)
    if model is None:
        sys.path.insert(0, str(REPO))  # the checkout's package, as the nodes get it
        from tof_mpd_ros.machine import cpu_model
        model = cpu_model()
    return {"cpu": model, "cores": os.cpu_count(),
            "load_average_1_5_15": [round(x, 2) for x in os.getloadavg()]}


def read_rss(pid: int) -> float | None:
    try:
        return vmrss_mb(Path(f"/proc/{pid}/status").read_text())
    except OSError:  # the process is gone
        return None


def start_node(executable: str, params: dict[str, object], env: dict[str, str],
               log_path: Path, namespace: str = "") -> subprocess.Popen:
    """``python -m tof_mpd_ros.nodes.<executable> --ros-args -p k:=v ...`` (as the node tests
    start them: no ros2 CLI needed), stdout and stderr to ``log_path``."""
    args = [sys.executable, "-m", f"tof_mpd_ros.nodes.{executable}", "--ros-args"]
    for key, value in params.items():
        args += ["-p", f"{key}:={value}"]
    if namespace:
        args += ["-r", f"__ns:={namespace}"]
    with open(log_path, "w") as log:  # the child keeps its own descriptor
        return subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT)


def stop_node(process: subprocess.Popen, timeout: float = 30.0) -> int | None:
    """SIGINT (as Ctrl-C and launch do), then SIGKILL if it does not exit; the exit code."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
    return process.returncode


def run(args: argparse.Namespace, log_dir: Path
        ) -> tuple[list[dict], dict, int | None, list[tuple[float, float | None, float | None]]]:
    """Start the nodes, measure, stop them. Returns the rows, the nodes' exit codes, the
    row in which a node died (None if none did) and the RSS trace: (seconds since the
    measurement began, corrector MB, sim_cell MB) once a second, for telling a leak from a
    step when two end-of-minute points disagree."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image

    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(args.domain_id),
               ROS_LOG_DIR=str(log_dir),
               PYTHONPATH=str(REPO) + os.pathsep + env.get("PYTHONPATH", ""))
    # As sim_demo.launch.py: the corrector's relative topics in /tof meet sim_cell's.
    corrector = start_node("corrector", {}, env, log_dir / "corrector.log", namespace="/tof")
    sim = start_node("sim_cell", {"rate_hz": args.rate}, env, log_dir / "sim_cell.log")
    procs = {"corrector": corrector, "sim_cell": sim}
    samples = Samples()
    context = rclpy.Context()
    try:
        rclpy.init(context=context, domain_id=args.domain_id)
        node = rclpy.create_node("soak_listener", context=context)
    except BaseException:  # never leave the node processes running behind a failed start
        context.try_shutdown()
        stop_node(sim)
        stop_node(corrector)
        raise
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def stamp(msg: object) -> int:
        return msg.header.stamp.sec * NS + msg.header.stamp.nanosec

    def on_output(msg: Image) -> None:
        samples.received.setdefault(stamp(msg), time.time_ns())

    def on_info(msg: CameraInfo) -> None:
        samples.sent.add(stamp(msg))

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == DIAGNOSTICS_NAME:
                samples.diagnostics.append((time.time_ns(),
                                            {kv.key: kv.value for kv in status.values}))

    # Best effort like the publishers; a deep history so that a stall of this process does not
    # lose what it is counting.
    deep = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT,
                      history=HistoryPolicy.KEEP_LAST, depth=1000)
    node.create_subscription(Image, OUTPUT, on_output, deep)
    node.create_subscription(CameraInfo, CAMERA_INFO, on_info, deep)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)

    def dead() -> str | None:
        for name, p in procs.items():
            if p.poll() is not None:
                return name
        return None

    rows: list[dict] = []
    died_in: int | None = None
    t0 = time.time_ns()  # reset when the measurement begins
    try:
        deadline = time.monotonic() + FIRST_OUTPUT_TIMEOUT_S
        while not samples.received and time.monotonic() < deadline and dead() is None:
            executor.spin_once(timeout_sec=0.1)
        if not samples.received:
            gone = dead()
            raise RuntimeError(f"no corrected output within {FIRST_OUTPUT_TIMEOUT_S:g} s"
                               + (f": {gone} exited, see {log_dir / (gone + '.log')}"
                                  if gone else f"; logs in {log_dir}"))
        end = time.monotonic() + args.warmup
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)

        minute_ns = round(args.minute_s * NS)
        n_rows = round(args.duration / args.minute_s)
        t0 = time.time_ns()
        print(f"measuring from {time.strftime('%H:%M:%S')} for {n_rows} x {args.minute_s:g} s "
              f"(after the first corrected output and {args.warmup:g} s of warm-up)", flush=True)
        print(TABLE_HEADER, flush=True)
        next_rss = 0
        loads: dict[int, float] = {}  # row index -> 1-minute load average when it ended
        while len(rows) < n_rows:
            executor.spin_once(timeout_sec=0.05)
            now = time.time_ns()
            if now >= next_rss:  # once a second: cheap, and close enough to a row's end
                samples.rss.append((now, read_rss(corrector.pid), read_rss(sim.pid)))
                next_rss = now + NS
            k = len(rows)
            row_end = t0 + (k + 1) * minute_ns
            if now >= row_end and k not in loads:
                loads[k] = round(os.getloadavg()[0], 2)
            # Row k's last outputs may arrive up to GRACE_S after it ends; print it then.
            if now >= row_end + GRACE_S * NS:
                rows.append(minute_row(samples, row_end - minute_ns, row_end, k + 1,
                                       loads.get(k)))
                print(format_row(rows[-1]), flush=True)
            gone = dead()
            if gone is not None:
                died_in = len(rows) + 1
                print(f"{gone} exited (code {procs[gone].returncode}) during minute {died_in}",
                      flush=True)
                break
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
        # sim_cell first, so the corrector is not stopped with frames still arriving.
        codes = {"sim_cell": stop_node(sim), "corrector": stop_node(corrector)}
    trace = [(round((t - t0) / NS, 1), c, s) for t, c, s in samples.rss]
    return rows, codes, died_in, trace


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=600.0,
                        help="measured seconds (default 600), a whole number of rows, >= 2 rows")
    parser.add_argument("--rate", type=float, default=30.0, help="sim_cell's rate_hz")
    parser.add_argument("--warmup", type=float, default=15.0,
                        help="seconds after the first corrected output before measuring")
    parser.add_argument("--minute-s", type=float, default=60.0,
                        help="length of a table row (default 60; shorter only for a quick "
                        "check of the script: growth is still per 60 s)")
    parser.add_argument("--max-growth", type=float, default=1.0, help="MB/min per node")
    parser.add_argument("--p99-limit", type=float, default=2.0,
                        help="no minute's p99 above this x the median minute's")
    parser.add_argument("--max-drops", type=int, default=None,
                        help="also fail when more frames than this lack an output "
                        "(default: not checked)")
    parser.add_argument("--domain-id", type=int, default=92)
    parser.add_argument("--out", type=Path, help="write rows, summary and machine as JSON")
    parser.add_argument("--log-dir", type=Path, help="node logs (default: a new temp dir)")
    args = parser.parse_args()
    n_rows = args.duration / args.minute_s
    if abs(n_rows - round(n_rows)) > 1e-9 or round(n_rows) < 2:
        parser.error("--duration must be a whole number (>= 2) of --minute-s rows")

    # Before rclpy loads: loopback only, this soak's own domain, a log directory (rclpy.init
    # needs HOME or ROS_LOG_DIR).
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="soak_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                      ROS_DOMAIN_ID=str(args.domain_id))
    os.environ.setdefault("ROS_LOG_DIR", str(log_dir))

    before = machine()
    print(f"machine: {before['cpu']}, {before['cores']} cores, load average "
          f"{before['load_average_1_5_15']}; sim_cell -> corrector at {args.rate:g} Hz, "
          f"domain {args.domain_id}, logs in {log_dir}", flush=True)
    try:
        rows, codes, died_in, rss_trace = run(args, log_dir)
    except RuntimeError as err:
        print(f"soak could not run: {err}", file=sys.stderr)
        return 2
    after = [round(x, 2) for x in os.getloadavg()]
    summary = summarise(rows, args.minute_s, args.p99_limit)
    fails = failures(summary, args.max_growth, args.max_drops)
    if died_in is not None:
        fails.insert(0, f"a node exited during minute {died_in}")
    tracebacks = [name for name in codes
                  if "Traceback" in (log_dir / f"{name}.log").read_text(errors="replace")]
    print(f"machine: {before['cpu']}, {before['cores']} cores, load average "
          f"{before['load_average_1_5_15']} before / {after} after (1, 5, 15 min)")
    print(format_summary(summary, fails))
    print(f"node exit codes after SIGINT: {codes}; traceback in the log of: "
          f"{', '.join(tracebacks) or 'none'} ({log_dir})")
    if args.out:
        args.out.write_text(json.dumps(
            {"machine": {**before, "load_average_after": after}, "rate_hz": args.rate,
             "duration_s": args.duration, "minute_s": args.minute_s, "rows": rows,
             "summary": summary, "failures": fails, "exit_codes": codes,
             "tracebacks_in_logs": tracebacks, "log_dir": str(log_dir),
             "rss_trace_s_corrector_sim_cell_mb": rss_trace}, indent=2))
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
