"""Contact detection details that the real clips do not pin down."""

from __future__ import annotations

import json
import warnings

import numpy as np

from staggered_cli.contacts.detect import detect_contacts
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
    from staggered_cli.contacts.detect import up_direction
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


def _cli(args, data=None):
    from click.testing import CliRunner

    from staggered_cli.cli.main import cli

    return CliRunner().invoke(cli, args, input=data)


def _warnings(result) -> list[str]:
    return [ln for ln in result.stderr.splitlines() if ln.startswith("staggered: WARNING:")]


def test_contact_joints_that_never_rest_are_named_in_one_line(tmp_path):
    """--contact-joints naming joints that never come to rest used to give
    no constraint and no word (also with -v).  On the Bandai run the hands
    never rest; on the CMU walk the head never does while the left foot has
    its three plants; on the BTS walk neither the pelvis (r asis) nor c7
    rest, its heel does.  A list that all rest stays silent."""
    from .conftest import mocap

    cases = [
        ("bandai2_run_normal_001.bvh", "Hand_L,Hand_R", "no contact on Hand_L, Hand_R (all 2 named)"),
        ("cmu_02_01_walk.bvh", "Head,LeftFoot", "no contact on Head (1 of the 2 named)"),
        ("ezc3d_BTS_walk_gaps.c3d", "r asis,r heel,c7", "no contact on r asis, c7 (2 of the 3 named)"),
        ("cmu_02_01_walk.bvh", "LeftFoot,RightToeBase", None),
    ]
    for name, joints, expected in cases:
        out = tmp_path / "doc.npz"
        r = _cli(["-v", "extract", str(mocap(name)), "--contact-joints", joints, "-o", str(out), "--force"])
        assert r.exit_code == 0, r.stderr
        lines = _warnings(r)
        if expected is None:
            assert lines == [], lines
            continue
        assert len(lines) == 1 and expected in lines[0] and "3 % of the figure height for 0.1 s" in lines[0], lines
        # the joints that rest have their constraints, the others none
        listed = _cli(["constraints", str(out), "--json"])
        joints_with = {c["joint"] for c in json.loads(listed.stdout)["constraints"]}
        named = joints.split(",")
        idle = expected.split("no contact on ")[1].split(" (")[0].split(", ")
        assert joints_with == set(named) - set(idle)


def test_a_detection_that_finds_nothing_says_what_it_removed_and_kept(tmp_path):
    """constraints --detect with a tolerance nothing meets: the feet's
    constraints go (as they did, silently), the one a user added on a hand
    stays, and one line says both; naming a joint that never rests keeps
    the feet's constraints, and the line says that too."""
    from .conftest import cli_extract

    doc = tmp_path / "walk.npz"
    doc.write_bytes(cli_extract("cmu_02_01_walk.bvh"))
    with_hand = tmp_path / "hand.npz"
    assert _cli(["constraints", str(doc), "--add", "LeftHand@0.5:0.7", "-o", str(with_hand)]).exit_code == 0
    n_feet = len(json.loads(_cli(["constraints", str(doc), "--json"]).stdout)["constraints"])
    assert n_feet >= 8

    out = tmp_path / "out.npz"
    r = _cli(["constraints", str(with_hand), "--detect", "--contact-tolerance", "0.001", "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    lines = _warnings(r)
    assert len(lines) == 1, lines
    assert "found no contact on LeftFoot, LeftToeBase, RightFoot, RightToeBase" in lines[0]
    assert f"removed the {n_feet} constraints they had, kept the 1 on other joints" in lines[0]
    rows = json.loads(_cli(["constraints", str(out), "--json"]).stdout)["constraints"]
    assert [c["joint"] for c in rows] == ["LeftHand"]

    r = _cli(["constraints", str(with_hand), "--detect", "--contact-joints", "Head", "-o", str(out), "--force"])
    lines = _warnings(r)
    assert len(lines) == 1 and "found no contact on Head" in lines[0], lines
    assert f"there were none on them, kept the {n_feet + 1} on other joints" in lines[0]
    assert len(json.loads(_cli(["constraints", str(out), "--json"]).stdout)["constraints"]) == n_feet + 1

    # a detection that finds something, on the default joints, says nothing
    r = _cli(["constraints", str(with_hand), "--detect", "-o", str(out), "--force"])
    assert r.exit_code == 0 and _warnings(r) == [], r.stderr


def _with_box(m, labels, carrier, spot, resting=0.6):
    """The marker clip ``m`` with a box: 4 markers (``labels``) on the
    corners of its base, a rigid set 0.25 x 0.18 figure heights, resting on
    the floor at ``spot`` (figure heights beside the figure's start, across
    its up axis) for the first ``resting`` share of the frames the figure
    (its ``carrier`` markers) is seen in, then carried
    0.1 figure heights under the mean of the ``carrier`` markers (the hands,
    or the pelvis of a lower-body set)."""
    from dataclasses import replace

    from staggered_cli.contacts.detect import up_direction

    P, H = np.asarray(m.points), m.figure_height()
    up = up_direction(P, H)
    side = np.roll(np.abs(up), 1)  # a horizontal axis
    h = P @ up
    floor = np.nanpercentile(np.nanmin(np.where(np.isfinite(h), h, np.inf), axis=1), 5)
    seen = np.flatnonzero(np.isfinite(P).all(axis=2).any(axis=1))  # (the BTS walk starts with gaps)
    start = np.nanmean(P[seen[: len(P) // 10]].reshape(-1, 3), axis=0)
    start = start - (start @ up) * up
    corners = np.array([[a, b] for a in (-0.125, 0.125) for b in (-0.09, 0.09)]) * H
    ahead = np.cross(up, side)
    offsets = corners[:, :1] * side + corners[:, 1:] * ahead  # (4, 3)
    idx = [m.labels.index(c) for c in carrier]
    carried = np.flatnonzero(np.isfinite(P[:, idx]).all(axis=(1, 2)))  # frames the figure is seen in
    T, cut = len(P), int(carried[int(resting * len(carried))])
    centre = np.empty((T, 3))
    centre[:cut] = start + spot * H * side + (floor + 0.01 * H) * up
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # carriers unseen: the box is too
        hold = np.nanmean(P[cut:, idx], axis=1) - 0.1 * H * up
    centre[cut:] = hold
    box = centre[:, None] + offsets[None]
    return replace(m, labels=tuple(m.labels) + tuple(labels), points=np.concatenate([P, box], axis=1))


def test_default_contact_markers_are_the_feet_not_a_carried_box():
    """A box that rests on the floor most of the clip has markers among the
    lowest of the set: the old rule (the lowest median heights) put default
    contacts on it, and a box resting far from the figure turned its up
    axis (the widest extent) too.  The subject prefix (a box labelled
    Box:C1 or BOX1 beside Male:LTOE, or Box:C1 beside an unprefixed set,
    resting right beside the feet) and, without prefixes, the figure's
    place (a box resting 2 figure heights beside the start) keep the
    defaults on the feet: the same markers as without the box, on each dev
    C3D."""
    from dataclasses import replace

    from staggered_cli.contacts.detect import _lowest_of, _median_height, contact_joints, up_direction

    from .conftest import dev_motion

    cmu = dev_motion("cmu_85_12_breakdance_long.c3d")
    bare = replace(cmu, labels=tuple(n.split(":")[1] for n in cmu.labels))
    org, bts = dev_motion("c3dorg_sample01_Eb015pi_walk.c3d"), dev_motion("ezc3d_BTS_walk_gaps.c3d")
    box4 = ("C1", "C2", "C3", "C4")
    cases = [  # clip, box labels, carried under, resting where
        (cmu, tuple(f"Box:{c}" for c in box4), ("Male:LWRA", "Male:RWRA"), 0.3),
        (cmu, tuple(f"BOX{c}" for c in box4), ("Male:LFIN", "Male:RFIN"), 0.3),
        (org, tuple(f"Box:{c}" for c in box4), ("PV1", "PV2", "PV3", "pv4"), 0.3),
        (bare, tuple(f"BOX{c}" for c in box4), ("LWRA", "RWRA"), 2.0),
        (bts, tuple(f"box {c}" for c in box4), ("r asis", "l asis", "sacrum"), 2.0),
    ]
    feet = {
        id(cmu): [f"Male:{s}{m}" for s in "LR" for m in ("ANK", "HEE", "MT5", "TOE")],
        id(bare): [f"{s}{m}" for s in "LR" for m in ("ANK", "HEE", "MT5", "TOE")],
        id(org): [f"{s}FT{i}" for s in "RL" for i in (1, 2, 3)],
        id(bts): ["r heel", "r met", "l heel", "l met"],
    }
    for m, labels, carrier, spot in cases:
        assert sorted(contact_joints(m)) == sorted(feet[id(m)])
        boxed = _with_box(m, labels, carrier, spot)
        # the hard case: the old rule, on all markers, takes the box
        P, H = boxed.points, boxed.figure_height()
        old = _lowest_of(_median_height(np.array(P), up_direction(P, H)), H)
        assert set(range(len(m.labels), len(boxed.labels))) & set(old.tolist()), labels
        assert sorted(contact_joints(boxed)) == sorted(feet[id(m)]), (labels, contact_joints(boxed))
        # and the contacts are those without the box (the figure's height,
        # which scales the tolerance, is measured without it too)
        assert detect_contacts(boxed) == detect_contacts(m), labels
