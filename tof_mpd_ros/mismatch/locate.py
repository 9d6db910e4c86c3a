"""Locate a mismatch: residual statistics per stratum, judged against the noise model.

For each descriptor of :mod:`.features` the pixels are binned (quantiles, or fixed bins for
distances), and each bin reports its mean residual, RMS, the z-score of that mean under the
noise model (``Σ r / sqrt(Σ σ²)``, i.e. assuming independent noise only) and the variance ratio
``mean(z²)`` (1 when the noise model is right). A rank correlation of the residual with every
descriptor summarises which one the residual follows.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from .features import DESCRIPTORS
from .wording import phrase

#: fixed bin edges for descriptors whose scale is known; the others use quantiles
FIXED_BINS: dict[str, tuple[float, ...]] = {
    "edge_distance_px": (0.0, 1.5, 3.0, 6.0, 12.0, np.inf),
}
N_QUANTILE_BINS = 5
#: residuals are clipped at this many σ for means and correlations (flying pixels)
CLIP_SIGMA = 6.0
#: a stratum is flagged when |z| of its mean exceeds this
Z_FLAG = 5.0


@dataclass
class Stratum:
    """Residual statistics of one bin of one descriptor."""

    descriptor: str
    low: float
    high: float
    n: int
    mean_mm: float
    rms_mm: float
    z: float
    variance_ratio: float

    def as_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
                for k, v in self.__dict__.items()}


def _clipped(residual: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    return np.clip(residual, -CLIP_SIGMA * sigma, CLIP_SIGMA * sigma)


def _bins(name: str, values: np.ndarray) -> np.ndarray:
    if name in FIXED_BINS:
        return np.asarray(FIXED_BINS[name])
    uniq = np.unique(values)
    if uniq.size <= N_QUANTILE_BINS:  # per-frame constants: one bin per value
        mids = (uniq[1:] + uniq[:-1]) / 2.0
        return np.concatenate([[-np.inf], mids, [np.inf]])
    edges = np.unique(np.quantile(values, np.linspace(0.0, 1.0, N_QUANTILE_BINS + 1)))
    edges[-1] = np.inf
    return edges


def strata(name: str, values: np.ndarray, residual: np.ndarray,
           sigma: np.ndarray) -> list[Stratum]:
    """Statistics of ``residual`` in bins of ``values`` (all 1-D float arrays, same length)."""
    ok = np.isfinite(values) & np.isfinite(residual) & np.isfinite(sigma)
    v, r, s = values[ok], residual[ok], sigma[ok]
    if v.size == 0:
        return []
    rc = _clipped(r, s)
    edges = _bins(name, v)
    out = []
    for lo, hi in itertools.pairwise(edges):
        sel = (v >= lo) & (v < hi)
        n = int(sel.sum())
        if n == 0:
            continue
        out.append(Stratum(name, float(lo), float(hi), n, float(rc[sel].mean()),
                           float(np.sqrt(np.mean(rc[sel] ** 2))),
                           float(rc[sel].sum() / np.sqrt(np.sum(s[sel] ** 2))),
                           float(np.mean((rc[sel] / s[sel]) ** 2))))
    return out


def correlations(descriptors: dict[str, np.ndarray], residual: np.ndarray,
                 sigma: np.ndarray) -> dict[str, dict[str, float]]:
    """Spearman correlation of the residual and of |z| with each descriptor."""
    out = {}
    rc = _clipped(residual, sigma)
    for name, values in descriptors.items():
        ok = np.isfinite(values) & np.isfinite(rc)
        if ok.sum() < 10 or np.ptp(values[ok]) == 0:
            out[name] = {"residual": 0.0, "abs_z": 0.0}
            continue
        r1 = stats.spearmanr(values[ok], rc[ok]).statistic
        r2 = stats.spearmanr(values[ok], np.abs(rc[ok] / sigma[ok])).statistic
        out[name] = {"residual": float(np.nan_to_num(r1)), "abs_z": float(np.nan_to_num(r2))}
    return out


def image_regions(residual: Sequence[np.ndarray], sigma: Sequence[np.ndarray],
                  grid: int = 3) -> list[dict[str, Any]]:
    """Mean residual and z per cell of a ``grid`` x ``grid`` split of the image."""
    h, w = residual[0].shape
    out = []
    for gy in range(grid):
        for gx in range(grid):
            rows = slice(gy * h // grid, (gy + 1) * h // grid)
            cols = slice(gx * w // grid, (gx + 1) * w // grid)
            r = np.concatenate([x[rows, cols].ravel() for x in residual])
            s = np.concatenate([x[rows, cols].ravel() for x in sigma])
            ok = np.isfinite(r) & np.isfinite(s)
            st = strata("region", np.zeros(int(ok.sum())), r[ok], s[ok])
            if st:
                d = st[0].as_dict()
                d.update(row=gy, col=gx)
                out.append(d)
    return out


def locate(descriptors: Sequence[dict[str, np.ndarray]], residual: Sequence[np.ndarray],
           sigma: Sequence[np.ndarray]) -> dict[str, Any]:
    """Where the residual exceeds the noise model, over all given frames.

    Args:
        descriptors: per frame, descriptor name -> (H, W) float64 values.
        residual: per frame, (H, W) float64 real − predicted range in mm (NaN = unused).
        sigma: per frame, (H, W) float64 predicted residual std in mm.

    Returns:
        JSON-ready dict: ``global`` stats, ``strata`` per descriptor, ``correlations``,
        ``regions`` (3 x 3 image grid) and ``flagged`` (strata with |z| > ``Z_FLAG``, strongest
        first).
    """
    r = np.concatenate([x.ravel() for x in residual])
    s = np.concatenate([x.ravel() for x in sigma])
    flat = {name: np.concatenate([d[name].ravel() for d in descriptors])
            for name in DESCRIPTORS}
    ok = np.isfinite(r) & np.isfinite(s)
    glob = strata("all", np.zeros(int(ok.sum())), r[ok], s[ok])
    per = {name: strata(name, flat[name], r, s) for name in DESCRIPTORS}
    flagged = sorted((st for lst in per.values() for st in lst if abs(st.z) > Z_FLAG),
                     key=lambda st: -abs(st.z))
    outliers = float(np.mean(np.abs(r[ok] / s[ok]) > 3.0)) if ok.any() else 0.0
    return {
        "global": glob[0].as_dict() if glob else {},
        "fraction_beyond_3_sigma": outliers,
        "strata": {name: [st.as_dict() for st in lst] for name, lst in per.items()},
        "correlations": correlations(flat, r, s),
        "regions": image_regions(residual, sigma),
        "flagged": [st.as_dict() for st in flagged[:12]],
    }


def describe_stratum(st: dict[str, Any]) -> str:
    """Words for a stratum (``templates/mismatch.txt``, ``stratum``):
    ``"edge_distance_px in [0, 1.5) px"``."""
    return phrase("stratum", stratum_facts(st))


def stratum_facts(st: dict[str, Any]) -> dict[str, Any]:
    """What a stratum's words say: its ``descriptor``, the descriptor's ``unit`` ("" when not
    in :data:`.features.DESCRIPTORS`), and the bin's ``low`` and ``high``, None where the bin
    is open (None, infinite or NaN)."""
    def bound(value: float | None) -> float | None:
        return None if value is None or not np.isfinite(value) else value

    return {"descriptor": st["descriptor"],
            "unit": DESCRIPTORS.get(st["descriptor"], ("", ""))[0],
            "low": bound(st["low"]), "high": bound(st["high"])}
