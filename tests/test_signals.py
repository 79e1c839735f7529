"""Signal helpers against their reference implementations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import find_peaks

from staggered_cli.signals.probability import local_maxima


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
    from staggered_cli import quat
    from staggered_cli.signals import trails

    rng = np.random.default_rng(3)
    q = quat.normalize(rng.normal(size=(257, 3, 4)))
    axes = quat.normalize(rng.normal(size=(5, 4)))[:, 1:]
    owner = np.array([2, 0, 0, 1, 2])
    monkeypatch.setattr(trails, "_TRAIL_BLOCK", block)
    want = quat.mul_vec(q[:, owner], axes[None])
    assert trails._rotated_columns(q, owner, axes).tobytes() == want.tobytes()
    for a, v in enumerate(owner):  # each column is its rotation's own product
        assert want[:, a].tobytes() == quat.mul_vec(q[:, v, None, :], axes[None, a]).reshape(-1, 3).tobytes()


@pytest.mark.parametrize("name", ["cmu_02_01_walk.bvh", "bandai2_run_normal_001.bvh"])
def test_limb_trails_measured_together_are_each_variables_own(monkeypatch, name):
    """The local evidence with every variable's limb trails measured alone
    (a group of one) and with all of them in one call: the same bits."""
    from staggered_cli.signals import trails

    from .conftest import dev_motion

    m = dev_motion(name)
    monkeypatch.setattr(trails, "_TRAIL_GROUP", 1)
    alone = trails.local_evidence(m)
    monkeypatch.setattr(trails, "_TRAIL_GROUP", 1 << 30)
    together = trails.local_evidence(m)
    for field in ("p", "weights", "speed", "breaks"):
        assert getattr(alone, field).tobytes() == getattr(together, field).tobytes(), field


@pytest.mark.parametrize(
    "name", ["cmu_02_01_walk.bvh", "cmu3dsmax_131_02_start_walk_stop.bvh", "c3dorg_sample01_Eb015pi_walk.c3d"]
)
@pytest.mark.parametrize("width", [2, 3, 5])
def test_long_clips_measured_a_few_trails_and_columns_at_a_time_keep_every_bit(monkeypatch, name, width):
    """A long clip's trails are measured a few at a time (never one alone,
    whose sums over frames would add pairwise; a width that leaves one over
    gives it to the last block) and its curvature smoothed a few columns at
    a time: with blocks forced down to a few frames' worth, the local
    evidence of a real clip is the same bits."""
    from staggered_cli.signals import smoothing, trails

    from .conftest import dev_motion

    m = dev_motion(name)
    monkeypatch.setattr(trails, "_TRAIL_GROUP", 1)  # one variable's trails a call, as a long clip's
    whole = trails.local_evidence(m)
    monkeypatch.setattr(trails, "_MEASURE_BLOCK", width * m.n_frames)
    monkeypatch.setattr(smoothing, "_SMOOTH_BLOCK", width * m.n_frames)
    parts = trails.local_evidence(m)
    for field in ("p", "weights", "speed", "breaks"):
        assert getattr(parts, field).tobytes() == getattr(whole, field).tobytes(), field


def test_column_blocks_never_leave_a_column_alone():
    from staggered_cli.signals.trails import _column_starts

    for n in range(2, 12):
        for width in range(2, 6):
            parts = _column_starts(n, width)
            assert [i for s in parts for i in range(n)[s]] == list(range(n))
            assert min(s.stop - s.start for s in parts) >= 2
