"""Fit one candidate effect's physical parameters to real frames and score it on held-out ones.

Every candidate is an effect of the simulator's registry. Its free parameters are the ones its
:class:`~tof_mpd_ros.sim.tof.ParamSpec` marks ``fit=True``, searched inside the spec's realistic
range ``[low, high]`` (mapped to the unit box): a coarse design over the box, then a Powell
refinement inside the box from the best starts (:func:`local_search`). The objective is the
robust, noise-normalised likelihood of :mod:`.likelihood` on the training pixels, with the
frames re-rendered by :class:`~.predict.FramePredictor` under
``ToFConfig.with_effect(name, enabled=True, ...)``.

The score is measured on held-out pixels only: the mean improvement of that likelihood per
pixel (millinats) minus a BIC-like cost per parameter, with a tile t-statistic for significance.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import ndimage, optimize

from ..sim.tof import EFFECTS, ToFConfig
from .data import Split
from .likelihood import (
    CORRELATION_PX,
    NU,
    REFERENCE_NOISE_MM,
    best_shift,
    bic_penalty,
    nll,
    tile_t_statistic,
    total_sigma,
)
from .predict import FramePredictor, Prediction

#: the candidate library (docs/mismatch.md); ``none`` is the answer when none is significant
CANDIDATES: tuple[str, ...] = (
    "multipath", "mixed_pixels", "wiggling", "amplitude_bias", "lens_scatter", "subsurface",
    "phase_wrapping", "pixel_offset", "temperature_drift", "time_offset", "hand_eye",
    "noise_model",
)
#: coarse-design size per number of free parameters (the rest of the budget goes to Powell)
DESIGN_POINTS = {1: 9, 2: 25}
DESIGN_POINTS_MANY = 16
#: parameter values at which an effect does nothing: the fit always starts there too, so a
#: fitted effect is never worse on the training pixels than leaving it out
NEUTRAL: dict[str, dict[str, float]] = {
    "lens_scatter": {"fraction": 0.0},
    "subsurface": {"fraction": 0.0},
    "temperature_drift": {"max_mm": 0.0},
    "time_offset": {"offset_ms": 0.0},
    "hand_eye": {"rx_mrad": 0.0, "ry_mrad": 0.0, "rz_mrad": 0.0, "tx_mm": 0.0, "ty_mm": 0.0,
                 "tz_mm": 0.0},
    "noise_model": {"scale": 1.0, "exponent": 1.0, "jitter_mm": 0.0},
}


#: the camera is at the same pose in every frame when no two poses differ by more than these
#: (mm, mrad): then a hand–eye error is a constant misregistration of ToF against reference
AT_REST_MM = 0.5
AT_REST_MRAD = 1.0

#: a positive range spanning more than this ratio is searched in log space (a time constant
#: of 5-2000 frames: linear steps could not tell 5 from 25)
LOG_RANGE_RATIO = 20.0


@dataclass(frozen=True)
class FreeParam:
    """One fitted parameter: its effect's spec name and realistic range, mapped to [0, 1]
    (linearly, or logarithmically for a wide positive range)."""

    name: str
    low: float
    high: float
    per_material: bool
    unit_name: str = ""

    @property
    def log(self) -> bool:
        return self.low > 0.0 and self.high / self.low > LOG_RANGE_RATIO

    @property
    def periodic(self) -> bool:
        """An angle over a whole turn: its range has no edge."""
        return self.unit_name == "rad" and abs(self.high - self.low - 2 * np.pi) < 1e-9

    def value(self, u: float) -> float | tuple[float]:
        t = float(np.clip(u, 0.0, 1.0))
        x = (self.low * (self.high / self.low) ** t if self.log
             else self.low + t * (self.high - self.low))
        return (x,) if self.per_material else x

    def unit(self, value: Any) -> float:
        v = float(np.atleast_1d(value)[0])
        if self.log:
            t = np.log(max(v, self.low) / self.low) / np.log(self.high / self.low)
        else:
            t = (v - self.low) / (self.high - self.low)
        return float(np.clip(t, 0.0, 1.0))


def free_params(effect: str) -> list[FreeParam]:
    """Fitted parameters of ``effect`` (per-material tuples are fitted as one shared value)."""
    return [FreeParam(p.name, float(p.low), float(p.high), isinstance(p.default, tuple),
                      p.unit)
            for p in EFFECTS[effect].params if p.fit and p.high > p.low]


def with_params(base: ToFConfig, effect: str, u: Sequence[float]) -> ToFConfig:
    """``base`` with ``effect`` enabled at unit-box point ``u``."""
    params = {p.name: p.value(x) for p, x in zip(free_params(effect), u, strict=True)}
    return base.with_effect(effect, enabled=True, **params)


def plain_params(config: ToFConfig, effect: str) -> dict[str, Any]:
    """JSON-friendly fitted parameters of ``effect`` in ``config``."""
    out = {}
    for p in free_params(effect):
        v = config.params(effect)[p.name]
        out[p.name] = float(np.atleast_1d(v)[0])
    return out


#: the camera's fixed pattern is what varies from pixel to pixel: each frame's residual less
#: its local mean over a Gaussian of this σ (px), so the smooth residual a scene effect leaves
#: (a halo, interreflection, a wiggle over the range) stays for the effects to explain
PATTERN_SMOOTH_PX = 2.0
#: a frame's high-passed residual beyond this many times its robust spread (flying pixels, the
#: reference's edge errors) is clipped before it is averaged into the pattern
PATTERN_CLIP = 4.0
#: pixels this close to a reference depth edge (px) do not inform the pattern
PATTERN_EDGE_PX = 2


@dataclass(frozen=True)
class FixedPattern:
    """The camera's fixed pattern of per-pixel range offsets, estimated from training frames.

    Attributes:
        rms_mm: the pattern's estimated pixel-to-pixel std τ, mm.
        full: (H, W) float64 pattern from every training frame, mm (a held-out frame's).
        leave_one_out: training frame index -> (H, W) float64 pattern from the other training
            frames, mm (so a fit is not judged on the noise of its own frame's pixels).
    """

    rms_mm: float
    full: np.ndarray
    leave_one_out: dict[int, np.ndarray]

    def of_frame(self, i: int) -> np.ndarray:
        return self.leave_one_out.get(i, self.full)


def _high_pass(residual: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A frame's residual less its local mean (normalised Gaussian convolution over the
    usable pixels, weights 1/σ²), clipped at ``PATTERN_CLIP`` robust spreads; and the
    weights (0 where unusable). Both (H, W) float64."""
    ok = np.isfinite(residual) & np.isfinite(sigma) & (sigma > 0)
    w = np.where(ok, 1.0 / np.where(ok, sigma, 1.0) ** 2, 0.0)
    r = np.where(ok, residual, 0.0)
    local = (ndimage.gaussian_filter(w * r, PATTERN_SMOOTH_PX, mode="nearest")
             / np.maximum(ndimage.gaussian_filter(w, PATTERN_SMOOTH_PX, mode="nearest"),
                          1e-300))
    d = np.where(ok, r - local, 0.0)
    if ok.any():
        z = d[ok] * np.sqrt(w[ok])
        spread = max(1.4826 * float(np.median(np.abs(z))), 1.0)
        bound = PATTERN_CLIP * spread / np.sqrt(np.where(ok, w, 1.0))
        d = np.clip(d, -bound, bound)
    return d, w


def fixed_pattern(frames: Sequence[int], residuals: Sequence[np.ndarray],
                  sigmas: Sequence[np.ndarray]) -> FixedPattern:
    """Empirical-Bayes estimate of a fixed pattern of per-pixel offsets from residuals of
    several frames of one camera.

    Each frame's residual less its local mean (:func:`_high_pass`) is averaged per pixel with
    weights 1/σ²: the raw estimate. The pattern's variance τ² is the mean product of two
    frames' residuals at the same pixel (a fixed pattern is in both, the noise of one frame is
    not in the other), and the noise's variance is κσ², κ measured on the same residuals, so
    neither leans on the noise law being right (the analysis fits it with the pattern
    projected out; judged by its own σ, a noise law 2.5× too low passed its excess off as
    pattern). Each pixel's estimate is shrunk by τ² / (τ² + v), v = κ / Σ 1/σ²: a pixel seen
    by few or noisy samples keeps little, a camera with no pattern gets none. Why high-pass: a
    fixed pattern is white from pixel to pixel, whereas what a scene effect leaves is smooth
    over many pixels and, as the arm moves, moves across them; what is left of it after the
    local mean averages out over frames seen from other poses.

    Args:
        frames: the frames' indices (keys of ``leave_one_out``).
        residuals: per frame, (H, W) float64 residual in mm (NaN = not used).
        sigmas: per frame, (H, W) float64 residual std in mm.
    """
    parts = [_high_pass(r, sig) for r, sig in zip(residuals, sigmas, strict=True)]
    seen = [w > 0 for _, w in parts]
    tau2 = _pattern_variance([d for d, _ in parts], seen)
    n_seen = sum(int(m.sum()) for m in seen)
    # κ: the residuals' noise variance beyond the pattern's, relative to the model's σ²
    kappa = max(sum(float(np.sum((d ** 2 - tau2) * w)) for d, w in parts) / max(n_seen, 1),
                1e-6)
    sums = [w * d for d, w in parts]
    total_s = np.sum(sums, axis=0)
    total_w = np.sum([w for _, w in parts], axis=0)

    def shrunk(s_sum: np.ndarray, w_sum: np.ndarray) -> np.ndarray:
        seen = w_sum > 0
        if tau2 <= 0.0 or not seen.any():
            return np.zeros_like(s_sum)
        safe = np.where(seen, w_sum, 1.0)
        return np.where(seen, (s_sum / safe) * tau2 / (tau2 + kappa / safe), 0.0)

    loo = {f: shrunk(total_s - s_f, total_w - w)
           for f, s_f, (_, w) in zip(frames, sums, parts, strict=True)}
    return FixedPattern(float(np.sqrt(tau2)), shrunk(total_s, total_w), loo)


def _pattern_variance(highs: Sequence[np.ndarray], seen: Sequence[np.ndarray]) -> float:
    """τ²: the mean product of two frames' high-passed residuals over the pixels both see,
    over every pair of frames (0 when negative or without a pair)."""
    total, count = 0.0, 0
    for f in range(len(highs)):
        for g in range(f + 1, len(highs)):
            both = seen[f] & seen[g]
            total += float(np.sum(highs[f][both] * highs[g][both]))
            count += int(both.sum())
    return max(total / count, 0.0) if count else 0.0


@dataclass
class Problem:
    """Frames, their predictors and the split: everything a fit and a score need.

    Attributes:
        real_mm: per frame, (H, W) float64 real range in mm, NaN = invalid.
        predictors: per frame, the cached predictor (its ``base`` is the current model).
        split: training / held-out pixels.
        usable: per frame, (H, W) bool pixels with real range, reference and base prediction.
        reference_noise_mm: std of the reference, mm.
        edge_jump_mm: per frame, (H, W) range step at reference depth edges (mm), or None.
        free_level: every model is judged at its own best constant range offset (the camera's
            level, a profile parameter), found on the training pixels: a candidate is not
            scored on what a level change alone would give, nor held to a level the profile
            set while the candidate's physics was missing (variable projection).
        free_pattern: every model is judged with the camera's own fixed pattern of per-pixel
            offsets projected out as well (:func:`fixed_pattern`, estimated on the training
            frames; a training frame's own from the other training frames): a camera that is
            not the nominal cell has a pattern of its own that no seed reproduces, and left in
            the residual it inflates the fitted noise law and hides every effect on top.
    """

    real_mm: list[np.ndarray]
    predictors: list[FramePredictor]
    split: Split
    usable: list[np.ndarray]
    reference_noise_mm: float = REFERENCE_NOISE_MM
    edge_jump_mm: list[np.ndarray] | None = None
    free_level: bool = False
    free_pattern: bool = False
    _base_cost: dict[int, np.ndarray] = field(default_factory=dict)
    _level: tuple[Any, float] | None = None
    _pattern: tuple[Any, FixedPattern | None] | None = None

    @property
    def base(self) -> ToFConfig:
        return self.predictors[0].base

    def judged(self, *, free_level: bool | None = None,
               free_pattern: bool | None = None) -> Problem:
        """This problem with the level and the fixed pattern free or not (None = as now),
        with caches of its own: what a model costs depends on both."""
        return replace(self, free_level=self.free_level if free_level is None else free_level,
                       free_pattern=(self.free_pattern if free_pattern is None
                                     else free_pattern),
                       _base_cost={}, _level=None, _pattern=None)

    def masks(self, which: str) -> list[np.ndarray]:
        part = self.split.train if which == "train" else self.split.test
        return [u & p for u, p in zip(self.usable, part, strict=True)]

    def frames_of(self, which: str) -> list[int]:
        return [i for i, m in enumerate(self.masks(which)) if m.any()]

    def cost_map(self, i: int, config: ToFConfig | None) -> np.ndarray:
        """(H, W) per-pixel cost of frame ``i`` under ``config`` (None = base); pixels the
        candidate leaves unpredicted keep their base cost, so dropping pixels gains nothing."""
        if i not in self._base_cost:
            self._base_cost[i] = self._raw_cost(i, None)
        if config is None:
            return self._base_cost[i]
        cost = self._raw_cost(i, config)
        return np.where(np.isfinite(cost), cost, self._base_cost[i])

    def model_range(self, i: int, config: ToFConfig | None) -> np.ndarray:
        """(H, W) float64 range (mm) the model ``config`` (None = base) predicts for frame
        ``i`` as it is judged: its prediction, plus the level and the camera's fixed pattern
        when they are free (:meth:`level`, :meth:`pattern`)."""
        return (self.predictors[i].predict(config).range_mm + self.level(config)
                + self.pattern(i, config))

    def residual(self, i: int, config: ToFConfig | None) -> np.ndarray:
        """(H, W) float64 real − :meth:`model_range`, mm (NaN where either is missing)."""
        return self.real_mm[i] - self.model_range(i, config)

    def pattern(self, i: int, config: ToFConfig | None) -> np.ndarray | float:
        """The camera's fixed pattern (mm) that frame ``i`` is judged with under ``config``:
        0 unless ``free_pattern``; a training frame's from the other training frames, a
        held-out frame's from all of them (cached for the last config)."""
        found = self.fixed_pattern(config)
        return 0.0 if found is None else found.of_frame(i)

    def fixed_pattern(self, config: ToFConfig | None) -> FixedPattern | None:
        """The camera's fixed pattern under ``config`` (None without ``free_pattern`` or with
        fewer than two training frames)."""
        if not self.free_pattern:
            return None
        if self._pattern is not None and self._pattern[0] is config:
            return self._pattern[1]
        train = [i for i in self.frames_of("train") if not self.masks("test")[i].any()]
        found = None
        if len(train) >= 2:
            shift = self.level(config)
            res, sig = [], []
            for i in train:
                pred = self.predictors[i].predict(config)
                res.append(np.where(self.masks("train")[i] & ~self._near_edge(i),
                                    self.real_mm[i] - pred.range_mm - shift, np.nan))
                sig.append(self._sigma(pred, i))
            found = fixed_pattern(train, res, sig)
        self._pattern = (config, found)
        return found

    def level(self, config: ToFConfig | None) -> float:
        """The constant range offset (mm) that ``config`` is judged at: 0, or with
        ``free_level`` its best one on the training pixels (cached for the last config)."""
        if not self.free_level:
            return 0.0
        if self._level is not None and self._level[0] is config:
            return self._level[1]
        res, sig = [], []
        for i, m in enumerate(self.masks("train")):
            if m.any():
                pred = self.predictors[i].predict(config)
                res.append((self.real_mm[i] - pred.range_mm)[m])
                sig.append(self._sigma(pred, i)[m])
        shift = best_shift(np.concatenate(res), np.concatenate(sig)) if res else 0.0
        self._level = (config, shift)
        return shift

    def _near_edge(self, i: int) -> np.ndarray:
        """(H, W) bool pixels of frame ``i`` within ``PATTERN_EDGE_PX`` of a reference depth
        edge: the reference's own edge errors, not the camera's pattern, dominate there."""
        if self.edge_jump_mm is None:
            return np.zeros(self.real_mm[i].shape, bool)
        return ndimage.binary_dilation(self.edge_jump_mm[i] > 0, iterations=PATTERN_EDGE_PX)

    def _sigma(self, pred: Prediction, i: int) -> np.ndarray:
        jump = 0.0 if self.edge_jump_mm is None else self.edge_jump_mm[i]
        return total_sigma(pred.noise_mm, self.reference_noise_mm, jump)

    def _raw_cost(self, i: int, config: ToFConfig | None) -> np.ndarray:
        pred = self.predictors[i].predict(config)
        return nll(self.residual(i, config), self._sigma(pred, i))

    def whitened(self, i: int, config: ToFConfig | None) -> np.ndarray:
        """(H, W) float64 residual of frame ``i`` under ``config`` over its σ (dimensionless;
        NaN where either is missing): what :meth:`cost_map` judges, before the Student-t."""
        pred = self.predictors[i].predict(config)
        return self.residual(i, config) / self._sigma(pred, i)

    def frame_level(self, i: int, config: ToFConfig | None, which: str = "test"
                    ) -> tuple[float, float]:
        """Frame ``i``'s residual level under ``config`` (None = base) beyond the level the
        model is judged at (:meth:`level`), in mm, and its standard error in mm, over the
        frame's ``which`` pixels; (NaN, NaN) without any.

        The level is the Student-t location of the residual (:func:`.likelihood.best_shift`);
        its error is the residual's robust spread (1.4826 MAD) over the square root of the
        effective sample count (pixels / ``CORRELATION_PX``: residuals are spatially
        correlated)."""
        m = self.masks(which)[i]
        pred = self.predictors[i].predict(config)
        r = (self.real_mm[i] - pred.range_mm - self.pattern(i, config))[m]
        ok = np.isfinite(r)
        if not ok.any():
            return float("nan"), float("nan")
        level = best_shift(r, self._sigma(pred, i)[m])
        spread = 1.4826 * float(np.median(np.abs(r[ok] - np.median(r[ok]))))
        n_eff = max(ok.sum() / CORRELATION_PX, 1.0)
        return level - self.level(config), spread / float(np.sqrt(n_eff))

    def total_cost(self, config: ToFConfig | None, which: str) -> tuple[float, int]:
        """(sum of the cost over the ``which`` pixels, number of pixels)."""
        total, count = 0.0, 0
        for i, m in enumerate(self.masks(which)):
            if m.any():
                total += float(self.cost_map(i, config)[m].sum())
                count += int(m.sum())
        return total, count


@dataclass
class FitResult:
    """A fitted candidate and its held-out score.

    Attributes:
        effect: candidate name.
        config: the current model with the candidate enabled at its fitted parameters.
        parameters: fitted parameter values (JSON-friendly).
        n_params: number of fitted parameters.
        train_gain: mean training cost improvement, nats per pixel.
        test_gain: mean held-out cost improvement, nats per pixel.
        penalty: complexity cost, nats per pixel.
        t_stat: tile t-statistic of the held-out improvement.
        score: ``1000 · (test_gain − penalty)`` (millinats per held-out pixel).
        note: why a candidate could not be fitted, if so.
    """

    effect: str
    config: ToFConfig
    parameters: dict[str, float]
    n_params: int
    train_gain: float = 0.0
    test_gain: float = 0.0
    penalty: float = 0.0
    t_stat: float = 0.0
    score: float = 0.0
    note: str = ""


def _design(k: int, rng: np.random.Generator) -> np.ndarray:
    """Starting points of the coarse search in the unit box, (M, k)."""
    if k == 1:
        return np.linspace(0.0, 1.0, DESIGN_POINTS[1])[:, None]
    if k == 2:
        g = np.linspace(0.0, 1.0, 5)
        return np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    # stratified random design: each coordinate takes every stratum once
    m = DESIGN_POINTS_MANY
    cols = [(rng.permutation(m) + rng.uniform(size=m)) / m for _ in range(k)]
    return np.stack(cols, axis=1)


def fit_effect(problem: Problem, effect: str, *, max_evals: int = 150,
               seed: int = 0, box: Sequence[tuple[float, float]] | None = None) -> FitResult:
    """Fit ``effect``'s free parameters on the training pixels, then score it held-out.

    Args:
        problem: the frames and the current model.
        effect: a candidate name.
        max_evals: budget of objective evaluations for the local refinement.
        seed: seed of the coarse design (deterministic).
        box: per free parameter, the part of its realistic range searched, in unit-box
            coordinates (default the whole range, (0, 1) each).
    """
    base = problem.base
    params = free_params(effect)
    k = len(params)
    if effect == "time_offset" and all(p.motion is None for p in problem.predictors):
        return FitResult(effect, base, {}, k, note="camera at rest in every frame")
    if effect == "hand_eye" and not camera_moves(problem.predictors):
        # identifying a hand–eye transform needs the arm to move (AX = XB): at one pose its
        # error is a constant offset of ToF against reference, which the reference's own
        # registration in the cell produces just as well
        return FitResult(effect, base, {}, k, note="camera at the same pose in every frame: a "
                         "hand-eye error cannot be told from the reference's registration")
    if k == 0:
        if base.enabled(effect):
            return FitResult(effect, base, {}, 0, note="already modelled, no free parameter")
        return score_fit(problem, FitResult(effect, base.with_effect(effect, enabled=True),
                                            {}, 0))
    base_train, n_train = problem.total_cost(None, "train")
    if n_train == 0:
        return FitResult(effect, base, {}, k, note="no training pixels")

    def cost(u: np.ndarray) -> float:
        return problem.total_cost(with_params(base, effect, u), "train")[0] / n_train

    current = base.params(effect)
    if not base.enabled(effect):
        current.update(NEUTRAL.get(effect, {}))
    bounds = [(0.0, 1.0)] * k if box is None else [tuple(map(float, b)) for b in box]
    lo, hi = np.array([b[0] for b in bounds]), np.array([b[1] for b in bounds])
    u0 = np.array([p.unit(current[p.name]) for p in params])
    design = np.clip(np.vstack([u0[None, :], lo + (hi - lo) * _design(
        k, np.random.default_rng(seed))]), lo, hi)
    costs = np.array([cost(u) for u in design])
    order = np.argsort(costs)
    best_u, best_c = design[order[0]], costs[order[0]]
    # two local searches for small problems; one (with the whole budget) for large ones
    starts = design[order[:2]] if k <= 2 else design[order[:1]]
    for start in starts:
        u, c = local_search(cost, start, lo, hi, max_evals // len(starts))
        if c < best_c:
            best_u, best_c = u, c
    fitted = with_params(base, effect, best_u)
    config = with_level(fitted, problem.level(fitted))
    result = FitResult(effect, config, plain_params(config, effect), k,
                       train_gain=float(base_train / n_train - best_c))
    return score_fit(problem, result)


def local_search(cost: Callable[[np.ndarray], float], start: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray, max_evals: int) -> tuple[np.ndarray, float]:
    """Powell's method from ``start`` inside the box [lo, hi] (unit-box coordinates), as an
    unconstrained search in z with u = lo + (hi − lo)(1 + sin z) / 2. Returns the best point
    and its cost, never worse than ``start``'s.

    Why not scipy's bounded Powell: its line search minimises over the whole feasible segment
    of each direction (``fminbound``), not from the current point, so it may jump to another
    valley near a bound and end *worse* than it started (measured in session 10 on the blind
    cases of session 9: ~40 % of lens-scatter fits stayed on their coarse-design point, and
    fits piled up at 0.995 of a range, e.g. a subsurface delay of 29.86 of 30 mm). The
    unconstrained line search brackets from the current point downhill, so each step improves.
    """
    span = np.where(hi > lo, hi - lo, 1.0)
    frac = np.clip((np.asarray(start, dtype=np.float64) - lo) / span, 0.0, 1.0)

    def to_u(z: np.ndarray) -> np.ndarray:
        return lo + (hi - lo) * 0.5 * (1.0 + np.sin(z))

    z0 = np.arcsin(2.0 * frac - 1.0)
    c0 = cost(to_u(z0))
    res = optimize.minimize(lambda z: cost(to_u(z)), z0, method="Powell",
                            options={"xtol": 1e-2, "ftol": 1e-6, "maxfev": max_evals})
    if res.fun < c0:
        return np.clip(to_u(res.x), lo, hi), float(res.fun)
    return to_u(z0), float(c0)


#: a joint fit's budget: iterations of the trust-region least squares (each also costs one
#: residual evaluation per free parameter for its finite-difference Jacobian)
JOINT_ITERATIONS = 20
#: a joint fit's finite-difference step in unit-box coordinates (a thousandth of a range:
#: well above float64 rounding of a rendered range, well below any effect's scale of change)
JOINT_STEP = 1e-3


def joint_fit(problem: Problem, effects: Sequence[str],
              boxes: dict[str, Sequence[tuple[float, float]] | None] | None = None,
              iterations: int = JOINT_ITERATIONS) -> ToFConfig:
    """Every free parameter of ``effects`` fitted at once on the training pixels, from the
    current model (``boxes``: per effect, the part of its range searched, unit-box). The
    noise law is held: with σ fixed the Student-t cost of :mod:`.likelihood` is a robust least
    squares (Cauchy loss of scale √ν on r/σ), which a trust-region method with bounds solves
    in a few Jacobians. Returns the better of the fit (its level found on the training pixels,
    as :func:`fit_effect` does) and the current model.

    Why (session 27): fitted one effect at a time, effects that trade the same smooth residual
    (an interreflection's gain, the camera's offset, wiggle and amplitude bias) walk down their
    shared valley by a few mnats/px per sweep; a coordinate descent of 4 sweeps stopped a
    concealed multipath gain of 0.13 at 0.49 with 59 mnats/px of held-out likelihood left.
    Periodic parameters (phases) are searched unbounded and wrapped."""
    base = problem.base
    boxes = boxes or {}
    fitted_effects = [e for e in effects if free_params(e)]
    if not fitted_effects:
        return base
    lo, hi, u0, periodic, ends = [], [], [], [], [0]
    for effect in fitted_effects:
        current = base.params(effect)
        if not base.enabled(effect):
            current.update(NEUTRAL.get(effect, {}))
        own = free_params(effect)
        box = boxes.get(effect) or [(0.0, 1.0)] * len(own)
        for p, (b_lo, b_hi) in zip(own, box, strict=True):
            lo.append(-np.inf if p.periodic else float(b_lo))
            hi.append(np.inf if p.periodic else float(b_hi))
            u0.append(p.unit(current[p.name]))
            periodic.append(p.periodic)
        ends.append(ends[-1] + len(own))
    lo_a, hi_a = np.array(lo), np.array(hi)
    # strictly inside the box (the trust region's requirement): a start on a bound moves off it
    x0 = np.clip(np.array(u0), np.where(np.isfinite(lo_a), lo_a + 1e-9, -np.inf),
                 np.where(np.isfinite(hi_a), hi_a - 1e-9, np.inf))

    def assemble(u: np.ndarray) -> ToFConfig:
        u = np.where(periodic, u % 1.0, u)
        config = base
        for effect, a, b in zip(fitted_effects, ends[:-1], ends[1:], strict=True):
            config = with_params(config, effect, u[a:b])
        return config

    frames = problem.frames_of("train")
    masks = problem.masks("train")
    # a pixel the trial leaves unpredicted keeps its base residual (as :meth:`cost_map`)
    z_base = [problem.whitened(i, None)[masks[i]] for i in frames]

    def whitened(u: np.ndarray) -> np.ndarray:
        config = assemble(u)
        out = []
        for i, zb in zip(frames, z_base, strict=True):
            z = problem.whitened(i, config)[masks[i]]
            out.append(np.where(np.isfinite(z), z, zb))
        return np.concatenate(out)

    found = optimize.least_squares(whitened, x0, bounds=(lo_a, hi_a), loss="cauchy",
                                   f_scale=float(np.sqrt(NU)), diff_step=JOINT_STEP,
                                   x_scale="jac", max_nfev=iterations, method="trf")
    fitted = assemble(found.x)
    fitted = with_level(fitted, problem.level(fitted))
    before = problem.total_cost(None, "train")[0]
    return fitted if problem.total_cost(fitted, "train")[0] < before else base


def camera_moves(predictors: Sequence[FramePredictor]) -> bool:
    """Whether the frames' camera poses (4×4, metres) differ by more than ``AT_REST_MM`` /
    ``AT_REST_MRAD``; frames without a pose do not count."""
    poses = [np.asarray(p.frame.pose, dtype=np.float64) for p in predictors
             if p.frame.pose is not None]
    for a in poses[1:]:
        moved_mm = 1e3 * np.linalg.norm(a[:3, 3] - poses[0][:3, 3])
        cos = (np.trace(poses[0][:3, :3].T @ a[:3, :3]) - 1.0) / 2.0
        turned_mrad = 1e3 * np.arccos(np.clip(cos, -1.0, 1.0))
        if moved_mm > AT_REST_MM or turned_mrad > AT_REST_MRAD:
            return True
    return False


def with_level(config: ToFConfig, shift_mm: float) -> ToFConfig:
    """``config`` with its constant range offset (``pixel_offset``'s mean) moved by
    ``shift_mm`` (which adds exactly that to every predicted range: nothing after it in the
    pipeline depends on the range)."""
    if shift_mm == 0.0:
        return config
    p = config.params("pixel_offset")
    if not config.enabled("pixel_offset"):
        p.update(offset_std_mm=0.0, gain_std=0.0, offset_mean_mm=0.0)
    return config.with_effect("pixel_offset", enabled=True,
                              offset_mean_mm=float(p["offset_mean_mm"]) + float(shift_mm),
                              offset_std_mm=p["offset_std_mm"], gain_std=p["gain_std"])


def score_fit(problem: Problem, result: FitResult) -> FitResult:
    """Fill in the held-out gain, penalty, t-statistic and score of a fitted candidate."""
    masks = problem.masks("test")
    frames = problem.frames_of("test")
    gains, used = [], []
    for i in frames:
        gains.append(problem.cost_map(i, None) - problem.cost_map(i, result.config))
        used.append(masks[i])
    n = int(sum(m.sum() for m in used))
    if n == 0:
        result.note = "no held-out pixels"
        return result
    result.test_gain = float(np.nan_to_num(
        sum(np.nansum(g[m]) for g, m in zip(gains, used, strict=True)) / n))
    result.penalty = float(bic_penalty(result.n_params, n))
    result.t_stat = tile_t_statistic(gains, used)
    result.score = 1000.0 * (result.test_gain - result.penalty)
    return result
