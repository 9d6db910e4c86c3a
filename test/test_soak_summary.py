"""The soak benchmark's pure parts (benchmarks/soak.py) on synthetic numbers: no ROS, no timing."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

# benchmarks/ is a folder of scripts, not a package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import soak

NS = soak.NS


def row(minute: int, rss: float | None, p99: float, sim_rss: float | None = 300.0,
        drops: dict[str, int] | None = None, sent: int = 1800, corrected: int = 1800
        ) -> dict:
    return {"minute": minute, "sent": sent, "corrected": corrected, "lost": sent - corrected,
            "node_received": sent, "node_published": corrected, "node_drops": drops or {},
            "p50_ms": p99 / 2, "p99_ms": p99, "max_ms": p99 * 1.1, "corrector_rss_mb": rss,
            "sim_cell_rss_mb": sim_rss, "load_1min": 1.0}


def test_vmrss_in_mb_and_absent_for_a_zombie() -> None:
    status = "Name:\tpython\nVmPeak:\t 9000 kB\nVmRSS:\t  488282 kB\nThreads:\t12\n"
    assert soak.vmrss_mb(status) == pytest.approx(488282 * 1024 / 1e6)
    assert soak.vmrss_mb("Name:\tpython\nState:\tZ (zombie)\n") is None


def test_lscpu_model_name() -> None:
    text = "Architecture:   x86_64\nModel name:     AMD EPYC 9B45\nThread(s) per core: 1\n"
    assert soak.lscpu_model(text) == "AMD EPYC 9B45"
    assert soak.lscpu_model("Architecture: x86_64\n") is None


def test_drops_are_counter_differences_between_the_diagnostics_at_the_row_edges() -> None:
    diags = [(10, {"dropped_queue_full": "3", "dropped_total": "3", "published": "50",
                   "last_error": "queue_full: busy", "rate_hz": "29.90"}),
             (20, {"dropped_queue_full": "7", "dropped_no_depth": "1", "dropped_total": "8",
                   "published": "80"})]
    assert soak.counters_at(diags, 5) == {}
    assert soak.counters_at(diags, 15) == {"dropped_queue_full": 3, "dropped_total": 3,
                                           "published": 50}
    assert soak.drops_between(soak.counters_at(diags, 15), soak.counters_at(diags, 25)) == \
        {"queue_full": 4, "no_depth": 1}
    assert soak.drops_between({}, {"dropped_queue_full": 0, "dropped_total": 0}) == {}


def test_a_minute_row_counts_frames_by_stamp_and_late_outputs_as_lost() -> None:
    start, end = 1000 * NS, 1060 * NS
    sent = {start + i * NS for i in range(60)} | {start - NS, end}  # two outside the row
    received = {s: s + 20_000_000 for s in sent}  # 20 ms each
    received[start + 5 * NS] = end + round((soak.GRACE_S + 1) * NS)  # too late: lost
    del received[start + 6 * NS]  # never came back
    samples = soak.Samples(
        sent=sent, received=received,
        diagnostics=[(start - NS, {"dropped_queue_full": "2", "received_depth": "100",
                                   "published": "98"}),
                     (end - NS, {"dropped_queue_full": "3", "received_depth": "160",
                                 "published": "157"})],
        rss=[(start, 400.0, 300.0), (end - 20 * NS, 410.0, 300.0),  # before the last 10 s
             (end - 3 * NS, 401.0, 300.2), (end - 2 * NS, 404.0, 300.2),  # one transient
             (end - NS, 401.5, 300.2), (end + NS, 999.0, 999.0)])  # after the row
    r = soak.minute_row(samples, start, end, 1, load_1min=2.5)
    assert (r["sent"], r["corrected"], r["lost"]) == (60, 58, 2)
    assert (r["node_received"], r["node_published"]) == (60, 59)
    assert r["node_drops"] == {"queue_full": 1}
    assert r["p50_ms"] == pytest.approx(20.0) and r["p99_ms"] == pytest.approx(20.0)
    # RSS: the median of the last 10 s of the row (the transient does not decide it); the peak.
    assert (r["corrector_rss_mb"], r["sim_cell_rss_mb"]) == (401.5, pytest.approx(300.2))
    assert (r["corrector_rss_peak_mb"], r["sim_cell_rss_peak_mb"]) == (410.0, 300.2)
    assert r["load_1min"] == 2.5


def test_an_empty_minute_has_no_latency() -> None:
    r = soak.minute_row(soak.Samples(), 0, 60 * NS, 1)
    assert (r["sent"], r["corrected"], r["lost"]) == (0, 0, 0)
    assert math.isnan(r["p99_ms"]) and r["corrector_rss_mb"] is None


def test_growth_is_the_slope_from_the_end_of_the_warm_up_minute() -> None:
    # The points are end-of-row RSS: whatever grew during minute 1 (before its end) is not in
    # them. From there on, 0.5 MB per minute.
    assert soak.growth_mb_per_min([500.0, 500.5, 501.0, 501.5]) == pytest.approx(0.5)
    # Two warm-up rows: the end of row 2 is the first point, the jump in row 2 does not count.
    assert soak.growth_mb_per_min([450.0, 500.0, 500.5, 501.0], warmup_rows=2) == \
        pytest.approx(0.5)
    # Rows of 30 s: 0.25 MB per row is 0.5 MB per minute.
    assert soak.growth_mb_per_min([500.0, 500.25, 500.5], minute_s=30.0) == pytest.approx(0.5)
    # Least squares, not last minus first: one high sample in the middle does not tilt it.
    assert soak.growth_mb_per_min([400.0, 400.0, 403.0, 400.0, 400.0]) == pytest.approx(0.0)
    assert soak.growth_mb_per_min([450.0]) is None  # nothing after the warm-up
    assert soak.growth_mb_per_min([450.0, 500.0, None]) is None  # the process was gone


def test_p99_stability_against_the_median_minute() -> None:
    steady = soak.p99_stability([30.0, 32.0, 31.0, 35.0])
    assert steady["stable"] and steady["max_over_min"] == pytest.approx(35.0 / 30.0)
    spike = soak.p99_stability([30.0, 31.0, 32.0, 70.0, 30.0])
    assert not spike["stable"] and spike["worst_over_median"] == pytest.approx(70.0 / 31.0)
    assert soak.p99_stability([30.0, 31.0, 62.0], limit=2.0)["stable"]  # exactly 2x passes
    assert not soak.p99_stability([30.0, math.nan, 31.0])["stable"]  # a minute without output
    assert not soak.p99_stability([])["stable"]


def test_summary_and_criteria() -> None:
    rows = [row(1, 460.0, 30.0, drops={"queue_full": 5}, corrected=1795),
            row(2, 460.5, 31.0), row(3, 460.8, 32.0, drops={"queue_full": 1, "no_depth": 2},
                                     corrected=1797),
            row(4, 461.5, 30.0)]
    s = soak.summarise(rows)
    assert (s["minutes"], s["sent"], s["corrected"], s["lost"]) == (4, 7200, 7192, 8)
    assert s["node_drops"] == {"queue_full": 6, "no_depth": 2} and s["node_drops_total"] == 8
    assert s["corrector_growth_mb_per_min"] == pytest.approx(0.48)
    assert s["sim_cell_growth_mb_per_min"] == pytest.approx(0.0)
    assert soak.failures(s) == []
    assert len(soak.failures(s, max_drops=0)) == 1
    assert "corrector" in soak.failures(s, max_growth=0.4)[0]

    leaking = soak.summarise([row(1, 450.0, 30.0), row(2, 452.0, 30.0), row(3, 454.0, 90.0)])
    fails = soak.failures(leaking)
    assert len(fails) == 2 and "2.00 MB/min" in fails[0] and "p99 unstable" in fails[1]
    text = soak.format_summary(leaking, fails)
    assert "FAIL" in text and "UNSTABLE" in text
    assert "PASS" in soak.format_summary(s, [])


def test_a_row_prints_on_one_line_with_its_drops() -> None:
    line = soak.format_row(row(2, 460.0, 31.0, drops={"queue_full": 4}, corrected=1796))
    assert "\n" not in line and line.endswith("queue_full 4")
    assert soak.format_row(row(1, None, math.nan)).split()[6:8] == ["-", "-"]
