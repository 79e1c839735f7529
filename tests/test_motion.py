"""Dense motion (staggered_cli.motion): channels to local rotations and
translations and back, joints with one or two rotation channels, frame rates."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import bvh_bytes, parse_bvh, read_bvh
from staggered_cli.motion import BvhMotion, channels_from_local, local_rotations_from_channels

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
