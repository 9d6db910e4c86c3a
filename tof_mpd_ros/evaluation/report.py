"""Write an evaluation to disk: ``results.json`` (every number), PNG plots and ``index.html``."""

from __future__ import annotations

import html
import json
from pathlib import Path

from .components import ComponentEvaluation
from .plots import plot_accuracy_curves, plot_error_map, plot_precision_recall


def write_component_report(evaluation: ComponentEvaluation, out_dir: str | Path, *,
                           title: str = "tof_mpd_ros evaluation",
                           extra: dict | None = None) -> Path:
    """Write the component analysis; returns the path of ``results.json``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = {**evaluation.to_dict(), **(extra or {})}
    (out / "results.json").write_text(json.dumps(results, indent=2))
    plots = [plot_accuracy_curves(evaluation.stages, out / "accuracy_components.png",
                                  title="component analysis"),
             plot_precision_recall(evaluation.edges, out / "edges_precision_recall.png")]
    for i, example in enumerate(evaluation.examples):
        for stage in ("raw", "calibrated", "full"):
            plots.append(plot_error_map(example[stage], example["reference"],
                                        out / f"error_frame{i}_{stage}.png",
                                        title=f"frame {i}: {stage}"))
    (out / "index.html").write_text(_html(title, evaluation, plots))
    return out / "results.json"


def _html(title: str, evaluation: ComponentEvaluation, plots: list[Path]) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(name)}</td><td>{v['whole']:.3f}</td><td>{v['boundary']:.3f}</td>"
        f"<td>{v['mae_mm']:.2f}</td><td>{v['rmse_mm']:.2f}</td></tr>"
        for name, v in evaluation.summary(5.0).items())
    edges = "".join(f"<tr><td>{html.escape(n)}</td><td>{c.max_f1:.3f}</td></tr>"
                    for n, c in evaluation.edges.items())
    images = "".join(f'<figure><img src="{p.name}" alt="{p.stem}"></figure>' for p in plots)
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            "</title><style>body{font-family:sans-serif;margin:2em}table{border-collapse:"
            "collapse}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}"
            "figure{display:inline-block;margin:4px}img{max-width:480px}</style></head><body>"
            f"<h1>{html.escape(title)}</h1><p>{evaluation.n_frames} frames; full correction "
            f"{1e3 * evaluation.seconds_per_frame:.1f} ms per frame (median).</p>"
            "<h2>Accuracy at 5 mm</h2><table><tr><th>stage</th><th>whole</th><th>boundary</th>"
            f"<th>MAE mm</th><th>RMSE mm</th></tr>{rows}</table>"
            f"<h2>Edges (max F1)</h2><table>{edges}</table><h2>Plots</h2>{images}"
            "</body></html>")
