"""The contact layer (staggered_cli.ik) on real walk and run captures.

Constraints here come from a small detector of the test's own (a joint that
stays within a tolerance of its mean for at least 0.1 s), independent of
``staggered_cli.contacts``, so that a change there cannot hide a bug here.
Lengths are reported as a percentage of the figure height ``H``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from staggered_cli import quat
from staggered_cli.contacts.constraint import Constraint
from staggered_cli.contacts.ik import blend_weight, ik_layer, two_bone_chain
from staggered_cli.errors import UsageError
from staggered_cli.io.bvh import read_bvh
from staggered_cli.io.schema import from_parts, to_parts
from staggered_cli.ops.bake import bake
from staggered_cli.skeleton import forward_kinematics

from .conftest import mocap

BLEND = 0.1
DELTA = 0.05  # the root edit, as a fraction of the figure height

#: walk and run files: (ankles, toes, detector tolerance as a fraction of H).
#: The tolerances are a few times each capture's noise (CMU at 120 Hz is noisier).
FILES = {
    "cmu_02_01_walk.bvh": (("LeftFoot", "RightFoot"), ("LeftToeBase", "RightToeBase"), 0.003),
    "bandai1_walk_normal_001.bvh": (("Foot_L", "Foot_R"), ("Toes_L", "Toes_R"), 0.002),
    "bandai2_run_normal_001.bvh": (("Foot_L", "Foot_R"), ("Toes_L", "Toes_R"), 0.003),
}


@dataclass
class Clip:
    name: str
    skeleton: object
    rot: np.ndarray
    tr: np.ndarray
    t: np.ndarray
    H: float
    pos: np.ndarray
    ankles: tuple[str, ...]
    toes: tuple[str, ...]
    tol: float

    def fk(self, rot: np.ndarray, tr: np.ndarray | None = None) -> np.ndarray:
        return forward_kinematics(self.skeleton, rot, self.tr if tr is None else tr)[1]

    def detect(self, joints, tol: float | None = None) -> list[Constraint]:
        out = []
        for name in joints:
            j = self.skeleton.index(name)
            for a, b in still_windows(self.pos[:, j], self.t, (self.tol if tol is None else tol) * self.H):
                out.append(Constraint(name, float(self.t[a]), float(self.t[b])))
        return out


def still_windows(pos: np.ndarray, t: np.ndarray, tol: float, min_len: float = 0.1, gap: float = BLEND):
    """Frame ranges [a, b] where ``pos`` (T, 3) stays within ``tol`` of its mean
    over the range, at least ``min_len`` seconds of samples long, grown
    greedily forward and at least ``gap`` apart (closer ones would be one
    contact split in two)."""
    need = int(np.ceil(min_len / (t[1] - t[0]) - 1e-3))  # frames (0.0333333 s frames: 3 for 0.1 s)
    out, i, n = [], 0, len(t)
    while i < n:
        j = i
        while j + 1 < n:
            seg = pos[i : j + 2]
            if np.linalg.norm(seg - seg.mean(axis=0), axis=-1).max() > tol:
                break
            j += 1
        if j - i + 1 >= need:
            out.append((i, j))
            i = j + 1
            while i < n and t[i] - t[j] < gap:
                i += 1
        else:
            i += 1
    return out


def load(name: str) -> Clip:
    m = read_bvh(mocap(name))
    rot, tr = m.local_rotations(), m.local_translations()
    t = np.arange(m.n_frames) * m.frame_time
    pos = forward_kinematics(m.skeleton, rot, tr)[1]
    ankles, toes, tol = FILES[name]
    return Clip(name, m.skeleton, rot, tr, t, m.figure_height(), pos, ankles, toes, tol)


@pytest.fixture(scope="module", params=sorted(FILES))
def clip(request) -> Clip:
    return load(request.param)


def root_bump(c: Clip, start: float, end: float, axis: int = 0, size: float = DELTA) -> np.ndarray:
    """Translations with the root moved by a raised cosine from 0 at ``start``
    to ``size * H`` halfway and back to 0 at ``end`` (a smooth edit)."""
    root = int(np.flatnonzero([c.skeleton.has_position(j) for j in range(c.skeleton.n_joints)])[0])
    u = np.clip((c.t - start) / (end - start), 0.0, 1.0)
    tr = c.tr.copy()
    tr[:, root, axis] += size * c.H * 0.5 * (1.0 - np.cos(2.0 * np.pi * u))
    return tr


def spread(p: np.ndarray) -> float:
    """Largest distance between two of the positions ``p`` (n, 3)."""
    return float(np.max(np.linalg.norm(p[:, None] - p[None], axis=-1)))


def inside(c: Clip, con) -> np.ndarray:
    return (c.t >= con.start) & (c.t <= con.end)


def knee_angle(c: Clip, pos: np.ndarray, joint: str) -> np.ndarray:
    """Interior angle (degrees) at the chain's middle joint, (T,)."""
    ch = two_bone_chain(c.skeleton, joint)
    u = pos[:, ch.upper] - pos[:, ch.middle]
    v = pos[:, ch.lower] - pos[:, ch.middle]
    cos = np.sum(u * v, -1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def bend_side(c: Clip, pos: np.ndarray, joint: str, axis: np.ndarray) -> np.ndarray:
    """Sign of the bend of the chain's middle joint about a fixed world-ish axis (T, 3)."""
    ch = two_bone_chain(c.skeleton, joint)
    n = np.cross(pos[:, ch.lower] - pos[:, ch.upper], pos[:, ch.middle] - pos[:, ch.upper])
    return np.sign(np.sum(n * axis, axis=-1))


def edit_cases(c: Clip):
    """For each ankle constraint, the root bump over it and the layer's result."""
    cons = c.detect(c.ankles + c.toes)
    for c0 in (k for k in cons if k.joint in c.ankles):
        tr = root_bump(c, c0.start, c0.end)
        yield cons, c0, tr, ik_layer(c.skeleton, c.rot, tr, c.t, cons, blend=BLEND)


# --- the chain ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, joint, chain",
    [
        ("cmu_01_01_forward_jumps.bvh", "LeftFoot", ("LeftUpLeg", "LeftLeg", "LeftFoot", "LeftFoot")),
        ("cmu_01_01_forward_jumps.bvh", "LeftToeBase", ("LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase")),
        ("cmu_01_01_forward_jumps.bvh", "RightHand", ("RightArm", "RightForeArm", "RightHand", "RightHand")),
        ("cmu_01_01_forward_jumps.bvh", "LFingers", ("LeftArm", "LeftForeArm", "LeftHand", "LFingers")),
        ("bandai2_run_normal_001.bvh", "Toes_L", ("UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L")),
        ("bandai2_run_normal_001.bvh", "Foot_R", ("UpperLeg_R", "LowerLeg_R", "Foot_R", "Foot_R")),
        ("bandai2_run_normal_001.bvh", "Hand_L", ("UpperArm_L", "LowerArm_L", "Hand_L", "Hand_L")),
        ("games105_idle.bvh", "lToeJoint", ("lHip", "lKnee", "lAnkle", "lToeJoint")),
        ("games105_idle.bvh", "rWrist", ("rShoulder", "rElbow", "rWrist", "rWrist")),
        ("cmu3dsmax_131_02_start_walk_stop.bvh", "RightToe", ("RightHip", "RightKnee", "RightAnkle", "RightToe")),
    ],
)
def test_chain_is_found_from_the_hierarchy(name, joint, chain):
    sk = read_bvh(mocap(name)).skeleton
    ch = two_bone_chain(sk, joint)
    assert tuple(sk.names[j] for j in (ch.upper, ch.middle, ch.lower, ch.effector)) == chain


@pytest.mark.parametrize("joint", ["Hips", "LHipJoint", "LeftUpLeg", "Spine", "Nowhere"])
def test_joints_without_a_chain_are_refused(joint):
    sk = read_bvh(mocap("cmu_01_01_forward_jumps.bvh")).skeleton
    with pytest.raises(UsageError):
        two_bone_chain(sk, joint)


# --- the weight --------------------------------------------------------------------


def test_blend_weight_is_one_inside_zero_outside_and_c1():
    t = np.linspace(0.0, 2.0, 20001)
    w = blend_weight(t, 0.8, 1.2, 0.25)
    assert np.all(w[(t >= 0.8) & (t <= 1.2)] == 1.0)
    assert np.all(w[(t <= 0.55) | (t >= 1.45)] == 0.0)
    assert np.all((w >= 0.0) & (w <= 1.0))
    assert w[np.argmin(np.abs(t - 0.675))] == pytest.approx(0.5, abs=1e-3)
    slope = np.diff(w) / np.diff(t)
    assert np.abs(np.diff(slope)).max() < 1e-2  # no kink anywhere: the slope is continuous
    assert np.array_equal(blend_weight(t, 0.8, 1.2, 0.0), ((t >= 0.8) & (t <= 1.2)).astype(float))


# --- the solver --------------------------------------------------------------------


def test_reachable_targets_are_met_exactly_and_only_the_chain_moves(clip):
    rng = np.random.default_rng(3)
    sk = clip.skeleton
    for joint in clip.ankles + clip.toes:
        ch = two_bone_chain(sk, joint)
        j = sk.index(joint)
        for k in rng.integers(0, len(clip.t), 4):
            target = clip.pos[k, j] + rng.normal(size=3) * 0.01 * clip.H
            con = Constraint(joint, float(clip.t[k]), float(clip.t[k]))
            out = ik_layer(sk, clip.rot, clip.tr, clip.t, [con], targets=[target])
            wr0, _ = forward_kinematics(sk, clip.rot[k : k + 1], clip.tr[k : k + 1])
            wr1, wp1 = forward_kinematics(sk, out[k : k + 1], clip.tr[k : k + 1])
            limb = np.linalg.norm(clip.pos[k, ch.middle] - clip.pos[k, ch.upper]) + np.linalg.norm(
                clip.pos[k, ch.lower] - clip.pos[k, ch.middle]
            )
            if np.linalg.norm(target - (clip.pos[k, j] - clip.pos[k, ch.lower]) - clip.pos[k, ch.upper]) > 0.99 * limb:
                continue  # out of reach: see the unreachable test
            assert np.linalg.norm(wp1[0, j] - target) < 1e-9 * clip.H
            assert np.degrees(quat.angle_between(wr0[0, ch.lower], wr1[0, ch.lower])) < 1e-9
            others = np.setdiff1d(np.arange(sk.n_joints), [ch.upper, ch.middle, ch.lower])
            assert np.array_equal(out[:, others], clip.rot[:, others])


# --- (a) planted feet stay planted under an edit ------------------------------------


def test_planted_feet_do_not_slide_after_a_root_edit(clip):
    without, with_layer = [], []
    sk = clip.skeleton
    for cons, c0, tr, out in edit_cases(clip):
        edited = clip.fk(clip.rot, tr)
        fixed = clip.fk(out, tr)
        bumped = (clip.t > c0.start) & (clip.t < c0.end)
        for con in cons:
            if not (inside(clip, con) & bumped).any():
                continue
            j = sk.index(con.joint)
            if con is c0:
                without.append(spread(edited[inside(clip, con), j]) / clip.H)
            with_layer.append(spread(fixed[inside(clip, con), j]) / clip.H)
    print(
        f"\n{clip.name}: {len(with_layer)} planted feet/toes under a {DELTA:.0%} root edit: "
        f"slide without the layer {100 * np.mean(without):.2f} % (max {100 * np.max(without):.2f} %), "
        f"with it {100 * np.mean(with_layer):.3f} % (max {100 * np.max(with_layer):.3f} %) of the figure height"
    )
    # the edit makes the planted foot slide by about its size (less where a short
    # contact at 30 Hz samples the bump off its peak)
    assert np.mean(without) > 0.9 * DELTA and min(without) > 0.6 * DELTA
    assert max(with_layer) < 0.0025


# --- (b) zero outside the windows ---------------------------------------------------


def test_layer_is_exactly_zero_outside_constraints_and_blend_windows(clip):
    cons = clip.detect(clip.ankles + clip.toes)
    tr = root_bump(clip, cons[0].start, cons[0].end)
    out = ik_layer(clip.skeleton, clip.rot, tr, clip.t, cons, blend=BLEND)
    window = np.zeros(len(clip.t), dtype=bool)
    for con in cons:
        window |= (clip.t > con.start - BLEND) & (clip.t < con.end + BLEND)
    assert (~window).any() and window.any()
    assert np.array_equal(out[~window], clip.rot[~window])
    chains = [two_bone_chain(clip.skeleton, con.joint) for con in cons]
    moved = sorted({j for ch in chains for j in (ch.upper, ch.middle, ch.lower)})
    others = np.setdiff1d(np.arange(clip.skeleton.n_joints), moved)
    assert np.array_equal(out[:, others], clip.rot[:, others])
    # the input is not modified
    assert np.array_equal(clip.rot, load(clip.name).rot)


# --- (c) knees stay continuous and on their side ------------------------------------


def test_knees_stay_continuous_and_do_not_flip(clip):
    worst = []
    for cons, _, tr, out in edit_cases(clip):
        edited, fixed = clip.fk(clip.rot, tr), clip.fk(out, tr)
        for joint in clip.ankles:
            ch = two_bone_chain(clip.skeleton, joint)
            near = np.zeros(len(clip.t) - 1, dtype=bool)  # frame steps where this leg's layer acts
            for con in cons:
                if two_bone_chain(clip.skeleton, con.joint).middle == ch.middle:
                    near |= (clip.t[1:] > con.start - BLEND) & (clip.t[:-1] < con.end + BLEND)
            before = np.abs(np.diff(knee_angle(clip, edited, joint)))[near].max()
            after = np.abs(np.diff(knee_angle(clip, fixed, joint)))[near].max()
            worst.append((after, before))
            # the knee bends to the same side as in the data wherever it is bent
            axis = np.cross(edited[:, ch.lower] - edited[:, ch.upper], edited[:, ch.middle] - edited[:, ch.upper])
            bent = knee_angle(clip, fixed, joint) < 170.0
            assert np.all(bend_side(clip, fixed, joint, axis)[bent] > 0)
    after, before = max(worst, key=lambda ab: ab[0] - ab[1])
    print(
        f"\n{clip.name}: near the constraints the largest frame-to-frame knee change is "
        f"{after:.2f} deg with the layer, {before:.2f} deg without (worst case)"
    )
    for after, before in worst:
        assert after < 1.5 * before + 1.0


# --- (d) the unedited motion is left (almost) alone -----------------------------------


@pytest.mark.parametrize(
    "name, joints, tol",
    [
        ("bandai1_walk_normal_001.bvh", ("Foot_L", "Foot_R", "Toes_L", "Toes_R"), 0.001),
        ("bandai2_run_normal_001.bvh", ("Foot_L", "Foot_R", "Toes_L", "Toes_R"), 0.001),
        ("cmu_02_01_walk.bvh", ("LeftFoot", "RightFoot"), 0.003),
    ],
)
def test_unedited_motion_barely_changes_when_constraints_agree_with_it(name, joints, tol):
    c = load(name)
    cons = c.detect(joints, tol)
    assert len(cons) >= 1
    out = ik_layer(c.skeleton, c.rot, c.tr, c.t, cons, blend=BLEND)
    change = np.linalg.norm(c.fk(out) - c.pos, axis=-1).max() / c.H
    print(f"\n{name}: {len(cons)} constraints within {tol:.2%} of H: joints move by at most {change:.3%} of H")
    assert change < 0.005


# --- (e) unreachable targets ----------------------------------------------------------


def test_unreachable_targets_are_approached_without_nan_or_flip(clip):
    cons = [k for k in clip.detect(clip.ankles) if k.joint == clip.ankles[0]]
    c0 = max(cons, key=lambda k: k.end - k.start)
    tr = root_bump(clip, c0.start - 0.1, c0.end + 0.1, axis=1, size=0.3)  # lift the body far off the floor (Y up)
    out = ik_layer(clip.skeleton, clip.rot, tr, clip.t, cons, blend=BLEND)
    assert np.all(np.isfinite(out))
    assert np.allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-12)
    edited, fixed = clip.fk(clip.rot, tr), clip.fk(out, tr)
    j = clip.skeleton.index(c0.joint)
    k = inside(clip, c0)
    plant = edited[k, j].mean(axis=0)
    # as close as the leg allows: nearer the plant than the edited foot, the knee not flipped
    assert np.all(np.linalg.norm(fixed[k, j] - plant, axis=-1) <= np.linalg.norm(edited[k, j] - plant, axis=-1) + 1e-9)
    angle = knee_angle(clip, fixed, c0.joint)
    assert angle[k].max() < 179.0  # the reach is capped just short of a straight leg
    ch = two_bone_chain(clip.skeleton, c0.joint)
    axis = np.cross(edited[:, ch.lower] - edited[:, ch.upper], edited[:, ch.middle] - edited[:, ch.upper])
    bent = angle < 170.0
    assert np.all(bend_side(clip, fixed, c0.joint, axis)[bent] > 0)


# --- several constraints on one joint ---------------------------------------------------


def test_close_constraints_on_one_joint_move_smoothly_between_plants():
    c = load("bandai1_walk_normal_001.bvh")
    joint = "Foot_L"
    j = c.skeleton.index(joint)
    whole = max(c.detect([joint]), key=lambda k: k.end - k.start)
    frames = np.flatnonzero(inside(c, whole))
    assert len(frames) >= 8
    # one contact split in two by a one-frame gap, its plants made to differ by an edit
    cut = frames[len(frames) // 2]
    cons = [Constraint(joint, whole.start, float(c.t[cut])), Constraint(joint, float(c.t[cut + 2]), whole.end)]
    tr = root_bump(c, whole.start, float(c.t[cut]))
    out = ik_layer(c.skeleton, c.rot, tr, c.t, cons, blend=BLEND)
    edited, fixed = c.fk(c.rot, tr), c.fk(out, tr)
    step_edit = np.linalg.norm(np.diff(edited[:, j], axis=0), axis=-1).max()
    step_fixed = np.linalg.norm(np.diff(fixed[:, j], axis=0), axis=-1).max()
    assert step_fixed < 1.5 * step_edit  # no pop between the two plants
    # away from the handover (blend/2 each side of the gap) each plant holds
    gap = c.t[cut + 1]
    for con in cons:
        hold = inside(c, con) & (np.abs(c.t - gap) > 0.5 * BLEND + 1e-9)
        assert hold.any()
        assert spread(fixed[hold, j]) < 1e-6 * c.H


# --- bad input ---------------------------------------------------------------------------


def test_bad_input_is_refused():
    c = load("cmu_02_01_walk.bvh")
    sk = c.skeleton
    ok = [Constraint("LeftFoot", 0.5, 0.7)]
    with pytest.raises(UsageError):
        ik_layer(sk, c.rot, c.tr, c.t, [Constraint("Nowhere", 0.5, 0.7)])
    with pytest.raises(UsageError):
        ik_layer(sk, c.rot, c.tr, c.t, [Constraint("LeftFoot", 0.7, 0.5)])
    with pytest.raises(UsageError):
        ik_layer(sk, c.rot, c.tr, c.t, ok, blend=-0.1)
    with pytest.raises(ValueError, match="translations"):
        ik_layer(sk, c.rot, c.tr[:-1], c.t, ok)
    with pytest.raises(ValueError, match="times"):
        ik_layer(sk, c.rot, c.tr, c.t[:-1], ok)
    with pytest.raises(ValueError, match="targets"):
        ik_layer(sk, c.rot, c.tr, c.t, ok, targets=[None, None])
    assert np.array_equal(ik_layer(sk, c.rot, c.tr, c.t, []), c.rot)


# --- the constraints command -------------------------------------------------------------


@pytest.fixture(scope="module")
def run_doc(tmp_path_factory):
    from staggered_cli.io.container import document_bytes
    from staggered_cli.model import variables as V

    c = load("bandai2_run_normal_001.bvh")
    m = read_bvh(mocap("bandai2_run_normal_001.bvh"))
    doc = V.from_motion(m, np.arange(0.0, c.t[-1], 0.5), constraints=tuple(c.detect(c.ankles)))
    path = tmp_path_factory.mktemp("ik") / "run.stag"
    path.write_bytes(document_bytes(*to_parts(doc), "npz"))
    return path, doc


def cli_run(*args):
    from click.testing import CliRunner

    from staggered_cli.cli.main import cli

    return CliRunner().invoke(cli, [str(a) for a in args])


def read_doc(path):
    from staggered_cli.io.container import parse_document
    from staggered_cli.io.schema import from_parts

    return from_parts(*parse_document(path.read_bytes(), "test"))


def test_constraints_command_lists_adds_and_removes(run_doc, tmp_path):
    path, doc = run_doc
    listed = cli_run("constraints", path, "--json")
    assert listed.exit_code == 0, listed.stderr
    rows = json.loads(listed.stdout)["constraints"]
    assert [(r["joint"], r["start"], r["end"]) for r in rows] == [
        (c.joint, round(c.start, 9), round(c.end, 9)) for c in doc.constraints
    ]
    table = cli_run("constraints", path)
    assert table.exit_code == 0 and len(table.stdout.splitlines()) == len(doc.constraints) + 1

    out = tmp_path / "edited.stag"
    edited = cli_run("constraints", path, "--remove", 0, "--add", "Hand_L@0.5:0.75", "-o", out, "--list")
    assert edited.exit_code == 0, edited.stderr
    cons = read_doc(out).constraints
    assert len(cons) == len(doc.constraints)
    assert doc.constraints[0] not in cons and any(c.joint == "Hand_L" and c.start == 0.5 for c in cons)
    assert [c.start for c in cons] == sorted(c.start for c in cons)
    assert "Hand_L" in edited.stdout  # the new list, since the document went to a file

    redetected = cli_run("constraints", out, "--detect", "--contact-joints", "Toes_L", "-o", tmp_path / "d.stag")
    assert redetected.exit_code == 0, redetected.stderr
    again = read_doc(tmp_path / "d.stag").constraints
    assert any(c.joint == "Toes_L" for c in again)
    assert [c for c in again if c.joint != "Toes_L"] == [c for c in cons if c.joint != "Toes_L"]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--add", "Nowhere@0:1"], "unknown joint"),
        (["--add", "Hips@0:1"], "no two-bone chain"),
        (["--add", "Foot_L@0:99"], "within the clip"),
        (["--add", "Foot_L0:1"], "JOINT@START:END"),
        (["--add", "Foot_L@1:0"], "must not exceed"),
        (["--remove", "99"], "no constraint 99"),
        (["--detect", "--remove", "0"], "apart from --detect"),
        (["--contact-joints", "Foot_L"], "go with --detect"),
        (["--add", "Foot_L@0:1", "--list"], "-o FILE"),
    ],
)
def test_constraints_command_refuses_bad_edits(run_doc, args, needle):
    result = cli_run("constraints", run_doc[0], *args)
    assert result.exit_code == 2, result.stderr
    assert needle in result.stderr and "Traceback" not in result.stderr


def test_a_constraint_added_by_hand_pins_its_joint(cmu_walk, tmp_path):
    """constraints --add means 'planted here': bake holds the joint at one
    place even though no edit disturbed it (detected contacts follow the
    capture instead)."""
    from click.testing import CliRunner

    from staggered_cli.cli.main import cli
    from staggered_cli.io.container import document_bytes, parse_document

    m, doc = cmu_walk
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
