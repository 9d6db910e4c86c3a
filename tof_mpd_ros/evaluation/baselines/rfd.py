"""RFD: a random forest regressing the multipath distortion directly (paper §V, after Reynolds
et al. CVPR 2011), trained on the same data and the same per-pixel input as the range-recovery
network F.

* Input: the patch encoding ``[x_R x_A b_R b_A]`` of :func:`tof_mpd_ros.correction.encoding.
  encode_frame` (280 features for 11×11 patches). Pass the :class:`EncodingConfig` that F was
  trained with, so the comparison isolates the regressor (forest vs network).
* Target: ``t = clip(R* − R, −15, 15)`` mm, as for F; pixels without a reference are skipped.
* Output: ``R̂ = R + forest(x)``.

Training pixels are subsampled uniformly (``samples_per_frame`` per frame) because the forest
cannot take the ~10 M patches F sees. ``max_features = 1/3`` of the columns per split (Breiman's
regression default) keeps fitting on 280 columns to seconds.

Persistence: refitted from the training frames; :meth:`RFD.forest_arrays` exports the trees to
pickle-free arrays when a fitted forest must be kept.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ...errors import InputError
from .base import Baseline, FrameLike, finish, prepare
from .forest import ForestArrays, make_forest, per_frame_quota, sample_pixels

if TYPE_CHECKING:  # the encoding pulls in torch: imported on use so the other baselines stay light
    from ...correction.encoding import EncodingConfig

TARGET_CLIP_MM = 15.0


def encode(range_mm: np.ndarray, amplitude: np.ndarray, config: EncodingConfig
           ) -> tuple[np.ndarray, np.ndarray]:
    """F's patch features of every pixel of one frame, as numpy.

    Args:
        range_mm: (H, W) float32 calibrated range in mm, NaN = invalid.
        amplitude: (H, W) float32 amplitude, NaN = invalid.
        config: the encoding F uses.

    Returns:
        ``(features, valid)``: (H*W, n_features) float32, row-major pixels, and (H, W) bool.
    """
    from ...correction.encoding import encode_frame

    feats, valid = encode_frame(range_mm, amplitude, config)
    return feats.numpy(), valid.numpy()[0]


class RFD(Baseline):
    """Random-forest distortion regression on F's features (supervised).

    Args:
        encoding: patch-encoding constants (default: :class:`EncodingConfig` defaults; pass F's).
        n_estimators, max_depth, min_samples_leaf: forest size.
        samples_per_frame: training pixels drawn per frame...
        max_samples: ...but at most this many in total (fit time grows faster than linearly:
            ~10 s per tree for 100 k samples of 280 features on one core).
        seed: seeds pixel sampling and the forest.
    """

    name: ClassVar[str] = "RFD"
    supervised: ClassVar[bool] = True
    # Fewer trees are searched without refitting: the first n trees of a bagged forest are a
    # forest of n trees.
    param_grid: ClassVar[dict[str, list[Any]]] = {"n_trees": [10, 20, 0]}
    fit_param_grid: ClassVar[dict[str, list[Any]]] = {"max_depth": [8, 12, 16]}

    def __init__(self, *, encoding: EncodingConfig | None = None, n_estimators: int = 30,
                 max_depth: int = 12, min_samples_leaf: int = 5, samples_per_frame: int = 2000,
                 max_samples: int = 100_000, seed: int = 0) -> None:
        super().__init__()
        self.fit_params = dict(encoding=encoding, n_estimators=n_estimators,
                               max_depth=max_depth, min_samples_leaf=min_samples_leaf,
                               samples_per_frame=samples_per_frame, max_samples=max_samples,
                               seed=seed)
        per_frame_quota(self.fit_params, 1)  # validates the sample counts
        if encoding is None:
            from ...correction.encoding import EncodingConfig

            encoding = EncodingConfig()
        self.encoding = encoding
        self._forest = make_forest(n_estimators=n_estimators, max_depth=max_depth,
                                   min_samples_leaf=min_samples_leaf, max_features=1.0 / 3.0,
                                   seed=seed)
        self._fitted = False
        self._cache: tuple[bytes, np.ndarray] | None = None

    def fit(self, frames: Sequence[FrameLike]) -> RFD:
        """Fit the distortion forest on frames with ``reference_mm``.

        Raises:
            InputError: no frame has a usable reference.
        """
        rng = np.random.default_rng(self.fit_params["seed"])
        quota = per_frame_quota(self.fit_params, len(frames))
        xs, ys = [], []
        for fr in frames:
            r, a, valid = prepare(fr.range_mm, fr.amplitude)
            if fr.reference_mm is None:
                continue
            ref = np.asarray(fr.reference_mm, np.float32)
            idx = sample_pixels(valid & np.isfinite(ref), quota, rng)
            if idx.size == 0:
                continue
            feats, _ = encode(r, a, self.encoding)
            xs.append(feats[idx])
            ys.append(np.clip(ref.ravel()[idx] - r.ravel()[idx], -TARGET_CLIP_MM, TARGET_CLIP_MM))
        if not xs:
            raise InputError("RFD.fit: no training frame has valid pixels with a reference")
        self._forest.fit(np.concatenate(xs), np.concatenate(ys))
        self._fitted = True
        self._cache = None
        return self

    def apply(self, range_mm: np.ndarray, amplitude: np.ndarray, *, n_trees: int = 0
              ) -> np.ndarray:
        """Correct one frame: R + predicted distortion; (H, W) float32 mm, NaN where invalid.

        ``n_trees``: use only the first n trees (0 = all), to search the forest size without
        refitting.
        """
        if not self._fitted:
            raise InputError("RFD: call fit(train_frames) before apply")
        n_all = len(self._forest.estimators_)
        if not (int(n_trees) == n_trees and 0 <= n_trees):
            raise InputError(f"RFD: n_trees must be an integer >= 0, got {n_trees}")
        r, a, valid = prepare(range_mm, amplitude)
        if not valid.any():
            return r
        # One-entry cache of per-tree predictions: a grid search varies n_trees per frame.
        key = r.tobytes() + a.tobytes()
        if self._cache is None or self._cache[0] != key:
            feats = np.ascontiguousarray(encode(r, a, self.encoding)[0][valid.ravel()])
            # The encoding is finite float32 by construction: skip sklearn's per-tree checks.
            per_tree = np.cumsum([t.predict(feats, check_input=False)
                                  for t in self._forest.estimators_], axis=0)
            self._cache = (key, per_tree)
        n = min(int(n_trees), n_all) or n_all
        out = r.copy()
        out[valid] = r[valid] + (self._cache[1][n - 1] / n).astype(np.float32)
        return finish(out, valid, r)

    def forest_arrays(self) -> ForestArrays:
        """The fitted forest as pickle-free arrays (see :mod:`.forest`)."""
        if not self._fitted:
            raise InputError("RFD: not fitted")
        return ForestArrays.from_sklearn(self._forest)
