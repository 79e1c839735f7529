"""Regression tests for review fixes: joints with one or two rotation channels,
``edit-pose --from-bvh`` on a file with fewer position channels, and
exaggeration that keeps the character in place."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import quat, sampling, variables
from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import bvh_bytes, parse_bvh, read_bvh
from staggered_cli.io.document import document_bytes, from_parts, parse_document, to_parts
from staggered_cli.motion import BvhMotion, channels_from_local, local_rotations_from_channels
from staggered_cli.ops import edit_pose as E
from staggered_cli.ops.extract import extract
from staggered_cli.representation import ROTATION, TRANSLATION

from .conftest import SAMPLES, mocap

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


def load(data: bytes):
    return from_parts(*parse_document(data, "test"))


def few_channel_motion(channels: np.ndarray) -> BvhMotion:
    """The FEW_CHANNELS skeleton with ``channels`` (T, 9), through the BVH writer and reader."""
    base = parse_bvh(FEW_CHANNELS.encode())
    m = BvhMotion(base.skeleton, np.asarray(channels, dtype=float), base.frame_time, base.frame_time_text, "%.6f")
    return parse_bvh(bvh_bytes(m))


def round_trip(m: BvhMotion) -> np.ndarray:
    rot = local_rotations_from_channels(m.skeleton, m.channels)
    return channels_from_local(m.skeleton, rot, m.local_translations(), m.channels)


# -- 1. joints with one or two rotation channels -------------------------------


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


# -- 2. --from-bvh with position channels on the root only ---------------------


def root_positions_only(m: BvhMotion, keep: tuple[str, ...], rename: dict[str, str] | None = None) -> BvhMotion:
    """``m`` with position channels only on the joints ``keep`` (as a Blender
    export writes it), and joints renamed by ``rename``."""
    sk = m.skeleton
    cols, channels = [], []
    for (a, b), (name, ch) in zip(m.channel_slices(), zip(sk.names, sk.channels, strict=True), strict=True):
        kept = [i for i, c in enumerate(ch) if name in keep or not c.endswith("position")]
        cols += [a + i for i in kept]
        channels.append(tuple(ch[i] for i in kept))
        assert b - a == len(ch)
    names = tuple((rename or {}).get(n, n) for n in sk.names)
    skel = replace(sk, channels=tuple(channels), names=names)
    out = BvhMotion(skel, m.channels[:, cols], m.frame_time, m.frame_time_text, m.number_format)
    return parse_bvh(bvh_bytes(out))


@pytest.fixture(scope="module")
def run_doc(tmp_path_factory):
    path = mocap("bandai2_run_normal_001.bvh")
    m = read_bvh(path)
    doc = extract(m, source_name=path.name, source_bytes=path.read_bytes())
    manifest, arrays = to_parts(doc)
    out = tmp_path_factory.mktemp("run") / "run.stag"
    out.write_bytes(document_bytes(manifest, arrays, "npz"))
    return m, doc, out


def test_from_bvh_takes_values_by_joint_name(run_doc, tmp_path):
    m, doc, doc_path = run_doc
    # this skeleton moves through Hips, below a still joint_Root
    blender = root_positions_only(m, ("joint_Root", "Hips"))
    assert not blender.skeleton.has_position(blender.skeleton.index("Spine"))
    f = tmp_path / "blender.bvh"
    f.write_bytes(bvh_bytes(blender))
    k, frame = 2, 40
    r = run(
        ["edit-pose", str(doc_path), "--pose", str(k), "--from-bvh", str(f), "--frame", str(frame)]
        + ["--joints", "Spine", "--subtree", "--format", "json"]
    )
    assert r.exit_code == 0, r.stderr
    edited = load(r.stdout_bytes)
    rot, tr = sampling.local_pose(edited, doc.pose_t[k : k + 1])
    rot0, tr0 = sampling.local_pose(doc, doc.pose_t[k : k + 1])
    sk = m.skeleton
    inside = sk.subtree(sk.index("Spine"))
    for j in range(sk.n_joints):
        if j in inside:
            assert np.degrees(quat.angle_between(rot[0, j], blender.local_rotations()[frame, j])) < 1e-6
            # no position channels in the file: the offset is the translation
            np.testing.assert_allclose(tr[0, j], sk.offsets[j], atol=1e-6)
        else:
            assert np.degrees(quat.angle_between(rot[0, j], rot0[0, j])) < 1e-6
            np.testing.assert_allclose(tr[0, j], tr0[0, j], atol=1e-6)
    # the whole pose (no --joints) works as well: every joint is in the file
    # (with root=True the root's place and heading come from the file too)
    values = E.values_from_motion(doc, blender, frame)
    whole = E.edit_pose(doc, k, values=values, root=True)
    rot, tr = sampling.local_pose(whole, doc.pose_t[k : k + 1])
    assert np.degrees(quat.angle_between(rot[0], blender.local_rotations()[frame])).max() < 1e-6
    np.testing.assert_allclose(tr[0], blender.local_translations()[frame], atol=1e-6)


def test_from_bvh_refuses_a_missing_joint_inside_the_mask(run_doc, tmp_path):
    m, doc, doc_path = run_doc
    other = root_positions_only(m, ("joint_Root", "Hips"), rename={"Head": "Kopf"})
    f = tmp_path / "renamed.bvh"
    f.write_bytes(bvh_bytes(other))
    base = ["edit-pose", str(doc_path), "--pose", "2", "--from-bvh", str(f), "--frame", "0", "--format", "json"]
    r = run(base + ["--joints", "Neck", "--subtree"])
    assert r.exit_code == 2, r.stderr
    assert "Head" in r.stderr and "Kopf" not in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.splitlines()) == 1
    r = run(base)  # the whole pose touches Head as well
    assert r.exit_code == 2 and "Head" in r.stderr
    # outside the mask a missing joint does not matter
    r = run(base + ["--joints", "UpperLeg_L", "--subtree"])
    assert r.exit_code == 0, r.stderr


# -- 3. exaggeration changes the shape, not the place ---------------------------


@pytest.fixture(scope="module")
def walk_doc():
    path = mocap("bandai1_walk_normal_001.bvh")
    m = read_bvh(path)
    return extract(m, source_name=path.name, source_bytes=path.read_bytes())


def test_exaggerate_keeps_the_root_in_place(walk_doc):
    doc = walk_doc
    k = min(16, doc.n_poses - 2)
    root = doc.source.skeleton.names[0]
    before = E.pose_values(doc, k, "true")
    ex = E.edit_pose(doc, k, exaggerate=1.5)  # relative to the average pose
    after = E.pose_values(ex, k, "true")
    moved_rot = 0.0
    for tr, b, a in zip(doc.tracks, before, after, strict=True):
        if tr.kind == TRANSLATION:
            np.testing.assert_array_equal(a, b)
        else:
            moved_rot = max(moved_rot, float(np.degrees(quat.angle_between(a, b)).max()))
    assert moved_rot > 1.0
    # the baked root stays where it was over the whole clip
    t = doc.frame_times
    _, tr0 = sampling.local_pose(doc, t)
    _, tr1 = sampling.local_pose(ex, t)
    np.testing.assert_allclose(tr1, tr0, atol=1e-9)
    # naming the root's joint scales its translation too
    for name in (root, "Hips"):
        named = E.edit_pose(doc, k, exaggerate=1.5, joints=[name])
        vals = E.pose_values(named, k, "true")
        ref = E.average_pose(doc)
        for tr, b, a, r in zip(doc.tracks, before, vals, ref, strict=True):
            if tr.kind != TRANSLATION:
                continue
            i = tr.names.index(f"{name}.position")
            np.testing.assert_allclose(a[i], r[i] + 1.5 * (b[i] - r[i]), atol=1e-9)
            others = np.arange(tr.n_vars) != i
            np.testing.assert_array_equal(a[others], b[others])


def test_exaggerate_through_the_cli(tmp_path):
    m = read_bvh(SAMPLES / "march.bvh")
    doc = variables.from_motion(m, np.arange(0.0, 4.0, 0.3))
    manifest, arrays = to_parts(doc)
    path = tmp_path / "march.stag"
    path.write_bytes(document_bytes(manifest, arrays, "npz"))
    r = run(["edit-pose", str(path), "--pose", "4", "--exaggerate", "2", "--format", "json"])
    assert r.exit_code == 0, r.stderr
    ex = load(r.stdout_bytes)
    for tr, a, b in zip(doc.tracks, E.pose_values(doc, 4, "true"), E.pose_values(ex, 4, "true"), strict=True):
        if tr.kind == TRANSLATION:
            np.testing.assert_allclose(b, a, atol=1e-12)
        else:
            assert tr.kind == ROTATION and np.degrees(quat.angle_between(a, b)).max() > 0.5
    root = m.skeleton.names[0]
    r = run(["edit-pose", str(path), "--pose", "4", "--exaggerate", "2", "--joints", root, "--format", "json"])
    assert r.exit_code == 0, r.stderr
    named = load(r.stdout_bytes)
    tr = next(tr for tr in doc.tracks if tr.kind == TRANSLATION)
    ti = doc.tracks.index(tr)
    i = tr.names.index(f"{root}.position")
    assert np.abs(E.pose_values(named, 4, "true")[ti][i] - E.pose_values(doc, 4, "true")[ti][i]).max() > 1e-3
