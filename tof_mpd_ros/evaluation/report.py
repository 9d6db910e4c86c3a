"""Write an evaluation to disk: ``results.json`` (every number), PNG plots and ``index.html``.

:func:`write_component_report` for ``tof-mpd evaluate``, :func:`write_benchmark_report` for
``tof-mpd benchmark`` (and the demo). The pages are the package's report templates
(``templates/components.html`` and ``templates/benchmark.html``, on ``templates/base.html``),
fed with the same dict that is written to ``results.json``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..templates import write_page
from .components import ComponentEvaluation
from .plots import plot_accuracy_curves, plot_error_map, plot_precision_recall

if TYPE_CHECKING:
    from .benchmark import BenchmarkResult


def _reliability_plot(cov: dict, path: Path) -> Path:
    """The fcn kind's σ reliability curve and k-σ coverage (:mod:`.uncertainty`)."""
    from .uncertainty import ReliabilityCurve, plot_reliability

    rel = cov["reliability"]
    curve = ReliabilityCurve(np.asarray(rel["sigma_rms_mm"], float),
                             np.asarray(rel["error_rms_mm"], float),
                             np.asarray(rel["count"], np.int64))
    observed = {f"{k:g}": (math.nan if v is None else v)
                for k, v in zip(cov["k"], cov["observed"], strict=True)}
    return plot_reliability(curve, observed, path, title="predicted σ against the actual error")


def write_component_report(evaluation: ComponentEvaluation, out_dir: str | Path, *,
                           title: str = "tof_mpd_ros evaluation",
                           extra: dict | None = None) -> Path:
    """Write the component analysis of either kind of model (the page names the kind; an fcn
    model has no edge curves, so no edge plot, and its σ coverage instead); returns the path
    of ``results.json``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = {**evaluation.to_dict(), **(extra or {})}
    (out / "results.json").write_text(json.dumps(results, indent=2))
    plots = [plot_accuracy_curves(evaluation.stages, out / "accuracy_components.png",
                                  title=f"component analysis ({evaluation.kind} model)")]
    if evaluation.edges:
        plots.append(plot_precision_recall(evaluation.edges, out / "edges_precision_recall.png"))
    if evaluation.coverage:
        plots.append(_reliability_plot(evaluation.coverage, out / "sigma_reliability.png"))
    for i, example in enumerate(evaluation.examples):
        for stage in ("raw", "calibrated", evaluation.final_stage):
            plots.append(plot_error_map(example[stage], example["reference"],
                                        out / f"error_frame{i}_{stage}.png",
                                        title=f"frame {i}: {stage}"))
    write_page(out / "index.html", "components.html", title=title, results=results,
               plots=[p.name for p in plots])
    return out / "results.json"


def write_benchmark_report(result: BenchmarkResult, out_dir: str | Path, *,
                           title: str = "tof_mpd_ros benchmark",
                           extra: dict | None = None) -> Path:
    """Write the benchmark: ``results.json`` (every number), the PNGs and ``index.html``.

    Files: ``accuracy_whole.png``, ``accuracy_boundary.png`` (Fig. 5), ``qualitative_frame{i}.png``
    (Fig. 6), ``profile_frame{i}.png`` (Fig. 7/8), ``edges_precision_recall.png`` (Fig. 10),
    ``accuracy_components.png`` (Fig. 8).

    Returns:
        The path of ``results.json``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = {**result.to_dict(), **(extra or {})}
    results["figures"] = {k: [p.name for p in v]
                          for k, v in _benchmark_figures(result, out).items()}
    (out / "results.json").write_text(json.dumps(results, indent=2, allow_nan=False,
                                                 default=_json_default))
    write_page(out / "index.html", "benchmark.html", title=title, results=results,
               proposed=result.proposed)
    return out / "results.json"


def _benchmark_figures(result: BenchmarkResult, out: Path) -> dict[str, list[Path]]:
    """Draw the benchmark's PNGs into ``out``: kind -> paths (``curves``, ``qualitative``,
    ``profiles``, ``edges`` (none for an fcn model: no G), ``components``), in the page's
    order."""
    from .benchmark import methods_for
    from .benchmark_plots import plot_method_curves, plot_profile, plot_qualitative

    figures: dict[str, list[Path]] = {"curves": [], "qualitative": [], "profiles": [],
                                      "edges": [], "components": []}
    for region in ("whole", "boundary"):
        label = "whole image" if region == "whole" else "boundary region (5 px)"
        figures["curves"].append(plot_method_curves(
            {m: getattr(ev, region) for m, ev in result.methods.items()},
            out / f"accuracy_{region}.png", title=f"accuracy, {label}"))
    best = result.best_baselines(2)
    for i, ex in enumerate(result.examples):
        ordered = {m: ex["estimates"][m] for m in methods_for(result.kind)
                   if m in ex["estimates"]}
        figures["qualitative"].append(plot_qualitative(
            ex["reference"], ordered, out / f"qualitative_frame{i}.png",
            line=ex["line"], title=f"test frame {ex['index']}: range (top) and error (bottom)"))
        if ex["line"] is not None:
            figures["profiles"].append(plot_profile(
                ex["profiles"], ["raw", "calibrated", *best, result.proposed],
                out / f"profile_frame{i}.png", line=ex["line"],
                title=f"test frame {ex['index']}: range along the red arrow"))
    if result.components.edges:
        figures["edges"].append(plot_precision_recall(result.components.edges,
                                                      out / "edges_precision_recall.png"))
    figures["components"].append(plot_accuracy_curves(result.components.stages,
                                                      out / "accuracy_components.png",
                                                      title="component analysis"))
    return figures


def _json_default(value: object) -> object:
    """numpy scalars/arrays in results (anything else is a bug and raises)."""
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
