"""Layers, transition controls and format version 2 (issue 16), on the real captures.

The quality bars: an added layer leaves the motion unchanged within 1e-9 of
the figure height; a 10° rotation at a top-layer pose gives exactly 10°
there, nothing outside that layer's neighbouring poses, and a smooth change;
removing the layer restores the motion within 1e-9.  ``--ease`` changes the
motion only within the pose's neighbouring knots; ``detail --gain 0`` is the
spline layer alone and ``--gain 1`` the identity; both survive culls.
"""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.io.container import document_bytes, parse_document
from staggered_cli.io.schema import DOCUMENT_VERSION, from_parts, to_parts
from staggered_cli.model.evaluate import evaluate
from staggered_cli.model.restructure import restructure
from staggered_cli.ops import layers
from staggered_cli.ops.bake import bake
from staggered_cli.ops.cull import choose, keep_poses
from staggered_cli.ops.edit_pose import edit_pose, joint_mask
from staggered_cli.ops.timing import succession

from .conftest import dev_document, one_line_error

BVH = "cmu_02_01_walk.bvh"
C3D = "c3dorg_sample01_Eb015pi_walk.c3d"


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


@pytest.fixture(scope="module")
def walk():
    return dev_document(BVH)  # extracted once per session (conftest), read-only


@pytest.fixture(scope="module")
def markers():
    return dev_document(C3D)


def world(doc) -> np.ndarray:
    """(T, J, 3) world joint positions of the baked motion, without the contact layer."""
    return bake(doc, ik=False).world()[1]


def height(doc) -> float:
    return float(doc.source.figure_height())


def local_rotation(doc, joint: str) -> np.ndarray:
    ti, i = doc.variable(joint)
    return evaluate(doc.tracks[ti], doc.frame_times)[:, i]


def with_layer(doc, n: int = 6):
    return layers.add_layer(doc, doc.pose_t[choose(doc, keep=str(n))])


# --- the stack -------------------------------------------------------------------


def test_an_added_layer_leaves_the_motion(walk):
    stacked = with_layer(walk)
    assert stacked.n_layers == 2 and len(stacked.poses_of(1)) == 6
    assert stacked.poses_of(1)[0] == 0.0 and stacked.poses_of(1)[-1] == walk.duration
    err = np.abs(world(stacked) - world(walk)).max() / height(walk)
    assert err < 1e-9, err


def test_ten_degrees_at_a_top_layer_pose(walk):
    stacked = with_layer(walk)
    before = local_rotation(stacked, "LeftArm")
    edited = edit_pose(stacked, 2, rotate={"LeftArm": (0.0, 0.0, 10.0)}, layer=1)
    after = local_rotation(edited, "LeftArm")
    change = np.degrees(quat.angle(quat.mul(quat.conj(before), after)))
    lt = stacked.poses_of(1)
    t = walk.frame_times
    at = int(np.argmin(np.abs(t - lt[2])))
    assert abs(t[at] - lt[2]) < 1e-9
    assert change[at] == pytest.approx(10.0, abs=1e-9)
    assert change.max() <= 10.0 + 1e-9
    outside = (t < lt[1] - 1e-9) | (t > lt[3] + 1e-9)
    assert change[outside].max() < 1e-9
    # smooth: what a 0.1 s moving average does not follow is under 1 % of the change's energy
    w = int(round(0.1 / walk.frame_time))
    avg = np.convolve(change, np.ones(w) / w, mode="same")
    inner = slice(w, -w)
    ratio = np.sum((change - avg)[inner] ** 2) / np.sum(change[inner] ** 2)
    assert ratio < 0.01, ratio
    # nothing else moved: the other joints' rotations are the same
    for joint in ("RightArm", "LeftUpLeg", "Head"):
        np.testing.assert_allclose(local_rotation(edited, joint), local_rotation(stacked, joint), atol=1e-12)
    # removing the layer restores the motion
    back = layers.remove_layer(edited, 1)
    err = np.abs(world(back) - world(walk)).max() / height(walk)
    assert err < 1e-9, err


def test_a_lower_layer_edit_is_exact_under_a_higher_one(walk):
    """With two layers, 10° at a pose of layer 1 is 10° in the whole stack,
    although layer 2 above it already turns the joint."""
    two = with_layer(with_layer(walk, 6), 5)
    t2 = two.poses_of(2)
    two = edit_pose(two, 2, rotate={"LeftArm": (20.0, 5.0, 0.0)}, layer=2)
    before = local_rotation(two, "LeftArm")
    k = 2
    edited = edit_pose(two, k, rotate={"LeftArm": (0.0, 0.0, 10.0)}, layer=1)
    after = local_rotation(edited, "LeftArm")
    change = np.degrees(quat.angle(quat.mul(quat.conj(before), after)))
    at = int(round(two.poses_of(1)[k] / walk.frame_time))
    assert change[at] == pytest.approx(10.0, abs=1e-9)
    assert len(t2) == 5


def test_a_marker_layer(markers):
    stacked = with_layer(markers, 5)
    err = np.nanmax(np.abs(bake(stacked, ik=False).points - bake(markers, ik=False).points)) / height(markers)
    assert err < 1e-9, err
    label = markers.target_names[3]
    edited = edit_pose(stacked, 2, translate={label: (0.0, 0.0, 25.0)}, layer=1)
    ti, i = edited.variable(label)
    t = markers.frame_times
    move = evaluate(edited.tracks[ti], t)[:, i] - evaluate(stacked.tracks[ti], t)[:, i]
    lt = stacked.poses_of(1)
    at = int(round(lt[2] / markers.frame_time))
    np.testing.assert_allclose(move[at], [0.0, 0.0, 25.0], atol=1e-9)
    outside = (t < lt[1] - 1e-9) | (t > lt[3] + 1e-9)
    assert np.abs(move[outside]).max() < 1e-9


def test_layers_survive_base_edits(walk):
    """Cull and succession act on the base layer; the layer above is kept as it is."""
    edited = edit_pose(with_layer(walk), 2, rotate={"LeftArm": (0.0, 0.0, 10.0)}, layer=1)
    culled = keep_poses(edited, choose(edited, keep="50%"))
    assert culled.n_layers == 2
    err = np.abs(world(culled) - world(edited)).max() / height(walk)
    assert err < 1e-6, err
    for a, b in zip(culled.tracks, edited.tracks, strict=True):
        np.testing.assert_array_equal(a.layers[1].knots.v, b.layers[1].knots.v)
    moved = succession(culled, 0.03, 1.5, joint="LeftShoulder", clamp=True)
    assert moved.n_layers == 2
    np.testing.assert_array_equal(moved.tracks[1].layers[1].knots.v, culled.tracks[1].layers[1].knots.v)


# --- transition controls ------------------------------------------------------------


def _changed_span(doc, new, k):
    """Times where the baked world positions differ, and pose k's neighbouring knot span."""
    diff = np.abs(world(new) - world(doc)).max(axis=(1, 2))
    t = doc.frame_times
    lo = doc.pose_t[k - 1] + min(0.0, float(np.nanmin(doc.refinements()[k - 1])))
    hi = doc.pose_t[k + 1] + max(0.0, float(np.nanmax(doc.refinements()[k + 1])))
    return diff, t, lo, hi


@pytest.mark.parametrize("x", [0.0, 2.0])
def test_ease_is_local(walk, x):
    k = walk.n_poses // 2
    eased = layers.ease(walk, k, x)
    diff, t, lo, hi = _changed_span(walk, eased, k)
    assert diff.max() > 1e-3 * height(walk)  # it did something
    outside = (t < lo - 1e-9) | (t > hi + 1e-9)
    assert diff[outside].max() < 1e-9 * height(walk)


def test_ease_one_is_the_identity_and_zero_is_linear(walk):
    k = walk.n_poses // 2
    same = layers.ease(walk, k, 1.0)
    for a, b in zip(same.tracks, walk.tracks, strict=True):
        np.testing.assert_allclose(a.tan_a, b.tan_a, atol=1e-15)
    flat = layers.ease(walk, k, 0.0)
    tr = flat.tracks[1]
    i = tr.names.index("LeftArm")
    sl = tr.knot_slice(i)
    kt, kv = tr.knot_t[sl], tr.knot_v[sl]
    j = int(np.flatnonzero(tr.knot_pose[sl] == k)[0])
    mid = 0.5 * (kt[j] + kt[j + 1])
    spline = evaluate(tr, np.array([mid]), "splines")[0, i]
    np.testing.assert_allclose(quat.angle_between(spline, quat.slerp(kv[j], kv[j + 1], 0.5)), 0.0, atol=1e-9)


def test_ease_survives_a_cull(walk):
    """A cull that removes poses away from the eased one keeps its segments' controls exactly."""
    k = walk.n_poses // 2
    eased = layers.ease(walk, k, 2.5)
    mask = np.ones(walk.n_poses, dtype=bool)
    mask[[2, 4, walk.n_poses - 3]] = False  # far from pose k
    culled = keep_poses(eased, mask)
    new_k = int(np.sum(mask[:k]))
    for a, b in zip(culled.tracks, eased.tracks, strict=True):
        first_a = np.flatnonzero((a.knot_pose == new_k) & ~a.knot_editing)
        first_b = np.flatnonzero((b.knot_pose == k) & ~b.knot_editing)
        seg_a = first_a - np.searchsorted(a.knot_ptr, first_a, side="right") + 1
        seg_b = first_b - np.searchsorted(b.knot_ptr, first_b, side="right") + 1
        np.testing.assert_array_equal(a.tan_a[seg_a], b.tan_a[seg_b])
        np.testing.assert_array_equal(a.tan_b[seg_a - 1], b.tan_b[seg_b - 1])
    err = np.abs(world(culled) - world(eased)).max() / height(walk)
    assert err < 1e-6, err


def test_detail_gain(walk):
    none = layers.detail(walk, 0.0)
    splines = bake(walk, layers="splines").world()[1]
    err = np.abs(world(none) - splines).max() / height(walk)
    assert err < 1e-6, err
    same = layers.detail(walk, 1.0)
    for a, b in zip(same.tracks, walk.tracks, strict=True):
        np.testing.assert_array_equal(a.samp_d, b.samp_d)
    # half the detail: half way between, roughly, and kept through a cull
    half = layers.detail(walk, 0.5)
    culled = keep_poses(half, choose(half, keep="50%"))
    err = np.abs(world(culled) - world(half)).max() / height(walk)
    assert err < 1e-6, err


def test_detail_on_part_of_the_body_and_time(walk):
    masks = joint_mask(walk, ["LeftArm"], True)
    span = (1.0, 2.0)
    soft = layers.detail(walk, 0.0, masks=masks, time_range=span)
    t = walk.frame_times
    for name in ("LeftArm", "LeftForeArm"):
        d = np.degrees(quat.angle_between(local_rotation(soft, name), local_rotation(walk, name)))
        assert d[(t < span[0]) | (t > span[1])].max() < 1e-9
        assert d[(t > 1.2) & (t < 1.8)].max() > 1e-3
    for name in ("RightArm", "Hips", "LeftUpLeg"):
        np.testing.assert_array_equal(local_rotation(soft, name), local_rotation(walk, name))


# --- the document format -------------------------------------------------------------


def test_version_3_round_trip_and_version_1_read(walk, caplog):
    edited = edit_pose(with_layer(walk), 2, rotate={"LeftArm": (0.0, 0.0, 10.0)}, layer=1)
    manifest, arrays = to_parts(edited)
    assert manifest["version"] == DOCUMENT_VERSION == 3 and manifest["layers"] == 2
    back = from_parts(*parse_document(document_bytes(manifest, arrays, "npz"), "test"))
    assert back.n_layers == 2
    np.testing.assert_array_equal(world(back), world(edited))
    # a version 1 document: one layer, arrays named track{n}.{key}
    m1, a1 = to_parts(walk)
    m1 = {k: v for k, v in m1.items() if k not in ("layers", "pose_parts", "layer_pose_parts")} | {"version": 1}
    a1 = {k.replace(".layer0.", "."): v for k, v in a1.items()}
    with caplog.at_level(logging.INFO, logger="staggered_cli"):
        old = from_parts(*parse_document(document_bytes(m1, a1, "json"), "old"))
    assert old.n_layers == 1
    np.testing.assert_array_equal(world(old), world(walk))
    assert [r.message for r in caplog.records if "version 1" in r.message] == [
        "document format version 1: converted to version 3 (one layer, every pose whole-body) on reading"
    ]


# --- the commands ----------------------------------------------------------------


@pytest.fixture(scope="module")
def walk_file(walk, tmp_path_factory):
    path = tmp_path_factory.mktemp("layers") / "walk.stag"
    path.write_bytes(document_bytes(*to_parts(walk), "npz"))
    return path


def test_layer_commands(walk_file, tmp_path):
    added = tmp_path / "added.stag"
    r = run(["layer", str(walk_file), "--add", "--times", "0.5,1.25,2", "-o", str(added)])
    assert r.exit_code == 0, r.stderr
    r = run(["edit-pose", str(added), "--layer", "1", "--pose", "2", "--rotate", "LeftArm=0,0,10", "-o", "-"])
    assert r.exit_code == 0, r.stderr
    info = run(["info", "-", "--json"], input=r.stdout_bytes)
    assert info.exit_code == 0, info.stderr
    summary = json.loads(info.stdout)
    assert len(summary["layers"]) == 2
    assert [p["time"] for p in summary["layers"][1]["poses"]] == pytest.approx(
        [0.0, 0.5, 1.25, 2.0, round(summary["frames"] * summary["frame_time"] - summary["frame_time"], 9)]
    )
    listed = run(["layer", "-", "--list"], input=r.stdout_bytes)
    assert listed.exit_code == 0 and "10°" in listed.stdout, listed.stdout
    removed = run(["layer", "-", "--remove", "1", "-o", "-"], input=r.stdout_bytes)
    assert removed.exit_code == 0, removed.stderr
    back = from_parts(*parse_document(removed.stdout_bytes, "test"))
    orig = from_parts(*parse_document(walk_file.read_bytes(), "test"))
    assert np.abs(world(back) - world(orig)).max() < 1e-9 * height(orig)
    r = run(["detail", str(walk_file), "--gain", "0.5", "--joints", "LeftArm", "--subtree", "-o", "-"])
    assert r.exit_code == 0, r.stderr
    r = run(["edit-pose", str(walk_file), "--pose", "3", "--ease", "0", "-o", "-"])
    assert r.exit_code == 0, r.stderr


@pytest.mark.parametrize(
    "args, needles",
    [
        (["layer", "{doc}", "--remove", "1", "-o", "-"], ["only its base layer"]),
        (["layer", "{doc}", "--add", "-o", "-"], ["--keep N or --times"]),
        (["layer", "{doc}", "--add", "--times", "0.5,99", "-o", "-"], ["--times", "outside the clip"]),
        (["layer", "{doc}", "--add", "--remove", "1", "-o", "-"], ["one of --add, --remove or --list"]),
        (["edit-pose", "{doc}", "--layer", "1", "--pose", "1", "--rotate", "LeftArm=0,0,1", "-o", "-"], ["--layer"]),
        (["edit-pose", "{doc}", "--pose", "1", "--ease", "-1", "-o", "-"], ["--ease"]),
        (
            ["edit-pose", "{doc}", "--pose", "1", "--rotate", "LeftArm=0,0,1", "--joints", "Head", "-o", "-"],
            ["--joints"],
        ),
        (["detail", "{doc}", "--gain", "11", "-o", "-"], ["--gain"]),
        (["detail", "{doc}", "--gain", "0.5", "--time", "50:60", "-o", "-"], ["outside the clip"]),
    ],
)
def test_layer_errors(walk_file, args, needles):
    result = run([a.replace("{doc}", str(walk_file)) for a in args])
    one_line_error(result, 2, *needles)


def test_restructure_refits_only_what_changed(walk):
    """A cull keeps every segment whose two knots it keeps: their controls and detail are the same numbers."""
    tr = walk.tracks[1]
    mask = np.ones(walk.n_poses, dtype=bool)
    mask[walk.n_poses // 2] = False
    new_index = np.cumsum(mask) - 1
    knots = tr.knots.subset(mask[tr.knot_pose], new_index[tr.knot_pose])
    new = restructure(tr, knots, frame_t=walk.frame_times)
    kept = tr.knot_pose != walk.n_poses // 2
    # every segment away from the removed pose is the old one
    same = 0
    for i in range(tr.n_vars):
        old_sl, new_sl = tr.knot_slice(i), new.knot_slice(i)
        n_old = old_sl.stop - old_sl.start
        for j in range(n_old - 1):
            g = old_sl.start + j
            if kept[g] and kept[g + 1]:
                nj = int(np.sum(kept[old_sl.start : g])) + new_sl.start
                np.testing.assert_array_equal(new.tan_a[nj - i], tr.tan_a[g - i])
                same += 1
    assert same > 0.8 * (len(tr.knot_t) - tr.n_vars)


def test_export_poses_says_it_exports_the_base_layer(walk_file, tmp_path):
    added = tmp_path / "added.stag"
    assert run(["layer", str(walk_file), "--add", "--keep", "4", "-o", str(added)]).exit_code == 0
    r = run(["export-poses", str(added), "-o", str(tmp_path / "poses.bvh")])
    assert r.exit_code == 0, r.stderr
    assert "export-poses works on the base layer's poses; the layer above it stays as it is" in r.stderr
    plain = run(["export-poses", str(walk_file), "-o", str(tmp_path / "plain.bvh")])
    assert plain.exit_code == 0 and "layer" not in plain.stderr


def test_displacement_samples_out_of_order_are_refused(walk):
    manifest, arrays = to_parts(walk)
    key = "track1.layer0.samp_s"
    s = arrays[key].copy()
    s[[10, 11]] = s[[11, 10]]
    arrays = {**arrays, key: s}
    with pytest.raises(Exception, match="samples are not in order"):
        from_parts(manifest, arrays)


def test_ease_and_detail_survive_a_retime(walk):
    """A succession down the left arm keeps the eased segments and the
    softened detail of every other variable to the bit."""
    k = walk.n_poses // 2
    edited = layers.detail(layers.ease(walk, k, 2.0), 0.5)
    moved = succession(edited, 0.03, 1.5, joint="LeftShoulder", clamp=True)
    before, after = edited.tracks[1], moved.tracks[1]
    arm = {"LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand", "LeftFingerBase", "LeftHandIndex1", "LThumb"}
    others = [i for i, n in enumerate(before.names) if n not in arm]
    assert len(others) > 20
    for i in others:
        a, b = before.knot_slice(i), after.knot_slice(i)
        np.testing.assert_array_equal(after.knot_t[b], before.knot_t[a])
        sa = slice(a.start - i, a.stop - i - 1)  # the variable's segments
        sb = slice(b.start - i, b.stop - i - 1)
        np.testing.assert_array_equal(after.tan_a[sb], before.tan_a[sa])
        np.testing.assert_array_equal(after.tan_b[sb], before.tan_b[sa])
        np.testing.assert_array_equal(after.samp_d[after.samples(i)], before.samp_d[before.samples(i)])
    # and the arm's retiming changed something
    i = before.names.index("LeftForeArm")
    assert not np.array_equal(after.knot_t[after.knot_slice(i)], before.knot_t[before.knot_slice(i)])


def test_a_layer_pose_moves_with_its_offset(walk_file, tmp_path):
    added = tmp_path / "added.stag"
    assert run(["layer", str(walk_file), "--add", "--times", "0.5,1.25,2", "-o", str(added)]).exit_code == 0
    r = run(["edit-pose", str(added), "--layer", "1", "--pose", "2", "--rotate", "LeftArm=0,0,10", "--time", "1.4"])
    assert r.exit_code == 0, r.stderr
    doc = from_parts(*parse_document(r.stdout_bytes, "test"))
    assert doc.poses_of(1)[2] == pytest.approx(1.4) and doc.poses_of(1)[1] == pytest.approx(0.5)
    ti, i = doc.variable("LeftArm")
    lay = doc.tracks[ti].layers[1]
    mine = np.flatnonzero((lay.knots.var == i) & (lay.knots.pose == 2))
    assert lay.knots.t[mine] == pytest.approx([1.4])
    assert np.degrees(quat.angle(lay.knots.v[mine]))[0] == pytest.approx(10.0)
    # the base layer's poses did not move
    np.testing.assert_array_equal(doc.pose_t, from_parts(*parse_document(walk_file.read_bytes(), "w")).pose_t)
    one_line_error(
        run(["edit-pose", str(added), "--layer", "1", "--pose", "0", "--time", "0.1"]),
        2,
        "first and last pose of layer 1",
    )
    one_line_error(
        run(["edit-pose", str(added), "--layer", "1", "--pose", "2", "--time", "2.5"]),
        2,
        "pose 2 of layer 1 can move only between its neighbours",
    )
    one_line_error(
        run(["edit-pose", str(added), "--layer", "1", "--pose", "9", "--time", "1"]), 2, "layer 1 has poses 0 to 4"
    )
