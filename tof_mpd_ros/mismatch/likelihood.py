"""Noise-normalised, robust residual statistics: the yardstick of every fit and score.

A residual r (real − predicted range, mm) is judged against the noise the model predicts for
that pixel, σ² = σ_ToF² + σ_ref² (ToF noise law at the expected amplitude, plus the reference's
own noise). The per-pixel cost is the negative log-likelihood of a Student-t with ``NU`` degrees
of freedom and scale σ: Gaussian for small z = r/σ, logarithmic for outliers, so flying pixels
at depth edges cannot dominate a fit, and a wrong σ (a noise-model error) costs through the
``log σ`` term.
"""

from __future__ import annotations

import numpy as np

#: degrees of freedom of the Student-t residual model
NU = 4.0
#: default std of the reference (structured light, fused), mm
REFERENCE_NOISE_MM = 0.5
#: pixels over which residuals are roughly correlated (for effective sample counts)
CORRELATION_PX = 16.0
#: where inside a pixel a depth edge lies is unknown to a one-sample reference: a quarter
#: pixel of uncertainty, i.e. this fraction of the edge's range step, joins σ at edge pixels
EDGE_POSITION_FRACTION = 0.25


def total_sigma(noise_mm: np.ndarray, reference_noise_mm: float,
                edge_jump_mm: np.ndarray | float = 0.0) -> np.ndarray:
    """(H, W) float64 std of a residual in mm: ToF noise, reference noise and, at depth edges,
    the edge-position uncertainty (``EDGE_POSITION_FRACTION`` × the range step), in
    quadrature."""
    extra = EDGE_POSITION_FRACTION * np.asarray(edge_jump_mm, dtype=np.float64)
    return np.sqrt(noise_mm ** 2 + reference_noise_mm ** 2 + extra ** 2)


def nll(residual_mm: np.ndarray, sigma_mm: np.ndarray) -> np.ndarray:
    """Per-pixel Student-t negative log-likelihood (nats, constants dropped).

    Args:
        residual_mm: (...) float residual in mm.
        sigma_mm: (...) float scale in mm (> 0).

    Returns:
        (...) float64 cost; NaN where either input is NaN.
    """
    z2 = (np.asarray(residual_mm, np.float64) / sigma_mm) ** 2
    return np.log(sigma_mm) + 0.5 * (NU + 1.0) * np.log1p(z2 / NU)


def best_shift(residual_mm: np.ndarray, sigma_mm: np.ndarray, iterations: int = 8) -> float:
    """The constant c minimising Σ nll(r − c, σ): the Student-t location, by iteratively
    reweighted least squares (weights (ν + 1) / (ν σ² + (r − c)²), the t's own), from the
    weighted median; 0 without finite pixels.

    Args:
        residual_mm, sigma_mm: (N,) float residuals and scales in mm.
    """
    r = np.asarray(residual_mm, np.float64)
    s = np.asarray(sigma_mm, np.float64)
    ok = np.isfinite(r) & np.isfinite(s) & (s > 0)
    if not ok.any():
        return 0.0
    r, s2 = r[ok], s[ok] ** 2
    c = float(np.median(r))
    for _ in range(iterations):
        w = (NU + 1.0) / (NU * s2 + (r - c) ** 2)
        c = float(np.sum(w * r) / np.sum(w))
    return c


def bic_penalty(n_params: int, n_pixels: int) -> float:
    """BIC-like complexity cost in nats *per pixel*: ½ k ln(n_eff) / n_eff · ... per pixel.

    Residuals are spatially correlated, so the effective number of independent samples is
    ``n_pixels / CORRELATION_PX``; the penalty of k parameters spread over the pixels is
    ``½ k ln(n_eff) / n_eff``.
    """
    n_eff = max(n_pixels / CORRELATION_PX, 2.0)
    return 0.5 * n_params * np.log(n_eff) / n_eff


def tile_t_statistic(gain: list[np.ndarray], masks: list[np.ndarray], tile_px: int = 4) -> float:
    """t-statistic of the mean per-tile improvement (robust to spatial correlation).

    Args:
        gain: per frame, (H, W) float per-pixel improvement (cost before − after), NaN = unused.
        masks: per frame, (H, W) bool pixels to count.
        tile_px: tile size in pixels.

    Returns:
        mean / (std / sqrt(m)) over the m tiles that hold at least a quarter of their pixels;
        0 when there are fewer than 3 such tiles or no spread.
    """
    sums = []
    for g, m in zip(gain, masks, strict=True):
        h, w = g.shape
        ok = m & np.isfinite(g)
        for v in range(0, h, tile_px):
            for u in range(0, w, tile_px):
                sel = ok[v:v + tile_px, u:u + tile_px]
                if sel.sum() >= tile_px * tile_px // 4:
                    sums.append(float(g[v:v + tile_px, u:u + tile_px][sel].mean()))
    if len(sums) < 3:
        return 0.0
    arr = np.asarray(sums)
    sd = arr.std(ddof=1)
    return 0.0 if sd <= 0 else float(arr.mean() / sd * np.sqrt(arr.size))
