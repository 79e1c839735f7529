"""The poses as handles (issue 13), measured on every dev BVH file: one pose
per cluster of coordinated events, a sparse layer at least as good as evenly
spaced poses, refinements that earn their keep, honest culling."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from staggered_cli.model.sampling import local_pose
from staggered_cli.model.variables import from_motion
from staggered_cli.ops import cull, timing
from staggered_cli.ops.extract import contact_clusters, extract
from staggered_cli.skeleton import forward_kinematics

from .conftest import BVH_FILES, dev_bvh_files, dev_document, dev_motion, staggered_warnings

TPOSE = ("cmu_01_01_forward_jumps.bvh", "cmu_115_06_pick_up_box.bvh")
WALKS = ("cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu3dsmax_131_02_start_walk_stop.bvh")


def _motion(name: str):
    return dev_motion(name)  # once per session (conftest)


def _doc(name: str):
    return dev_document(name)


@functools.cache
def _culled(name: str, keep: str):
    d = _doc(name)
    return cull.keep_poses(d, cull.choose(d, keep=keep))


def _spline_error(doc) -> float:
    """Mean world joint position error of the spline layer alone, % of figure height."""
    m = doc.source
    rot, tr = local_pose(doc, doc.frame_times, "splines")
    pos = forward_kinematics(m.skeleton, rot, tr)[1]
    return float(np.linalg.norm(pos - m.world()[1], axis=-1).mean() / m.figure_height() * 100)


def _even(name: str, n: int):
    m = _motion(name)
    f = np.unique(np.round(np.linspace(0, m.n_frames - 1, n)).astype(int))
    return from_motion(m, f * float(m.frame_time))


@functools.cache
def _ratios(keep: str | None) -> dict[str, float]:
    out = {}
    for name in BVH_FILES:
        d = _doc(name) if keep is None else _culled(name, keep)
        out[name] = _spline_error(d) / _spline_error(_even(name, d.n_poses))
    return out


@pytest.mark.parametrize("keep", [None, "25%"])
def test_the_sparse_layer_is_at_least_as_good_as_even_spacing(keep):
    """Geometric mean of extracted / even <= 0.85 over the dev BVH files, no
    file above 1.10 (issue 34's bars), at the candidate count and after cull
    --keep 25% (measured 0.767 and 1.068 (bandai1_bow: a limb's swing with
    no pose near draws a pose as a contact change does; 0.756 and 1.061
    without), 0.794 and 1.009 (bandai2_run); 0.780 and 1.100, 0.782 and
    1.000 while a segment with one
    inner sample kept straight controls; before the limbs' knots went on
    their own extremes 0.793 and 1.107, 0.841; before the root's: 0.825 and
    1.234)."""
    if len(BVH_FILES) < 10:
        pytest.skip("needs the 10 dev BVH files")
    r = _ratios(keep)
    gm = float(np.exp(np.mean(np.log(list(r.values())))))
    assert gm <= 0.85, (gm, r)
    assert max(r.values()) <= 1.10, r


def test_refinements_earn_their_keep():
    """At the same pose times, dropping the refinements is worse on balance."""
    if len(BVH_FILES) < 10:
        pytest.skip("needs the 10 dev BVH files")
    ratios = []
    for name in BVH_FILES:
        d = _doc(name)
        ratios.append(_spline_error(from_motion(_motion(name), d.pose_t)) / _spline_error(d))
    assert np.exp(np.mean(np.log(ratios))) >= 1.0, ratios
    # and they are there: a staggered pose is not an even one
    refined = [np.mean(_doc(n).refinements()[1:-1] != 0) for n in BVH_FILES if _doc(n).n_poses > 2]
    assert np.mean(refined) > 0.05 and np.median(refined) > 0.05, refined


@pytest.mark.parametrize("name", BVH_FILES)
def test_poses_are_min_spacing_apart(name):
    d = _doc(name)
    ft = d.frame_time
    gaps = np.diff(d.pose_t)
    if name in TPOSE:  # the pose right after the T-pose frame
        assert abs(d.pose_t[1] - ft) < 1e-9
        gaps = gaps[1:]
    assert gaps.min() >= 0.1 - 0.5 * ft - 1e-9, gaps.min()


def test_min_spacing_is_an_option():
    d = extract(_motion("cmu_02_01_walk.bvh"), min_spacing=0.3)
    assert np.diff(d.pose_t).min() >= 0.3 - 0.5 * d.frame_time
    assert d.parameters["min_spacing"] == 0.3


@pytest.mark.parametrize("name", TPOSE)
def test_a_pose_follows_the_tpose_frame(name):
    """Before, nothing followed the T-pose: 56 % of the height off at frame 1."""
    d = _doc(name)
    m = _motion(name)
    rot, tr = local_pose(d, d.frame_times[:5], "splines")
    err = np.linalg.norm(forward_kinematics(m.skeleton, rot, tr)[1] - m.world()[1][:5], axis=-1)
    assert err.max() / m.figure_height() < 0.01


def test_walks_are_sparse_and_idle_sparser():
    rates = {n: _doc(n).n_poses / _doc(n).duration for n in WALKS}
    assert all(3.0 <= r <= 8.0 for r in rates.values()), rates
    idle = _doc("games105_idle.bvh")
    assert idle.n_poses / idle.duration <= 0.5 * min(rates.values())


def test_contact_changes_have_a_pose_nearby():
    """At least 80 % of the contact changes have a pose within 0.075 s, on every walk and overall."""
    hit = total = 0
    for name in dev_bvh_files():
        d = _doc(name)
        changes = [t for c in d.constraints for t in (c.start, c.end) if 0 < t < d.duration - 1e-9]
        near = [np.min(np.abs(d.pose_t - t)) <= 0.075 + 1e-9 for t in changes]
        hit, total = hit + sum(near), total + len(near)
        if name in WALKS:
            assert np.mean(near) >= 0.8, (name, np.mean(near))
    assert total > 500 and hit / total >= 0.8


def test_a_planted_legs_knots_land_on_its_contact_change():
    """Events inside one cluster become refinements: where a pose has a
    contact change of one leg within its refinement window, that leg's knots
    (hip down to the foot) lie on the change."""
    d = _doc("cmu_02_01_walk.bvh")
    names = d.variable_names
    ext = d.pose_t[:, None] + d.refinements()
    leg = [t for c in d.constraints if c.joint in ("LeftFoot", "LeftToeBase") for t in (c.start, c.end)]
    checked = 0
    for t in leg:
        k = int(np.argmin(np.abs(d.pose_t - t)))
        if k in (0, d.n_poses - 1) or abs(d.pose_t[k] - t) < 1e-9 or abs(d.pose_t[k] - t) > 0.075:
            continue
        for j in ("LeftUpLeg", "LeftLeg", "LeftFoot"):
            e = ext[k, names.index(j)]
            assert abs(e - d.pose_t[k]) < 1e-9 or np.min(np.abs(np.array(leg) - e)) < 1e-6, (k, j, e)
        checked += 1
    assert checked >= 3


def test_contact_clusters_cover_each_change_once():
    b = np.array([3, 4, 10, 11, 12, 13, 14, 30])
    clusters = contact_clusters(b, 2, 40)
    # [3, 4], [10..14] and [30]: a pose on any frame of a cluster covers its changes
    assert [c.tolist() for c in clusters] == [[2, 3, 4, 5], [12], [28, 29, 30, 31, 32]]


@pytest.mark.parametrize("name", BVH_FILES)
def test_cull_keep_n_gives_exactly_n(name):
    d = _doc(name)
    for n in sorted({min(3, d.n_poses), max(2, d.n_poses // 3), d.n_poses}):
        assert cull.choose(d, keep=str(n)).sum() == n
    for pct in ("10%", "25%", "30%", "50%"):
        want = max(2, int(np.floor(d.n_poses * float(pct[:-1]) / 100 + 0.5)))
        assert cull.choose(d, keep=pct).sum() == want


def test_cull_says_when_it_cannot_keep_what_was_asked():
    d = _doc("cmu_02_01_walk.bvh")
    with staggered_warnings() as seen:
        mask = cull.choose(d, keep=str(d.n_poses + 5))
    assert mask.all()
    assert len(seen) == 1 and "only" in seen[0] and seen[0].startswith("keep ")


def test_interval_and_select_give_exactly_those_poses():
    d = _doc("bandai1_walk_normal_001.bvh")
    assert d.constraints
    mask = cull.choose(d, select=[0, 3, 5, d.n_poses - 1])
    assert np.flatnonzero(mask).tolist() == [0, 3, 5, d.n_poses - 1]
    a, b = d.pose_t[4] - 1e-6, d.pose_t[8] + 1e-6
    mask = cull.choose(d, interval=(a, b))
    assert np.flatnonzero(mask).tolist() == [0, 4, 5, 6, 7, 8, d.n_poses - 1]


def test_contact_poses_take_precedence_inside_the_count():
    """--keep prefers poses on contact changes (they are kept over the others
    unless dropping them saves a lot of misfit), never beyond the count."""
    for name in WALKS:
        d = _doc(name)
        on = cull.contact_poses(d)
        n = max(3, d.n_poses // 3)
        kept = cull.choose(d, keep=str(n))
        plain = cull.choose(d, keep=str(n), ignore_contacts=True)
        assert kept.sum() == plain.sum() == n
        assert (kept & on).sum() >= (plain & on).sum()
    # the paper's priority is there too, with the same budget
    assert cull.choose(d, keep=str(n), by="paper").sum() == n


def test_culling_by_error_keeps_a_better_layer_than_the_papers_priority():
    errs = {by: [] for by in ("error", "paper")}
    for name in ("cmu_02_01_walk.bvh", "bandai2_run_normal_001.bvh", "cmu_05_06_modern_dance.bvh"):
        d = _doc(name)
        for by in errs:
            errs[by].append(_spline_error(cull.keep_poses(d, cull.choose(d, keep="25%", by=by))))
    assert np.mean(errs["error"]) < np.mean(errs["paper"]), errs


def test_readme_succession_works_after_culling_on_every_skeleton():
    """cull --keep 30% | succession --offset 0.03 --power 1.5 down the left
    shoulder, without --clamp, on every dev skeleton; the far-knot warning is
    at most one line per command."""
    for name in BVH_FILES:
        m = _motion(name)
        shoulder = next(
            n for n in m.skeleton.names if "shoulder" in n.lower() and (n.lower().startswith("l") or n.endswith("_L"))
        )
        c = _culled(name, "30%")
        with staggered_warnings() as seen:
            out = timing.succession(c, 0.03, 1.5, joint=shoulder)
        assert out.n_poses == c.n_poses
        assert len([s for s in seen if "neighbouring pose" in s]) <= 1
