"""Random forests shared by RF-WF and RFD: construction, training-pixel sampling, and a
pickle-free export of a fitted forest to plain arrays (``.npz``) with a numpy predictor.

The export stores, per tree, sklearn's node arrays (``children_left``, ``children_right``,
``feature``, ``threshold``, leaf ``value``) concatenated with per-tree offsets. Loading executes no
code, and :class:`ForestArrays` predicts exactly what the sklearn forest predicts (mean over trees
of the reached leaves' values; sklearn thresholds are float64 compared against float32 features,
which is reproduced).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from sklearn.ensemble import RandomForestRegressor

from ...errors import InputError, WeightsError
from ...npz_file import read_npz

_FIELDS = ("left", "right", "feature", "threshold", "value", "offsets")


def make_forest(*, n_estimators: int, max_depth: int | None, min_samples_leaf: int,
                max_features: float | str, seed: int) -> RandomForestRegressor:
    """A single-threaded (``n_jobs=1``, the machine is shared) seeded regression forest."""
    if n_estimators < 1 or (max_depth is not None and max_depth < 1) or min_samples_leaf < 1:
        raise InputError(f"forest needs n_estimators, max_depth, min_samples_leaf >= 1, got "
                         f"{n_estimators}, {max_depth}, {min_samples_leaf}")
    return RandomForestRegressor(n_estimators=n_estimators, max_depth=max_depth,
                                 min_samples_leaf=min_samples_leaf, max_features=max_features,
                                 n_jobs=1, random_state=seed)


def per_frame_quota(fit_params: dict, n_frames: int) -> int:
    """Training pixels per frame: ``samples_per_frame``, lowered so that ``n_frames`` frames
    give at most ``max_samples`` in total (a forest cannot take the ~10 M patches F sees)."""
    spf, total = int(fit_params["samples_per_frame"]), int(fit_params["max_samples"])
    if spf < 1 or total < 1:
        raise InputError(f"samples_per_frame and max_samples must be >= 1, got {spf}, {total}")
    return max(1, min(spf, total // max(1, n_frames)))


def sample_pixels(mask: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Flat indices of up to ``n`` distinct pixels drawn uniformly from the True pixels of the
    (H, W) bool ``mask`` (all of them when fewer), sorted."""
    idx = np.flatnonzero(mask)
    if idx.size > n:
        idx = np.sort(rng.choice(idx, size=n, replace=False))
    return idx


@dataclass(frozen=True)
class ForestArrays:
    """A fitted regression forest as flat arrays (all trees concatenated).

    Attributes:
        left, right: (n_nodes,) int64 child index *within the tree*; -1 at leaves.
        feature: (n_nodes,) int64 split feature; -2 at leaves.
        threshold: (n_nodes,) float64; go left when ``x[feature] <= threshold``.
        value: (n_nodes,) float64 node prediction (used at leaves).
        offsets: (n_trees + 1,) int64 start of each tree's nodes.
    """

    left: np.ndarray
    right: np.ndarray
    feature: np.ndarray
    threshold: np.ndarray
    value: np.ndarray
    offsets: np.ndarray

    @classmethod
    def from_sklearn(cls, forest: RandomForestRegressor) -> ForestArrays:
        """Export a fitted single-output sklearn forest."""
        trees = [est.tree_ for est in forest.estimators_]
        sizes = [t.node_count for t in trees]
        return cls(
            left=np.concatenate([t.children_left for t in trees]).astype(np.int64),
            right=np.concatenate([t.children_right for t in trees]).astype(np.int64),
            feature=np.concatenate([t.feature for t in trees]).astype(np.int64),
            threshold=np.concatenate([t.threshold for t in trees]).astype(np.float64),
            value=np.concatenate([t.value[:, 0, 0] for t in trees]).astype(np.float64),
            offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        )

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(N,) float64 mean leaf value over trees for (N, n_features) float32 ``x``."""
        x = np.asarray(x, np.float32)
        rows = np.arange(x.shape[0])
        total = np.zeros(x.shape[0])
        for start in self.offsets[:-1]:
            node = np.zeros(x.shape[0], np.int64)
            while True:  # descend all samples one level per pass
                leaf = self.left[start + node] == -1
                if leaf.all():
                    break
                g = start + node
                feat = np.where(leaf, 0, self.feature[g])
                go_left = x[rows, feat].astype(np.float64) <= self.threshold[g]
                node = np.where(leaf, node, np.where(go_left, self.left[g], self.right[g]))
            total += self.value[start + node]
        return total / (len(self.offsets) - 1)

    def save(self, path: str | Path) -> None:
        """Write the arrays to an ``.npz`` (no pickle)."""
        np.savez(path, **{k: getattr(self, k) for k in _FIELDS})

    @classmethod
    def load(cls, path: str | Path) -> ForestArrays:
        """Read :meth:`save` output; raises :class:`WeightsError` if missing or malformed."""
        path = Path(path)
        if not path.is_file():
            raise WeightsError(f"{path}: no such forest arrays file")
        arrays = read_npz(path, WeightsError, "forest arrays file")
        missing = [k for k in _FIELDS if k not in arrays]
        if missing:
            raise WeightsError(f"{path}: forest arrays missing: {', '.join(missing)}")
        problem = _forest_problem(*(arrays[k] for k in _FIELDS))
        if problem:
            raise WeightsError(f"{path}: not a forest: {problem}")
        return cls(**{k: arrays[k] for k in _FIELDS})


def _forest_problem(left: np.ndarray, right: np.ndarray, feature: np.ndarray,
                    threshold: np.ndarray, value: np.ndarray, offsets: np.ndarray) -> str:
    """What keeps these arrays from being a forest :meth:`ForestArrays.predict` can walk ("" if
    nothing). Children must come after their parent in the same tree (as sklearn numbers them):
    then every descent ends at a leaf, whatever the file holds."""
    nodes = (left, right, feature, threshold, value)
    if any(a.ndim != 1 for a in (*nodes, offsets)) or len({a.size for a in nodes}) != 1:
        return "arrays must be 1-D, and all but offsets of one length"
    if any(a.dtype.kind not in "iu" for a in (left, right, feature, offsets)) or any(
            a.dtype.kind not in "fiu" for a in (threshold, value)):
        return "left, right, feature and offsets must be integers, threshold and value numbers"
    n = left.size
    if offsets.size < 2 or offsets[0] != 0 or offsets[-1] != n or np.any(np.diff(offsets) <= 0):
        return f"offsets must rise strictly from 0 to the {n} nodes"
    tree_size = np.repeat(np.diff(offsets), np.diff(offsets))
    local = np.arange(n) - np.repeat(offsets[:-1], np.diff(offsets))
    leaf = left == -1
    inner_ok = ((left > local) & (left < tree_size) & (right > local) & (right < tree_size)
                & (feature >= 0))
    if not np.all(leaf | inner_ok):
        return "a split node's children must follow it within its tree and its feature be >= 0"
    if not np.all(np.isfinite(value[leaf])):
        return "leaf values must be finite"
    return ""
