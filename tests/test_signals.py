"""Signal helpers against their reference implementations."""

from __future__ import annotations

import numpy as np
import pytest
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


@pytest.mark.parametrize("block", [3, 50, 1 << 15])
def test_trails_made_in_blocks_of_frames_are_the_whole_products(monkeypatch, block):
    from staggered_cli import quat, signals

    rng = np.random.default_rng(3)
    q = quat.normalize(rng.normal(size=(257, 4)))
    axes = quat.normalize(rng.normal(size=(5, 4)))[:, 1:]
    monkeypatch.setattr(signals, "_TRAIL_BLOCK", block)
    assert signals._rotated(q, axes).tobytes() == quat.mul_vec(q[:, None, :], axes[None]).tobytes()
