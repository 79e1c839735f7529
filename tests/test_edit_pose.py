"""edit-pose on real captures: exaggeration changes the shape, not the place
(BVH root, C3D centroid); --from-bvh takes values by joint name, keeps the
document's place and heading, never changes far frames, and refuses a file
of another rig."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.errors import DataError
from staggered_cli.io.bvh import bvh_bytes, parse_bvh
from staggered_cli.io.container import parse_document
from staggered_cli.io.schema import from_parts
from staggered_cli.model import sampling
from staggered_cli.model.kinds import TRANSLATION
from staggered_cli.motion import BvhMotion
from staggered_cli.ops import edit_pose as E
from staggered_cli.ops.bake import bake

from .conftest import dev_bake, dev_document, dev_motion, document_file, mocap, one_line_error


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


def load(data: bytes):
    return from_parts(*parse_document(data, "test"))


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
def run_doc(tmp_path_factory, bandai_run):
    m, doc = bandai_run
    return m, doc, document_file(doc, tmp_path_factory.mktemp("run") / "run.stag")


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


@pytest.fixture(scope="module")
def walk_doc():
    return dev_document("bandai1_walk_normal_001.bvh")


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
    # naming the root's joint alone keeps its place; with root=True (--root) its translation is scaled too
    named = E.edit_pose(doc, k, exaggerate=1.5, joints=["Hips"])
    _, tr2 = sampling.local_pose(named, t)
    np.testing.assert_allclose(tr2, tr0, atol=1e-9)
    for name in (root, "Hips"):
        named = E.edit_pose(doc, k, exaggerate=1.5, joints=[name], root=True)
        vals = E.pose_values(named, k, "true")
        ref = E.average_pose(doc)
        for tr, b, a, r in zip(doc.tracks, before, vals, ref, strict=True):
            if tr.kind != TRANSLATION:
                continue
            i = tr.names.index(f"{name}.position")
            np.testing.assert_allclose(a[i], r[i] + 1.5 * (b[i] - r[i]), atol=1e-9)
            others = np.arange(tr.n_vars) != i
            np.testing.assert_array_equal(a[others], b[others])


EB015 = "c3dorg_sample01_Eb015pi_walk.c3d"


CMU_C3D = "cmu_85_12_breakdance_long.c3d"


BTS = "ezc3d_BTS_walk_gaps.c3d"


def c3d_doc(name: str):
    """(clip, extracted document, its unedited bake), made once per session."""
    return dev_motion(name), dev_document(name), dev_bake(name).points


def centroid_moved(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance (file units) between the per-frame centroids of the
    markers seen in both ``a`` and ``b`` (T, M, 3)."""
    seen = np.all(np.isfinite(a), -1) & np.all(np.isfinite(b), -1)
    n = seen.sum(axis=1)
    ok = n > 0
    ca = np.where(seen[..., None], a, 0.0).sum(axis=1)[ok] / n[ok, None]
    cb = np.where(seen[..., None], b, 0.0).sum(axis=1)[ok] / n[ok, None]
    return float(np.linalg.norm(ca - cb, axis=1).max())


@pytest.mark.parametrize(
    "name, relative_to, bound",
    [
        (EB015, "average", 0.01),  # before: 48 %
        (EB015, "prev", 0.01),  # before: 2.9 %
        # the breakdance's upper body turns about the held stance (planted
        # feet to the body's centre, as they were) with its limbs at their
        # lengths (test_exaggerate_truth): the centroid follows it (3.3 %,
        # 5.6 % against the previous pose); with the limbs stretched instead
        # it stayed within 0.24 %
        (CMU_C3D, "average", 0.04),  # before the shape was scaled about the centre: 28 %
        (CMU_C3D, "prev", 0.06),  # before: 3.0 %
        (BTS, "average", 0.01),  # before: 97 %
        (BTS, "prev", 0.01),  # before: 7.3 %
    ],
)
def test_c3d_exaggerate_changes_the_shape_not_the_place(name, relative_to, bound):
    m, doc, plain = c3d_doc(name)
    size = m.figure_height()
    seen = np.all(np.isfinite(m.points), axis=2)
    frame = np.rint(doc.pose_t / doc.frame_time).astype(int)
    poses = [3, doc.n_poses // 2, doc.n_poses - 4]
    if relative_to == "prev":  # a previous pose must capture the markers the pose shows
        poses = [k for k in poses if not np.any(seen[frame[k]] & ~seen[frame[k - 1]])]
        assert poses, "no pose to test"
    for k in poses:
        edited = E.edit_pose(doc, k, exaggerate=1.5, relative_to=relative_to)
        out = bake(edited).points
        assert centroid_moved(out, plain) <= bound * size, (k, centroid_moved(out, plain) / size)
        # the shape did change (pose 3 of the breakdance is close to pose 2: 0.8 %)
        assert np.nanmax(np.linalg.norm(out - plain, axis=-1)) > 0.005 * size


@pytest.mark.parametrize("name", [EB015, BTS])
def test_c3d_exaggerate_relative_to_the_average_scales_a_body_shape(name):
    """The average a walk's pose is exaggerated against is a body's shape:
    on the BTS walk, whose markers are each seen over another stretch of
    the walkway, the mean of each marker alone put the right shank 1.6 m
    ahead of C7, and halving the difference threw it 0.57 m (0.44 of the
    figure's height).  Now no marker moves more than a fifth of it."""
    m, doc, plain = c3d_doc(name)
    size = m.figure_height()
    for k in (3, doc.n_poses // 2, doc.n_poses - 4):
        for w in (0.5, 1.5):
            out = bake(E.edit_pose(doc, k, exaggerate=w, relative_to="average")).points
            moved = np.nanmax(np.linalg.norm(out - plain, axis=-1))
            assert 0.005 * size < moved <= 0.2 * size, (k, w, moved / size)


def test_c3d_exaggerate_refuses_a_reference_pose_missing_markers_of_the_pose(tmp_path):
    """Pose 1 of the BTS walk captures 5 of the 22 markers pose 9 shows: the
    others' places there are gap fillers, no pose to exaggerate against."""
    path = document_file(dev_document(BTS), tmp_path / "bts.stag")
    argv = ["edit-pose", str(path), "--pose", "9", "--exaggerate", "2", "--relative-to", "1", "-o", "-"]
    r = CliRunner().invoke(cli, argv)
    one_line_error(r, 2, "pose 1 (frame 276) does not capture 17 of the markers pose 9 shows", "average")


@pytest.fixture(scope="module")
def dance():
    return dev_motion("cmu_05_06_modern_dance.bvh")


def outside_neighbours(doc, k: int, blend: float = 0.1) -> np.ndarray:
    """(T,) frames beyond pose k's neighbours' knots and a blend window."""
    lo = min(tr.knot_t[tr.knot_pose == k - 1].min() for tr in doc.tracks) - blend
    hi = max(tr.knot_t[tr.knot_pose == k + 1].max() for tr in doc.tracks) + blend
    t = doc.frame_times
    return (t < lo - 1e-9) | (t > hi + 1e-9)


@pytest.mark.parametrize("root", [False, True], ids=["keep-place", "root"])
def test_from_bvh_keeps_place_and_heading_and_never_changes_far_frames(cmu_walk, dance, root):
    m, doc = cmu_walk
    k, frame = 3, 300
    values = E.values_from_motion(doc, dance, frame)
    edited = E.edit_pose(doc, k, values=values, root=root)
    a, b = bake(edited), bake(doc)
    # far frames (frame 0 and the last included) are the source's own numbers
    far = outside_neighbours(doc, k)
    assert far[0] and far[-1]
    np.testing.assert_array_equal(a.channels[far], b.channels[far])  # before: 10° (24° with --root) at frame 0
    f = int(round(doc.pose_t[k] / doc.frame_time))
    up = E.up_axis(doc)
    hips = m.skeleton.index("Hips")
    heading_a, rest_a = E.heading_split(a.world()[0][f, hips], up)
    heading_b, _ = E.heading_split(b.world()[0][f, hips], up)
    heading_file, rest_file = E.heading_split(dance.world()[0][frame, hips], up)
    place = np.linalg.norm(a.world()[1][f, hips] - b.world()[1][f, hips]) / m.figure_height()
    if root:  # everything from the file: its heading, 54° off the walk's
        assert np.degrees(quat.angle_between(heading_a, heading_file)) < 1e-6
        assert np.degrees(quat.angle_between(heading_a, heading_b)) > 45.0
        assert place > 0.3
    else:  # before: 54° and 45 % of the height
        assert np.degrees(quat.angle_between(heading_a, heading_b)) < 1e-6
        assert place < 1e-9
    # the rest of the root's rotation, and every other joint, come from the file
    assert np.degrees(quat.angle_between(rest_a, rest_file)) < 1e-6
    joints = [m.skeleton.index(n) for n in ("LeftUpLeg", "LeftLeg", "RightArm", "Head")]
    local = bake(edited, ik=False).local_rotations()[f, joints]  # (the contact layer bends planted legs)
    assert np.degrees(quat.angle_between(local, dance.local_rotations()[frame, joints])).max() < 1e-3


def test_from_bvh_refuses_a_file_with_other_axes(cmu_walk, tmp_path):
    m, doc = cmu_walk
    doc_path = document_file(doc, tmp_path / "doc.stag")
    # Blender's default export: Y-up offsets turned Z-up (+90° about X)
    turn = quat.from_euler(np.array([90.0, 0.0, 0.0]), "XYZ")
    sk = m.skeleton
    z_up = type(m)(
        type(sk)(
            sk.names,
            sk.parents,
            quat.mul_vec(turn, sk.offsets),
            sk.channels,
            sk.end_parents,
            quat.mul_vec(turn, sk.end_offsets),
        ),
        m.channels,
        m.frame_time,
        m.frame_time_text,
        m.number_format,
    )
    bad = tmp_path / "blender_z_up.bvh"
    bad.write_bytes(bvh_bytes(z_up))
    r = CliRunner().invoke(cli, ["edit-pose", str(doc_path), "--pose", "3", "--from-bvh", str(bad), "--frame", "0"])
    one_line_error(r, 1, "blender_z_up.bvh", "joint 'LeftUpLeg'", "11 % of the figure height")
    # the same rig on another actor (CMU subject 115, bones up to 3.5 % longer) is accepted
    other = mocap("cmu_115_06_pick_up_box.bvh")
    r = CliRunner().invoke(
        cli,
        [
            "edit-pose",
            str(doc_path),
            "--pose",
            "3",
            "--from-bvh",
            str(other),
            "--frame",
            "100",
            "-o",
            "-",
            "--format",
            "json",
        ],
    )
    assert r.exit_code == 0, r.stderr


def test_from_bvh_refuses_a_joint_under_another_parent(cmu_walk, tmp_path):
    m, doc = cmu_walk
    sk = m.skeleton
    parents = sk.parents.copy()
    j = sk.index("RightUpLeg")
    parents[j] = sk.index("LHipJoint")  # same names and offsets, another hierarchy
    moved = type(m)(
        type(sk)(sk.names, parents, sk.offsets, sk.channels, sk.end_parents, sk.end_offsets),
        m.channels,
        m.frame_time,
        m.frame_time_text,
        m.number_format,
    )
    with pytest.raises(DataError, match="'RightUpLeg': its parent is 'LHipJoint', not 'RHipJoint'"):
        E.values_from_motion(doc, moved, 0)


def test_a_negative_pose_index_counts_from_the_end_and_past_it_is_refused(tmp_path):
    """As the README says (command-line conventions): `--pose -1` is the last
    pose, `--pose -K-1` one line, exit 2."""
    doc = dev_document("cmu_02_01_walk.bvh")
    k = doc.n_poses - 2
    a = E.edit_pose(doc, -2, rotate={"LeftArm": (0.0, 0.0, 10.0)})
    b = E.edit_pose(doc, k, rotate={"LeftArm": (0.0, 0.0, 10.0)})
    assert bvh_bytes(bake(a)) == bvh_bytes(bake(b)) != bvh_bytes(dev_bake("cmu_02_01_walk.bvh"))
    path = document_file(doc, tmp_path / "walk.stag")
    far = str(-doc.n_poses - 1)
    r = CliRunner().invoke(cli, ["edit-pose", str(path), "--pose", far, "--rotate", "LeftArm=0,0,10", "-o", "-"])
    one_line_error(r, 2, f"pose {far} is out of range", f"poses 0 to {doc.n_poses - 1}")
