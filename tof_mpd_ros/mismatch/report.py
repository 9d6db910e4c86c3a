"""Write an :class:`~.analyse.Analysis`: ``report.json``, the fitted simulator config, PNG plots
(matplotlib Agg) and an ``index.html`` that embeds them with the tables (the package's report
template ``templates/mismatch.html``)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MismatchError
from ..templates import render
from .analysis import Analysis
from .locate import describe_stratum
from .wording import text

REPORT_JSON = "report.json"
CONFIG_JSON = "fitted_config.json"


def to_json(analysis: Analysis) -> dict[str, Any]:
    """The JSON document of a report: the answer first (selected effects, verdict), then the
    evidence (docs/mismatch.md lists the fields). Its sentences (verdict, the profile's
    summary, evidence, reasons) come from ``templates/mismatch.txt``."""
    m = analysis.metrics
    return _clean({
        "selected": analysis.selected,
        "verdict": text("verdict", analysis.selected, misfits(analysis.unexplained)),
        "workflow": analysis.workflow,
        "camera_profile": {"effects": analysis.profile,
                           "parameters": {e: analysis.parameters[e] for e in analysis.profile},
                           "facts": analysis.profile_facts,
                           "summary": text("profile_summary", analysis.profile_words)},
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


def misfits(unexplained: list[dict[str, Any]]) -> list[dict[str, str]]:
    """``{"effect", "case"}`` of every entry of ``Analysis.unexplained`` that says the model
    does not explain the residual, in order, each pair once; a fit inside the camera's own
    window is not one (the camera may have that value)."""
    pairs = [(u["effect"], u["case"]) for u in unexplained if u.get("case") != "camera_window"]
    return [{"effect": e, "case": c} for e, c in dict.fromkeys(pairs)]


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
    """The PNGs of a report: name -> path (``histogram`` always, ``images`` and ``ranking``
    when there is something to show)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {"histogram": _residual_histogram(plt, analysis, out / "residual_histogram.png")}
    if analysis.residual_before:
        paths["images"] = _residual_images(plt, analysis, out / "residual_images.png")
    first = [r for r in analysis.ranking() if r["round"] == 1]
    if first:
        paths["ranking"] = _ranking_bars(plt, first, out / "ranking.png")
    return paths


def _residual_histogram(plt: Any, analysis: Analysis, path: Path) -> Path:
    """Held-out residuals before and after the fit, pooled over frames (mm)."""
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
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _residual_images(plt: Any, analysis: Analysis, path: Path) -> Path:
    """The residual maps (mm) of up to three held-out frames, before (top) and after."""
    n = min(len(analysis.residual_before), 3)
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 5.2), squeeze=False)
    lim = float(np.nanpercentile(np.abs(np.stack(analysis.residual_before[:n])), 95)) or 1.0
    for j in range(n):
        for row, (maps, title) in enumerate(((analysis.residual_before, "before"),
                                             (analysis.residual_after, "after"))):
            im = axes[row, j].imshow(maps[j], cmap="coolwarm", vmin=-lim, vmax=lim)
            axes[row, j].set_title(f"frame {analysis.test_frames[j]} {title}", fontsize=9)
            axes[row, j].axis("off")
    fig.colorbar(im, ax=axes, shrink=0.8, label="residual (mm)")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _ranking_bars(plt: Any, first: list[dict[str, Any]], path: Path) -> Path:
    """The first round's candidates by score (millinats per held-out pixel, floored at -20)."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    names = [r["effect"] for r in first][::-1]
    ax.barh(names, [max(r["score"], -20.0) for r in first][::-1])
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("score (millinats / held-out pixel, after penalty)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _html(doc: dict[str, Any], paths: dict[str, Path]) -> str:
    """The page (templates/mismatch.html) of a report document and the files written."""
    figures = [(p.name, key) for key, p in paths.items() if p.suffix == ".png"]
    return render("mismatch.html", title="sim-vs-real mismatch", doc=doc, figures=figures,
                  describe=describe_stratum, config_json=CONFIG_JSON, report_json=REPORT_JSON)
