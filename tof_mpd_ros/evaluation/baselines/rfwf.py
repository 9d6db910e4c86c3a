"""RF-WF: a random-forest confidence (Reynolds et al. CVPR 2011) driving a confidence-weighted
Gaussian filter (Frank et al., Optical Engineering 2009).

Training: for every valid pixel with a reference, the target confidence is
``c* = exp(−|R − R*| / tau_mm)`` (1 = exact, 1/e at ``tau_mm`` error) and a regression forest
learns it from hand-crafted local features (:func:`local_features`): amplitude, range, local range
spread and gradients, amplitude gradients, distance to invalid pixels — per-pixel cues in the
spirit of Reynolds et al., without their global (whole-frame) features.

Filtering: ``R̂ = G_σ * (c^γ · v · R) / G_σ * (c^γ · v)`` with the predicted confidence c clipped
to [1e-3, 1], validity v and a Gaussian G_σ of ``sigma`` pixels; γ (``power``) sharpens the
confidence. A pixel's own low confidence lets its neighbours dominate it — including confident
pixels across a depth edge, which is why RF-WF smooths noise well but drags over-shooting pixels
next to a nearer surface towards that surface (the paper: the baselines "tended to blur the
boundaries"). ``power = 0`` is a plain Gaussian; the grid search can pick it.

Persistence: the forest is refitted from the training frames (seconds); to keep one without pickle
export it with :meth:`RFWF.forest_arrays` / :class:`.forest.ForestArrays`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import cv2
import numpy as np
from scipy import ndimage

from ...errors import InputError
from .base import Baseline, FrameLike, amplitude_guide, fill_nearest, finish, prepare
from .forest import ForestArrays, make_forest, per_frame_quota, sample_pixels

FEATURE_NAMES = (
    "amplitude", "range_mm", "range_std3_mm", "range_std5_mm", "range_grad_mm",
    "range_laplacian_mm", "range_minus_median5_mm", "amplitude_std5", "amplitude_grad",
    "valid_fraction5", "dist_to_invalid_px", "amplitude_range2",
)


def _masked_box(x: np.ndarray, v: np.ndarray, size: int) -> np.ndarray:
    """Mean of x over the valid pixels of each size×size window; (H, W) float32."""
    num = cv2.boxFilter(x * v, -1, (size, size), normalize=False, borderType=cv2.BORDER_REFLECT)
    den = cv2.boxFilter(v, -1, (size, size), normalize=False, borderType=cv2.BORDER_REFLECT)
    return num / np.maximum(den, 1e-6)


def _masked_std(x: np.ndarray, v: np.ndarray, size: int) -> np.ndarray:
    mean = _masked_box(x, v, size)
    return np.sqrt(np.maximum(_masked_box(x * x, v, size) - mean * mean, 0.0))


def local_features(range_mm: np.ndarray, amplitude: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Hand-crafted per-pixel features (order: :data:`FEATURE_NAMES`).

    Args:
        range_mm: (H, W) float32 radial range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude, NaN = invalid.
        valid: (H, W) bool validity.

    Returns:
        (H, W, 12) float32. Amplitudes are scaled by the frame's 99th percentile
        (:func:`.base.amplitude_guide`) so the features do not depend on the sensor's unit;
        ranges and range differences are in mm. Values at invalid pixels are meaningless.
    """
    v = valid.astype(np.float32)
    offset = float(np.mean(range_mm[valid]))
    r = (fill_nearest(range_mm, valid) - offset).astype(np.float32)  # centred: float32 sums
    a = amplitude_guide(amplitude, valid)
    a = fill_nearest(a, valid)
    gy, gx = np.gradient(r)
    agy, agx = np.gradient(a)
    lap = cv2.Laplacian(r, cv2.CV_32F, borderType=cv2.BORDER_REFLECT)
    med = ndimage.median_filter(r, size=5, mode="reflect")
    dist = ndimage.distance_transform_edt(valid) if not valid.all() else np.full(r.shape, 99.0)
    feats = [
        a, r + offset, _masked_std(r, v, 3), _masked_std(r, v, 5), np.hypot(gx, gy), lap,
        r - med, _masked_std(a, v, 5), np.hypot(agx, agy),
        cv2.boxFilter(v, -1, (5, 5), borderType=cv2.BORDER_REFLECT), np.minimum(dist, 10.0),
        a * ((r + offset) / 1000.0) ** 2,
    ]
    return np.stack(feats, axis=-1).astype(np.float32)


def confidence_filter(range_mm: np.ndarray, confidence: np.ndarray, valid: np.ndarray, *,
                      sigma: float, power: float) -> np.ndarray:
    """Confidence-weighted Gaussian filter (Frank et al. 2009).

    Args:
        range_mm: (H, W) float32 range in mm, NaN = invalid.
        confidence: (H, W) float in [0, 1]; ignored where invalid.
        valid: (H, W) bool.
        sigma: Gaussian sigma in pixels (> 0).
        power: exponent γ applied to the confidence (>= 0).

    Returns:
        (H, W) float32 range in mm, NaN where a valid pixel had no support (caller falls back).
    """
    w = np.where(valid, np.clip(confidence, 1e-3, 1.0) ** power, 0.0).astype(np.float32)
    offset = float(np.mean(range_mm[valid]))
    num = cv2.GaussianBlur(np.where(valid, range_mm - offset, 0.0).astype(np.float32) * w,
                           (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    den = cv2.GaussianBlur(w, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / den + offset
    out[den <= 1e-9] = np.nan
    return out


class RFWF(Baseline):
    """Random-forest confidence + confidence-weighted Gaussian filter (supervised).

    Args:
        tau_mm: error scale of the target confidence exp(−|R − R*| / tau_mm), mm.
        n_estimators, max_depth, min_samples_leaf: forest size.
        samples_per_frame: training pixels drawn per frame (uniformly among valid ones with a
            reference)...
        max_samples: ...but at most this many in total.
        seed: seeds pixel sampling and the forest.
    """

    name: ClassVar[str] = "RF-WF"
    supervised: ClassVar[bool] = True
    param_grid: ClassVar[dict[str, list[Any]]] = {
        "sigma": [0.5, 1.0, 1.5, 2.0, 3.0],
        "power": [0.0, 1.0, 2.0, 4.0],
    }
    fit_param_grid: ClassVar[dict[str, list[Any]]] = {"tau_mm": [2.0, 5.0, 10.0]}

    def __init__(self, *, tau_mm: float = 5.0, n_estimators: int = 30, max_depth: int = 12,
                 min_samples_leaf: int = 5, samples_per_frame: int = 4000,
                 max_samples: int = 100_000, seed: int = 0) -> None:
        super().__init__()
        if not tau_mm > 0:
            raise InputError(f"RF-WF needs tau_mm > 0, got {tau_mm}")
        self.fit_params = dict(tau_mm=tau_mm, n_estimators=n_estimators, max_depth=max_depth,
                               min_samples_leaf=min_samples_leaf,
                               samples_per_frame=samples_per_frame, max_samples=max_samples,
                               seed=seed)
        per_frame_quota(self.fit_params, 1)  # validates the sample counts
        self._forest = make_forest(n_estimators=n_estimators, max_depth=max_depth,
                                   min_samples_leaf=min_samples_leaf, max_features=0.5,
                                   seed=seed)
        self._fitted = False
        self._cache: tuple[bytes, np.ndarray] | None = None

    def fit(self, frames: Sequence[FrameLike]) -> RFWF:
        """Fit the confidence forest on frames with ``reference_mm``.

        Raises:
            InputError: no frame has a usable reference.
        """
        rng = np.random.default_rng(self.fit_params["seed"])
        quota = per_frame_quota(self.fit_params, len(frames))
        xs, ys = [], []
        for fr in frames:
            r, a, valid = prepare(fr.range_mm, fr.amplitude)
            if fr.reference_mm is None or not valid.any():
                continue
            ref = np.asarray(fr.reference_mm, np.float32)
            idx = sample_pixels(valid & np.isfinite(ref), quota, rng)
            xs.append(local_features(r, a, valid).reshape(-1, len(FEATURE_NAMES))[idx])
            err = np.abs(r.ravel()[idx] - ref.ravel()[idx])
            ys.append(np.exp(-err / self.fit_params["tau_mm"]))
        if not xs or sum(len(y) for y in ys) == 0:
            raise InputError("RF-WF.fit: no training frame has valid pixels with a reference")
        self._forest.fit(np.concatenate(xs), np.concatenate(ys))
        self._fitted = True
        self._cache = None
        return self

    def confidence(self, range_mm: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
        """(H, W) float32 predicted confidence in [0, 1], NaN where invalid."""
        if not self._fitted:
            raise InputError("RF-WF: call fit(train_frames) before apply")
        r, a, valid = prepare(range_mm, amplitude)
        conf = np.full(r.shape, np.nan, np.float32)
        if valid.any():
            feats = local_features(r, a, valid)[valid]
            conf[valid] = self._forest.predict(feats)
        return conf

    def apply(self, range_mm: np.ndarray, amplitude: np.ndarray, *, sigma: float = 1.5,
              power: float = 2.0) -> np.ndarray:
        """Correct one frame (see the module doc); (H, W) float32 mm, NaN where invalid."""
        if not (sigma > 0 and power >= 0):
            raise InputError(f"RF-WF needs sigma > 0 and power >= 0, got {sigma}, {power}")
        r, a, valid = prepare(range_mm, amplitude)
        if not valid.any():
            return r
        # One-entry cache: a grid search filters the same frame with many (sigma, power).
        key = r.tobytes() + a.tobytes()
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, self.confidence(r, a))
        out = confidence_filter(r, self._cache[1], valid, sigma=sigma, power=power)
        return finish(out, valid, r)

    def forest_arrays(self) -> ForestArrays:
        """The fitted forest as pickle-free arrays (see :mod:`.forest`)."""
        if not self._fitted:
            raise InputError("RF-WF: not fitted")
        return ForestArrays.from_sklearn(self._forest)
