"""Regressions found by review: each test is one bug that was fixed."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli.io.bvh import read_bvh
from staggered_cli.io.c3d import read_c3d
from staggered_cli.io.document import from_parts, to_parts
from staggered_cli.ops import cull, timing
from staggered_cli.ops.bake import bake
from staggered_cli.ops.extract import extract

from .conftest import mocap


@pytest.fixture(scope="module")
def run():
    m = read_bvh(mocap("bandai2_run_normal_001.bvh"))
    return m, extract(m)


@pytest.fixture(scope="module")
def walk():
    m = read_bvh(mocap("cmu_02_01_walk.bvh"))
    return m, extract(m)


def test_adding_a_pose_inside_a_staggered_span_makes_room(run, caplog):
    """1.1179 s lies between pose 6's editing and extreme knots of several
    variables: those refinements collapse, the motion does not change, and the
    document stays readable (it used to be written with crossing knots)."""
    m, doc = run
    with caplog.at_level("WARNING"):
        added = cull.add_pose(doc, 1.1179)
    assert "collapse to 0" in caplog.text
    assert added.n_poses == doc.n_poses + 1
    manifest, arrays = to_parts(added)
    from_parts(manifest, arrays)
    assert np.abs(bake(added, ik=False).channels - m.channels).max() < 1e-6


def test_culling_after_a_timing_edit_keeps_the_baked_motion(run):
    _, doc = run
    edited = timing.succession(doc, 0.01, 1.0, joint="UpperArm_L", clamp=True)
    before = bake(edited, ik=False).channels
    after = bake(cull.keep_poses(edited, cull.choose(edited, keep="50%")), ik=False).channels
    assert np.abs(after - before).max() < 1e-6
    moved = timing.retime_pose(doc, 5, doc.pose_t[5] + 0.02)
    before = bake(moved, ik=False).channels
    after = bake(cull.keep_poses(moved, cull.choose(moved, keep="50%")), ik=False).channels
    assert np.abs(after - before).max() < 1e-6


def test_clamp_stops_short_and_moves_only_the_chosen_poses(walk):
    _, doc = walk
    out = timing.succession(doc, -0.02, 1.5, joint="LeftShoulder", clamp=True)
    assert out.n_poses == doc.n_poses
    mask = timing.select_poses(doc, [3])
    one = timing.randomize(doc, 0.2, 0, poses=mask, clamp=True)
    changed = np.any(one.refinements() != doc.refinements(), axis=1)
    assert not changed[np.arange(doc.n_poses) != 3].any()


@pytest.mark.parametrize("name, fps", [("bandai2_run_normal_001.bvh", 30.0), ("cmu_02_01_walk.bvh", 120.0)])
def test_baking_at_the_nominal_rate_is_the_identity(name, fps):
    m = read_bvh(mocap(name))
    doc = extract(m)
    out = bake(doc, fps=fps)
    assert out.n_frames == m.n_frames
    np.testing.assert_array_equal(out.channels, m.channels)


def test_resampling_never_flips_to_the_twin_triple(run):
    m, doc = run
    for fps in (24.0, 60.0, 100.0):
        ch = bake(doc, fps=fps).channels
        # consecutive output frames are at most a source frame apart: no jump near 180 degrees
        assert np.abs(np.diff(ch[:, 3:], axis=0)).max() < 90.0


def test_resampled_c3d_markers_do_not_judder():
    m = read_c3d(mocap("c3dorg_sample01_Eb015pi_walk.c3d"))
    doc = extract(m)
    with_layer = bake(doc, fps=100.0).points
    without = bake(doc, fps=100.0, ik=False).points
    # the layer used to hold markers on the nearest source frame: a staircase
    # whose every other step was exactly zero
    for c in doc.constraints:
        m_i = m.labels.index(c.joint)
        t = np.arange(len(with_layer)) / 100.0
        inside = (t >= c.start) & (t <= c.end)
        steps = np.linalg.norm(np.diff(with_layer[inside, m_i], axis=0), axis=1)
        ref = np.linalg.norm(np.diff(without[inside, m_i], axis=0), axis=1)
        assert np.sum(steps == 0.0) <= np.sum(ref == 0.0) + 1
    assert np.nanmax(np.abs(with_layer - without)) < 5e-3 * m.figure_height()


def test_open_ended_time_ranges(walk):
    _, doc = walk
    assert cull.choose(doc, interval=(1.0, np.inf)).sum() >= 2
    assert timing.select_poses(doc, time_range=(-np.inf, 1.0)).any()


def test_contacts_move_with_a_retimed_pose(walk):
    _, doc = walk
    c = doc.constraints[len(doc.constraints) // 2]
    k = int(np.argmin(np.abs(doc.pose_t - c.start)))
    k = min(max(k, 1), doc.n_poses - 2)
    dt = 0.3 * (doc.pose_t[k + 1] - doc.pose_t[k])
    moved = timing.retime_pose(doc, k, doc.pose_t[k] + dt)
    old = {(x.joint, x.start) for x in doc.constraints}
    shifted = [x for x in moved.constraints if (x.joint, x.start) not in old]
    assert shifted and all(x.source_span != (x.start, x.end) for x in shifted)
    manifest, arrays = to_parts(moved)
    assert from_parts(manifest, arrays).constraints == moved.constraints
    # the unedited parts keep their constraints and the bake stays finite
    assert np.all(np.isfinite(bake(moved).channels))


def test_variables_that_never_move_are_not_retimed(run):
    """Bandai has constant position channels on every joint: retiming them
    changed nothing visible and could only get the edit refused."""
    _, doc = run
    out = timing.succession(doc, 0.02, 1.0, joint="Shoulder_L")
    names = doc.variable_names
    changed = np.any(out.refinements() != doc.refinements(), axis=0)
    assert not any(changed[i] for i, n in enumerate(names) if n.endswith(".position"))
    assert changed[names.index("LowerArm_L")]


def test_priorities_follow_the_poses_that_remain(walk):
    """After a cull the neighbours are farther apart: priorities are the
    paper's P(t_k)(t_{k+1} - t_{k-1}) over the poses that remain."""
    _, doc = walk
    culled = cull.keep_poses(doc, cull.choose(doc, keep="50%", ignore_contacts=True))
    P = doc.signals["P"]
    f = np.rint(culled.pose_t[1:-1] / doc.frame_time).astype(int)
    np.testing.assert_allclose(culled.priority[1:-1], P[f] * (culled.pose_t[2:] - culled.pose_t[:-2]))
    assert np.isinf(culled.priority[[0, -1]]).all()


def test_a_constraint_added_by_hand_pins_its_joint(walk, tmp_path):
    """constraints --add means 'planted here': bake holds the joint at one
    place even though no edit disturbed it (detected contacts follow the
    capture instead)."""
    from click.testing import CliRunner

    from staggered_cli.cli.main import cli
    from staggered_cli.io.document import document_bytes, parse_document, to_parts

    m, doc = walk
    c = next(x for x in doc.constraints if x.joint == "LeftFoot" and x.end - x.start > 0.3)
    # the flat-foot middle of the stance: at heel strike and heel-off the
    # ankle's mean position is beyond the leg's reach
    quarter = 0.25 * (c.end - c.start)
    middle = (round(c.start + quarter, 4), round(c.end - quarter, 4))
    path = tmp_path / "w.stag"
    path.write_bytes(document_bytes(*to_parts(doc), "npz"))
    index = doc.constraints.index(c)
    out = tmp_path / "pinned.stag"
    r = CliRunner().invoke(
        cli,
        [
            "constraints",
            str(path),
            "--remove",
            str(index),
            "--add",
            f"LeftFoot@{middle[0]}:{middle[1]}",
            "-o",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.stderr
    pinned = from_parts(*parse_document(out.read_bytes(), str(out)))
    assert any(x.pin for x in pinned.constraints)
    baked = bake(pinned)
    from staggered_cli.motion import BvhMotion

    j = m.skeleton.index("LeftFoot")
    t = doc.frame_times
    inside = (t >= middle[0]) & (t <= middle[1])
    size = m.figure_height()
    before = m.world()[1][inside, j]
    after = BvhMotion(m.skeleton, baked.channels, m.frame_time).world()[1][inside, j]
    spread = lambda p: np.linalg.norm(p - p.mean(axis=0), axis=1).max() / size  # noqa: E731
    assert spread(before) > 0.005  # the captured ankle moves
    assert spread(after) < 0.1 * spread(before)


def test_detecting_again_on_a_retimed_document_keeps_its_time(walk):
    """constraints --detect runs on the captured motion; on a document whose
    poses were retimed, the new constraints follow the retimed plants."""
    from staggered_cli.ops.constraints import redetect

    _, doc = walk
    few = cull.keep_poses(doc, cull.choose(doc, keep="6", ignore_contacts=True))
    moved = timing.retime_pose(few, 2, few.pose_t[2] + 0.15)
    again = redetect(moved, None, None, None)
    key = lambda c: (c.joint, round(c.start, 6), round(c.end, 6))  # noqa: E731
    assert sorted(map(key, again)) == sorted(map(key, moved.constraints))
