"""SPEC section 9 quality bars on extracted documents of real captures."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli.io.bvh import read_bvh
from staggered_cli.motion import local_rotations_from_channels, local_translations_from_channels
from staggered_cli.ops import cull, timing
from staggered_cli.ops import edit_pose as E
from staggered_cli.ops.bake import bake
from staggered_cli.ops.extract import extract
from staggered_cli.skeleton import body_joints, forward_kinematics

from .conftest import dev_document, dev_motion, mocap
from .test_ops import shifted_within_a_frame

WALKS = ["cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu_01_01_forward_jumps.bvh"]


@pytest.fixture(scope="module", params=WALKS)
def extracted(request):
    return dev_motion(request.param), dev_document(request.param)  # once per session (conftest)


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


def test_culling_prefers_contact_poses_within_the_count(extracted):
    m, doc = extracted
    n = int(np.floor(0.25 * doc.n_poses + 0.5))
    kept = cull.choose(doc, keep="25%")
    plain = cull.choose(doc, keep="25%", ignore_contacts=True)
    assert kept.sum() == plain.sum() == n
    on = cull.contact_poses(doc)
    assert (kept & on).sum() >= (plain & on).sum()
    assert (kept & on).sum() >= min(on.sum(), n - 2) // 2


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
    cases = []
    for k in range(1, doc.n_poses - 1):
        for j in np.flatnonzero(depth > 0):
            if sk.names[j] not in names:
                continue
            f = int(round((doc.pose_t[k] + ext[k, names.index(sk.names[j])]) / ft))
            if 4 <= f <= m.n_frames - 5:
                cases.append((j, f, offset * depth[j] ** power))
    hits, counted = shifted_within_a_frame(a, b, cases, ft, still=0.5)
    total = len(counted)
    assert total >= 10
    assert hits / total >= 0.8, (hits, total)


@pytest.mark.parametrize("name", ["cmu_02_01_walk.bvh", "bandai2_run_normal_001.bvh"])
def test_contact_layer_keeps_planted_feet_after_moving_the_root(name):
    """edit-pose --translate <root>=5 % of the height on poses inside contacts:
    without the layer the foot slides by about the edit; with it the foot
    follows its captured path (slide measured against the source, after
    removing the constant offset the edit gives the whole plant)."""
    m = read_bvh(mocap(name))
    doc = extract(m)
    sk = m.skeleton
    size = m.figure_height()
    root = sk.names[body_joints(sk)[0]]  # the moving root (Hips, not Bandai's static joint_Root)
    t = np.arange(m.n_frames) * m.frame_time
    source = _positions(m)
    slides = {False: [], True: []}
    for c in doc.constraints:
        k = int(np.argmin(np.abs(doc.pose_t - 0.5 * (c.start + c.end))))
        if not c.start < doc.pose_t[k] < c.end or k in (0, doc.n_poses - 1):
            continue
        edited = E.edit_pose(doc, k, translate={root: (0.05 * size, 0.0, 0.0)})
        inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
        j = sk.index(c.joint)
        for ik in (False, True):
            d = _positions(bake(edited, ik=ik))[inside, j] - source[inside, j]
            slides[ik].append(np.linalg.norm(d - d.mean(axis=0), axis=1).max() / size)
        if len(slides[True]) >= 4:
            break
    assert len(slides[True]) >= 3
    assert np.mean(slides[False]) > 0.01  # about the edit
    assert np.mean(slides[True]) < 0.0025
    assert np.max(slides[True]) < 0.005
