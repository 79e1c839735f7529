"""SPEC section 9 quality bars on extracted documents of real captures."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli import quat
from staggered_cli.io.bvh import read_bvh
from staggered_cli.motion import local_rotations_from_channels, local_translations_from_channels
from staggered_cli.ops import cull, timing
from staggered_cli.ops import edit_pose as E
from staggered_cli.ops.bake import bake
from staggered_cli.ops.extract import extract
from staggered_cli.skeleton import forward_kinematics

from .conftest import mocap
from .test_ops import _lag

WALKS = ["cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu_01_01_forward_jumps.bvh"]


@pytest.fixture(scope="module", params=WALKS)
def extracted(request):
    m = read_bvh(mocap(request.param))
    return m, extract(m, source_name=request.param)


def _positions(motion):
    sk = motion.skeleton
    rot = local_rotations_from_channels(sk, motion.channels)
    tr = local_translations_from_channels(sk, motion.channels)
    return forward_kinematics(sk, rot, tr)[1]


def test_cull_to_a_quarter_keeps_the_motion(extracted):
    m, doc = extracted
    culled = cull.keep_poses(doc, cull.choose(doc, keep="25%", ignore_contacts=True))
    assert culled.n_poses <= int(np.ceil(doc.n_poses * 0.25)) + 1
    err = np.abs(_positions(bake(culled)) - _positions(m)).max()
    assert err < 1e-6 * m.figure_height()


def test_culling_keeps_contact_poses_by_default(extracted):
    m, doc = extracted
    culled = cull.keep_poses(doc, cull.choose(doc, keep="25%"))
    on_contact = cull.contact_poses(culled)
    assert on_contact.sum() >= min(cull.contact_poses(doc).sum(), 1)
    assert np.array_equal(cull.contact_poses(doc).sum(), on_contact.sum())


def test_an_edit_changes_only_its_neighbourhood(extracted):
    m, doc = extracted
    k = doc.n_poses // 2
    sk = m.skeleton
    arm = next(n for n in sk.names if "arm" in n.lower() and sk.has_rotation(sk.index(n)))
    edited = E.edit_pose(doc, k, rotate={arm: (10.0, 0.0, 15.0)}, exaggerate=1.3, relative_to="prev")
    a, b = bake(doc, ik=False).channels, bake(edited, ik=False).channels
    changed = np.flatnonzero(np.abs(a - b).max(axis=1) > 1e-9) * doc.frame_time
    ref = doc.refinements()
    lo = doc.pose_t[k - 1] + ref[k - 1].min()
    hi = doc.pose_t[k + 1] + ref[k + 1].max()
    assert changed.size
    assert changed.min() > lo - 1e-9 and changed.max() < hi + 1e-9


def test_succession_on_a_culled_walk_moves_extrema_by_s_d_power():
    m = read_bvh(mocap("cmu_02_01_walk.bvh"))
    doc = extract(m)
    doc = cull.keep_poses(doc, cull.choose(doc, keep="30%", ignore_contacts=True))
    offset, power = 0.02, 1.5
    out = timing.succession(doc, offset, power, joint="LeftShoulder")
    sk = m.skeleton
    depth = sk.depth_below(sk.index("LeftShoulder"))
    a = local_rotations_from_channels(sk, bake(doc, ik=False).channels)
    b = local_rotations_from_channels(sk, bake(out, ik=False).channels)
    ext = doc.refinements()
    names = doc.variable_names
    ft = doc.frame_time
    hits = total = 0
    for k in range(1, doc.n_poses - 1):
        for j in np.flatnonzero(depth > 0):
            if sk.names[j] not in names:
                continue
            i = names.index(sk.names[j])
            expect = offset * depth[j] ** power
            f = int(round((doc.pose_t[k] + ext[k, i]) / ft))
            if f < 4 or f > m.n_frames - 5 or np.degrees(quat.angle_between(a[f - 3, j], a[f + 3, j])) < 0.5:
                continue
            total += 1
            hits += abs(_lag(a[:, j], b[:, j], f, int(expect / ft) + 6) * ft - expect) <= ft
    assert total >= 10
    assert hits / total >= 0.8, (hits, total)
