"""Joint and marker names as users type them (issue 14, item 6).

One ``--steps`` must serve a library of several skeletons: body parts
(``@left-arm``) resolve per skeleton, C3D labels work without their subject
prefix (``LSHO`` for ``Male:LSHO``), and an unknown name suggests the
closest ones.  Checked on every dev BVH of ../shared/mocap and the CMU C3D.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli.cli.main import cli
from staggered_cli.contacts.detect import contact_joints
from staggered_cli.errors import UsageError
from staggered_cli.io.bvh import read_bvh
from staggered_cli.io.c3d import read_c3d
from staggered_cli.model.variables import from_motion
from staggered_cli.names import PARTS, body_part, resolve
from staggered_cli.ops.edit_pose import joint_mask
from staggered_cli.ops.timing import randomize

from .conftest import dev_bvh_files, mocap, one_line_error, short_bvh

CMU = ("LeftShoulder", "RightShoulder", "LHipJoint", "RHipJoint", "LowerBack", "Neck")
#: file -> the joint each of PARTS resolves to, and a joint deep inside each part
EXPECTED = {
    "cmu_01_01_forward_jumps.bvh": (CMU, ("LeftHand", "RightHand", "LeftFoot", "RightFoot", "Spine1", "Head")),
    "cmu_02_01_walk.bvh": (CMU, ("LeftHand", "RightHand", "LeftFoot", "RightFoot", "Spine1", "Head")),
    "cmu_05_06_modern_dance.bvh": (CMU, ("LeftHand", "RightHand", "LeftFoot", "RightFoot", "Spine1", "Head")),
    "cmu_115_06_pick_up_box.bvh": (CMU, ("LeftHand", "RightHand", "LeftFoot", "RightFoot", "Spine1", "Head")),
    "cmu3dsmax_131_02_start_walk_stop.bvh": (
        ("LeftCollar", "RightCollar", "LHipJoint", "RHipJoint", "lowerback", "lowerneck"),
        ("lhand", "rhand", "LeftAnkle", "RightAnkle", "Chest2", "Head"),
    ),
    "games105_idle.bvh": (
        ("lTorso_Clavicle", "rTorso_Clavicle", "lHip", "rHip", "pelvis_lowerback", "torso_head"),
        ("lWrist", "rWrist", "lAnkle", "rAnkle", "lowerback_torso", "torso_head"),
    ),
}
BANDAI = (
    "bandai1_bow_normal_001",
    "bandai1_dance-short_normal_001",
    "bandai1_walk_normal_001",
    "bandai2_run_normal_001",
)
for _f in BANDAI:
    EXPECTED[f"{_f}.bvh"] = (
        ("Shoulder_L", "Shoulder_R", "UpperLeg_L", "UpperLeg_R", "Spine", "Neck"),
        ("Hand_L", "Hand_R", "Foot_L", "Foot_R", "Chest", "Head"),
    )


def test_every_dev_bvh_is_covered():
    assert sorted(EXPECTED) == dev_bvh_files()


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_body_parts_resolve_on_every_dev_skeleton(name):
    sk = read_bvh(mocap(name)).skeleton
    roots, inside = EXPECTED[name]
    for part, root, deep in zip(PARTS, roots, inside, strict=True):
        j = sk.index("@" + part)
        assert sk.names[j] == root, (part, sk.names[j])
        part_joints = {sk.names[i] for i in sk.subtree(j)}
        assert deep in part_joints, (part, deep)
    # the limbs' subtrees are the whole limb and nothing of the other side or the trunk
    for part in ("left-arm", "right-arm", "left-leg", "right-leg"):
        sub = set(sk.subtree(sk.index("@" + part)).tolist())
        for other in ("left-arm", "right-arm", "left-leg", "right-leg", "spine", "head"):
            if other != part:
                assert sk.index("@" + other) not in sub, (part, other)
    assert len(sk.subtree(sk.index("@left-arm"))) == len(sk.subtree(sk.index("@right-arm")))
    assert len(sk.subtree(sk.index("@left-leg"))) == len(sk.subtree(sk.index("@right-leg")))


# Naming schemes that are not in ../shared/mocap: (name, parent name) lists
# written from those tools' documented skeletons.
MIXAMO = [
    ("Hips", None),
    ("Spine", "Hips"),
    ("Spine1", "Spine"),
    ("Spine2", "Spine1"),
    ("Neck", "Spine2"),
    ("Head", "Neck"),
    ("LeftShoulder", "Spine2"),
    ("LeftArm", "LeftShoulder"),
    ("LeftForeArm", "LeftArm"),
    ("LeftHand", "LeftForeArm"),
    ("RightShoulder", "Spine2"),
    ("RightArm", "RightShoulder"),
    ("RightForeArm", "RightArm"),
    ("RightHand", "RightForeArm"),
    ("LeftUpLeg", "Hips"),
    ("LeftLeg", "LeftUpLeg"),
    ("LeftFoot", "LeftLeg"),
    ("LeftToeBase", "LeftFoot"),
    ("RightUpLeg", "Hips"),
    ("RightLeg", "RightUpLeg"),
    ("RightFoot", "RightLeg"),
    ("RightToeBase", "RightFoot"),
]
XSENS = [
    ("Pelvis", None),
    ("L5", "Pelvis"),
    ("L3", "L5"),
    ("T12", "L3"),
    ("T8", "T12"),
    ("Neck", "T8"),
    ("Head", "Neck"),
    ("RightShoulder", "T8"),
    ("RightUpperArm", "RightShoulder"),
    ("RightForeArm", "RightUpperArm"),
    ("RightHand", "RightForeArm"),
    ("LeftShoulder", "T8"),
    ("LeftUpperArm", "LeftShoulder"),
    ("LeftForeArm", "LeftUpperArm"),
    ("LeftHand", "LeftForeArm"),
    ("RightUpperLeg", "Pelvis"),
    ("RightLowerLeg", "RightUpperLeg"),
    ("RightFoot", "RightLowerLeg"),
    ("RightToe", "RightFoot"),
    ("LeftUpperLeg", "Pelvis"),
    ("LeftLowerLeg", "LeftUpperLeg"),
    ("LeftFoot", "LeftLowerLeg"),
    ("LeftToe", "LeftFoot"),
]
PYMO = [  # GENEA / Trinity gesture data as loaded with PyMO
    ("b_root", None),
    ("b_spine0", "b_root"),
    ("b_spine1", "b_spine0"),
    ("b_neck0", "b_spine1"),
    ("b_head", "b_neck0"),
    ("b_l_shoulder", "b_spine1"),
    ("b_l_arm", "b_l_shoulder"),
    ("b_l_forearm", "b_l_arm"),
    ("b_l_wrist", "b_l_forearm"),
    ("b_r_shoulder", "b_spine1"),
    ("b_r_arm", "b_r_shoulder"),
    ("b_r_forearm", "b_r_arm"),
    ("b_r_wrist", "b_r_forearm"),
    ("b_l_upleg", "b_root"),
    ("b_l_leg", "b_l_upleg"),
    ("b_l_foot", "b_l_leg"),
    ("b_r_upleg", "b_root"),
    ("b_r_leg", "b_r_upleg"),
    ("b_r_foot", "b_r_leg"),
]


def _skeleton(pairs, prefix=""):
    names = [prefix + n for n, _ in pairs]
    index = {n: i for i, (n, _) in enumerate(pairs)}
    parents = np.array([-1 if p is None else index[p] for _, p in pairs])
    return names, parents


@pytest.mark.parametrize(
    "pairs, prefix, expected",
    [
        (
            MIXAMO,
            "mixamorig:",
            ("LeftShoulder", "RightShoulder", "LeftUpLeg", "RightUpLeg", "Spine", "Neck"),
        ),
        (XSENS, "", ("LeftShoulder", "RightShoulder", "LeftUpperLeg", "RightUpperLeg", "L5", "Neck")),
        (PYMO, "", ("b_l_shoulder", "b_r_shoulder", "b_l_upleg", "b_r_upleg", "b_spine0", "b_neck0")),
    ],
)
def test_body_parts_in_other_naming_schemes(pairs, prefix, expected):
    names, parents = _skeleton(pairs, prefix)
    got = tuple(names[body_part(p, names, parents)].removeprefix(prefix) for p in PARTS)
    assert got == expected
    if prefix:  # the namespace is optional, as for C3D subject prefixes
        assert names[resolve("LeftForeArm", names, parents)] == "mixamorig:LeftForeArm"


def test_an_unresolvable_part_names_the_closest_joints():
    names, parents = _skeleton([("Hips", None), ("Spine", "Hips"), ("Neck", "Spine"), ("LeftUpLeg", "Hips")])
    with pytest.raises(UsageError) as err:
        resolve("@left-arm", names, parents)
    msg = err.value.message
    assert msg.startswith("no joint of this skeleton is @left-arm (closest: ") and "\n" not in msg
    assert "LeftUpLeg" in msg.split("closest:")[1]
    with pytest.raises(UsageError, match=r"unknown body part @left-hand \(parts: @left-arm"):
        resolve("@left-hand", names, parents)


def test_unknown_joint_names_suggest_close_ones():
    sk = read_bvh(mocap("cmu3dsmax_131_02_start_walk_stop.bvh")).skeleton
    with pytest.raises(UsageError) as err:
        sk.index("LeftArm")  # the cgspeed name; 3dsMax calls the upper arm LeftShoulder
    assert err.value.message.startswith("unknown joint 'LeftArm' (did you mean: ")
    with pytest.raises(UsageError, match=r"did you mean: LeftElbow"):
        sk.index("leftelbow")


@pytest.fixture(scope="module")
def breakdance():
    return read_c3d(mocap("cmu_85_12_breakdance_long.c3d"))


def test_c3d_labels_without_subject_prefix(breakdance):
    labels = breakdance.labels
    assert labels[resolve("LSHO", labels, what="marker")] == "Male:LSHO"
    assert contact_joints(breakdance, ["LTOE", "Male:RTOE"]) == ("Male:LTOE", "Male:RTOE")
    with pytest.raises(UsageError, match=r"unknown marker 'LSHOO' \(did you mean: Male:LSHO"):
        resolve("LSHOO", labels, what="marker")
    with pytest.raises(UsageError, match="needs a BVH skeleton"):
        resolve("@left-arm", labels, what="marker")
    twice = ("Male:LSHO", "Female:LSHO")
    with pytest.raises(UsageError, match="ambiguous: Male:LSHO, Female:LSHO"):
        resolve("LSHO", twice, what="marker")


def test_c3d_commands_take_labels_without_prefix(breakdance):
    doc = from_motion(breakdance, np.linspace(0.0, 5.0, 11), source_name="bd.c3d")
    mask = np.concatenate(joint_mask(doc, ["LSHO", "LELB"], False))
    assert [doc.variable_names[i] for i in np.flatnonzero(mask)] == ["Male:LSHO", "Male:LELB"]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bd.stag"
        from staggered_cli.cli.common import write_document

        write_document(doc, str(path), "npz", False)
        runner = CliRunner()
        r = runner.invoke(cli, ["succession", str(path), "--chain", "LSHO,LELB,LWRA", "--offset", "0.01", "--clamp"])
        assert r.exit_code == 0, r.stderr
        r = runner.invoke(cli, ["constraints", str(path), "--add", "LTOE@1:2", "-o", "-", "--format", "json"])
        assert r.exit_code == 0, r.stderr
        assert '"joint": "Male:LTOE"' in r.stdout
        r = runner.invoke(cli, ["succession", str(path), "--chain", "LSHO,LELBB", "--offset", "0.01"])
        one_line_error(r, 2, "bd.stag", "--chain: unknown marker 'LELBB' (did you mean: Male:LELB")


def test_joints_body_part_subtree_is_the_whole_limb():
    m = read_bvh(mocap("bandai2_run_normal_001.bvh"))
    doc = from_motion(m, np.linspace(0.0, m.n_frames * m.frame_time - m.frame_time, 9))
    mask = np.concatenate(joint_mask(doc, ["@left-arm"], True))
    assert sorted(doc.variable_names[i] for i in np.flatnonzero(mask)) == sorted(
        ["Shoulder_L", "UpperArm_L", "LowerArm_L", "Hand_L", "Shoulder_L.position", "UpperArm_L.position",
         "LowerArm_L.position", "Hand_L.position"]
    )  # fmt: skip
    out = randomize(doc, 0.02, 3, joints=["@left-arm"], subtree=True, clamp=True)
    moved = np.any(out.refinements() != doc.refinements(), axis=0)
    assert moved.any() and not np.any(moved & ~mask)


def _joint_channels(motion, names):
    cols = []
    for j, (a, b) in enumerate(motion.channel_slices()):
        if motion.skeleton.names[j] in names:
            cols.extend(range(a, b))
    return motion.channels[:, cols]


def test_one_batch_steps_serves_every_dev_skeleton():
    """``--joint @left-arm`` in one step, over the 10 dev BVH: every file is
    done, its left arm is staggered and the rest of the body is unchanged."""
    files = [mocap(n) for n in dev_bvh_files()]
    steps = "cull --keep 30%|succession --joint @left-arm --offset 0.02 --power 1.5 --clamp"
    with tempfile.TemporaryDirectory() as tmp:
        lib, out = Path(tmp) / "in", Path(tmp) / "out"
        lib.mkdir()
        for f in files:  # the first 10 s of each: the skeleton is what the names are about
            (lib / f.name).write_bytes(short_bvh(f.name, 10.0))
        r = CliRunner().invoke(cli, ["batch", str(lib), str(out), "--jobs", "2", "--steps", steps])
        assert r.exit_code == 0, r.stdout + r.stderr
        # the idle stance keeps only its end poses: nothing to stagger, its output is its input
        assert "10 files: 9 built, 1 unchanged, 0 skipped, 0 failed" in r.stdout
        for f in files:
            src, baked = read_bvh(lib / f.name), read_bvh(out / f.name)
            sk = src.skeleton
            arm = {sk.names[i] for i in sk.subtree(sk.index("@left-arm"))}
            rest = set(sk.names) - arm
            np.testing.assert_allclose(_joint_channels(baked, rest), _joint_channels(src, rest), atol=1e-3)
            change = np.abs(_joint_channels(baked, arm) - _joint_channels(src, arm)).max()
            if f.name != "games105_idle.bvh":  # an idle stance keeps only its end poses: nothing to stagger
                assert change > 0.05, (f.name, change)  # degrees


def test_unknown_names_suggest_the_same_side_and_segment_first():
    """A name from another skeleton's scheme suggests this skeleton's joint
    for the same bone: not the first joints, not a spelling cousin."""
    bandai = read_bvh(mocap("bandai2_run_normal_001.bvh")).skeleton
    with pytest.raises(UsageError) as err:
        bandai.index("LeftArm")
    assert err.value.message == "unknown joint 'LeftArm' (did you mean: UpperArm_L, Shoulder_L, LowerArm_L?)"
    cmu = read_bvh(mocap("cmu_02_01_walk.bvh")).skeleton
    with pytest.raises(UsageError) as err:
        cmu.index("UpperArm_L")
    assert err.value.message == "unknown joint 'UpperArm_L' (did you mean: LeftArm, LeftShoulder, LeftForeArm?)"
    with pytest.raises(UsageError, match=r"did you mean: RightUpLeg, "):
        cmu.index("UpperLeg_R")
    with pytest.raises(UsageError, match=r"did you mean: LowerArm_L, "):
        bandai.index("leftelbow")  # glued side word, joint named for where it sits
    games = read_bvh(mocap("games105_idle.bvh")).skeleton
    with pytest.raises(UsageError, match=r"did you mean: rHip, rKnee\?"):
        games.index("RightUpLeg")
