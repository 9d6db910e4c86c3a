"""The reports' one page builder (tof_mpd_ros.templates): every template ships and compiles,
every HTML report is one base page with one stylesheet, and the library writes no HTML or prose
of its own."""

from __future__ import annotations

import re
from fnmatch import fnmatch
from pathlib import Path

import pytest

from tof_mpd_ros import templates
from tof_mpd_ros.templates import fmt, ordinal, spec, words

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
    assert spec(float("nan"), ".1f") == "nan" and spec(0.612, ">8.1%") == "   61.2%"
    assert spec("ab", "<4") + "|" == "ab  |" and spec(None, "") == "None"
    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 111)] == [
        "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "111th"]


# -- the mismatch tool, the real-data report and the demo summary: words in templates ---------

MISMATCH = REPO / "tof_mpd_ros" / "mismatch"
#: where an f-string with words is still allowed, and why (error messages and log calls are
#: allowed everywhere)
WORDS_ALLOWED = {("report.py", "_residual_images"): "a plot panel's title",
                 ("benchmark.py", "run_benchmark"): "the progress callback's 'case 3'"}


def _assembled_words(path: Path, only: str | None = None) -> list[str]:
    """Every place in ``path`` (or in its function ``only``) that assembles words in code: an
    f-string, a ``%``-format, a ``+`` or a ``.join``/``.format`` on a string literal with a
    space in its text, outside ``raise`` and log calls; as ``"function:line"``."""
    import ast

    tree = ast.parse(path.read_text())
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}

    def inside(node: ast.AST, test) -> ast.AST | None:
        while node in parents:
            node = parents[node]
            if test(node):
                return node
        return None

    def spaced(node: ast.AST) -> bool:
        return (isinstance(node, ast.Constant) and isinstance(node.value, str)
                and " " in node.value)

    def words(node: ast.AST) -> bool:
        if isinstance(node, ast.JoinedStr):
            return any(spaced(v) for v in node.values)
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Mod, ast.Add)):
            return spaced(node.left) or spaced(node.right)
        return (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr in ("join", "format") and spaced(node.func.value))

    def logged(node: ast.AST) -> bool:
        return (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and isinstance(node.func.value, ast.Name)
                and node.func.value.id in ("_log", "log", "logger"))

    found = []
    for node in ast.walk(tree):
        if not words(node) or inside(node, lambda n: isinstance(n, ast.Raise) or logged(n)):
            continue
        func = inside(node, lambda n: isinstance(n, ast.FunctionDef))
        name = func.name if func else "-"
        if (only is None or name == only) and (path.name, name) not in WORDS_ALLOWED:
            found.append(f"{name}:{node.lineno}")
    return found


def test_the_finder_of_assembled_words_finds_them(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text('def a(x):\n    return f"fitted {x}"\n'
                     'def b(x):\n    return "; ".join(x)\n'
                     'def c(x):\n    return "gain %d" % x\n'
                     'def d(x):\n    raise ValueError(f"bad {x}")\n'
                     'def e(x):\n    return f"{x}_mm" + "_key"\n')
    assert _assembled_words(probe) == ["a:2", "b:4", "c:6"]


@pytest.mark.parametrize("path", sorted(MISMATCH.glob("*.py")), ids=lambda p: p.name)
def test_no_mismatch_module_assembles_sentences(path: Path) -> None:
    """The mismatch tool's sentences (evidence, reasons, the camera's profile, the verdict,
    the real-data report, the benchmark's table) come from templates/*.txt."""
    assert _assembled_words(path) == []


def test_the_demo_summary_is_not_assembled_in_code() -> None:
    assert _assembled_words(REPO / "tof_mpd_ros" / "cli" / "demo.py", "_print_summary") == []


def test_the_mismatch_phrases_live_in_the_templates() -> None:
    code = "".join(p.read_text() for p in MISMATCH.glob("*.py"))
    text = "".join((TEMPLATE_DIR / n).read_text() for n in
                   ("mismatch.txt", "mode_disagreement.txt", "mismatch_benchmark.txt"))
    for phrase in ("mnats/px (t =", "its correction correlates", "correction concentrated where",
                   "correction spread evenly", "too few held-out pixels", "lower than nominal",
                   "a grey world;", "mm at 4φ", "not named as missing physics",
                   "at the edge of its realistic range", "none: no significant",
                   "on static surfaces", "percentiles 5/25/50/75/95", "per-effect top-1"):
        assert phrase not in code and phrase in text, phrase


def _unexplained_why(**_: object) -> str:
    from tof_mpd_ros.mismatch.analysis import _Search
    from tof_mpd_ros.mismatch.fit import FitResult
    from tof_mpd_ros.sim.tof import ToFConfig

    search = _Search(None, [], {}, 15.0, 3.0, None, units_assumed=True)
    fit = FitResult("multipath", ToFConfig.nominal(), {"gain": 1.0}, 1, score=40.0, t_stat=9.0)
    assert search._first_explained([fit], 15.0, 0) is None
    return search.unexplained[0]["why"]


def _profile() -> str:
    from tof_mpd_ros.mismatch.profile import describe_profile
    from tof_mpd_ros.sim.tof import ToFConfig

    nominal = ToFConfig.nominal()
    fitted = nominal.with_effect("noise_model", scale=0.28, exponent=1.234, jitter_mm=0.0456)
    return " | ".join(describe_profile(nominal, fitted, {"mod_freq_hz": 50e6,
                                                         "mod_freq_from_recording": True,
                                                         "amplitude_scale": 2.3104},
                                       ["noise_model", "wiggling", "lens_scatter"]))


def _verdict() -> str:
    from tof_mpd_ros.mismatch.analysis import Analysis
    from tof_mpd_ros.mismatch.report import to_json
    from tof_mpd_ros.sim.tof import ToFConfig

    nominal = ToFConfig.nominal()
    doc = to_json(Analysis([], [], {}, nominal, nominal, {}, {}, [],
                           profile_words=["one", "two"]))
    return f"{doc['verdict']} | {doc['camera_profile']['summary']}"


def _evidence(monkeypatch: pytest.MonkeyPatch) -> str:
    """explain() words the facts evidence_facts() measures (here given)."""
    from tof_mpd_ros.mismatch import analysis
    from tof_mpd_ros.mismatch.fit import FitResult
    from tof_mpd_ros.sim.tof import ToFConfig

    facts = {"too_few": False, "parameters": {"a1_mm": 14.33, "p1_rad": -2.4712},
             "test_gain_mnats": 1302.94, "t": 34.12, "variance_ratio": None,
             "correction": {"correlation": 0.661, "rms_mm": 6.333, "where": {
                 "stratum": {"descriptor": "range_mm", "unit": "mm", "low": 210.0,
                             "high": 239.4}, "mean_mm": 8.7, "overall_mm": 5.68, "rho": -0.99,
                 "descriptor": "range_mm"}}}
    monkeypatch.setattr(analysis, "evidence_facts", lambda *_: facts)
    return analysis.explain(None, FitResult("wiggling", ToFConfig.nominal(), {}, 4), [])


def _disagreement() -> str:
    from tof_mpd_ros.mismatch.realdata import format_disagreement

    cell = {"lo": 1800.0, "hi": 2100.5, "n": 10, "median_mm": -4.0, "mad_mm": 1.0}
    return format_disagreement({
        "modes": [7, 1], "n": 1234, "share_of_pixels": 0.3456, "median_mm": -4.5,
        "mad_mm": 1.2, "robust_sigma_mm": 1.8, "mean_mm": -4.4, "rms_mm": 6.0,
        "percentiles_mm": {"5": -10.1, "25": -6.0, "50": -4.5, "75": -3.0, "95": 2.2},
        "slope_mm_per_m": 0.3, "spearman": {"range": 0.12, "amplitude_a": -0.5,
                                            "amplitude_b": float("nan")},
        "by_range_mm": [cell, cell], "by_amplitude_a": [cell], "by_amplitude_b": [],
        "by_surface": []})


def _benchmark_table() -> str:
    from tof_mpd_ros.mismatch.benchmark import text_table

    row = {"case": "b/2", "truth": [], "selected": ["wiggling"], "top1": False,
           "rmse_before_mm": 4.0, "rmse_after_mm": 3.9, "excess_before_mm": None,
           "excess_after_mm": 0.9}
    return text_table([row], {"cases": 1, "f": 1 / 3, "by_base": {}, "per_effect_top1": {},
                              "per_effect_parameter_error_median": {"x": None, "y": 0.12345}})


def _demo_summary(capsys: pytest.CaptureFixture) -> str:
    from tof_mpd_ros.cli.demo import _print_summary

    row = {"whole": 0.61234, "boundary": 0.0, "mae_mm": 12.345, "ms_per_frame": 1234.56}
    _print_summary({"weights": "shipped", "n_test_frames": 3, "ms_per_frame": 12.4,
                    "summary_5mm": {"proposed": row}, "ranking_statement": "Ranking.",
                    "differences_from_paper": [{"aspect": "x", "why": "y."}],
                    "targets": {"t": True, "u": False}, "edges_max_f1": {}}, Path("out"))
    return capsys.readouterr().out


#: (template, a phrase in it, what renders it, its exact output before the move to templates)
WORDED = [
    ("mismatch.txt", "not named as missing physics", _unexplained_why,
     "gain 1.00 is within what the camera itself may have (0.57-1.68: the grey world's albedo "
     "may be off by 0.6-1.6x and interreflection scales as albedo^1.1): not named as missing "
     "physics"),
    ("mismatch.txt", "lower than nominal", _profile,
     "modulation frequency 50 MHz (from the recording) | amplitude units 2.31× the "
     "simulator's (median albedo taken as 0.5: a grey world; albedo and units are degenerate) "
     "| noise 3.6× lower than nominal (amplitude exponent 1.2, jitter 0.046 mm) | wiggle "
     "3.0 mm at 4φ, 1.0 mm at 8φ"),
    ("mismatch.txt", "no significant mismatch", _verdict,
     "none: no significant mismatch | one; two"),
    ("mismatch.txt", "with the residual", _evidence,
     "fitted a1_mm 14.3, p1_rad -2.47; held-out gain 1302.9 mnats/px (t = 34.1); its "
     "correction correlates 0.66 with the residual (RMS correction 6.33 mm); correction "
     "concentrated where range_mm in [210, 239) mm (mean 8.70 mm vs 5.68 mm overall; rank "
     "correlation -0.99 with range_mm)"),
    ("mode_disagreement.txt", "on static surfaces", _disagreement,
     "mode 7 − mode 1 on static surfaces: n = 1234 pixels (35 % of the image)\n"
     "  median -4.5 mm, MAD 1.2 mm (robust σ 1.8 mm), mean -4.4 mm, RMS 6.0 mm\n"
     "  percentiles 5/25/50/75/95: -10.1 / -6.0 / -4.5 / -3.0 / 2.2 mm; slope 0.3 mm per m of "
     "range\n"
     "  by range mm: 1800–2100.5: -4.0 ± 1.0 (n 10); 1800–2100.5: -4.0 ± 1.0 (n 10)\n"
     "  by amplitude 7: 1800–2100.5: -4.0 ± 1.0 (n 10)\n"
     "  by amplitude 1: \n"
     "  by surface (its median range): \n"
     "  Spearman ρ with range 0.12, amplitude 7 -0.5, amplitude 1 nan"),
    ("mismatch_benchmark.txt", "per-effect top-1", _benchmark_table,
     "  case  truth                              selected                           ok  "
     "rmse b/a/oracle (mm)  excess b/a (mm)  visible (mnats/px)  refitted (mnats/px)  "
     "truth over answer (mnats/px)\n"
     "   b/2  none                               wiggling                           n    "
     "4.00/ 3.90/  n/a      n/a/ 0.90      n/a                 n/a                  n/a\n\n"
     "cases                                1\n"
     "f                                    0.3333\n"
     "per-effect top-1: \n"
     "per-effect median parameter error: y 0.123"),
    ("demo_summary.txt", "differs from the paper", _demo_summary,
     "\nweights: shipped; 3 test frames; proposed 12 ms per frame\n"
     "method        <5 mm whole  <5 mm boundary   MAE mm  ms/frame\n"
     "proposed            61.2%            0.0%    12.35    1234.6\n"
     "Ranking.\n"
     "differs from the paper (x): y.\n"
     "targets: t: met, u: NOT met\n"
     "edge max F1: \n"
     "report: out/report/index.html\n"),
]


@pytest.mark.parametrize("name,phrase,produce,expected", WORDED,
                         ids=[w[2].__name__.strip("_") for w in WORDED])
def test_the_words_come_from_the_templates(name: str, phrase: str, produce, expected: str,
                                           monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture) -> None:
    """Each text is exactly what the code wrote before its words moved to the template, and
    editing the template changes it."""
    import inspect

    def run() -> str:
        wanted = {"monkeypatch": monkeypatch, "capsys": capsys}
        return produce(**{p: wanted[p] for p in inspect.signature(produce).parameters
                          if p in wanted})

    assert run() == expected
    original = templates._source
    templates.environment.cache_clear()
    monkeypatch.setattr(templates, "_source", lambda n: original(n).replace(phrase, "EDITED")
                        if n == name else original(n))
    try:
        edited = run()
    finally:
        monkeypatch.setattr(templates, "_source", original)
        templates.environment.cache_clear()
    assert edited == expected.replace(phrase, "EDITED") and phrase in expected
