"""Issue 34 item 3, fast motion: extract's default ``filter_width`` and
``min_spacing`` follow the motion's tempo (``ops.extract.tempo_scale``).

Fast clips are made here, never stored: a real 120 Hz clip keeps every
k-th frame at the same frame rate, so it plays k times as fast (a walk at
three times its speed steps as a sprint does)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import staggered_cli as st
from staggered_cli.contacts.constraint import Constraint
from staggered_cli.ops.extract import (
    DEFAULT_MIN_SPACING,
    MIN_TEMPO_SCALE,
    REFERENCE_STRIDE,
    stride_period,
    tempo_scale,
)
from staggered_cli.signals.smoothing import DEFAULT_FILTER_WIDTH

from .conftest import BVH_FILES, C3D_FILES, dev_document, dev_motion
from .events import clip_events

#: The dev clips that walk, and the one that stands idle.
WALKS = (
    "cmu_02_01_walk.bvh",
    "bandai1_walk_normal_001.bvh",
    "c3dorg_sample01_Eb015pi_walk.c3d",
    "ezc3d_BTS_walk_gaps.c3d",
)
IDLE = "games105_idle.bvh"


def _steps(joint: str, starts) -> list[Constraint]:
    return [Constraint(joint, float(s), float(s) + 0.3) for s in starts]


def test_stride_is_the_median_restart_of_one_joint():
    left = _steps("LeftFoot", [0.0, 1.2, 2.4, 3.6])
    right = _steps("RightFoot", [0.6, 1.4, 2.2])  # 0.8 s twice
    assert stride_period(left) == pytest.approx(1.2)
    assert stride_period(left + right) == pytest.approx(1.2)  # median of 1.2, 1.2, 1.2, 0.8, 0.8
    # fewer than three starts of any joint, or no contact: no stride, the defaults stay
    assert stride_period(_steps("LeftFoot", [0.0, 0.5])) is None
    assert stride_period([]) is None and tempo_scale([]) == 1.0


def test_scale_is_clamped_between_a_third_and_one():
    assert tempo_scale(_steps("LeftFoot", [0, 2, 4])) == 1.0  # slower than a walk: today's durations
    assert tempo_scale(_steps("LeftFoot", [0, 0.5, 1.0])) == pytest.approx(0.5 / REFERENCE_STRIDE)
    assert tempo_scale(_steps("LeftFoot", [0, 0.1, 0.2])) == MIN_TEMPO_SCALE


@pytest.mark.parametrize("name", BVH_FILES + C3D_FILES)
def test_dev_clips_record_the_durations_their_tempo_gives(name):
    """Walks, idle, the bow and the box lift keep 0.15/0.1 (measured strides:
    walks 1.0-2.5 s, the others none); the run (0.73 s: 0.11/0.073), the
    Bandai dance (0.67 s), the stylised walk of cmu3dsmax_131_02 (0.65 s)
    and the breakdance (0.67 s) get shorter ones; the document records
    what was used."""
    doc = dev_document(name)
    scale = tempo_scale(doc.constraints)
    assert doc.parameters["filter_width"] == round(DEFAULT_FILTER_WIDTH * scale, 3)
    assert doc.parameters["min_spacing"] == round(DEFAULT_MIN_SPACING * scale, 3)
    if name in WALKS or name in (IDLE, "bandai1_bow_normal_001.bvh", "cmu_115_06_pick_up_box.bvh"):
        assert scale == 1.0, name
    if name == "bandai2_run_normal_001.bvh":
        assert scale == pytest.approx(0.73, abs=0.02)


def test_pose_density_stays_sparse():
    """A walk 3-8 poses per second while it walks (from its first contact's
    start to its last's end: ezc3d_BTS_walk_gaps.c3d sees no marker before
    2.5 s: 18 poses in 6.74 s, 2.7 a second, but 16 in its 4.24 s of
    walking; measured 3.25-4.21 on the four walks), idle at most half the
    sparsest walk's (0.6); no dev clip above 8 (the run 7.6, the most)."""

    def density(name):
        doc = dev_document(name)
        return doc.n_poses / doc.duration

    def walking(name):
        doc = dev_document(name)
        a = min(c.start for c in doc.constraints)
        b = max(c.end for c in doc.constraints)
        return np.count_nonzero((doc.pose_t >= a) & (doc.pose_t <= b)) / (b - a)

    walks = {n: walking(n) for n in WALKS}
    assert all(3.0 <= d <= 8.0 for d in walks.values()), walks
    assert density(IDLE) <= 0.5 * min(walks.values()), (density(IDLE), walks)
    every = {n: density(n) for n in BVH_FILES + C3D_FILES}
    assert max(every.values()) <= 8.0, every


def test_explicit_durations_win():
    doc = st.extract(dev_motion("bandai2_run_normal_001.bvh"), filter_width=0.15, min_spacing=0.1)
    assert doc.parameters["filter_width"] == 0.15 and doc.parameters["min_spacing"] == 0.1
    assert doc.n_poses < dev_document("bandai2_run_normal_001.bvh").n_poses  # 13 against 17


def _faster(name: str, k: int):
    m = dev_motion(name)
    return replace(m, channels=np.ascontiguousarray(m.channels[::k]), source=b"", source_values=None, name="")


def _per_stride(doc) -> float:
    return doc.n_poses / doc.duration * stride_period(doc.constraints)


@pytest.mark.parametrize("k", [2, 3])
def test_a_faster_walk_keeps_its_poses_per_step(k):
    """cmu_02_01 played k times as fast: its stride shrinks k times (1.11 s
    to 0.55 and 0.37 s) and so do the defaults; it keeps most of its poses
    per stride (measured 4.7 at 1x; 3.1 at 2x, 3.9 at 3x; with 0.15/0.1
    2.3 at both, one pose per stance), and its poses fall at the same phases
    of the step: of the 1x clip's poses, 2/3 (2x) and 3/4 (3x) have one of
    the fast clip's within 0.1 s in the 1x clip's time (with 0.15/0.1:
    0.58, 0.50)."""
    name = "cmu_02_01_walk.bvh"
    base = dev_document(name)
    fast = st.extract(_faster(name, k))
    old = st.extract(_faster(name, k), filter_width=0.15, min_spacing=0.1)
    stride = stride_period(fast.constraints)
    assert stride == pytest.approx(stride_period(base.constraints) / k, rel=0.05)
    assert fast.parameters["min_spacing"] == pytest.approx(0.1 * stride / REFERENCE_STRIDE, abs=0.001)
    assert _per_stride(fast) >= 3.0 and _per_stride(old) < 2.5, (_per_stride(fast), _per_stride(old))

    def same_phase(doc):
        back = doc.pose_t * k  # the fast clip's times in the 1x clip's
        return np.mean(np.min(np.abs(back[None, :] - base.pose_t[:, None]), axis=1) <= 0.1 + 1e-9)

    assert same_phase(fast) >= 0.65 and same_phase(fast) > same_phase(old) + 0.05, (same_phase(fast), same_phase(old))


def test_faster_hops_keep_a_pose_in_every_flight_and_at_the_contacts():
    """cmu_01_01's hops played three times as fast (stride 1.68 s to 0.56 s):
    a pose in every flight phase (both feet off >= 0.1 s, found by
    tests/events.py), 80 % of the contact changes with a pose within
    0.075 s, and twice the poses 0.15/0.1 give (measured 60 against 28:
    with those, the fast hops lose the poses between take-off and landing)."""
    motion = _faster("cmu_01_01_forward_jumps.bvh", 3)
    doc = st.extract(motion)
    old = st.extract(motion, filter_width=0.15, min_spacing=0.1)
    assert doc.n_poses >= 1.8 * old.n_poses, (doc.n_poses, old.n_poses)
    ev = clip_events(motion, "cmu_01_01_forward_jumps.bvh")
    assert len(ev.flights) >= 8
    for a, b in ev.flights:
        assert np.any((doc.pose_t >= a - 1e-9) & (doc.pose_t <= b + 1e-9)), (a, b)
    changes = np.array([t for c in doc.constraints for t in (c.start, c.end) if 0 < t < doc.duration - 1e-9])
    near = np.min(np.abs(doc.pose_t[None, :] - changes[:, None]), axis=1) <= 0.075 + 1e-9
    assert near.mean() >= 0.8, near.mean()
