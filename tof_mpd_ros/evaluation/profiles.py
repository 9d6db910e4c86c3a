"""Range profiles along a line across an object boundary (the paper's Fig. 7 and 8).

:func:`choose_boundary_line` picks, in one reference frame, the horizontal or vertical segment
centred on a ground-truth boundary pixel that crosses the largest depth step while its reference
is mostly present; :func:`sample_profile` reads any (H, W) range image along it, so every method
is plotted on the same pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..validation import check_array

DEFAULT_LENGTH_PX = 40


@dataclass(frozen=True)
class ProfileLine:
    """An axis-aligned pixel segment.

    Attributes:
        row, col: (row, col) of the first pixel.
        length: number of pixels.
        axis: ``"horizontal"`` (along a row, columns increase) or ``"vertical"`` (rows increase).
        step_mm: reference depth step across the line (|median of the last quarter − median of
            the first quarter|), mm.
    """

    row: int
    col: int
    length: int
    axis: str
    step_mm: float

    def pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """``(rows, cols)``: (length,) int arrays of the line's pixels in order."""
        k = np.arange(self.length)
        if self.axis == "horizontal":
            return np.full(self.length, self.row), self.col + k
        return self.row + k, np.full(self.length, self.col)

    @property
    def end(self) -> tuple[int, int]:
        """(row, col) of the last pixel."""
        rows, cols = self.pixels()
        return int(rows[-1]), int(cols[-1])

    def to_dict(self) -> dict:
        return {"start_row_col": [self.row, self.col], "end_row_col": list(self.end),
                "length_px": self.length, "axis": self.axis, "step_mm": self.step_mm}


def _step(values: np.ndarray, min_valid: float) -> float:
    """Depth step of one candidate's reference values, or -1 when too much is missing."""
    ok = np.isfinite(values)
    q = max(2, values.size // 4)
    head, tail = values[:q][ok[:q]], values[-q:][ok[-q:]]
    if ok.mean() < min_valid or head.size < q // 2 + 1 or tail.size < q // 2 + 1:
        return -1.0
    return float(abs(np.median(tail) - np.median(head)))


def choose_boundary_line(reference_mm: np.ndarray, edges: np.ndarray | None = None, *,
                         length_px: int = DEFAULT_LENGTH_PX, min_valid: float = 0.8,
                         max_candidates: int = 600, border_px: int = 5, seed: int = 0
                         ) -> ProfileLine | None:
    """The segment across one boundary with the largest reference depth step.

    Candidates are horizontal and vertical segments centred on a ground-truth boundary pixel,
    lying wholly inside the image and not along its border, with no other boundary pixel
    farther than ``length_px // 10`` (at least 2) from the centre, and with ``min_valid`` of
    their reference present.

    Args:
        reference_mm: (H, W) float reference radial range in mm, NaN = missing.
        edges: (H, W) bool ground-truth boundary pixels; default
            :func:`~tof_mpd_ros.correction.edges.ground_truth_edges` of the reference.
        length_px: segment length in pixels (shortened to fit small images, at least 4).
        min_valid: fraction of the segment's reference pixels that must be present.
        border_px: lines keep at least this far from the image border (less on tiny images).
        max_candidates: boundary pixels tried (a seeded random subset when there are more).
        seed: seeds that subset.

    Returns:
        The chosen :class:`ProfileLine`, or None when the frame has no usable boundary.
    """
    ref = check_array("reference_mm", reference_mm, ndim=2, dtype_kind="fiu").astype(np.float64)
    if edges is None:
        from ..correction.edges import ground_truth_edges

        edges, _ = ground_truth_edges(ref)
    edges = check_array("edges", edges, ndim=2, shape=ref.shape, dtype_kind="bui").astype(bool)
    h, w = ref.shape
    rows, cols = np.nonzero(edges)
    if rows.size == 0:
        return None
    if rows.size > max_candidates:
        pick = np.random.default_rng(seed).choice(rows.size, max_candidates, replace=False)
        rows, cols = rows[np.sort(pick)], cols[np.sort(pick)]
    best: ProfileLine | None = None
    for axis, size in (("horizontal", w), ("vertical", h)):
        n = min(int(length_px), size)
        if n < 4:
            continue
        centre_window = max(2, n // 10)
        for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
            centre, across, across_size = (c, r, h) if axis == "horizontal" else (r, c, w)
            start = centre - n // 2
            if start < 0 or start + n > size:
                continue  # the boundary must sit mid-line
            if min(across, across_size - 1 - across) < min(border_px, across_size // 4):
                continue  # not along the image border
            if axis == "horizontal":
                values, on_edge = ref[r, start:start + n], edges[r, start:start + n]
            else:
                values, on_edge = ref[start:start + n, c], edges[start:start + n, c]
            # One boundary crossing: no other boundary pixel away from the centre.
            off_centre = np.abs(np.arange(n) - n // 2) > centre_window
            if on_edge[off_centre].any():
                continue
            step = _step(values, min_valid)
            if step > (best.step_mm if best else 0.0):
                row, col = (r, start) if axis == "horizontal" else (start, c)
                best = ProfileLine(int(row), int(col), n, axis, step)
    return best


def sample_profile(image: np.ndarray, line: ProfileLine) -> np.ndarray:
    """(length,) float values of an (H, W) image along ``line`` (NaN stays NaN).

    Raises:
        InputError: the line does not fit the image.
    """
    img = check_array("image", image, ndim=2, dtype_kind="fiub")
    rows, cols = line.pixels()
    if rows.min() < 0 or cols.min() < 0 or rows.max() >= img.shape[0] or \
            cols.max() >= img.shape[1]:
        raise InputError(f"profile line {line.to_dict()} does not fit an image of shape "
                         f"{img.shape}")
    return img[rows, cols].astype(np.float64)
