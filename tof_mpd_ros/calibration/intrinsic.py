"""Per-pixel intrinsic calibration: a linear model from observed (range, amplitude) to true range.

The paper removes intrinsic systematic errors before anything else with "a linear model for each
pixel location relating the observed measurements (both range and amplitude) to the true range",
fitted from many checkerboard poses. The model used here, at every pixel ``p``::

    true_range(p) ~= c0(p) + c1(p) * range(p) + c2(p) * a(amplitude(p))

with ``a(A) = A`` (``amplitude_term="linear"``, the default: the paper's wording, and it removes
an offset, a gain and a bias proportional to amplitude) or ``a(A) = 1 / A``
(``amplitude_term="inverse"``, for sensors whose bias grows as the signal weakens).

Fitting is per-pixel ridge regression of the *correction* ``true - range`` on globally
standardised features, vectorised over pixels and NaN-aware. The ridge term pulls the two slopes
towards the identity model (``c1 = 1, c2 = 0``), never the offset, so a pixel with few or
degenerate samples still gets its mean offset right and cannot blow up.

:meth:`IntrinsicCalibration.fit` is the package's one implementation of the fit (on stacked
arrays); :func:`fit_calibration` fits from checkerboard frames (``tof-mpd calibrate intrinsic``,
``tof-mpd train`` and the demo go through it); :func:`save_calibration` and
:func:`load_calibration` write and read the calibration ``.npz`` (no pickle).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic_file import write_atomically
from ..errors import CalibrationError, InputError
from ..frame import ToFFrame
from ..npz_file import read_npz
from ..validation import check_array

AMPLITUDE_TERMS = ("linear", "inverse")


def valid_measurement(range_mm: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
    """Pixels whose ToF measurement is usable: finite range > 0 and finite amplitude > 0.

    Args:
        range_mm: (..., H, W) float radial range in mm.
        amplitude: (..., H, W) float amplitude, same shape.

    Returns:
        (..., H, W) bool.
    """
    with np.errstate(invalid="ignore"):
        return np.isfinite(range_mm) & np.isfinite(amplitude) & (range_mm > 0) & (amplitude > 0)


def _amplitude_feature(amplitude: np.ndarray, term: str) -> np.ndarray:
    if term == "linear":
        return amplitude
    with np.errstate(divide="ignore", invalid="ignore"):
        return 1.0 / amplitude


@dataclass
class IntrinsicCalibration:
    """Per-pixel linear calibration ``true = c0 + c1 * range + c2 * a(amplitude)``.

    Attributes:
        c0: (H, W) float32 offset in mm.
        c1: (H, W) float32 range gain (dimensionless).
        c2: (H, W) float32 amplitude coefficient, mm per amplitude unit (``linear``) or
            mm * amplitude unit (``inverse``).
        fitted: (H, W) bool, False where too few samples were seen and the identity is used.
        amplitude_term: ``"linear"`` or ``"inverse"`` (see the module docstring).
        rms_mm: (H, W) float32 RMS residual of the fit in mm (NaN where not fitted), or None.
    """

    c0: np.ndarray
    c1: np.ndarray
    c2: np.ndarray
    fitted: np.ndarray
    amplitude_term: str = "linear"
    rms_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.amplitude_term not in AMPLITUDE_TERMS:
            raise CalibrationError(f"amplitude_term must be one of {AMPLITUDE_TERMS}, "
                                   f"got {self.amplitude_term!r}")
        c0 = check_array("c0", self.c0, ndim=2, dtype_kind="fiu", error=CalibrationError)
        self.c0 = c0.astype(np.float32, copy=False)
        shape = c0.shape
        self.c1 = check_array("c1", self.c1, ndim=2, shape=shape, dtype_kind="fiu",
                              error=CalibrationError).astype(np.float32, copy=False)
        self.c2 = check_array("c2", self.c2, ndim=2, shape=shape, dtype_kind="fiu",
                              error=CalibrationError).astype(np.float32, copy=False)
        self.fitted = check_array("fitted", self.fitted, ndim=2, shape=shape,
                                  dtype_kind="biu", error=CalibrationError).astype(bool)
        if self.rms_mm is not None:
            self.rms_mm = check_array("rms_mm", self.rms_mm, ndim=2, shape=shape,
                                      dtype_kind="f", error=CalibrationError
                                      ).astype(np.float32, copy=False)
        if not all(np.isfinite(c).all() for c in (self.c0, self.c1, self.c2)):
            raise CalibrationError("calibration coefficients must be finite")

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the images this calibration applies to."""
        return self.c0.shape  # type: ignore[return-value]

    @classmethod
    def identity(cls, height: int, width: int, amplitude_term: str = "linear"
                 ) -> IntrinsicCalibration:
        """The calibration that returns the observed range unchanged."""
        shape = (int(height), int(width))
        return cls(np.zeros(shape, np.float32), np.ones(shape, np.float32),
                   np.zeros(shape, np.float32), np.zeros(shape, bool), amplitude_term)

    def central(self, width: int, height: int) -> IntrinsicCalibration:
        """The calibration of the central ``width`` x ``height`` window of these pixels (the
        window :meth:`~tof_mpd_ros.camera.Intrinsics.crop_window` cuts from an image).

        Raises:
            CalibrationError: the window does not fit.
        """
        h, w = self.shape
        if not (0 < width <= w and 0 < height <= h):
            raise CalibrationError(f"a {width}x{height} window does not fit in the "
                                   f"calibration's {w}x{h}")
        top, left = (h - height) // 2, (w - width) // 2
        rows, cols = slice(top, top + height), slice(left, left + width)
        return IntrinsicCalibration(
            self.c0[rows, cols], self.c1[rows, cols], self.c2[rows, cols],
            self.fitted[rows, cols], self.amplitude_term,
            None if self.rms_mm is None else self.rms_mm[rows, cols])

    @property
    def is_identity(self) -> bool:
        return bool((self.c0 == 0).all() and (self.c1 == 1).all() and (self.c2 == 0).all())

    @classmethod
    def fit(
        cls,
        range_mm: np.ndarray,
        amplitude: np.ndarray,
        true_mm: np.ndarray,
        *,
        amplitude_term: str = "linear",
        ridge: float = 1.0,
        min_samples: int = 3,
        max_unfitted_fraction: float = 0.05,
        chunk: int = 64,
    ) -> IntrinsicCalibration:
        """Fit the per-pixel model by ridge least squares from N captures.

        Args:
            range_mm: (N, H, W) float observed radial range in mm; NaN/inf/<= 0 = invalid.
            amplitude: (N, H, W) float observed amplitude; NaN/inf/<= 0 = invalid.
            true_mm: (N, H, W) float true radial range in mm (checkerboard plane); NaN = missing.
            amplitude_term: ``"linear"`` or ``"inverse"``.
            ridge: ridge weight on the two standardised slopes, in units of samples
                (features are standardised over all valid samples, so 1.0 acts like one extra
                sample pulling the pixel towards ``c1 = 1, c2 = 0``). Must be > 0.
            min_samples: a pixel with fewer valid samples keeps the identity model.
            max_unfitted_fraction: raise if more than this fraction of pixels keep the identity.
            chunk: captures processed at a time (bounds memory to ~chunk * H * W * 80 bytes).

        Returns:
            The fitted calibration.

        Raises:
            CalibrationError: mismatched stacks, too few captures or valid samples.
        """
        r = check_array("range_mm", range_mm, ndim=3, dtype_kind="fiu", error=CalibrationError)
        a = check_array("amplitude", amplitude, ndim=3, shape=r.shape, dtype_kind="fiu",
                        error=CalibrationError)
        t = check_array("true_mm", true_mm, ndim=3, shape=r.shape, dtype_kind="fiu",
                        error=CalibrationError)
        if amplitude_term not in AMPLITUDE_TERMS:
            raise CalibrationError(f"amplitude_term must be one of {AMPLITUDE_TERMS}, "
                                   f"got {amplitude_term!r}")
        if not ridge > 0:
            raise CalibrationError(f"ridge must be > 0, got {ridge}")
        if r.shape[0] < min_samples:
            raise CalibrationError(f"calibration needs at least {min_samples} captures, "
                                   f"got {r.shape[0]}")
        stats = _feature_stats(r, a, t, amplitude_term, chunk)
        if stats is None:
            raise CalibrationError("calibration stacks contain no valid sample (finite range "
                                   "> 0, amplitude > 0 and true range)")
        sums = _accumulate(r, a, t, amplitude_term, stats, chunk)
        return _solve(sums, stats, ridge, min_samples, max_unfitted_fraction, amplitude_term)

    def apply(self, range_mm: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
        """Calibrated range.

        Args:
            range_mm: (..., H, W) float observed radial range in mm.
            amplitude: (..., H, W) float amplitude, same shape.

        Returns:
            (..., H, W) float32 calibrated radial range in mm; NaN where the measurement is
            invalid (non-finite, or range/amplitude <= 0).

        Raises:
            InputError: shapes differ from each other or from the calibration's (H, W).
        """
        r = check_array("range_mm", range_mm, ndim=(2, 3), shape=self.shape, dtype_kind="fiu")
        a = check_array("amplitude", amplitude, ndim=(2, 3), shape=self.shape,
                        dtype_kind="fiu")
        if r.shape != a.shape:
            raise InputError(f"range_mm {r.shape} and amplitude {a.shape} differ in shape")
        r32 = r.astype(np.float32, copy=False)
        a32 = a.astype(np.float32, copy=False)
        ok = valid_measurement(r32, a32)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            out = self.c0 + self.c1 * r32 + self.c2 * _amplitude_feature(a32, self.amplitude_term)
        return np.where(ok, out, np.float32(np.nan)).astype(np.float32, copy=False)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Named arrays for a weights file (no object arrays: loads without pickle)."""
        arrays = {"c0": self.c0, "c1": self.c1, "c2": self.c2,
                  "fitted": self.fitted.astype(np.uint8),
                  "amplitude_term": np.array(self.amplitude_term)}
        if self.rms_mm is not None:
            arrays["rms_mm"] = self.rms_mm
        return arrays

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> IntrinsicCalibration:
        """Inverse of :meth:`to_arrays`.

        Raises:
            CalibrationError: a required array is missing or malformed.
        """
        missing = [k for k in ("c0", "c1", "c2", "fitted", "amplitude_term") if k not in arrays]
        if missing:
            raise CalibrationError(f"calibration arrays missing: {', '.join(missing)}")
        return cls(arrays["c0"], arrays["c1"], arrays["c2"], arrays["fitted"],
                   str(arrays["amplitude_term"]), arrays.get("rms_mm"))


@dataclass(frozen=True)
class _Stats:
    """Global means and standard deviations of the two features (float64)."""

    mean_r: float
    std_r: float
    mean_a: float
    std_a: float


def _chunk_features(r: np.ndarray, a: np.ndarray, t: np.ndarray, term: str
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(mask, range, amplitude feature, correction) of one chunk in float64, zero where invalid."""
    r = r.astype(np.float64)
    af = _amplitude_feature(a.astype(np.float64), term)
    t = t.astype(np.float64)
    m = valid_measurement(r, a) & np.isfinite(t) & np.isfinite(af)
    zero = np.float64(0.0)
    return m, np.where(m, r, zero), np.where(m, af, zero), np.where(m, t - r, zero)


def _feature_stats(r: np.ndarray, a: np.ndarray, t: np.ndarray, term: str, chunk: int
                   ) -> _Stats | None:
    n = s_r = s_rr = s_a = s_aa = 0.0
    for i in range(0, r.shape[0], chunk):
        m, rr, af, _ = _chunk_features(r[i:i + chunk], a[i:i + chunk], t[i:i + chunk], term)
        n += m.sum()
        s_r, s_rr = s_r + rr.sum(), s_rr + (rr * rr).sum()
        s_a, s_aa = s_a + af.sum(), s_aa + (af * af).sum()
    if n == 0:
        return None
    mean_r, mean_a = s_r / n, s_a / n
    # A constant feature gets scale 1 so standardisation never divides by zero.
    std_r = float(np.sqrt(max(s_rr / n - mean_r ** 2, 0.0))) or 1.0
    std_a = float(np.sqrt(max(s_aa / n - mean_a ** 2, 0.0))) or 1.0
    return _Stats(float(mean_r), std_r, float(mean_a), std_a)


def _accumulate(r: np.ndarray, a: np.ndarray, t: np.ndarray, term: str, st: _Stats, chunk: int
                ) -> dict[str, np.ndarray]:
    """Per-pixel sums of the normal equations over all captures, (H, W) float64 each."""
    keys = ("n", "u", "v", "uu", "uv", "vv", "e", "ue", "ve", "ee")
    sums = {k: np.zeros(r.shape[1:], np.float64) for k in keys}
    for i in range(0, r.shape[0], chunk):
        m, rr, af, e = _chunk_features(r[i:i + chunk], a[i:i + chunk], t[i:i + chunk], term)
        u = np.where(m, (rr - st.mean_r) / st.std_r, 0.0)
        v = np.where(m, (af - st.mean_a) / st.std_a, 0.0)
        for k, x in (("n", m.astype(np.float64)), ("u", u), ("v", v), ("uu", u * u),
                     ("uv", u * v), ("vv", v * v), ("e", e), ("ue", u * e), ("ve", v * e),
                     ("ee", e * e)):
            sums[k] += x.sum(axis=0)
    return sums


def _solve(s: dict[str, np.ndarray], st: _Stats, ridge: float, min_samples: int,
           max_unfitted_fraction: float, term: str) -> IntrinsicCalibration:
    n = s["n"]
    normal = np.stack([np.stack([n, s["u"], s["v"]], -1),
                       np.stack([s["u"], s["uu"], s["uv"]], -1),
                       np.stack([s["v"], s["uv"], s["vv"]], -1)], -2)  # (H, W, 3, 3)
    rhs = np.stack([s["e"], s["ue"], s["ve"]], -1)  # (H, W, 3)
    fitted = n >= max(min_samples, 1)
    unfitted = 1.0 - fitted.mean()
    if unfitted > max_unfitted_fraction:
        raise CalibrationError(
            f"too few valid samples: {unfitted:.1%} of pixels have fewer than {min_samples} "
            f"valid captures (allowed {max_unfitted_fraction:.1%}); median per pixel "
            f"{np.median(n):.0f}")
    regularised = normal + np.diag([0.0, ridge, ridge])
    # Unfitted pixels get an identity system so the batched solve never sees a singular matrix.
    regularised[~fitted] = np.eye(3)
    coef = np.linalg.solve(regularised, rhs[..., None])[..., 0]  # (H, W, 3): e ~ a0 + a1 u + a2 v
    coef[~fitted] = 0.0
    rss = (s["ee"] - 2 * (coef * rhs).sum(-1)
           + np.einsum("...i,...ij,...j->...", coef, normal, coef))
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(fitted, np.sqrt(np.maximum(rss, 0.0) / np.maximum(n, 1)), np.nan)
    # Undo the standardisation: true = r + a0 + a1 (r - mr)/sr + a2 (af - ma)/sa.
    a0, a1, a2 = coef[..., 0], coef[..., 1], coef[..., 2]
    c1 = 1.0 + a1 / st.std_r
    c2 = a2 / st.std_a
    c0 = a0 - a1 * st.mean_r / st.std_r - a2 * st.mean_a / st.std_a
    return IntrinsicCalibration(c0, c1, c2, fitted, term, rms.astype(np.float32))


def fit_calibration(frames: Sequence[ToFFrame], **kwargs: Any) -> IntrinsicCalibration:
    """Fit the per-pixel intrinsic calibration from checkerboard captures.

    Args:
        frames: ToF frames of the checkerboard with ``reference_mm`` = true radial range of the
            board plane (NaN = missing), all of one (H, W).
        **kwargs: passed to :meth:`IntrinsicCalibration.fit` (``amplitude_term``, ``ridge``,
            ``min_samples``, ``max_unfitted_fraction``).

    Raises:
        CalibrationError: no frames, a frame without reference, mixed sizes or too few samples.
    """
    if len(frames) == 0:
        raise CalibrationError("fit_calibration needs checkerboard frames, got none")
    shape = frames[0].range_mm.shape
    for i, f in enumerate(frames):
        if f.reference_mm is None:
            raise CalibrationError(f"checkerboard frame {i} has no reference_mm")
        if f.range_mm.shape != shape:
            raise CalibrationError(f"checkerboard frame {i} is {f.range_mm.shape}, frame 0 is "
                                   f"{shape}")
    return IntrinsicCalibration.fit(np.stack([f.range_mm for f in frames]),
                                    np.stack([f.amplitude for f in frames]),
                                    np.stack([f.reference_mm for f in frames]), **kwargs)


def save_calibration(path: Path, calibration: IntrinsicCalibration) -> None:
    """Write ``calibration`` as an ``.npz`` of :meth:`IntrinsicCalibration.to_arrays`,
    atomically (a reader sees the old file or the new one); like ``np.savez``, ``.npz`` is
    appended to a name without it."""
    path = Path(path)
    if not path.name.endswith(".npz"):
        path = path.with_name(path.name + ".npz")
    arrays = calibration.to_arrays()
    write_atomically(path, lambda stream: np.savez(stream, **arrays))


def load_calibration(path: Path) -> IntrinsicCalibration:
    """Read a calibration .npz written by :func:`save_calibration` (no pickle).

    Raises:
        CalibrationError: no such file, not an npz, or malformed arrays (the message names the
            file).
    """
    if not Path(path).is_file():
        raise CalibrationError(f"{path}: no such calibration file")
    arrays = read_npz(Path(path), CalibrationError, "calibration file")
    try:
        return IntrinsicCalibration.from_arrays(arrays)
    except CalibrationError as err:
        raise CalibrationError(f"{path}: {err}") from err
