"""The fits' local search: Powell inside the box, every step downhill from its start."""

from __future__ import annotations

import numpy as np
from scipy import optimize

from tof_mpd_ros.mismatch.fit import local_search


def _two_valleys(u: np.ndarray) -> float:
    """A deep, narrow valley at (0.3, 0.03) and a shallower, broad one along u1 = 0.62. A line
    search over the whole feasible segment of u1 (scipy's bounded Powell: golden section from
    0.38 and 0.62) lands in the far one and ends worse than a start beside the near one."""
    near = np.exp(-((u[0] - 0.3) ** 2 / 0.02 + (u[1] - 0.03) ** 2 / 0.004))
    far = 0.6 * np.exp(-((u[1] - 0.62) ** 2) / 0.02)
    return float(-near - far)


def test_finds_the_valley_it_starts_in_never_ending_worse():
    lo, hi = np.zeros(2), np.ones(2)
    for start in ([0.3, 0.0], [0.25, 0.0], [0.35, 0.05]):
        u, c = local_search(_two_valleys, np.array(start), lo, hi, 150)
        assert c <= _two_valleys(np.array(start))
        np.testing.assert_allclose(u, [0.3, 0.03], atol=0.01)
        # what the bounded Powell this replaced does from the same start
        bounded = optimize.minimize(_two_valleys, np.array(start), method="Powell",
                                    bounds=[(0, 1), (0, 1)],
                                    options={"xtol": 1e-2, "ftol": 1e-6, "maxfev": 150})
        assert bounded.fun > _two_valleys(np.array(start))


def test_stays_in_its_box_and_keeps_a_collapsed_coordinate():
    def bowl(u: np.ndarray) -> float:
        return float((u[0] - 0.2) ** 2 + (u[1] - 0.9) ** 2)

    lo, hi = np.array([0.4, 0.5]), np.array([0.8, 0.5])
    u, c = local_search(bowl, np.array([0.6, 0.5]), lo, hi, 150)
    assert np.all(u >= lo) and np.all(u <= hi) and u[1] == 0.5
    # the minimum lies outside the box: the search ends on the box's near edge
    assert abs(u[0] - 0.4) < 0.01 and c < bowl(np.array([0.6, 0.5]))


def test_a_start_at_the_minimum_stays():
    u, c = local_search(lambda u: float(np.sum((u - 0.5) ** 2)), np.array([0.5, 0.5]),
                        np.zeros(2), np.ones(2), 100)
    np.testing.assert_allclose(u, [0.5, 0.5], atol=1e-3)
    assert c < 1e-6
