"""Write an :class:`~.analyse.Analysis`: ``report.json``, the fitted simulator config, PNG plots
(matplotlib Agg) and an ``index.html`` that embeds them with the tables."""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MismatchError
from .analysis import Analysis
from .locate import describe_stratum

REPORT_JSON = "report.json"
CONFIG_JSON = "fitted_config.json"


def to_json(analysis: Analysis) -> dict[str, Any]:
    """The JSON document of a report: the answer first (selected effects, verdict), then the
    evidence (docs/mismatch.md lists the fields)."""
    m = analysis.metrics
    return _clean({
        "selected": analysis.selected,
        "verdict": (", ".join(analysis.selected) if analysis.selected
                    else "none: no significant mismatch"),
        "workflow": analysis.workflow,
        "camera_profile": {"effects": analysis.profile,
                           "parameters": {e: analysis.parameters[e] for e in analysis.profile},
                           "facts": analysis.profile_facts,
                           "summary": "; ".join(analysis.profile_words)},
        "unexplained": analysis.unexplained,
        "ranking": analysis.ranking(),
        "parameters": analysis.parameters,
        "rmse_before_mm": m.get("rmse_before_mm"),
        "rmse_after_mm": m.get("rmse_after_mm"),
        "metrics": m,
        "held_out_frames": analysis.test_frames,
        "location": analysis.location,
        "config_before": analysis.config_before.to_dict(),
        "config_after": analysis.config_after.to_dict(),
    })


def _clean(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    return obj


def write_report(analysis: Analysis, out_dir: str | Path) -> dict[str, Path]:
    """Write ``report.json``, ``fitted_config.json``, PNGs and ``index.html`` into ``out_dir``.

    Returns:
        name -> path of every file written.

    Raises:
        MismatchError: the directory cannot be created or written.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        doc = to_json(analysis)
        paths = {"report": out / REPORT_JSON, "config": out / CONFIG_JSON}
        paths["report"].write_text(json.dumps(doc, indent=2))
        paths["config"].write_text(json.dumps(analysis.config_after.to_dict(), indent=2))
        paths.update(_plots(analysis, out))
        paths["html"] = out / "index.html"
        paths["html"].write_text(_html(doc, paths))
    except OSError as err:
        raise MismatchError(f"cannot write the report to {out}: {err}") from err
    return paths


def _plots(analysis: Analysis, out: Path) -> dict[str, Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    rb = np.concatenate([r.ravel() for r in analysis.residual_before]) \
        if analysis.residual_before else np.array([])
    ra = np.concatenate([r.ravel() for r in analysis.residual_after]) \
        if analysis.residual_after else np.array([])
    rb, ra = rb[np.isfinite(rb)], ra[np.isfinite(ra)]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    if rb.size:
        lim = float(np.percentile(np.abs(rb), 99)) or 1.0
        bins = np.linspace(-lim, lim, 81)
        ax.hist(rb, bins=bins, histtype="step", label="before (nominal)", density=True)
        ax.hist(ra, bins=bins, histtype="step", label="after (fitted)", density=True)
        ax.legend()
    ax.set_xlabel("held-out residual real − predicted range (mm)")
    ax.set_ylabel("density")
    fig.tight_layout()
    paths["histogram"] = out / "residual_histogram.png"
    fig.savefig(paths["histogram"], dpi=100)
    plt.close(fig)

    n = min(len(analysis.residual_before), 3)
    if n:
        fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 5.2), squeeze=False)
        lim = float(np.nanpercentile(np.abs(np.stack(analysis.residual_before[:n])), 95)) or 1.0
        for j in range(n):
            for row, (maps, title) in enumerate(((analysis.residual_before, "before"),
                                                 (analysis.residual_after, "after"))):
                im = axes[row, j].imshow(maps[j], cmap="coolwarm", vmin=-lim, vmax=lim)
                axes[row, j].set_title(f"frame {analysis.test_frames[j]} {title}", fontsize=9)
                axes[row, j].axis("off")
        fig.colorbar(im, ax=axes, shrink=0.8, label="residual (mm)")
        paths["images"] = out / "residual_images.png"
        fig.savefig(paths["images"], dpi=100)
        plt.close(fig)

    rows = analysis.ranking()
    first = [r for r in rows if r["round"] == 1]
    if first:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        names = [r["effect"] for r in first][::-1]
        ax.barh(names, [max(r["score"], -20.0) for r in first][::-1])
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_xlabel("score (millinats / held-out pixel, after penalty)")
        fig.tight_layout()
        paths["ranking"] = out / "ranking.png"
        fig.savefig(paths["ranking"], dpi=100)
        plt.close(fig)
    return paths


def _table(rows: list[list[Any]], head: list[str]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>"
                   for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _fmt(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def _html(doc: dict[str, Any], paths: dict[str, Path]) -> str:
    m = doc["metrics"]
    metric_rows = [[k.replace("_before", ""), _fmt(m.get(k)), _fmt(m.get(k.replace("before",
                                                                                    "after")))]
                   for k in m if "before" in k]
    ranking = [[r["round"], r["effect"], _fmt(r["score"]), _fmt(r["t"]), r["n_params"],
                r["evidence"]] for r in doc["ranking"]]
    loc = doc["location"]
    flagged = [[describe_stratum(s), s["n"], _fmt(s["mean_mm"]), _fmt(s["z"]),
                _fmt(s["variance_ratio"])] for s in loc.get("flagged", [])]
    corr = [[k, _fmt(v["residual"]), _fmt(v["abs_z"])]
            for k, v in loc.get("correlations", {}).items()]
    imgs = "".join(f'<p><img src="{p.name}" alt="{k}"></p>'
                   for k, p in paths.items() if p.suffix == ".png")
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>sim-vs-real mismatch</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}
table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px;font-size:13px;vertical-align:top}}</style>
</head><body>
<h1>Sim-vs-real mismatch</h1>
<p><b>Verdict:</b> {html.escape(doc["verdict"])} ({html.escape(doc["workflow"])})</p>
<p><b>The camera's profile:</b> {html.escape(doc["camera_profile"]["summary"])}</p>
{"".join(f"<p><b>Not named:</b> {html.escape(u['effect'])} "
         f"{html.escape(json.dumps(u['parameters_at_edge']) if u['parameters_at_edge'] else '')}"
         f" — {html.escape(u['why'])}</p>" for u in doc["unexplained"])}
<p>Fitted parameters: {html.escape(json.dumps(doc["parameters"]))}</p>
<h2>Held-out residuals before / after</h2>{_table(metric_rows, ["metric", "before", "after"])}
{imgs}
<h2>Candidates (score = held-out gain − complexity penalty, millinats/pixel)</h2>
{_table(ranking, ["round", "effect", "score", "t", "params", "evidence"])}
<h2>Where the residual exceeds the noise model (before modelling)</h2>
{_table(flagged, ["stratum", "pixels", "mean (mm)", "z", "var. ratio"])}
<h3>Rank correlation of the residual with each descriptor</h3>
{_table(corr, ["descriptor", "residual", "|z|"])}
<p>Files: {CONFIG_JSON} (simulator config with the fitted effects), {REPORT_JSON}.</p>
</body></html>"""
