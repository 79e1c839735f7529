"""Contact detection details that the real clips do not pin down."""

from __future__ import annotations

import numpy as np

from staggered_cli.contacts import detect_contacts
from staggered_cli.io.bvh import read_bvh
from staggered_cli.ops import cull, timing

from .conftest import SAMPLES


def test_a_lifted_foot_turning_around_is_not_a_contact():
    """The sample marches in place: each foot rests for half of every 1.2 s
    stride and slows to a stop at the top of its lift, 20 cm up; only the
    rests are contacts."""
    m = read_bvh(SAMPLES / "march.bvh")
    found = detect_contacts(m)
    assert sorted({c.joint for c in found}) == ["LeftFoot", "RightFoot"]
    wr, wp = m.world()
    t = np.arange(m.n_frames) * m.frame_time
    for c in found:
        y = wp[(t >= c.start - 1e-9) & (t <= c.end + 1e-9), m.skeleton.index(c.joint), 1]
        assert y.max() < wp[:, m.skeleton.index(c.joint), 1].min() + 0.05 * m.figure_height()
    # four rests per foot in 4 s, each about half a stride
    for foot in ("LeftFoot", "RightFoot"):
        spans = [c.end - c.start for c in found if c.joint == foot and 0 < c.start and c.end < t[-1]]
        assert len(spans) >= 2 and all(0.5 < s < 0.9 for s in spans)


def test_detecting_again_on_a_retimed_document_keeps_its_time(cmu_walk):
    """constraints --detect runs on the captured motion; on a document whose
    poses were retimed, the new constraints follow the retimed plants."""
    from staggered_cli.ops.constraints import redetect

    _, doc = cmu_walk
    few = cull.keep_poses(doc, cull.choose(doc, keep="6", ignore_contacts=True))
    moved = timing.retime_pose(few, 2, few.pose_t[2] + 0.15)
    again = redetect(moved, None, None, None)
    key = lambda c: (c.joint, round(c.start, 6), round(c.end, 6))  # noqa: E731
    assert sorted(map(key, again)) == sorted(map(key, moved.constraints))


def test_the_up_direction_of_some_columns_is_that_of_their_copy():
    """``up_direction`` of the body's columns, measured without a copy of
    them (its median on its own copy of one coordinate), is that of the
    copied columns; the caller's points are left as they were."""
    from staggered_cli.contacts import up_direction
    from staggered_cli.skeleton import body_joints

    from .conftest import dev_motion

    for name in ("cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "games105_idle.bvh"):
        m = dev_motion(name)
        wp, h = m.world_positions(), m.figure_height()
        body = body_joints(m.skeleton)
        before = wp.tobytes()
        assert up_direction(wp, h, body).tolist() == up_direction(np.array(wp[:, body]), h).tolist()
        assert wp.tobytes() == before
    rng = np.random.default_rng(5)  # gaps, and a figure centred on the floor (the other branch)
    pts = rng.normal(size=(300, 6, 3))
    pts[rng.random((300, 6)) < 0.2] = np.nan
    cols = np.array([4, 0, 2])
    for h in (0.1, 1000.0):
        assert up_direction(pts, h, cols).tolist() == up_direction(pts[:, cols].copy(), h).tolist()
