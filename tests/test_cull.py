"""Culling and adding poses (paper section 4.2): the baked motion stays, and
priorities follow the poses that remain."""

from __future__ import annotations

import numpy as np

from staggered_cli.io.document import from_parts, to_parts
from staggered_cli.ops import cull, timing
from staggered_cli.ops.bake import bake


def test_adding_a_pose_inside_a_staggered_span_makes_room(bandai_run, caplog):
    """1.1179 s lies between pose 6's editing and extreme knots of several
    variables: those refinements collapse, the motion does not change, and the
    document stays readable (it used to be written with crossing knots)."""
    m, doc = bandai_run
    with caplog.at_level("WARNING"):
        added = cull.add_pose(doc, 1.1179)
    assert "collapse to 0" in caplog.text
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
