"""The ranking at 5 mm and how it compares with the paper's (§V-C, Fig. 5), claim by claim.

:func:`compare_with_paper` decides, from the measured accuracies and the evidence the benchmark
collected, which of the paper's claims hold and which measurements explain each difference; the
words are the package's template ``templates/paper_comparison.txt`` (one group of macros per
finding), fed with those facts. The result is plain data (written to ``results.json`` and shown
by the HTML report).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import InputError
from ...templates import macros, words
from ..diagnosis import REGIONS
from .config import BASELINE_NAMES, F_ALONE, PROPOSED, REFERENCE_EDGES, SMOOTHING_BASELINES

# The paper's numbers (§V-C, Fig. 5): fraction of pixels within 5 mm, whole image.
PAPER_WITHIN_5MM = {"raw": 0.30, "calibrated": 0.45, PROPOSED: 0.63}
TEMPLATE = "paper_comparison.txt"
_EDGE_REGION, _INTERIOR_REGION = REGIONS[0][0], REGIONS[-1][0]


def rank_methods(whole: Mapping[str, float], boundary: Mapping[str, float],
                 mae: Mapping[str, float] | None = None) -> list[str]:
    """Methods best first: by accuracy on the whole image, then boundary accuracy, then lower
    MAE, then name (deterministic). NaN accuracies rank last."""
    def key(name: str) -> tuple:
        w, b = whole[name], boundary.get(name, float("nan"))
        m = float("inf") if mae is None else mae.get(name, float("inf"))
        return (-(w if np.isfinite(w) else -1.0), -(b if np.isfinite(b) else -1.0),
                m if np.isfinite(m) else float("inf"), name)

    return sorted(whole, key=key)


@dataclass(frozen=True)
class _Evidence:
    """The measurements that explain a difference, in the shapes the template words them
    (each None or empty when not measured). ``raw``: :func:`compare_with_paper`'s evidence."""

    raw: Mapping[str, Any]

    @property
    def noise(self) -> dict[str, float] | None:
        """Share of the calibrated error variance away from boundaries that is pixel noise,
        and the rms (mm) of the noise and of the smooth bias (NaN when not given)."""
        if self.raw.get("noise_share") is None:
            return None
        return {"share": self.raw["noise_share"],
                "rms_mm": self.raw.get("noise_rms_mm", float("nan")),
                "bias_mm": self.raw.get("bias_rms_mm", float("nan"))}

    @property
    def training(self) -> dict[str, int | None] | None:
        """How many patches (and epochs) F and G were trained on."""
        if self.raw.get("f_training_patches") is None:
            return None
        return {"patches": self.raw["f_training_patches"], "epochs": self.raw.get("f_epochs")}

    def misses(self, names: Sequence[str], own: str = PROPOSED) -> dict[str, Any] | None:
        """What the misses (≥ 5 mm) of ``names`` are made of (:class:`~..diagnosis.MissTally`
        rows), and ``lever``: what most of the model's own method's (``own``: ``proposed``
        or ``fcn``; else F's) misses are — ``"beyond_clip"`` (out of F's reach),
        ``"noise"`` (noise-limited), ``"bias"`` (within reach), or None when neither was
        measured."""
        tally = self.raw.get("misses")
        if not tally:
            return None
        per = {n: tally["methods"][n] for n in names if n in tally["methods"]}
        if not per:
            return None
        row = per.get(own) or per.get(F_ALONE)
        lever = None
        if row is not None:
            noisy, beyond = row.get("noise_limited") or 0.0, row.get("beyond_clip") or 0.0
            lever = "beyond_clip" if beyond >= 0.5 else "noise" if noisy >= 0.5 else "bias"
        return {"clip_mm": tally.get("clip_mm"), "methods": per, "lever": lever, "own": own}

    def _regions(self) -> tuple[Mapping[str, Any], Mapping[str, Any]] | None:
        regions = self.raw.get("regions")
        if not regions:
            return None
        return regions.get(_EDGE_REGION, {}), regions.get(_INTERIOR_REGION, {})

    def regions(self, names: Sequence[str]) -> list[dict[str, Any]]:
        """Accuracy at 5 mm within 2 px of an edge and beyond 5 px, per name measured."""
        both = self._regions()
        if both is None:
            return []
        edge, inner = both
        return [{"name": n, "edge": edge[n]["within"], "interior": inner[n]["within"]}
                for n in names if n in edge and n in inner]

    def edge_loss(self, name: str) -> dict[str, Any] | None:
        """Change of ``name`` against calibrated (fraction) within 2 px of an edge and beyond
        5 px, and whether it loses more on the edges."""
        both = self._regions()
        if both is None:
            return None
        edge, inner = both
        if name not in edge or "calibrated" not in edge:
            return None
        d_edge = edge[name]["within"] - edge["calibrated"]["within"]
        d_inner = inner[name]["within"] - inner["calibrated"]["within"]
        return {"edge": d_edge, "interior": d_inner, "on_edges": d_edge < d_inner}


@dataclass(frozen=True)
class _Scores:
    """Accuracy at 5 mm of the methods in the paper's Fig. 5, both rankings, and F alone's;
    ``proposed``: the method in the paper's method's place (``proposed``, or ``fcn``)."""

    whole: dict[str, float]
    boundary: dict[str, float]
    ranking_whole: list[str]
    ranking_boundary: list[str]
    baselines: list[str]
    f_alone: tuple[float, float] | None
    proposed: str = PROPOSED

    def regions(self) -> tuple[tuple[str, list[str], dict[str, float]], ...]:
        """(region, ranking, scores) for ``"whole"`` (image) and ``"boundary"`` (region)."""
        return (("whole", self.ranking_whole, self.whole),
                ("boundary", self.ranking_boundary, self.boundary))


def _finding(kind: str, agrees: bool, **facts: Any) -> dict[str, Any]:
    """The facts of one finding; the evidence keys the template reads default to absent."""
    return {"kind": kind, "agrees": agrees, "noise": None, "misses": None, "regions": [],
            "training": None, **facts}


def _best(s: _Scores, ev: _Evidence) -> list[dict[str, Any]]:
    """Claim: the proposed method (or the model in its place) is best at 5 mm, in each
    region."""
    out = []
    own = s.proposed
    for region, ranking, scores in s.regions():
        top = ranking[0]
        f = _finding("best", top == own, region=region, expected=own, top=top)
        if not f["agrees"]:
            f["margin"] = scores[top] - scores[own]
            if top == "RFD":
                f.update(misses=ev.misses([own, F_ALONE, "RFD"], own), training=ev.training)
            elif top in SMOOTHING_BASELINES:
                f.update(noise=ev.noise, misses=ev.misses([own, top], own))
            elif top == "calibrated":
                f.update(regions=ev.regions(["calibrated", F_ALONE, own]),
                         misses=ev.misses([own, F_ALONE], own), training=ev.training)
        out.append(f)
    return out


def _second(s: _Scores, ev: _Evidence) -> list[dict[str, Any]]:
    """Claim: RFD is second at 5 mm, in each region (only when RFD was benchmarked)."""
    if "RFD" not in s.whole:
        return []
    val, val_cal = ev.raw.get("val_scores", {}), ev.raw.get("val_calibrated")
    out = []
    for region, ranking, scores in s.regions():
        f = _finding("second", ranking[1] == "RFD", region=region, expected="RFD",
                     second=ranking[1], ours=s.proposed)
        if not f["agrees"]:
            position = ranking.index("RFD") + 1
            ahead = [m for m in ranking[:position - 1] if m != s.proposed]
            smoothers = [m for m in ahead if m in SMOOTHING_BASELINES]
            f.update(position=position, score=scores["RFD"], ahead=ahead,
                     smoothers=bool(smoothers), below_calibrated="calibrated" in ahead,
                     val_rfd=val.get("RFD") if val_cal is not None else None, val_cal=val_cal,
                     pixels=ev.raw.get("rfd_training_pixels"))
            if smoothers:
                f.update(noise=ev.noise, misses=ev.misses(["RFD", *smoothers], s.proposed))
            if f["below_calibrated"]:
                f["regions"] = ev.regions(["calibrated", "RFD"])
        out.append(f)
    return out


def _above_calibrated(s: _Scores, ev: _Evidence) -> list[dict[str, Any]]:
    """Claim: every baseline improves on the calibrated range, in each region."""
    val, val_cal = ev.raw.get("val_scores", {}), ev.raw.get("val_calibrated")
    out = []
    for region, _, scores in s.regions():
        below = [m for m in s.baselines if scores[m] < scores["calibrated"]]
        reasons = []
        for m in below:
            reason = {"name": m, "score": scores[m], "calibrated": scores["calibrated"],
                      "whole": s.whole[m], "whole_calibrated": s.whole["calibrated"],
                      "val": val.get(m), "val_cal": val_cal}
            if region == "boundary":
                reason.update(case="boundary", edge_loss=ev.edge_loss(m))
            elif m in val and val_cal is not None:
                reason["case"] = "no_setting" if val[m] <= val_cal else "no_transfer"
            else:
                reason["case"] = "below"
            reasons.append(reason)
        out.append(_finding("above_calibrated", not below, region=region, below=below,
                            reasons=reasons, boundary_share=ev.raw.get("boundary_share")))
    return out


def _calibration(s: _Scores) -> dict[str, Any]:
    """Claim: the calibrated range is better than the raw range."""
    return _finding("calibration", s.whole["calibrated"] > s.whole["raw"],
                    paper_raw=PAPER_WITHIN_5MM["raw"],
                    paper_calibrated=PAPER_WITHIN_5MM["calibrated"], raw=s.whole["raw"],
                    calibrated=s.whole["calibrated"])


def _geodesic(s: _Scores, ev: _Evidence) -> list[dict[str, Any]]:
    """Claim: geodesic filtering with G adds to F (component analysis, Fig. 8)."""
    if s.f_alone is None:
        return []
    full = (s.whole[s.proposed], s.boundary[s.proposed])
    oracle = ev.raw.get("reference_edges")
    return [_finding("geodesic", full[0] >= s.f_alone[0] and full[1] >= s.f_alone[1],
                     f_alone=s.f_alone, full=full, oracle=oracle,
                     oracle_helps=oracle is not None and oracle[1] >= s.f_alone[1]
                     and oracle[0] >= s.f_alone[0],
                     regions=ev.regions([F_ALONE, PROPOSED, REFERENCE_EDGES]))]


def _network(s: _Scores, ev: _Evidence) -> list[dict[str, Any]]:
    """Claim: the network F beats the forest RFD on the same features and target (the paper's
    argument for a network: "Comparison with the RFD justified the use of NNs")."""
    if s.f_alone is None or "RFD" not in s.whole:
        return []
    rfd = (s.whole["RFD"], s.boundary["RFD"])
    agrees = s.f_alone[0] >= rfd[0] and s.f_alone[1] >= rfd[1]
    f = _finding("network", agrees, f_alone=s.f_alone, rfd=rfd, chosen=ev.raw.get("rfd_chosen"),
                 pixels=ev.raw.get("rfd_training_pixels"))
    if not agrees:
        f.update(training=ev.training, misses=ev.misses([F_ALONE, "RFD"], s.proposed))
    return [f]


def _worded(template: Any, finding: Mapping[str, Any]) -> dict[str, Any]:
    """A finding as the report shows it: ``{"aspect", "paper", "ours", "agrees", "why"}``
    (``why`` None when it agrees or nothing measured explains it)."""
    def word(field: str) -> str | None:
        return words(getattr(template, f"{finding['kind']}_{field}")(finding)) or None

    return {"aspect": word("aspect"), "paper": word("paper"), "ours": word("ours"),
            "agrees": finding["agrees"], "why": None if finding["agrees"] else word("why")}


def compare_with_paper(acc5: Mapping[str, tuple[float, float]], evidence: Mapping[str, Any],
                       *, proposed: str = PROPOSED) -> dict[str, Any]:
    """The ranking at 5 mm and every way it differs from the paper's, with the reason.

    Args:
        acc5: method -> (fraction within 5 mm whole image, boundary region), for the methods of
            the paper's Fig. 5 (raw, calibrated, the baselines present, ``proposed``); may also
            hold ``F`` (ranked separately, it is a component).
        proposed: the method judged in the paper's method's place: ``proposed`` (the patch
            kind's full method) or ``fcn`` (a model of the fcn kind, which has no ``F``).
        evidence: measurements explaining differences (any may be absent):
            ``noise_share`` (fraction of the calibrated error variance away from boundaries
            that is pixel-to-pixel noise), ``noise_rms_mm``, ``bias_rms_mm``,
            ``boundary_share`` (fraction of evaluated pixels in the boundary region),
            ``val_scores`` (method -> validation score at 5 mm), ``val_calibrated`` (calibrated
            on the same validation frames), ``rfd_training_pixels``, ``rfd_chosen`` (its chosen
            parameters), ``f_training_patches``, ``f_epochs``, ``regions``
            (:class:`~..diagnosis.RegionTally` result), ``misses``
            (:class:`~..diagnosis.MissTally` result), ``reference_edges`` (the full method
            with the reference's edges: (whole, boundary) within 5 mm).

    Returns:
        ``{"ranking_whole": [...], "ranking_boundary": [...], "statement": str,
        "paper_ranking": str, "paper_within_5mm": {...},
        "findings": [{"aspect", "paper", "ours", "agrees", "why"}...], "targets": {...}}``.
    """
    paper = {k: v for k, v in acc5.items() if k != F_ALONE}
    if proposed not in paper or "calibrated" not in paper or "raw" not in paper:
        raise InputError(f"compare_with_paper needs raw, calibrated and {proposed}")
    whole = {k: v[0] for k, v in paper.items()}
    bound = {k: v[1] for k, v in paper.items()}
    s = _Scores(whole, bound, rank_methods(whole, bound), rank_methods(bound, whole),
                [m for m in BASELINE_NAMES if m in paper],
                tuple(acc5[F_ALONE]) if F_ALONE in acc5 else None, proposed)
    ev = _Evidence(evidence)
    facts = [*_best(s, ev), *_second(s, ev), *_above_calibrated(s, ev), _calibration(s),
             *_geodesic(s, ev), *_network(s, ev)]
    template = macros(TEMPLATE)
    targets = {f"{proposed}_beats_every_baseline_{region}": all(scores[proposed] > scores[m]
                                                                for m in s.baselines)
               for region, scores in (("whole", whole), ("boundary", bound))}
    return {"ranking_whole": s.ranking_whole, "ranking_boundary": s.ranking_boundary,
            "statement": words(template.statement(s)),
            "paper_ranking": words(template.paper_ranking(PAPER_WITHIN_5MM)),
            "paper_within_5mm": PAPER_WITHIN_5MM,
            "findings": [_worded(template, f) for f in facts], "targets": targets}
