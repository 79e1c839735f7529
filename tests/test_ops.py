"""Editing operations on real motion: cull, edit-pose, succession, randomize, bake."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli import quat
from staggered_cli.errors import KnotOrderError, UsageError
from staggered_cli.io.bvh import read_bvh
from staggered_cli.io.schema import to_parts
from staggered_cli.model import sampling, variables
from staggered_cli.motion import local_rotations_from_channels
from staggered_cli.ops import cull, timing
from staggered_cli.ops import edit_pose as E
from staggered_cli.ops.bake import bake

from .conftest import mocap, staggered_warnings


@pytest.fixture(scope="module")
def walk():
    m = read_bvh(mocap("cmu_02_01_walk.bvh"))
    rng = np.random.default_rng(11)
    pose_t = np.arange(0.0, (m.n_frames - 1) * m.frame_time - 0.1, 0.2)
    doc = variables.from_motion(m, pose_t)
    ref = np.round(rng.uniform(-0.05, 0.05, (doc.n_poses, len(doc.variable_names))) / m.frame_time) * m.frame_time
    return variables.from_motion(m, doc.pose_t, ref)


def _rot(motion):
    return local_rotations_from_channels(motion.skeleton, motion.channels)


def test_cull_keeps_the_motion(walk):
    base = bake(walk).channels
    for keep in ("25%", "3", "60%"):
        c = cull.keep_poses(walk, cull.choose(walk, keep=keep))
        assert c.n_poses < walk.n_poses
        assert c.pose_t[0] == 0.0 and c.pose_t[-1] == walk.pose_t[-1]
        assert np.abs(bake(c).channels - base).max() < 1e-6
    added = cull.add_pose(cull.keep_poses(walk, cull.choose(walk, keep="25%")), 1.2345)
    assert np.abs(bake(added).channels - base).max() < 1e-6
    with pytest.raises(UsageError):
        cull.choose(walk, keep="0%")
    with pytest.raises(UsageError):
        cull.add_pose(walk, 99.0)


def test_rotate_true_pose_is_exact_and_local(walk):
    k = 6
    sk = walk.source.skeleton
    j = sk.index("LeftArm")
    edited = E.edit_pose(walk, k, rotate={"LeftArm": (0.0, 0.0, 20.0)})
    r0, _ = sampling.local_pose(walk, walk.pose_t[k : k + 1])
    r1, _ = sampling.local_pose(edited, walk.pose_t[k : k + 1])
    assert np.degrees(quat.angle_between(r0[0, j], r1[0, j])) == pytest.approx(20.0, abs=1e-9)
    # about the joint's local Z axis, applied after the current rotation
    expected = quat.mul(r0[0, j], quat.from_euler(np.array([0.0, 0.0, 20.0]), "XYZ"))
    assert np.degrees(quat.angle_between(expected, r1[0, j])) < 1e-9
    base, out = bake(walk).channels, bake(edited).channels
    changed = np.flatnonzero(np.abs(out - base).max(axis=1) > 1e-9) * walk.frame_time
    ref = walk.refinements()
    lo = walk.pose_t[k - 1] + min(ref[k - 1].min(), 0.0)
    hi = walk.pose_t[k + 1] + max(ref[k + 1].max(), 0.0)
    assert changed.size and changed.min() > lo and changed.max() < hi


def test_edit_keeps_detail(walk):
    """The change baked(edited) ⊖ baked(original) is smooth: the detail rides along."""
    k = 6
    edited = E.edit_pose(walk, k, rotate={"LeftArm": (0.0, 0.0, 20.0), "RightUpLeg": (10.0, 0.0, 0.0)}, on="extreme")
    a, b = _rot(bake(walk)), _rot(bake(edited))
    diff = quat.log(quat.mul(quat.conj(a), b))  # (T, J, 3)
    orig = quat.log(a)
    n = max(3, int(round(0.1 / walk.frame_time)) | 1)
    kernel = np.ones(n) / n

    def high(x):
        smooth = np.apply_along_axis(lambda s: np.convolve(s, kernel, mode="same"), 0, x)
        return (x - smooth)[n:-n]

    assert np.sum(high(diff) ** 2) < 0.01 * np.sum(high(orig) ** 2)


def test_exaggerate_identity_and_inverse(walk):
    base = bake(walk).channels
    for rel in ("prev", "next", "average", "2"):
        same = E.edit_pose(walk, 5, exaggerate=1.0, relative_to=rel)
        assert np.abs(bake(same).channels - base).max() < 1e-6
    there = E.edit_pose(walk, 5, exaggerate=2.0, relative_to="prev", on="extreme")
    assert np.abs(bake(there).channels - base).max() > 1.0
    back = E.edit_pose(there, 5, exaggerate=0.5, relative_to="prev", on="extreme")
    assert np.abs(bake(back).channels - base).max() < 1e-6
    with pytest.raises(UsageError):
        E.edit_pose(walk, 5, exaggerate=2.0, relative_to="sideways")
    with pytest.raises(UsageError):
        E.edit_pose(walk, 99, exaggerate=2.0)
    with pytest.raises(UsageError):
        E.edit_pose(walk, 5, rotate={"NoSuchJoint": (0.0, 0.0, 1.0)})


def test_from_bvh_sets_the_true_pose(walk):
    m = walk.source
    values = E.values_from_motion(walk, m, 100)
    edited = E.edit_pose(walk, 6, values=values, joints=["LeftUpLeg"], subtree=True)
    r, _ = sampling.local_pose(edited, walk.pose_t[6:7])
    sk = m.skeleton
    src = m.local_rotations()[100]
    for name in ("LeftUpLeg", "LeftLeg", "LeftFoot"):
        j = sk.index(name)
        assert np.degrees(quat.angle_between(r[0, j], src[j])) < 1e-9
    other = read_bvh(mocap("bandai1_walk_normal_001.bvh"))
    with pytest.raises(UsageError):
        E.values_from_motion(walk, other, 0)


def test_retime_pose(walk):
    moved = timing.retime_pose(walk, 5, walk.pose_t[5] + 0.05)
    assert moved.pose_t[5] == pytest.approx(walk.pose_t[5] + 0.05)
    np.testing.assert_allclose(moved.refinements(), walk.refinements(), atol=1e-12)
    with pytest.raises(UsageError):
        timing.retime_pose(walk, 5, walk.pose_t[6] + 0.01)
    with pytest.raises(UsageError):
        timing.retime_pose(walk, 0, 0.1)


def _lag(orig: np.ndarray, edited: np.ndarray, f: int, max_lag: int, half: int = 2) -> float:
    """Sub-frame lag (frames) that best aligns edited(t + lag) with orig(t) around frame f."""
    T = len(orig)
    best, errs = None, []
    lags = range(-max_lag, max_lag + 1)
    for L in lags:
        idx = np.arange(f - half, f + half + 1)
        j = idx + L
        if idx.min() < 0 or j.min() < 0 or idx.max() >= T or j.max() >= T:
            errs.append(np.inf)
            continue
        errs.append(float(np.sum(quat.angle_between(orig[idx], edited[j]) ** 2)))
    errs = np.array(errs)
    i = int(np.argmin(errs))
    best = list(lags)[i]
    if 0 < i < len(errs) - 1 and np.all(np.isfinite(errs[i - 1 : i + 2])):
        a, b, c = errs[i - 1], errs[i], errs[i + 1]
        den = a - 2 * b + c
        if den > 0:
            best += 0.5 * (a - c) / den
    return best


def shifted_within_a_frame(a, b, cases, ft: float, still: float) -> tuple[int, list]:
    """How many of ``cases`` (joint j, frame f, expected shift in seconds)
    moved by their shift within one frame ``ft``, from rotations ``a`` to
    ``b`` (T, J, 4), counting only joints that turn at least ``still``
    degrees over frames f-3..f+3 (stiller ones cannot be timed).  Returns
    the hits and the cases counted."""
    counted = [(j, f, e) for j, f, e in cases if np.degrees(quat.angle_between(a[f - 3, j], a[f + 3, j])) >= still]
    hits = sum(abs(_lag(a[:, j], b[:, j], f, int(e / ft) + 6) * ft - e) <= ft for j, f, e in counted)
    return int(hits), counted


@pytest.mark.parametrize("power", [1.0, 1.5])
def test_succession_shifts_extrema_by_offset_times_depth_power(power):
    m = read_bvh(mocap("cmu_02_01_walk.bvh"))
    doc = variables.from_motion(m, np.arange(0.0, (m.n_frames - 1) * m.frame_time, 0.6))
    offset = 0.02
    out = timing.succession(doc, offset, power, joint="LeftShoulder")
    sk = m.skeleton
    depth = sk.depth_below(sk.index("LeftShoulder"))
    a, b = _rot(bake(doc)), _rot(bake(out))
    ft = m.frame_time
    cases = [
        (j, int(round(doc.pose_t[k] / ft)), offset * depth[j] ** power)
        for k in range(1, doc.n_poses - 1)
        for j in np.flatnonzero(depth > 0)
        if sk.has_rotation(j)
    ]
    hits, counted = shifted_within_a_frame(a, b, cases, ft, still=0.5)
    total = len(counted)
    assert total >= 10
    assert hits / total >= 0.8
    # joints outside the subtree and the ends of the clip are unchanged
    outside = np.flatnonzero(depth < 0)
    assert np.degrees(quat.angle_between(a[:, outside], b[:, outside])).max() < 1e-6
    assert np.degrees(quat.angle_between(a[[0, -1]], b[[0, -1]])).max() < 1e-6


def test_succession_refuses_crossing_and_clamps(walk):
    with pytest.raises(KnotOrderError):
        timing.succession(walk, 0.3, 1.0, joint="LeftShoulder")
    with staggered_warnings() as seen:
        clamped = timing.succession(walk, 0.3, 1.0, joint="LeftShoulder", clamp=True)
    assert any("closer to a neighbouring pose" in s for s in seen), seen
    assert np.abs(bake(clamped).channels[[0, -1]] - bake(walk).channels[[0, -1]]).max() < 1e-6
    with pytest.raises(UsageError):
        timing.succession(walk, 0.01, -1.0, joint="LeftShoulder")
    with pytest.raises(UsageError):
        timing.succession(walk, 0.01, 1.0, joint="Tail")


def test_randomize_is_reproducible_and_bounded(walk):
    tau = 0.02
    a = timing.randomize(walk, tau, seed=4, joints=["RightArm"], subtree=True)
    b = timing.randomize(walk, tau, seed=4, joints=["RightArm"], subtree=True)
    c = timing.randomize(walk, tau, seed=5, joints=["RightArm"], subtree=True)
    ma, aa = to_parts(a)
    mb, ab = to_parts(b)
    assert ma == mb and all(np.array_equal(aa[k], ab[k]) for k in aa)
    shift = a.refinements() - walk.refinements()
    assert np.abs(shift).max() <= tau and np.abs(shift).max() > tau / 2
    assert not np.allclose(a.refinements(), c.refinements())
    sk = walk.source.skeleton
    names = walk.variable_names
    inside = set(sk.names[j] for j in sk.subtree(sk.index("RightArm")))
    untouched = [i for i, n in enumerate(names) if n.split(".")[0] not in inside]
    assert np.abs(shift[:, untouched]).max() == 0.0
    assert np.abs(shift[[0, -1]]).max() == 0.0
    x, y = _rot(bake(walk)), _rot(bake(a))
    outside = [j for j in range(sk.n_joints) if sk.names[j] not in inside]
    assert np.degrees(quat.angle_between(x[:, outside], y[:, outside])).max() < 1e-6


def test_bake_resamples_and_splines_layer(walk):
    m30 = bake(walk, fps=30.0)
    assert m30.n_frames == int(np.floor(walk.duration * 30 + 1e-6)) + 1
    assert m30.frame_time == pytest.approx(1 / 30)
    src = walk.source.channels[::4][: m30.n_frames]
    n = min(len(src), m30.n_frames)
    # frames at multiples of 4 source frames line up (0.008333 s is not exactly 1/120)
    assert np.median(np.abs(m30.channels[:n] - src[:n])) < 1.0
    smooth = bake(walk, layers="splines")
    assert smooth.n_frames == walk.n_frames
    assert np.abs(smooth.channels - walk.source.channels).max() > 0.01
