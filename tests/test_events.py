"""The event finder of the event benchmark (issue 34, tests/events.py and
bench/bench_events.py) on the dev files, and the floor the project stands
on today: contact changes with a pose within 0.075 s.

The finder's numbers were measured on the dev files (see each test); they
check the finder, not the project: a wrong up axis, a wrong place joint, a
heading that turns with the arms or a floor rule that calls a planted foot
airborne each break one of them.  Only ``import staggered_cli as st``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import staggered_cli as st

from .conftest import dev_bvh_files, mocap
from .events import clip_events, find_events

WALKS = ("cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu3dsmax_131_02_start_walk_stop.bvh")


@functools.cache
def _motion(name: str):
    return st.read(mocap(name))


@functools.cache
def _events(name: str, **options):
    return clip_events(_motion(name), name, **options)


def _names(name: str, joints) -> list[str]:
    return [_motion(name).skeleton.names[int(j)] for j in joints]


@pytest.mark.parametrize(
    "name, place, feet, hand, arm",
    [
        (
            "cmu_02_01_walk.bvh",
            "Hips",
            ["LeftFoot", "LeftToeBase"],
            "LeftHand",
            ["LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"],
        ),
        (
            "bandai2_run_normal_001.bvh",
            "Hips",
            ["Foot_L", "Toes_L"],
            "Hand_L",
            ["Shoulder_L", "UpperArm_L", "LowerArm_L", "Hand_L"],
        ),
        (
            "cmu3dsmax_131_02_start_walk_stop.bvh",
            "Hips",
            ["LeftAnkle", "LeftToe"],
            "lhand",
            ["LeftCollar", "LeftShoulder", "LeftElbow", "LeftWrist", "lhand"],
        ),
        (
            "games105_idle.bvh",
            "RootJoint",
            ["lAnkle", "lToeJoint"],
            "lWrist",
            ["lTorso_Clavicle", "lShoulder", "lElbow", "lWrist"],
        ),
    ],
)
def test_the_finder_reads_each_skeleton(name, place, feet, hand, arm):
    """Y up (head above feet) on every skeleton; the place joint is the first
    that moves (Bandai: Hips under the still joint_Root; GAMES-105's idle
    root barely moves: the joint both legs hang from); two legs; each arm
    from the collar to the hand, without the fingers."""
    e = _events(name)
    assert np.array_equal(e.up, [0, 1, 0])
    assert _names(name, [e.place]) == [place]
    assert len(e.feet) == 2 and _names(name, e.feet[0]) == feet
    assert len(e.arms) == 2
    assert _names(name, e.arms[hand]) == arm


def test_a_walks_root_bob_is_one_minimum_a_step():
    """The hips go down once a step (0.43-0.67 s apart, 0.55 s on average):
    5 minima in cmu_02_01's 2.86 s at 0.5 % prominence, 11 in bandai's
    6.5 s at 1 %.  The CMU walk's
    bob is about 1 % of the figure height on a 5 % drift, so at the
    benchmark's 3 % it has none (measured: 0)."""
    for name, prominence, n in (("cmu_02_01_walk.bvh", 0.005, 5), ("bandai1_walk_normal_001.bvh", 0.01, 11)):
        e = _events(name, root_prominence=prominence)
        lows = e.root_extremes[e.root_kinds < 0]
        assert n - 1 <= len(lows) <= n + 1, (name, lows)
        assert np.all((np.diff(lows) > 0.4) & (np.diff(lows) < 0.75)), (name, np.diff(lows))
        assert 0.5 <= np.mean(np.diff(lows)) <= 0.62, (name, np.diff(lows))
        assert np.all(np.diff(e.root_kinds) != 0), name  # a high between two lows
    assert len(_events("cmu_02_01_walk.bvh").root_extremes) == 0


def test_a_walks_hands_swing_once_a_step_in_antiphase():
    """Bandai walk: 12 extremes a hand, 0.50-0.57 s apart; when one hand is
    forthest forward the other is forthest back (extremes within 0.1 s)."""
    e = _events("bandai1_walk_normal_001.bvh")
    left, right = e.swings["Hand_L"], e.swings["Hand_R"]
    for t in (left, right):
        assert 11 <= len(t) <= 13, t
        assert np.all((np.diff(t) > 0.45) & (np.diff(t) < 0.65)), np.diff(t)
    assert np.max(np.min(np.abs(left[:, None] - right[None, :]), axis=1)) <= 0.1


def test_each_forward_jump_is_one_flight_with_its_apex_in_it():
    """cmu_01_01: 10 two-footed hops, both feet off for 0.33-0.42 s each
    (measured), each holding exactly one high point of the hips; the
    T-pose frame 0 takes no part."""
    e = _events("cmu_01_01_forward_jumps.bvh")
    assert 9 <= len(e.flights) <= 11, e.flights
    length = e.flights[:, 1] - e.flights[:, 0]
    assert np.all((length > 0.25) & (length < 0.5)), length
    highs = e.root_extremes[e.root_kinds > 0]
    assert [int(np.sum((highs >= a) & (highs <= b))) for a, b in e.flights] == [1] * len(e.flights)
    assert e.root_extremes.min() > 1.0 and e.flights.min() > 1.0  # the T-pose is not a jump


def test_a_run_has_short_flights_and_a_high_in_each():
    """bandai2_run (30 Hz, 2.3 s): 3 flights of 4-5 frames (0.13-0.17 s,
    two more of 2 frames are shorter than 0.1 s), each with a hips high;
    11 root extremes alternating high and low, about 0.18 s apart."""
    e = _events("bandai2_run_normal_001.bvh")
    assert 2 <= len(e.flights) <= 5, e.flights
    length = e.flights[:, 1] - e.flights[:, 0] + 1 / 30
    assert np.all((length >= 0.1 - 1e-9) & (length < 0.25)), length
    highs = e.root_extremes[e.root_kinds > 0]
    assert all(np.any((highs >= a - 0.05) & (highs <= b + 0.05)) for a, b in e.flights)
    assert 9 <= len(e.root_extremes) <= 13 and np.all(np.diff(e.root_kinds) != 0)
    assert np.all((np.diff(e.root_extremes) > 0.1) & (np.diff(e.root_extremes) < 0.3))


@pytest.mark.parametrize(
    "name",
    [*WALKS, "cmu_115_06_pick_up_box.bvh", "bandai1_bow_normal_001.bvh", "games105_idle.bvh"],
)
def test_nobody_flies_while_walking_or_standing(name):
    """One foot is always down (a walk's stance foot, in CMU's walk 2 % of the
    height above its floor on a drifting floor, still and so planted)."""
    assert len(_events(name).flights) == 0


def test_idle_has_no_events():
    e = _events("games105_idle.bvh")
    assert len(e.root_extremes) == 0 and len(e.flights) == 0
    assert all(len(t) == 0 for t in e.swings.values())


def test_the_finder_refuses_a_skeleton_without_feet():
    m = _motion("cmu_02_01_walk.bvh")
    names = [n.replace("Foot", "Paw").replace("Toe", "Claw") for n in m.skeleton.names]
    with pytest.raises(ValueError, match="two legs"):
        find_events(names, m.skeleton.parents, m.world_positions(), float(m.frame_time), m.figure_height())


def test_extreme_knots_are_the_pose_times_plus_the_refinements():
    """What the benchmark reads as a variable's extreme knots: every knot of
    variable i is at t_k + r[k,i], plus an editing knot at t_k where r != 0."""
    doc = st.extract(_motion("cmu_01_01_forward_jumps.bvh"))
    ref, col = doc.refinements(), 0
    assert np.count_nonzero(ref) > 0
    for tr in doc.tracks:
        var = tr.knots.var
        for i in range(len(tr.names)):
            r = ref[:, col + i]
            want = np.sort(np.concatenate([doc.pose_t + r, doc.pose_t[r != 0]]))
            assert np.allclose(np.sort(tr.knot_t[var == i]), want, atol=1e-9), tr.names[i]
        col += len(tr.names)


@pytest.mark.parametrize(
    "name",
    ["cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu_01_01_forward_jumps.bvh", "cmu_115_06_pick_up_box.bvh"],
)
def test_hand_swings_have_a_knot_of_their_arm(name):
    """Issue 34 item 1: an arm's rotations put their extreme knots where the
    hand swings back along the body's heading (else where the hand, seen
    from the collar, turns back).  Measured: 100 % of the swing
    extremes of the two walks and the box lift, 98 % of the jumps' (52 of
    53; 85 % while a CMU skeleton's heading was zero); 47 % of all before
    issue 34."""
    row = _bench().measure_doc(st.extract(_motion(name)), _events(name), _motion(name), sparse=False)
    assert row["swing_knot"] >= 0.9, row["swing_knot"]


@pytest.mark.parametrize(
    "name", ["bandai2_run_normal_001.bvh", "cmu_01_01_forward_jumps.bvh", "cmu_05_06_modern_dance.bvh"]
)
def test_every_flight_phase_has_a_pose(name):
    """Issue 34 item 3: both feet off the ground for 0.1 s or more gets a
    pose in the air (extract's flight_frames).  Measured: every flight of
    the run, the jumps and the CMU dance; 13 of the Bandai dance's 14 (the
    14th: the project's contacts see a foot planted in it)."""
    row = _bench().measure_doc(st.extract(_motion(name)), _events(name), _motion(name), sparse=False)
    assert row["flight"] == 1.0, row["flight"]


@functools.cache
def _row(name: str) -> dict:
    """The benchmark's numbers of a dev file's extracted document (no sparse ratio)."""
    return _bench().measure_doc(st.extract(_motion(name)), _events(name), _motion(name), sparse=False)


def test_root_and_swing_extremes_have_extreme_knots_over_the_dev_files():
    """Issue 34's knot bars, pooled over every event of the dev BVH files:
    85 % of the root height extremes with a root extreme knot within 0.05 s,
    85 % of the hand swing extremes with a knot of that arm.  Measured: 195
    of 209 (93.3 %) and 354 of 375 (94.4 %; 343 while a CMU skeleton's
    heading was zero); 177 (84.7 %) and 327 (87 %)
    while a segment with one inner sample kept straight controls; 81 % and
    80 % before the height's and the heading's extremes came first."""
    hits = {"root": [0, 0], "swing": [0, 0]}
    for name in dev_bvh_files():
        row, ev = _row(name), _events(name)
        count = {"root": len(ev.root_extremes), "swing": sum(len(t) for t in ev.swings.values())}
        for k in hits:
            if count[k]:
                hits[k][0] += round(row[f"{k}_knot"] * count[k])
                hits[k][1] += count[k]
    assert hits["root"][1] > 200 and hits["root"][0] / hits["root"][1] >= 0.9, hits
    assert hits["swing"][1] > 350 and hits["swing"][0] / hits["swing"][1] >= 0.9, hits


def test_poses_are_not_early_or_late_on_average():
    """Issue 34 item 2: the mean signed offset of the nearest pose to each
    kind of event, over the dev files, within 0.02 s (measured: root -2 ms,
    swing +6 ms, take-off +11 ms, landing +7 ms; +21 ms take-off with the
    flights' poses at their middle frames, whose nearest pose came 67 ms
    after a short hop's first airborne frame; before the flights' poses
    -16, -3, -21, +9 ms)."""
    b = _bench()
    offsets: dict[str, list] = {k: [] for k in b.KINDS}
    for name in dev_bvh_files():
        row = _row(name)
        for k in b.KINDS:
            offsets[k].extend(row["offsets"][k])
    for k, v in offsets.items():
        assert abs(np.nanmean(v)) <= 0.02, (k, np.nanmean(v))


def test_contact_changes_keep_a_pose_nearby():
    """The floor of issue 34 (not its targets): today 97 % of the contact
    changes of the dev BVH files have a pose within 0.075 s (bandai walk
    83 %, the lowest); every file with 10 or more changes keeps 80 %."""
    hit = total = 0
    for name in dev_bvh_files():
        doc = st.extract(_motion(name))
        changes = np.array([t for c in doc.constraints for t in (c.start, c.end) if 0 < t < doc.duration - 1e-9])
        if not len(changes):
            continue
        near = np.min(np.abs(doc.pose_t[None, :] - changes[:, None]), axis=1) <= 0.075 + 1e-9
        hit, total = hit + int(near.sum()), total + len(near)
        if len(near) >= 10:
            assert near.mean() >= 0.8, (name, near.mean())
    assert total > 500 and hit / total >= 0.8, (hit, total)


@pytest.mark.parametrize("name", ["cmu_01_01_forward_jumps.bvh", "cmu_115_06_pick_up_box.bvh"])
def test_the_tpose_frame_makes_no_event(name):
    """Frame 0 of the cgspeed files is a T-pose: counted, the arms dropping
    from it make a swing extreme at frame 1 (0.008 s); left out, the first
    event of either file comes at 0.19 s or later (measured)."""
    e = _events(name)
    first = min([*e.root_extremes, *(t for v in e.swings.values() for t in v), *e.flights.ravel()])
    assert first >= 0.15, first


@functools.cache
def _bench():
    """bench/bench_events.py as a module (bench/ is not a package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "bench_events.py"
    spec = importlib.util.spec_from_file_location("bench_events", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_benchmarks_even_baseline_is_even_and_unrefined():
    """The sparse ratio's baseline: as many poses, none refined, on the
    evenly spaced frames; a document of two poses (idle) is its own baseline
    (ratio exactly 1)."""
    b = _bench()
    doc = st.extract(_motion("bandai2_run_normal_001.bvh"))
    even = b.even(doc)
    assert even.n_poses == doc.n_poses and not np.any(even.refinements())
    frames = np.round(even.pose_t / doc.frame_time)
    assert np.allclose(even.pose_t, frames * doc.frame_time) and np.ptp(np.diff(frames)) <= 1
    idle = _motion("games105_idle.bvh")
    row = b.measure_doc(st.extract(idle), _events("games105_idle.bvh"), idle, sparse=True)
    assert row["sparse"] == 1.0 and row["poses"] == 2


def test_the_benchmarks_nearest_offsets():
    b = _bench()
    times = np.array([0.0, 1.0, 2.0])
    got = b.nearest_offset(times, np.array([0.2, 0.6, 1.9, 5.0, -1.0]))
    assert np.allclose(got, [-0.2, 0.4, 0.1, -3.0, 1.0])
    assert len(b.nearest_offset(times, np.zeros(0))) == 0
    assert np.allclose(b.nearest_offset(np.array([1.0]), np.array([0.5, 3.0])), [0.5, -2.0])



def test_a_jumps_flight_has_its_pose_at_the_top():
    """The pose of a flight goes on its top, where an animator keys a jump's
    apex (extract's flight_frames: the vertex of the parabola the figure's
    centre follows, not the middle of the airborne frames).  On the forward
    jumps (120 Hz) the hips' highest frame of each flight (found here) has
    a pose within 0.02 s: measured at most 0.017 s (mean 0.007); at the
    flights' middle frames up to 0.025 s (mean 0.013)."""
    name = "cmu_01_01_forward_jumps.bvh"
    m, ev = _motion(name), _events(name)
    doc = st.extract(m)
    h = m.world_positions()[:, ev.place] @ ev.up
    t = np.arange(m.n_frames) * m.frame_time
    tops = []
    for a, b in ev.flights:
        inside = (t >= a - 1e-9) & (t <= b + 1e-9)
        tops.append(t[inside][np.argmax(h[inside])])
    near = np.min(np.abs(doc.pose_t[None, :] - np.array(tops)[:, None]), axis=1)
    assert len(tops) >= 9 and np.all(near <= 0.02), np.round(near, 3)


def test_no_bias_on_a_clip_with_a_jump_or_a_hop():
    """Issue 34: on every dev clip with a flight, the mean signed offset of
    the nearest pose to each kind of event within 0.03 s.  Measured: the
    Bandai dance -2, +6, +14, -7 ms (root, swing, take-off, landing), the
    run -9, +20, -11, +22, the jumps +15, +2, +14, +15, the CMU dance -5,
    -17, +8, +20.  The CMU dance's swings were -36 ms before a limb's swing
    with no pose near counted as a contact change in the placement: three
    slow swings in its last two seconds had their nearest pose 0.14-0.22 s
    away."""
    b = _bench()
    seen = 0
    for name in dev_bvh_files():
        if len(_events(name).flights) == 0:
            continue
        seen += 1
        for k, v in _row(name)["offsets"].items():
            if len(v):
                assert abs(np.mean(v)) <= 0.03, (name, k, np.mean(v))
    assert seen == 4 and b.KINDS


def test_a_slow_swing_far_from_the_poses_gets_one():
    """The CMU dance's slow last seconds: each hand swing of 5 % of the
    height or more (found here) has a pose within 0.12 s (measured 0.117,
    0.058 and 0.017 s; before, 0.142, 0.217 and 0.208 s)."""
    name = "cmu_05_06_modern_dance.bvh"
    doc, ev = st.extract(_motion(name)), _events(name)
    late = np.sort(np.concatenate([t[t > 5.5] for t in ev.swings.values()]))
    assert len(late) >= 3, late
    near = np.min(np.abs(doc.pose_t[None, :] - late[:, None]), axis=1)
    assert np.all(near <= 0.12) and np.mean(near) < 0.07, np.round(near, 3)
