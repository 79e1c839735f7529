"""Culling and adding poses (paper section 4.2): the baked motion stays, and
priorities follow the poses that remain."""

from __future__ import annotations

import numpy as np

from staggered_cli.io.schema import from_parts, to_parts
from staggered_cli.ops import cull, timing
from staggered_cli.ops.bake import bake

from .conftest import dev_document, dev_motion, staggered_warnings


def test_adding_a_pose_inside_a_staggered_span_makes_room(bandai_run):
    """1.1179 s lies between pose 8's editing and extreme knots of several
    variables (pose 6 before the run's tempo-scaled spacing gave it 17 poses
    for 13): those refinements collapse, the motion does not change, and the
    document stays readable (it used to be written with crossing knots)."""
    m, doc = bandai_run
    with staggered_warnings() as seen:
        added = cull.add_pose(doc, 1.1179)
    assert any(s.startswith("add_time 1.12 s: pose 8") and "collapse to 0" in s for s in seen), seen
    assert added.n_poses == doc.n_poses + 1
    manifest, arrays = to_parts(added)
    from_parts(manifest, arrays)
    assert np.abs(bake(added, ik=False).channels - m.channels).max() < 1e-6


def test_culling_after_a_timing_edit_keeps_the_baked_motion(bandai_run):
    _, doc = bandai_run
    edited = timing.succession(doc, 0.01, 1.0, joint="UpperArm_L", clamp=True)
    before = bake(edited, ik=False).channels
    after = bake(cull.keep_poses(edited, cull.choose(edited, keep="50%")), ik=False).channels
    assert np.abs(after - before).max() < 1e-6
    moved = timing.retime_pose(doc, 5, doc.pose_t[5] + 0.02)
    before = bake(moved, ik=False).channels
    after = bake(cull.keep_poses(moved, cull.choose(moved, keep="50%")), ik=False).channels
    assert np.abs(after - before).max() < 1e-6


def test_open_ended_time_ranges(cmu_walk):
    _, doc = cmu_walk
    assert cull.choose(doc, interval=(1.0, np.inf)).sum() >= 2
    assert timing.select_poses(doc, time_range=(-np.inf, 1.0)).any()


def test_priorities_follow_the_poses_that_remain(cmu_walk):
    """After a cull the neighbours are farther apart: priorities are the
    paper's P(t_k)(t_{k+1} - t_{k-1}) over the poses that remain."""
    _, doc = cmu_walk
    culled = cull.keep_poses(doc, cull.choose(doc, keep="50%", ignore_contacts=True))
    P = doc.signals["P"]
    f = np.rint(culled.pose_t[1:-1] / doc.frame_time).astype(int)
    np.testing.assert_allclose(culled.priority[1:-1], P[f] * (culled.pose_t[2:] - culled.pose_t[:-2]))
    assert np.isinf(culled.priority[[0, -1]]).all()


def test_ranking_and_refitting_evaluate_the_motion_once(monkeypatch):
    """choose and keep_poses both need the base layer's motion at the frame
    times: given it (as the command gives it), they evaluate it once per
    track, and the document is the one keep_poses makes on its own, byte
    for byte."""
    from dataclasses import replace

    from staggered_cli.io.container import document_bytes

    doc = replace(dev_document("cmu_02_01_walk.bvh"))
    calls = []
    real = cull.evaluate
    monkeypatch.setattr(cull, "evaluate", lambda *a, **k: calls.append(a[0].kind) or real(*a, **k))
    motion = cull.base_motion(doc)
    assert all(not d.flags.writeable for d in motion)  # shared: read-only
    mask = cull.choose(doc, keep="25%", motion=motion)
    culled = cull.keep_poses(doc, mask, motion)
    assert calls == [tr.kind for tr in doc.tracks]
    fresh = cull.keep_poses(doc, mask)  # without it: evaluated again
    assert len(calls) == 2 * len(doc.tracks)
    assert document_bytes(*to_parts(culled), "npz") == document_bytes(*to_parts(fresh), "npz")


def test_the_motion_of_another_document_is_not_reused():
    """After ranking one document, culling an edited one refits to the edited motion."""
    _, doc = dev_motion("bandai2_run_normal_001.bvh"), dev_document("bandai2_run_normal_001.bvh")
    edited = timing.succession(doc, 0.02, 1.0, joint="UpperArm_L", clamp=True)
    mask = cull.choose(doc, keep="50%")
    culled = cull.keep_poses(edited, mask)
    assert np.abs(bake(culled, ik=False).channels - bake(edited, ik=False).channels).max() < 1e-6


def test_a_pose_added_within_half_a_frame_of_another_is_refused(bandai_run):
    """``--add-time`` refuses a time less than half a frame from a pose, not
    only the pose's exact time: 0.2 s beside a pose at 0.199992 s (120 Hz)
    used to make a second pose 8 microseconds away, which a later edit of
    either turned into a one-frame pop in the bake."""
    import pytest

    from staggered_cli.errors import UsageError

    _, doc = bandai_run
    ft, t = doc.frame_time, float(doc.pose_t[3])
    assert round(t, 2) == 0.5  # 0.6 before the run's tempo-scaled spacing
    with pytest.raises(UsageError, match=r"there is already a pose at 0\.50 s \(pose 3\)"):
        cull.add_pose(doc, t)
    for dt in (1e-5, -1e-5, 0.49 * ft, -0.49 * ft):
        with pytest.raises(UsageError, match=r"pose 3 is at 0\.50 s, less than half a frame away"):
            cull.add_pose(doc, t + dt)
    added = cull.add_pose(doc, t + 0.51 * ft)
    assert added.n_poses == doc.n_poses + 1
    assert np.min(np.diff(added.pose_t)) >= 0.5 * ft
