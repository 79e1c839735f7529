"""Extraction (paper section 4, Appendix B; SPEC sections 4 and 6) on the real
motion capture: round trip, determinism, contacts against an independent
reference, poses on contact changes, sparse idle motion, frame-rate
consistency, and the signal operators on curves whose answers are known."""

from __future__ import annotations

import inspect
import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.ndimage import gaussian_filter1d

import staggered_cli as st
from staggered_cli.contacts import detect as C
from staggered_cli.errors import UsageError
from staggered_cli.io.container import document_bytes
from staggered_cli.io.schema import to_parts
from staggered_cli.model import sampling
from staggered_cli.motion import BvhMotion, channels_from_local
from staggered_cli.ops.extract import extract, flight_frames, refinement_frames, strongest_frames
from staggered_cli.signals import probability, smoothing, trails

from .conftest import BVH_FILES, C3D_FILES, cli_extract, dev_document, dev_motion, mocap

#: Clips whose contacts are checked against the reference (walk, run, jump).
CONTACT_CLIPS = [
    "cmu_02_01_walk.bvh",
    "bandai1_walk_normal_001.bvh",
    "bandai2_run_normal_001.bvh",
    "cmu_01_01_forward_jumps.bvh",
    "cmu3dsmax_131_02_start_walk_stop.bvh",
    "c3dorg_sample01_Eb015pi_walk.c3d",
    "ezc3d_BTS_walk_gaps.c3d",
]
#: CMU cgspeed files whose frame 0 is a T-pose.
TPOSE = ("cmu_01_01_forward_jumps.bvh", "cmu_115_06_pick_up_box.bvh")


def _motion(name: str):
    return dev_motion(name)  # read once per session (conftest)


def _extracted(name: str):
    """Each file is extracted once for the whole session (conftest)."""
    return dev_document(name)


def _rate(doc) -> float:
    return float(doc.source.rate)


def _frames(times, doc) -> np.ndarray:
    return np.rint(np.asarray(times) * _rate(doc)).astype(int)


# --- round trip and determinism ---------------------------------------------------


@pytest.mark.parametrize("name", BVH_FILES)
def test_bvh_extract_then_bake_reproduces_the_source(name):
    doc = _extracted(name)
    src = _motion(name)
    rot, tr = sampling.local_pose(doc, doc.frame_times)
    ch = channels_from_local(src.skeleton, rot, tr, src.channels)
    assert np.abs(ch - src.channels).max() < 1e-6
    # and the document is a real one: several poses, refined, valid knots
    assert doc.n_poses >= 2
    ref = doc.refinements()
    assert np.all(ref[[0, -1]] == 0)


@pytest.mark.parametrize("name", C3D_FILES)
def test_c3d_extract_then_bake_reproduces_the_source(name):
    doc = _extracted(name)
    src = _motion(name)
    pts = sampling.marker_points(doc, doc.frame_times)
    np.testing.assert_array_equal(np.isnan(pts), np.isnan(src.points))
    assert np.nanmax(np.abs(pts - src.points)) < 1e-6 * src.figure_height()


@pytest.mark.parametrize("name", ["bandai2_run_normal_001.bvh", "ezc3d_BTS_walk_gaps.c3d"])
def test_extract_is_deterministic(name):
    m1, a1 = to_parts(_extracted(name))
    m2, a2 = to_parts(extract(_motion(name), source_name=name))
    assert json.dumps(m1, sort_keys=True) == json.dumps(m2, sort_keys=True)
    assert sorted(a1) == sorted(a2)
    for key in a1:
        np.testing.assert_array_equal(a1[key], a2[key])
    assert document_bytes(m1, a1, "npz") == document_bytes(m2, a2, "npz")


def test_document_records_signals_and_parameters():
    doc = _extracted("cmu_02_01_walk.bvh")
    T, V = doc.n_frames, len(doc.variable_names)
    assert doc.signals["P"].shape == (T,)
    assert doc.signals["p"].shape == (T, V)
    assert doc.signals["weights"].shape == (V,)
    assert doc.signals["contact"].shape == (T,)
    assert np.all((doc.signals["p"] >= 0) & (doc.signals["p"] <= 1))
    assert set(doc.parameters) >= {
        "smoothing",
        "filter_width",
        "refine_window",
        "min_contact",
        "contact_tolerance",
        "significance",
        "contact_joints",
    }
    json.dumps(doc.parameters)  # JSON-able
    assert np.all(np.isinf(doc.priority[[0, -1]]))
    inner = doc.priority[1:-1]
    assert np.all(np.isfinite(inner)) and np.all(inner >= 0)
    # w_k = P(t_k)(t_{k+1} - t_{k-1})
    f = _frames(doc.pose_t, doc)
    np.testing.assert_allclose(inner, doc.signals["P"][f[1:-1]] * (doc.pose_t[2:] - doc.pose_t[:-2]))


@pytest.mark.parametrize(
    "name", ["cmu_01_01_forward_jumps.bvh", "bandai1_dance-short_normal_001.bvh", "cmu_85_12_breakdance_long.c3d"]
)
def test_refinements_are_whole_frames_bounded_and_closer_to_their_pose(name):
    doc = _extracted(name)
    ref = doc.refinements()
    ft = doc.frame_time
    np.testing.assert_allclose(ref / ft, np.rint(ref / ft), atol=1e-6)
    assert np.abs(ref).max() <= 0.25 + 1e-9
    ext = doc.pose_t[:, None] + ref
    # strictly closer to its own pose than to the neighbours
    assert np.all(np.abs(ext[1:-1] - doc.pose_t[1:-1, None]) < np.abs(ext[1:-1] - doc.pose_t[:-2, None]))
    assert np.all(np.abs(ext[1:-1] - doc.pose_t[1:-1, None]) < np.abs(ext[1:-1] - doc.pose_t[2:, None]))
    # staggered: refinements stay where they earn their keep (issue 13), on
    # 11-21 % of the moving variables of these clips
    moving = doc.signals["weights"] > 0
    assert np.mean(ref[1:-1][:, moving] != 0) > 0.1


# --- contacts -------------------------------------------------------------------------


def _reference_intervals(pos: np.ndarray, height: float, rate: float, first: int) -> list[tuple[int, int]]:
    """Independent contacts: speed (central differences, Gaussian-smoothed
    with σ = 0.02 s) below half a figure height per second for at least
    0.1 s (frames before ``first`` are ignored: a T-pose)."""
    T = len(pos)
    speed = np.full(T, np.inf)
    v = np.linalg.norm(np.gradient(pos[first:], axis=0), axis=-1) * rate / height
    speed[first:] = gaussian_filter1d(v, 0.02 * rate, mode="nearest")
    low = speed < 0.5  # NaN (a C3D gap) is not low
    step = np.diff(np.concatenate([[0], low.astype(int), [0]]))
    starts, ends = np.flatnonzero(step == 1), np.flatnonzero(step == -1) - 1
    # a central difference spans two frame steps: n slow frames in a row mean
    # the point stayed slow from frame a-1 to b+1, over (n + 1) frame steps
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if (b - a + 2) / rate >= 0.1 - 1e-9]


def _boundaries(intervals, T: int, first: int) -> list[tuple[str, int]]:
    """Starts and ends, leaving out the clip's ends (nothing changes there)."""
    out = []
    for a, b in intervals:
        if a > first:
            out.append(("start", a))
        if b < T - 1:
            out.append(("end", b))
    return out


def _matched(a, b, tol: int) -> int:
    return sum(any(k == k2 and abs(f - f2) <= tol for k2, f2 in b) for k, f in a)


def contact_scores(name: str) -> tuple[float, float, int, int]:
    """Recall and precision of the detected contact starts and ends against
    the reference, within ±0.1 s, per joint and kind."""
    doc = _extracted(name)
    motion = _motion(name)
    rate = _rate(doc)
    first = 1 if name in TPOSE else 0
    joints = tuple(doc.parameters["contact_joints"])
    if isinstance(motion, BvhMotion):
        wp = motion.world()[1]
        pos = wp[:, [motion.skeleton.index(j) for j in joints]]
    else:
        pos = motion.points[:, [motion.labels.index(j) for j in joints]]
    height = motion.figure_height()
    tol = int(round(0.1 * rate))
    n_ref = n_det = hit_ref = hit_det = 0
    for n, joint in enumerate(joints):
        ref = _boundaries(_reference_intervals(pos[:, n], height, rate, first), doc.n_frames, first)
        mine = [c for c in doc.constraints if c.joint == joint]
        det_iv = list(zip(_frames([c.start for c in mine], doc), _frames([c.end for c in mine], doc), strict=True))
        det = _boundaries(det_iv, doc.n_frames, first)
        n_ref += len(ref)
        n_det += len(det)
        hit_ref += _matched(ref, det, tol)
        hit_det += _matched(det, ref, tol)
    return hit_ref / max(n_ref, 1), hit_det / max(n_det, 1), n_ref, n_det


@pytest.mark.parametrize("name", CONTACT_CLIPS)
def test_contacts_agree_with_the_reference(name):
    recall, precision, n_ref, n_det = contact_scores(name)
    assert n_ref >= 4 and n_det >= 4
    assert recall >= 0.8, f"recall {recall:.2f}"
    assert precision >= 0.8, f"precision {precision:.2f}"


def test_running_stance_is_found():
    doc = _extracted("bandai2_run_normal_001.bvh")
    # the run has no 0.25 s plant, yet every foot joint gets a stance per stride
    for joint in doc.parameters["contact_joints"]:
        spans = [c.end - c.start for c in doc.constraints if c.joint == joint]
        assert len(spans) >= 2
        assert max(spans) < 0.25
    assert extract(_motion("bandai2_run_normal_001.bvh"), min_contact=0.25).constraints == ()


@pytest.mark.parametrize(
    "name, expected",
    [
        ("cmu_02_01_walk.bvh", {"LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase"}),
        ("cmu3dsmax_131_02_start_walk_stop.bvh", {"LeftAnkle", "LeftToe", "RightAnkle", "RightToe"}),
        ("bandai2_run_normal_001.bvh", {"Foot_L", "Toes_L", "Foot_R", "Toes_R"}),
        ("games105_idle.bvh", {"lAnkle", "lToeJoint", "rAnkle", "rToeJoint"}),
        ("ezc3d_BTS_walk_gaps.c3d", {"r heel", "r met", "l heel", "l met"}),
        ("c3dorg_sample01_Eb015pi_walk.c3d", {"RFT1", "RFT2", "RFT3", "LFT1", "LFT2", "LFT3"}),
    ],
)
def test_default_contact_joints_are_the_feet(name, expected):
    assert set(C.contact_joints(_motion(name))) == expected


def test_contact_joints_by_option():
    m = _motion("cmu_02_01_walk.bvh")
    assert C.contact_joints(m, ["LeftHand"]) == ("LeftHand",)
    with pytest.raises(UsageError, match="Nope"):
        C.contact_joints(m, ["Nope"])
    with pytest.raises(UsageError, match="Nope"):
        C.contact_joints(_motion("ezc3d_BTS_walk_gaps.c3d"), ["Nope"])


def test_up_direction_without_assuming_an_axis():
    rng = np.random.default_rng(5)
    # a "figure" 1.7 tall, 0.4 wide, walking 3 units along x, standing on z = 0
    T = 50
    pts = rng.uniform([0, -0.2, 0], [0.4, 0.2, 1.7], (T, 20, 3)) + np.linspace(0, 3, T)[:, None, None] * [1, 0, 0]
    np.testing.assert_array_equal(C.up_direction(pts, 1.7), [0, 0, 1])
    np.testing.assert_array_equal(C.up_direction(-pts[..., [2, 0, 1]], 1.7), [-1, 0, 0])


def test_planted_intervals_on_a_synthetic_step():
    rate = 100
    t = np.arange(100) / rate
    x = np.where(t < 0.3, 0.0, np.where(t < 0.5, (t - 0.3) * 5, 1.0))  # rests, moves, rests
    pos = np.stack([x, 0 * x, 0 * x], axis=1)
    iv = C.planted_intervals(pos, 0.03, 11)
    assert len(iv) == 2
    (a0, b0), (a1, b1) = iv
    assert a0 == 0 and b1 == 99
    assert b0 == 30 and a1 == 50
    pos[80:85] = np.nan  # a gap ends a contact
    assert C.planted_intervals(pos, 0.03, 11)[1:] == [(a1, 79), (85, 99)]


# --- poses --------------------------------------------------------------------------------


@pytest.mark.parametrize("name", [n for n in BVH_FILES + C3D_FILES if "idle" not in n and "bow" not in n])
def test_poses_sit_on_contact_changes(name):
    doc = _extracted(name)
    T = doc.n_frames
    changes = []
    for c in doc.constraints:
        s, e = _frames([c.start, c.end], doc)
        if s > (1 if name in TPOSE else 0):
            changes.append(s)
        if e < T - 1:
            changes.append(e)
    if not changes:
        pytest.skip("no contact changes")
    # one pose per cluster of changes, within half the tent filter's width
    pose_f = _frames(doc.pose_t, doc)
    near = [np.min(np.abs(pose_f - f)) <= 0.075 * _rate(doc) + 1e-6 for f in changes]
    assert np.mean(near) >= 0.8


def test_refinement_frames_take_the_nearest_peak_closer_to_its_pose():
    p = np.zeros((50, 2))
    p[[8, 14], 0] = 1.0
    p[30, 1] = 1.0
    poses = np.array([0, 10, 20, 49])
    r = refinement_frames(p, poses, 5)
    np.testing.assert_array_equal(r, [[0, 0], [-2, 0], [0, 0], [0, 0]])
    # a wider window: 30 is closer to 20 than to 49; 14 is closer to 10 than to 20
    r = refinement_frames(p, poses, 12)
    np.testing.assert_array_equal(r, [[0, 0], [-2, 0], [0, 10], [0, 0]])


def test_strongest_frames_take_the_largest_swing_closer_to_its_pose():
    e = np.zeros((50, 2))
    e[[7, 12], 0] = [0.05, 0.02]  # the nearer (12) is the smaller swing
    e[[25, 33], 1] = 0.03  # a tie: the nearer to 30
    poses = np.array([0, 10, 30, 49])
    r = strongest_frames(e, poses, 5)
    np.testing.assert_array_equal(r, [[0, 0], [-3, 0], [0, 3], [0, 0]])
    # 7 is out of a 2-frame window: the smaller swing it is
    r = strongest_frames(e, poses, 2)
    np.testing.assert_array_equal(r, [[0, 0], [2, 0], [0, 0], [0, 0]])
    # a peak midway between two poses belongs to neither
    e2 = np.zeros((50, 1))
    e2[20, 0] = 1.0
    np.testing.assert_array_equal(strongest_frames(e2, poses, 15)[:, 0], [0, 0, 0, 0])


@pytest.mark.parametrize(
    ("name", "torso", "tops"),
    [
        (
            "cmu_02_01_walk.bvh",
            {"Hips", "LowerBack", "Spine", "Spine1"},
            {"LHipJoint", "RHipJoint", "LeftShoulder", "RightShoulder", "Neck"},
        ),
        (
            "bandai1_walk_normal_001.bvh",
            {"joint_Root", "Hips", "Spine", "Chest"},
            {"UpperLeg_L", "UpperLeg_R", "Shoulder_L", "Shoulder_R", "Neck"},
        ),
        (
            "games105_idle.bvh",
            {"RootJoint", "pelvis_lowerback", "lowerback_torso"},
            {"lHip", "rHip", "lTorso_Clavicle", "rTorso_Clavicle", "torso_head"},
        ),
    ],
)
def test_limbs_hang_below_the_torso(name, torso, tops):
    """The torso is where the body branches into limbs; each arm is one limb
    from its collar to its fingers, each leg from the hip to the toe."""
    m = dev_motion(name)
    sk = m.skeleton
    top = trails.limb_tops(sk, m.figure_height())
    assert {sk.names[j] for j in np.flatnonzero(top < 0)} == torso
    assert {sk.names[t] for t in top[top >= 0]} == tops
    hand = next(j for j, n in enumerate(sk.names) if n in ("LeftHand", "Hand_L", "lWrist"))
    assert sk.names[top[hand]] in {"LeftShoulder", "Shoulder_L", "lTorso_Clavicle"}


def test_limb_extremes_are_where_the_hand_turns_back():
    """An arm swinging back and forth at the shoulder with the elbow bending
    in step: the hand, seen from the collar, turns back at the ends of the
    swing (frames 15, 45, 75), the limb's largest extremes; along the arm it
    comes in least at the swing's middle (31, 59: a smaller swing)."""
    m = dev_motion("cmu_02_01_walk.bvh")
    sk, h = m.skeleton, m.figure_height()
    T, rate = 91, 30.0
    ang = np.radians(30.0) * np.sin(2 * np.pi * np.arange(T) / 60.0)
    names = ("LeftShoulder", "LeftArm", "LeftForeArm")
    targets = np.array([sk.names.index(n) for n in names])
    rot = np.zeros((T, 3, 4))
    rot[..., 0] = 1.0
    rot[:, 1] = np.stack([np.cos(ang / 2), 0 * ang, np.sin(ang / 2), 0 * ang], axis=1)  # about y: the arm lies along x
    bend = np.radians(10.0) * (1 + np.sin(2 * np.pi * np.arange(T) / 60.0))
    rot[:, 2] = np.stack([np.cos(bend / 2), 0 * bend, np.sin(bend / 2), 0 * bend], axis=1)
    e = trails.limb_extremes(sk, targets, rot, h, rate, which=np.array([0]))
    assert e.shape == (T, 1)
    at = np.flatnonzero(e[:, 0])
    big = at[e[at, 0] > 0.5 * e[:, 0].max()]
    np.testing.assert_array_equal(big, [15, 45, 75])
    assert set(at) - set(big) <= {29, 30, 31, 59, 60, 61}


@pytest.mark.parametrize(
    "name, pairs",
    [
        ("bandai1_walk_normal_001.bvh", (("Shoulder_L", "Shoulder_R"), ("UpperLeg_L", "UpperLeg_R"))),
        ("cmu_02_01_walk.bvh", (("LeftShoulder", "RightShoulder"), ("LHipJoint", "RHipJoint"))),
        ("cmu3dsmax_131_02_start_walk_stop.bvh", None),
    ],
)
def test_heading_offsets_swing_the_hands_in_opposition_whichever_way_the_figure_faces(name, pairs):
    """A walk: each hand's offset from the pelvis along the heading
    swings by 0.1-0.8 of the figure height, the left forward when the right
    is back (correlation below -0.8), and so do the feet; the figure turned
    by 90 degrees about the up axis and moved gives the same offsets, up to
    the heading's sign.  A CMU skeleton's hip joints sit on the pelvis: the
    heading comes from the first joints of the legs that stand apart (it was
    zero, so were every CMU clip's offsets)."""
    from staggered_cli.skeleton import body_joints

    m = dev_motion(name)
    sk, h, w = m.skeleton, m.figure_height(), m.world_positions()
    tops = np.unique(trails.limb_tops(sk, h))
    tops = tops[tops >= 0]
    up = C.up_direction(w, h, body_joints(sk))
    off = trails.heading_offsets(sk, w, tops, up, m.rate)
    col = {sk.names[t]: i for i, t in enumerate(tops)}
    if pairs is None:  # other names: every limb's end swings along the heading by 5 % of the height or more
        swing = np.ptp(off, axis=0) / h
        assert np.all(swing > 0.05), dict(zip([sk.names[t] for t in tops], swing, strict=True))
        return
    for left, right in pairs:
        a, b = off[:, col[left]], off[:, col[right]]
        assert 0.1 < np.ptp(a) / h < 0.8 and 0.1 < np.ptp(b) / h < 0.8, (np.ptp(a) / h, np.ptp(b) / h)
        assert np.corrcoef(a, b)[0, 1] < -0.8, np.corrcoef(a, b)[0, 1]
    turn = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # 90 degrees about y (up)
    assert np.allclose(up, [0.0, 1.0, 0.0])
    turned = trails.heading_offsets(sk, w @ turn.T + [3.0, 0.0, -7.0], tops, up, m.rate)
    assert np.allclose(np.abs(turned), np.abs(off), atol=1e-9 * h)


def test_flight_frames_are_the_tops_of_the_times_in_the_air():
    from staggered_cli.contacts.constraint import Constraint

    rate = 30.0
    cons = [
        Constraint("L", 0.0, 1.0),  # frames 0-30
        Constraint("R", 0.5, 1.5),  # 15-45: no flight between L and R
        Constraint("L", 2.0, 2.5),  # 60-75: off 46-59 (14 frames), middle 52
        Constraint("R", 2.6, 3.0),  # 78-90: off 76-77, 2 frames (0.067 s): too short
        Constraint("L", 3.2, 3.3),  # 96-99: off 91-95, 5 frames (0.167 s): middle 93
    ]
    np.testing.assert_array_equal(flight_frames(cons, 120, rate), [52, 93])  # 100-119: the clip's end, no flight
    assert len(flight_frames([], 120, rate)) == 0
    # with the figure's centre: a body that falls at 1 g flies, one that
    # stays up (on its hands: no contact joint planted) does not
    t = np.arange(120) / rate
    g = 9.81 / 1.75
    center = np.full(120, 0.55)
    center[45:61] = 0.55 + 0.5 * g * (t[45:61] - t[45]) * (t[60] - t[45:61])  # frames 45-60: a throw
    np.testing.assert_array_equal(flight_frames(cons, 120, rate, center), [52])
    center[45:61] = 0.55 + 0.1 * g * (t[45:61] - t[45]) * (t[60] - t[45:61])  # 0.2 g: held up
    assert len(flight_frames(cons, 120, rate, center)) == 0
    # the pose goes on the top of the throw, not the middle of the frames in the air
    top = t[49]
    center[40:66] = 0.55 + 0.5 * g * ((t[49] - t[40]) ** 2 - (t[40:66] - top) ** 2)
    np.testing.assert_array_equal(flight_frames(cons, 120, rate, center), [49])


def test_laplacian_smoothing_does_not_depend_on_the_memory_layout():
    """A column picked out of a (T, V, 3) array is not C-contiguous: the
    smoothing once returned it unsmoothed (its in-place steps went to a copy)."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(60, 5, 3))
    picked = x[:, [1, 3]]
    assert not picked.flags["C_CONTIGUOUS"]
    want = smoothing.laplacian_smooth(np.ascontiguousarray(picked), 0.025, 120.0)
    got = smoothing.laplacian_smooth(picked, 0.025, 120.0)
    assert np.abs(want - picked).max() > 0.1  # it smooths
    np.testing.assert_array_equal(got, want)


def test_coordinate_extremes_find_where_a_coordinate_turns_back_and_ignore_jitter():
    """A bob of 4 % of the figure height on a forward walk turns at its
    maxima and minima (within a frame), and the forward axis never does; a
    wiggle of 0.2 % (under EXTREME_SWING) is no extreme."""
    rate, h = 120.0, 1.7
    t = np.arange(240) / rate
    bob = 0.02 * h * np.sin(2 * np.pi * 2.0 * t)  # 2 Hz: extremes at 0.125 + k 0.25 s
    trail = np.stack([1.4 * t, 0.9 * h + bob, np.zeros_like(t)], axis=1)[:, None, :]
    jitter = trail + np.stack([np.zeros_like(t), 0.001 * h * np.sin(2 * np.pi * 15 * t), np.zeros_like(t)], 1)[:, None]
    for x in (trail, jitter):
        ext = trails.coordinate_extremes(x, h, rate)
        found = np.flatnonzero(ext[:, 0]) / rate
        want = 0.125 + 0.25 * np.arange(8)
        assert len(found) == len(want), found
        np.testing.assert_allclose(found, want, atol=1.0 / rate + 1e-9)
        np.testing.assert_allclose(ext[ext > 0], 0.04, rtol=0.1)  # the swing, in figure heights
    still = np.repeat(trail[:1], len(t), axis=0) + 0.002 * h * np.sin(2 * np.pi * 3 * t)[:, None, None]
    assert not trails.coordinate_extremes(still, h, rate).any()


@pytest.mark.parametrize(
    "name, least",
    # measured 92 %, 100 %, 91 % (the largest extreme near a pose, and the
    # flights' poses; the nearest extreme gave 90 %, 90 %, 82 %; before issue
    # 34: 36 %, 80 %, 73 %, the root
    # refined at 1 of 86, 7 of 49, 0 of 34 poses)
    [
        ("cmu_01_01_forward_jumps.bvh", 0.9),
        ("cmu3dsmax_131_02_start_walk_stop.bvh", 0.9),
        ("cmu_05_06_modern_dance.bvh", 0.8),
    ],
)
def test_the_roots_extreme_knots_sit_on_its_height_extremes(name, least):
    """The root translation is refined onto its own extremes: most of the
    root's height extremes (found by tests/events.py, code apart from the
    project) have a root extreme knot within 0.05 s, and the root is refined
    at many poses."""
    from .events import clip_events

    doc = dev_document(name)
    ev = clip_events(dev_motion(name), name)
    col = doc.variable_names.index(dev_motion(name).skeleton.names[ev.place] + ".position")
    ref = doc.refinements()[:, col]
    knots = np.sort(doc.pose_t + ref)
    near = np.array([np.min(np.abs(knots - e)) <= 0.05 + 1e-9 for e in ev.root_extremes])
    assert len(near) >= 10 and near.mean() >= least, (near.mean(), len(near))
    assert np.count_nonzero(ref) >= 0.4 * doc.n_poses, np.count_nonzero(ref)


def _poses_per_second(doc) -> float:
    return doc.n_poses / doc.duration


def test_idle_is_sparse_and_walks_keep_their_contact_poses():
    idle = _poses_per_second(_extracted("games105_idle.bvh"))
    for walk in ("cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh"):
        assert idle <= 0.5 * _poses_per_second(_extracted(walk))
    # without the gate the idle clip is as busy as a walk: the gate is what makes it sparse
    ungated = extract(_motion("games105_idle.bvh"), significance=0.0)
    assert _poses_per_second(ungated) > 2 * idle


def test_30_and_120_hz_give_the_same_poses():
    m = _motion("cmu_02_01_walk.bvh")
    m30 = replace(m, channels=m.channels[::4], frame_time=m.frame_time * 4)
    assert m30.rate == 30.0
    d120, d30 = _extracted("cmu_02_01_walk.bvh"), extract(m30)
    # the same contacts, to within a 30 Hz frame or two
    assert len(d30.constraints) == len(d120.constraints)
    # pose probability: the same curve
    P120 = d120.signals["P"][::4]
    assert np.corrcoef(P120, d30.signals["P"])[0, 1] > 0.85
    # most 30 Hz poses have a 120 Hz pose within the poses' spacing (placement
    # optimizes the fit, so a slightly different count moves a neighbour or two)
    d = np.array([np.min(np.abs(d120.pose_t - t)) for t in d30.pose_t])
    assert np.mean(d <= 0.1 + 1e-6) >= 0.85
    assert np.mean(d <= 2 / 30 + 1e-6) >= 0.6
    assert 0.6 <= d30.n_poses / d120.n_poses <= 1.4


def test_tpose_frame_does_not_flood_the_signals():
    m = _motion("cmu_01_01_forward_jumps.bvh")
    cut = replace(m, channels=m.channels[1:])
    full, rest = trails.local_evidence(m), trails.local_evidence(cut)
    assert full.breaks[0] and not full.breaks[1:].any()
    assert not rest.breaks.any()
    # the evidence after the jump is what the clip without the T-pose gives
    np.testing.assert_allclose(full.p[1:], rest.p, atol=1e-6)
    np.testing.assert_allclose(full.weights, rest.weights, rtol=1e-3)
    P_full, P_rest = probability.pose_probability(full), probability.pose_probability(rest)
    half = int(np.ceil(0.075 * 120))  # the tent filter reaches frame 0 only from the first frames
    np.testing.assert_allclose(P_full[1 + half :], P_rest[half:], atol=1e-9)
    assert np.abs(P_full[1 : 1 + half] - P_rest[:half]).max() < 0.05


# --- signal operators ----------------------------------------------------------------------


def test_scaled_curvature_is_the_sine_of_half_the_turn():
    turn = np.radians(10.0)
    a = np.arange(40) * turn
    circle = np.stack([np.cos(a), np.sin(a), 0 * a], axis=1)[:, None, :]
    k = trails.scaled_curvature(circle)[:, 0]
    np.testing.assert_allclose(k[1:-1], np.sin(turn / 2), rtol=1e-9)
    assert k[0] == 0 and k[-1] == 0
    k2 = trails.scaled_curvature(circle, span=2)[:, 0]
    np.testing.assert_allclose(k2[2:-2], np.sin(turn), rtol=1e-9)
    line = np.stack([a, 2 * a, 0 * a], axis=1)[:, None, :]
    assert np.abs(trails.scaled_curvature(line)).max() < 1e-7
    still = np.zeros((10, 1, 3))
    assert np.all(trails.scaled_curvature(still) == 0)
    rng = np.random.default_rng(1)
    noise = rng.normal(size=(500, 3, 3))
    k = trails.scaled_curvature(noise)
    assert k.min() >= 0 and k.max() <= 1


def test_smoothing_is_a_duration():
    n30, r30 = smoothing.smoothing_iterations(0.05, 30)
    n120, r120 = smoothing.smoothing_iterations(0.05, 120)
    # a diffusion: sixteen times the iterations at four times the rate
    # (each full iteration adds a variance of 1/2 frame², the partial one 2 r)
    assert abs((n120 / 2 + 2 * r120) / (n30 / 2 + 2 * r30) - 16) < 1e-9
    assert n120 > 10 * n30
    # the same Gaussian width in seconds at both rates
    for rate in (30, 120, 250):
        x = np.zeros(2001)
        x[1000] = 1.0
        y = smoothing.laplacian_smooth(x, 0.05, rate)
        t = (np.arange(2001) - 1000) / rate
        assert abs(np.sqrt(np.sum(y * t**2)) - 0.05) < 1e-6
        assert abs(y.sum() - 1) < 1e-12
    # nothing crosses a break
    x = np.r_[np.ones(10), np.zeros(10)]
    breaks = np.zeros(19, dtype=bool)
    breaks[9] = True
    np.testing.assert_array_equal(smoothing.laplacian_smooth(x, 0.1, 120, breaks), x)


def test_tent_filter_and_pulses_are_rate_independent():
    x = np.ones(50)
    np.testing.assert_allclose(smoothing.tent_filter(x, 0.15, 120), 1.0)
    for rate in (30, 60, 120, 250):
        pulse = probability.contact_pulses([rate], 2 * rate, rate, 0.05)
        assert abs(pulse.sum() / rate - 0.05) <= 1.0 / rate + 1e-9
        assert pulse[rate] == 1.0


def test_local_maxima_plateaus_and_zeros():
    x = np.array([0, 1, 1, 1, 0, 0, 0, 2, 0, 0.0])
    np.testing.assert_array_equal(probability.local_maxima(x), [2, 7])
    assert len(probability.local_maxima(np.zeros(10))) == 0


# --- the command ----------------------------------------------------------------------------


def test_cli_extract_writes_a_document(tmp_path):
    from staggered_cli.cli.main import cli

    out = tmp_path / "run.json"
    src = str(mocap("bandai2_run_normal_001.bvh"))
    res = CliRunner().invoke(cli, ["extract", src, "-o", str(out), "--min-contact", "0.1"])
    assert res.exit_code == 0, res.output
    info = CliRunner().invoke(cli, ["info", "--json", str(out)])
    assert info.exit_code == 0, info.output
    summary = json.loads(info.stdout)
    doc = _extracted("bandai2_run_normal_001.bvh")
    assert [p["time"] for p in summary["poses"]] == pytest.approx(list(doc.pose_t))
    assert len(summary["constraints"]) == len(doc.constraints)
    # refuse to clobber; refuse a document as input; unknown joint; bad number
    assert CliRunner().invoke(cli, ["extract", src, "-o", str(out)]).exit_code == 2
    assert CliRunner().invoke(cli, ["extract", str(out), "-o", str(tmp_path / "x.stag")]).exit_code == 2
    res = CliRunner().invoke(cli, ["extract", src, "--contact-joints", "Nope", "-o", str(tmp_path / "y.stag")])
    assert res.exit_code == 2 and "Nope" in res.stderr
    res = CliRunner().invoke(cli, ["extract", src, "--filter-width", "nan", "-o", str(tmp_path / "z.stag")])
    assert res.exit_code == 2
    assert not (tmp_path / "x.stag").exists() and not (tmp_path / "y.stag").exists()


@pytest.mark.parametrize("name", ["bandai2_run_normal_001.bvh", "c3dorg_sample01_Eb015pi_walk.c3d"])
def test_cli_extract_writes_the_library_document_byte_for_byte(name):
    """The command is the library's extract and nothing else: the tests that
    share one extraction per clip (conftest.cli_extract) rely on it."""
    from staggered_cli.cli.main import cli

    r = CliRunner().invoke(cli, ["extract", str(mocap(name)), "-o", "-"])
    assert r.exit_code == 0, r.stderr
    assert r.stdout_bytes == cli_extract(name)


def test_cli_defaults_are_the_library_defaults():
    from staggered_cli.cli.extract import extract as command
    from staggered_cli.ops import extract as ops

    defaults = {p.name: p.default for p in command.params}
    # the two durations the clip's tempo decides (ops.tempo_scale) are None in the CLI, the API and the library
    assert defaults["filter_width"] is None and defaults["min_spacing"] is None
    api = inspect.signature(st.extract).parameters
    library = inspect.signature(ops.extract).parameters
    assert api["filter_width"].default is None and api["min_spacing"].default is None
    assert library["filter_width"].default is None and library["min_spacing"].default is None
    assert defaults["refine_window"] == ops.DEFAULT_REFINE_WINDOW
    assert defaults["min_contact"] == C.DEFAULT_MIN_CONTACT
    assert defaults["contact_tolerance"] == C.DEFAULT_TOLERANCE
    assert defaults["significance"] == ops.DEFAULT_SIGNIFICANCE


def test_spaced_candidates_are_the_greedy_choice_strongest_first():
    """Candidates taken strongest first when at least ``spacing`` from every
    frame taken (ties on strength by frame): the plain greedy choice, on
    enough candidates that checking every taken frame would be quadratic."""
    from staggered_cli.ops.extract import _spaced

    rng = np.random.default_rng(11)
    strength = np.round(rng.random(20_000), 2)  # many ties
    frames = rng.choice(20_000, size=5_000, replace=False).tolist()
    forced = np.array([0, 7_000, 19_999])
    taken = list(forced)
    for f in sorted(frames, key=lambda f: (-strength[f], f)):
        if min(abs(t - f) for t in taken) >= 9:
            taken.append(f)
    got = _spaced(frames, strength, forced, 9)
    assert got.tolist() == sorted(taken)


@pytest.mark.parametrize("name", ["cmu3dsmax_131_02_start_walk_stop.bvh", "cmu_02_01_walk.bvh"])
def test_a_long_clips_fit_a_joint_at_a_time_gives_the_same_document(monkeypatch, name):
    """Past BY_COLUMN_BYTES of rotations (an hour at 120 Hz), extract drops
    the clip's rotations before the fit and the fit makes each joint's as it
    takes it: forced on a dev clip, the same document bytes."""
    from staggered_cli.io.bvh import read_bvh
    from staggered_cli.model import variables

    want = document_bytes(*to_parts(_extracted(name)), "npz")
    monkeypatch.setattr(variables, "BY_COLUMN_BYTES", 0)
    m = read_bvh(mocap(name))
    assert variables.fits_by_column(m)
    got = extract(m, source_name=name)
    assert "_local_rotations" not in m.__dict__
    assert document_bytes(*to_parts(got), "npz") == want
