"""Dense motion (staggered_cli.motion): channels to local rotations and
translations and back, joints with one or two rotation channels, frame rates."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.errors import UsageError
from staggered_cli.io.bvh import bvh_bytes, parse_bvh, read_bvh
from staggered_cli.motion import (
    MAX_FRAME_TIME,
    MAX_RATE,
    MIN_FRAME_TIME,
    MIN_RATE,
    BvhMotion,
    MarkerMotion,
    channels_from_local,
    frame_time_problem,
    local_rotations_from_channels,
    local_translations_from_channels,
    nominal_rate,
    position_columns,
    rate_problem,
    rotation_columns,
)

from .conftest import SAMPLES, dev_motion

# a leg whose knee has two rotation channels and whose ankle has one
FEW_CHANNELS = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Knee
\t{
\t\tOFFSET 0 -40 0
\t\tCHANNELS 2 Zrotation Xrotation
\t\tJOINT Ankle
\t\t{
\t\t\tOFFSET 0 -40 0
\t\t\tCHANNELS 1 Xrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0 0 10
\t\t\t}
\t\t}
\t}
}
MOTION
Frames: 1
Frame Time: 0.0333333
0 90 0 0 0 0 0 0 0
"""


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


def few_channel_motion(channels: np.ndarray) -> BvhMotion:
    """The FEW_CHANNELS skeleton with ``channels`` (T, 9), through the BVH writer and reader."""
    base = parse_bvh(FEW_CHANNELS.encode())
    m = BvhMotion(base.skeleton, np.asarray(channels, dtype=float), base.frame_time, base.frame_time_text, "%.6f")
    return parse_bvh(bvh_bytes(m))


def round_trip(m: BvhMotion) -> np.ndarray:
    rot = local_rotations_from_channels(m.skeleton, m.channels)
    return channels_from_local(m.skeleton, rot, m.local_translations(), m.channels)


def test_one_and_two_channel_joints_round_trip_exactly():
    # Knee (Z, X) and Ankle (X): the reviewer's rows (a middle angle beyond
    # +-90 and a wrap to 190), whole turns, and values near the lock at 90
    rows = [
        (10, 100, 190),
        (10, 120, -170),
        (190, 30, 370),
        (-200, -135, -95),
        (350, 90, 90),
        (45, -90, 270),
        (725, 179, -181),
        (0, 180, 540),
    ]
    ch = np.zeros((len(rows), 9))
    ch[:, 1] = 90.0
    ch[:, 6:9] = rows
    m = few_channel_motion(ch)
    np.testing.assert_array_equal(m.channels, ch)
    back = round_trip(m)
    assert np.abs(back - ch).max() < 1e-9, back[:, 6:9]


def smooth_few_channel_motion() -> np.ndarray:
    T = 60
    t = np.arange(T) / 30.0
    ch = np.zeros((T, 9))
    ch[:, 0] = np.round(20.0 * t, 4)
    ch[:, 1] = np.round(90.0 + 3.0 * np.sin(4.0 * t), 4)
    ch[:, 3] = np.round(15.0 * np.sin(2.0 * t), 4)
    ch[:, 6] = np.round(10.0 + 100.0 * t, 4)  # Knee Z: 10 -> 207, through 190
    ch[:, 7] = np.round(100.0 + 40.0 * np.sin(3.0 * t), 4)  # Knee X beyond 90
    ch[:, 8] = np.round(150.0 + 100.0 * np.sin(2.5 * t), 4)  # Ankle X past 180
    return ch


def test_one_and_two_channel_joints_survive_extract_and_bake(tmp_path):
    ch = smooth_few_channel_motion()
    m = few_channel_motion(ch)
    assert np.abs(round_trip(m) - ch).max() < 1e-9
    src = tmp_path / "leg.bvh"
    src.write_bytes(bvh_bytes(m))
    doc = tmp_path / "leg.stag"
    r = run(["extract", str(src), "-o", str(doc)])
    assert r.exit_code == 0, r.stderr
    out = tmp_path / "leg_back.bvh"
    r = run(["bake", str(doc), "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    back = read_bvh(out)
    assert back.channels.shape == ch.shape
    assert np.abs(back.channels - ch).max() < 1e-9, np.abs(back.channels - ch).max(axis=0)


# -- frame rates, channel layout, derived arrays -------------------------------


@pytest.mark.parametrize(
    "frame_time, rate",
    [
        (0.0083333, 120.0),
        (0.008333, 120.0),
        (0.016667, 60.0),
        (0.0333333, 30.0),
        (0.033333, 30.0),
        (0.01, 100.0),
        (0.04, 25.0),
        (1 / 29.97, 29.97),  # a true fractional rate stays fractional
        (0.007, 1 / 0.007),
        (0.0, 0.0),
    ],
)
def test_nominal_rate_snaps_rounded_frame_times(frame_time, rate):
    assert nominal_rate(frame_time) == pytest.approx(rate, rel=1e-12)
    if rate and rate == round(rate):
        assert nominal_rate(frame_time) == round(rate)  # exactly the whole number


def test_frame_time_and_rate_limits():
    for ft in (MIN_FRAME_TIME, 0.0083333, MAX_FRAME_TIME, MAX_FRAME_TIME * (1 + 1e-10)):
        assert frame_time_problem(ft) is None, ft
    for ft in (MIN_FRAME_TIME * 0.99, 1.01, 0.0, -0.01, 1e308):
        assert "is out of range: frame times go from 0.0001 to 1 s (1 Hz to 10000 Hz)" == frame_time_problem(ft)
    assert rate_problem(MIN_RATE) is None and rate_problem(MAX_RATE) is None and rate_problem(120.0) is None
    assert rate_problem(0.5) == "is out of range: frame rates go from 1 Hz to 10000 Hz"
    assert rate_problem(10_001.0) is not None


def test_channel_layout_of_few_channel_and_partial_position_joints():
    m = parse_bvh(FEW_CHANNELS.encode())
    sk = m.skeleton
    assert m.channel_slices() == [(0, 6), (6, 8), (8, 9)]
    assert rotation_columns(sk) == [(0, [3, 4, 5], "ZXY"), (1, [6, 7], "ZX"), (2, [8], "X")]
    assert position_columns(sk) == [(0, [0, 1, 2])]
    # a joint with only Y and X position channels keeps its offset's z
    partial = replace(sk, channels=(sk.channels[0], ("Yposition", "Xposition", "Zrotation"), ("Xrotation",)))
    assert position_columns(partial) == [(0, [0, 1, 2]), (1, [7, 6, -1])]
    ch = np.array([[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, -7.0, 4.0, 0.0, 0.0]])
    tr = local_translations_from_channels(partial, ch)
    np.testing.assert_array_equal(tr[0, 0], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(tr[0, 1], [4.0, -7.0, sk.offsets[1, 2]])
    np.testing.assert_array_equal(tr[0, 2], sk.offsets[2])


def test_local_rotations_follow_each_joints_order_and_are_unrolled():
    m = parse_bvh(FEW_CHANNELS.encode())
    sk = m.skeleton
    t = np.linspace(0.0, 1.0, 50)
    ch = np.zeros((50, 9))
    ch[:, 3:6] = np.stack([400.0 * t, 80.0 * t - 40.0, -300.0 * t], axis=-1)  # root turns past 360 degrees
    ch[:, 6:8] = np.stack([30.0 * t, 200.0 * t], axis=-1)
    ch[:, 8] = 720.0 * t
    rot = local_rotations_from_channels(sk, ch)
    root = quat.from_euler(ch[:, 3:6], "ZXY")
    np.testing.assert_allclose(np.abs(np.sum(rot[:, 0] * root, axis=-1)), 1.0, atol=1e-12)  # same rotation
    knee = quat.mul(quat.from_axis_angle("Z", np.radians(ch[:, 6])), quat.from_axis_angle("X", np.radians(ch[:, 7])))
    np.testing.assert_allclose(np.abs(np.sum(rot[:, 1] * knee, axis=-1)), 1.0, atol=1e-12)
    assert np.all(np.sum(rot[1:] * rot[:-1], axis=-1) > 0.0)  # each joint's track is unrolled
    np.testing.assert_allclose(
        np.degrees(quat.angle(rot[:, 2])), np.abs((720.0 * t + 180.0) % 360.0 - 180.0), atol=1e-9
    )


def test_channels_come_back_nearest_the_reference():
    m = few_channel_motion(smooth_few_channel_motion())
    rot, tr = m.local_rotations(), m.local_translations()
    turned = m.channels.copy()
    turned[:, 3:] += 360.0 * np.array([1, -2, 0, 1, -1, 2])  # whole turns on every rotation channel
    back = channels_from_local(m.skeleton, rot, tr, turned)
    np.testing.assert_allclose(back, turned, atol=1e-9)
    # the positions come from the translations, not the reference
    moved = tr.copy()
    moved[:, 0] += [1.0, -2.0, 0.5]
    out = channels_from_local(m.skeleton, rot, moved, m.channels)
    np.testing.assert_allclose(out[:, :3], m.channels[:, :3] + [1.0, -2.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(out[:, 3:], m.channels[:, 3:], atol=1e-9)


def test_derived_arrays_are_computed_once_and_read_only(cmu_walk):
    m, _ = cmu_walk
    # the local rotations and world positions are kept; world rotations and
    # local translations (mostly the constant offsets) are made when asked
    assert m.local_rotations() is m.local_rotations() and m.world_positions() is m.world_positions()
    assert m.world()[1] is m.world_positions()
    for a in (m.local_rotations(), m.local_translations(), *m.world()):
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a[0, 0, 0] = 1.0
    assert m.n_frames == 343 and m.rate == 120.0 and m.frame_time_text == "0.008333"


def test_marker_motion_lookup_and_figure_height():
    pts = np.full((4, 3, 3), np.nan)
    pts[:, 0] = [0.0, 0.0, 0.0]
    pts[:, 1] = [0.0, 0.0, 1700.0]
    pts[:, 2] = [300.0, 0.0, 900.0]
    pts[3, 1] = np.nan  # the head marker lost in the last frame
    m = MarkerMotion(("Male:LTOE", "Male:HEAD", "Male:LWRA"), pts, 100.0, "mm")
    assert m.n_frames == 4 and m.frame_time == pytest.approx(0.01)
    assert m.index("HEAD") == 1 and m.index("Male:LWRA") == 2
    with pytest.raises(UsageError, match="LTOE"):
        m.index("LTOO")
    assert m.figure_height() == pytest.approx(1700.0)  # median over frames of the largest side
    assert MarkerMotion(("a",), np.full((5, 1, 3), np.nan), 50.0).figure_height() == 1.0  # nothing seen
    twice = MarkerMotion(("Male:LSHO", "Female:LSHO"), np.zeros((1, 2, 3)), 50.0)
    with pytest.raises(UsageError, match="ambiguous"):
        twice.index("LSHO")


def test_real_c3d_figure_height():
    m = dev_motion("c3dorg_sample01_Eb015pi_walk.c3d")
    assert m.units == "mm" and m.rate == 50.0
    # pelvis, thigh, shank and foot markers only: the lower body's box, in millimetres (measured)
    assert m.figure_height() == pytest.approx(914.5000272542238, rel=1e-9)


def _rotations_joint_by_joint(sk, channels):
    """The plain form: each joint's rotations over the whole clip, then
    each joint's whole track unrolled on its own."""
    from staggered_cli.motion import rotation_columns

    rot = quat.identity((len(channels), sk.n_joints))
    for j, cols, order in rotation_columns(sk):
        if len(order) == 3:
            rot[:, j] = quat.from_euler(channels[:, cols], order)
        else:
            q = quat.identity((len(channels),))
            for col, axis in zip(cols, order, strict=True):
                q = quat.mul(q, quat.from_axis_angle(axis, np.radians(channels[:, col])))
            rot[:, j] = q
    for j in range(sk.n_joints):
        rot[:, j] = quat.unroll(rot[:, j], axis=0)
    return rot


@pytest.mark.parametrize("block", [4, 28, 1 << 18])
def test_rotations_made_in_blocks_of_frames_are_those_of_whole_tracks(monkeypatch, block):
    """Blocks of a few frames, made and unrolled (a block boundary between
    every few frames), with flips that cross boundaries and exact half-turn
    steps (dot 0, where the parity must carry over unchanged): the same bits."""
    from staggered_cli import motion as motion_module

    m = parse_bvh((SAMPLES / "march.bvh").read_bytes())
    ch = np.array(m.channels, copy=True)
    rng = np.random.default_rng(7)
    rows = rng.choice(len(ch), size=len(ch) // 3, replace=False)
    ch[rows, 3:] += rng.choice([180.0, -360.0, 540.0, 90.0], size=(len(rows), ch.shape[1] - 3))
    ch[5:9, 3:6] = [[0.0, 0.0, 0.0], [180.0, 0.0, 0.0], [0.0, 180.0, 0.0], [90.0, 90.0, 90.0]]
    want = _rotations_joint_by_joint(m.skeleton, ch)
    monkeypatch.setattr(motion_module, "_ROTATION_BLOCK", block)
    monkeypatch.setattr(quat, "_UNROLL_BLOCK", block)
    got = motion_module.local_rotations_from_channels(m.skeleton, ch)
    assert got.tobytes() == want.tobytes()
    raw = motion_module.local_rotations_from_channels(m.skeleton, ch, unroll=False)
    assert np.array_equal(np.abs(quat.dot(raw, got)), np.abs(quat.dot(got, got)))  # only signs differ


@pytest.mark.parametrize("block", [1, 40, 1 << 13])
def test_joints_of_one_euler_order_converted_together_give_each_joints_bits(monkeypatch, block):
    """The 3dsMax-friendly CMU file mixes ZYX and ZXY joints, the
    few-channel leg has one- and two-channel joints: channels to rotations
    and back, a group of joints and a block of frames at a time (a block of
    one joint-frame to many frames), are bit for bit each joint alone."""
    from staggered_cli import motion as motion_module

    monkeypatch.setattr(motion_module, "_EULER_BLOCK", block)
    mixed = dev_motion("cmu3dsmax_131_02_start_walk_stop.bvh")
    groups = motion_module.euler_groups(mixed.skeleton)[0]
    assert {len(js) for order, js, _ in groups} == {19, 12}  # the root is ZYX too
    for m in (mixed, few_channel_motion(smooth_few_channel_motion())):
        sk, ch = m.skeleton, np.asarray(m.channels)[:300]
        rot = local_rotations_from_channels(sk, ch)
        assert rot.tobytes() == _rotations_joint_by_joint(sk, ch).tobytes()
        turned = ch + 360.0 * np.round(np.sin(np.arange(ch.size)).reshape(ch.shape))  # whole turns to undo
        back = channels_from_local(sk, rot, local_translations_from_channels(sk, ch), turned)
        want = turned.copy()
        for j, cols, order in rotation_columns(sk):
            if len(order) == 3:
                want[:, cols] = quat.to_euler(rot[:, j], order, turned[:, cols])
        assert back[:, [c for _, cols, o in rotation_columns(sk) if len(o) == 3 for c in cols]].tobytes() == (
            want[:, [c for _, cols, o in rotation_columns(sk) if len(o) == 3 for c in cols]].tobytes()
        )


@pytest.mark.parametrize("name", ["cmu3dsmax_131_02_start_walk_stop.bvh", "bandai1_walk_normal_001.bvh"])
def test_rotation_columns_made_a_joint_at_a_time_are_the_clips_bits(name):
    """A long clip's fit takes its rotations a joint at a time, each made
    alone when asked (mixed Euler orders, unrolled): each is the column of
    the whole clip's, bit for bit, and so are the few-channel joints'."""
    for m in (dev_motion(name), few_channel_motion(smooth_few_channel_motion())):
        m = BvhMotion(m.skeleton, np.asarray(m.channels), m.frame_time)  # nothing cached
        joints = np.arange(m.skeleton.n_joints)[::-1]
        lazy = m.local_rotation_columns(joints)
        assert "_local_rotations" not in m.__dict__
        whole = local_rotations_from_channels(m.skeleton, m.channels)
        assert len(lazy) == len(joints)
        for n, j in enumerate(joints):
            assert lazy[n].tobytes() == whole[:, j].tobytes(), m.skeleton.names[j]
        assert "_local_rotations" not in m.__dict__  # made for the asking, not kept
        cached = m.local_rotations()
        assert all(c.base is cached or c.base is cached.base for c in m.local_rotation_columns(joints[:3]))


def test_translations_of_some_joints_are_those_columns_and_world_positions_hold(monkeypatch):
    """Translations are made for the joints asked (a clip's translation
    variables are a joint or two), and forward kinematics makes each block
    of frames' own: the same bits as the whole clip's at once."""
    from staggered_cli import motion as motion_module
    from staggered_cli.skeleton import forward_kinematics

    m = dev_motion("cmu_02_01_walk.bvh")
    sk = m.skeleton
    whole = local_translations_from_channels(sk, m.channels)
    joints = np.array([0, 5, 2])
    assert m.local_translations(joints).tobytes() == whole[:, joints].tobytes()
    assert m.local_translations().tobytes() == whole.tobytes()
    _, wp = forward_kinematics(sk, local_rotations_from_channels(sk, m.channels), whole)
    monkeypatch.setattr(motion_module, "_FK_BLOCK", 7 * sk.n_joints)  # blocks of 7 frames
    fresh = BvhMotion(sk, np.asarray(m.channels), m.frame_time)
    assert fresh.world_positions().tobytes() == wp.tobytes()
