"""The reports' one page builder (tof_mpd_ros.templates): every template ships and compiles,
every HTML report is one base page with one stylesheet, and the library writes no HTML or prose
of its own."""

from __future__ import annotations

import re
from fnmatch import fnmatch
from pathlib import Path

import pytest

from tof_mpd_ros import templates
from tof_mpd_ros.templates import fmt, ordinal, words

REPO = Path(__file__).resolve().parents[1]
TEMPLATE_DIR = REPO / "tof_mpd_ros" / "templates"
PAGES = ("benchmark.html", "components.html", "mismatch.html")


def test_every_template_file_is_package_data_and_compiles() -> None:
    files = sorted(p.name for p in TEMPLATE_DIR.iterdir() if p.suffix != ".py"
                   and p.is_file())
    assert files == templates.template_names()
    assert set(PAGES) | {"base.html", "report.css", "paper_comparison.txt"} <= set(files)
    setup = (REPO / "setup.py").read_text()
    patterns = re.findall(r'"(templates/[^"]+)"', setup)
    assert all(any(fnmatch(f"templates/{f}", p) for p in patterns) for f in files), patterns
    for name in files:
        if name.endswith((".html", ".txt")):
            templates.environment(prose=name.endswith(".txt")).get_template(name)


def test_pages_extend_the_one_base_page_with_the_one_stylesheet() -> None:
    css = (TEMPLATE_DIR / "report.css").read_text()
    for name in PAGES:
        source = (TEMPLATE_DIR / name).read_text()
        assert '{% extends "base.html" %}' in source and "<style" not in source, name
    base = (TEMPLATE_DIR / "base.html").read_text()
    assert base.count("<style>") == 1 and '{% include "report.css" %}' in base
    page = templates.render("components.html", title="t <&>", plots=["a.png"], results={
        "n_frames": 1, "seconds_per_frame": float("nan"), "edges": {},
        "summary_5mm": {"raw": {"whole": 0.5, "boundary": None, "mae_mm": 1.0,
                                "rmse_mm": 2.0}}})
    assert page.count("<style>") == 1 and css.strip() in page
    assert "<title>t &lt;&amp;&gt;</title>" in page          # autoescaped
    assert "<td>0.500</td><td>–</td>" in page                  # missing numbers as a dash
    assert '<img src="a.png" alt="a">' in page


def test_no_html_or_report_prose_in_library_code() -> None:
    """HTML lives in the templates; the paper comparison's sentences too."""
    sources = [*(REPO / "tof_mpd_ros" / "evaluation").rglob("*.py"),
               REPO / "tof_mpd_ros" / "mismatch" / "report.py"]
    for path in sources:
        text = path.read_text()
        for tag in ("<html", "<table", "<tr>", "<td>", "<p>", "<style", "<img"):
            assert tag not in text, (path, tag)
    paper = (REPO / "tof_mpd_ros/evaluation/benchmark/paper.py").read_text()
    for phrase in ("points above the proposed method", "Measured on these frames",
                   "above it.", "Ranking at 5 mm", "improve marginally"):
        assert phrase not in paper
        assert phrase in (TEMPLATE_DIR / "paper_comparison.txt").read_text()


def test_the_comparison_words_come_from_the_template(monkeypatch: pytest.MonkeyPatch) -> None:
    from tof_mpd_ros.evaluation.benchmark import compare_with_paper

    acc = {"raw": (0.3, 0.2), "calibrated": (0.45, 0.3), "RFD": (0.7, 0.6),
           "proposed": (0.6, 0.5)}
    original = templates._source

    def edited(name: str) -> str | None:
        text = original(name)
        return text.replace("points above the proposed method", "POINTS ABOVE") \
            if name == "paper_comparison.txt" else text

    templates.environment.cache_clear()
    monkeypatch.setattr(templates, "_source", edited)
    try:
        why = compare_with_paper(acc, {})["findings"][0]["why"]
    finally:
        monkeypatch.undo()
        templates.environment.cache_clear()
    assert why == "RFD is 10.0 points above the proposed method.".replace(
        "points above the proposed method", "POINTS ABOVE")
    assert compare_with_paper(acc, {})["findings"][0]["why"] == \
        "RFD is 10.0 points above the proposed method."


def test_words_and_filters() -> None:
    assert words("  a\n  b ,c ( d ) .\n") == "a b,c ( d)."
    assert fmt(None, ".1f") == fmt(float("nan"), ".1f") == "–"
    assert fmt(0.1234, ".1f", 100) == "12.3" and fmt(3, "+.0f") == "+3"
    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 111)] == [
        "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "111th"]
