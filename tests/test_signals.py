"""Signal helpers against their reference implementations."""

from __future__ import annotations

import numpy as np
from scipy.signal import find_peaks

from staggered_cli.signals import local_maxima


def test_local_maxima_follow_find_peaks():
    rng = np.random.default_rng(0)
    for _ in range(2000):
        x = np.round(rng.normal(size=rng.integers(1, 40)), 1)
        if rng.random() < 0.3:
            x = np.abs(x)
        peaks, _ = find_peaks(x)
        np.testing.assert_array_equal(local_maxima(x), peaks[x[peaks] > 0])


def test_plateaus_give_their_middle_and_edges_are_not_peaks():
    assert local_maxima(np.array([0, 1, 2, 2, 2, 1, 0.0])).tolist() == [3]
    assert local_maxima(np.array([0, 1, 2, 2, 1, 0.0])).tolist() == [2]
    assert local_maxima(np.array([3, 1, 2, 1, 3.0])).tolist() == [2]
    assert local_maxima(np.array([0, 0, 0.0])).tolist() == []
