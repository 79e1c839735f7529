"""Issue 15: export-poses, edit-pose --from-bvh --all and new, on the dev captures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import bvh_bytes, parse_bvh, read_bvh
from staggered_cli.io.container import parse_document
from staggered_cli.io.schema import from_parts
from staggered_cli.motion import BvhMotion, local_rotations_from_channels, rotation_columns
from staggered_cli.ops import pose_file as P
from staggered_cli.ops.bake import bake

from .conftest import cli_document, dev_motion, mocap, one_line_error
from .test_ops import shifted_within_a_frame

CLIPS = ["bandai1_walk_normal_001.bvh", "cmu_02_01_walk.bvh", "cmu3dsmax_131_02_start_walk_stop.bvh"]


def run(args, input=None):
    return CliRunner().invoke(cli, [str(a) for a in args], input=input)


def load(data: bytes):
    return from_parts(*parse_document(data, "test"))


@pytest.fixture(scope="module", params=CLIPS)
def extracted(request, tmp_path_factory):
    doc_path = tmp_path_factory.mktemp("dcc") / "doc.stag"
    doc_path.write_bytes(cli_document(request.param))  # `staggered extract`, once per session (conftest)
    return dev_motion(request.param), doc_path, load(doc_path.read_bytes())


def _token(x: str):
    try:
        return float(x)
    except ValueError:
        return x


def _arm(sk) -> int:
    limb = ("arm", "elbow")
    return next(j for j, n in enumerate(sk.names) if any(x in n.lower() for x in limb) and sk.has_rotation(j))


def _world(motion):
    return motion.world()[1]


def _same_tracks(a, b) -> bool:
    return all(
        np.array_equal(getattr(x, f), getattr(y, f))
        for x, y in zip(a.tracks, b.tracks, strict=True)
        for f in ("knot_t", "knot_v", "tan_a", "tan_b", "samp_s", "samp_d")
    )


def test_export_writes_the_source_layout_one_frame_per_pose(extracted):
    m, doc_path, doc = extracted
    r = run(["export-poses", doc_path, "-o", "-"])
    assert r.exit_code == 0, r.stderr
    assert r.stderr.splitlines() == [r.stderr.strip()]
    assert "frame k is pose k" in r.stderr and "Blender shows frame k as frame k+1" in r.stderr
    # the times to the frames' precision, as every message prints them
    assert f"t = {doc.seconds(doc.pose_t[0])[:-2]}, {doc.seconds(doc.pose_t[1])[:-2]}," in r.stderr
    assert f"last {doc.seconds(doc.pose_t[-1])})" in r.stderr
    text = r.stdout
    src_text = mocap(CLIPS[[c in str(doc.source_name) for c in CLIPS].index(True)]).read_text()
    # same hierarchy, channels, orders, offsets; same frame time as written
    assert [_token(x) for x in text.split("MOTION")[0].split()] == [
        _token(x) for x in src_text.split("MOTION")[0].split()
    ]
    assert f"Frame Time: {m.frame_time_text}" in text
    poses = parse_bvh(text.encode())
    assert poses.n_frames == doc.n_poses
    # an unedited pose on a source frame is that frame, printed as the source printed it
    frames = np.rint(doc.pose_t / m.frame_time).astype(int)
    src_lines = src_text.split("MOTION")[1].strip().splitlines()[2:]
    out_lines = text.split("MOTION")[1].strip().splitlines()[2:]
    on = np.abs(frames * m.frame_time - doc.pose_t) < 1e-9
    assert on.sum() == doc.n_poses
    # (numbers compared as numbers: cmu3dsmax writes some with fewer decimals than its format)
    assert [[_token(x) for x in src_lines[f].split()] for f in frames] == [
        [_token(x) for x in ln.split()] for ln in out_lines
    ]
    assert [src_lines[f].count("-") for f in frames] == [ln.count("-") for ln in out_lines]  # -0 kept
    assert np.array_equal(poses.channels, m.channels[frames])
    info = json.loads(run(["info", doc_path, "--json"]).stdout)
    assert [p["frame"] for p in info["poses"]] == frames.tolist()


def test_all_of_the_unchanged_file_changes_nothing(extracted, tmp_path):
    m, doc_path, doc = extracted
    poses = tmp_path / "poses.bvh"
    assert run(["export-poses", doc_path, "-o", poses]).exit_code == 0
    r = run(["edit-pose", doc_path, "--from-bvh", poses, "--all", "-o", "-"])
    assert r.exit_code == 0, r.stderr
    assert f"0 of {doc.n_poses} poses changed (0 joints)" in r.stderr
    out = load(r.stdout_bytes)
    assert _same_tracks(doc, out)
    size = m.figure_height()
    assert np.abs(_world(bake(out)) - _world(bake(doc))).max() <= 1e-9 * size


def _edit_two(poses: BvhMotion, k1: int, k2: int, joint: int, root_shift: float) -> BvhMotion:
    """+12 degrees on the first rotation channel of ``joint`` at k1, and the
    root moved along its first position channel at k2."""
    ch = poses.channels.copy()
    cols = next(c for j, c, _ in rotation_columns(poses.skeleton) if j == joint)
    ch[k1, cols[0]] += 12.0
    ch[k2, cols[1]] -= 9.0
    root_cols = [i for i, n in enumerate(poses.skeleton.channels[0]) if n.endswith("position")]
    ch[k2, root_cols[0]] += root_shift
    return parse_bvh(bvh_bytes(BvhMotion(poses.skeleton, ch, poses.frame_time, poses.frame_time_text, "%.6f")))


@pytest.mark.parametrize("on", ["true", "extreme"])
def test_two_poses_edited_in_the_file_come_back_in_one_step(extracted, tmp_path, on):
    m, doc_path, doc = extracted
    sk = m.skeleton
    size = m.figure_height()
    exported = parse_bvh(run(["export-poses", doc_path, "--on", on, "-o", "-"]).stdout_bytes)
    k1, k2 = doc.n_poses // 3, 2 * doc.n_poses // 3
    arm = _arm(sk)
    edited = _edit_two(exported, k1, k2, arm, 0.05 * size)
    path = tmp_path / "edited.bvh"
    path.write_bytes(bvh_bytes(edited))
    r = run(["edit-pose", doc_path, "--from-bvh", path, "--all", "--on", on, "-o", "-"])
    assert r.exit_code == 0, r.stderr
    assert f"2 of {doc.n_poses} poses changed (2 joints)" in r.stderr
    out = load(r.stdout_bytes)
    # the document's poses are now the file's
    back = P.export_poses(out, on)
    fk_file = _world(edited)
    fk_back = _world(back)
    assert np.abs(fk_back - fk_file).max() <= 1e-4 * size
    # the baked motion passes through the edited true poses at their times
    baked = bake(out, ik=False)
    if on == "true":
        f = np.rint(doc.pose_t / m.frame_time).astype(int)
        assert np.abs(_world(baked)[f] - fk_file).max() <= 1e-4 * size
    # and changes nowhere outside the edited poses' neighbours' knots
    a = _world(bake(doc, ik=False))
    b = _world(baked)
    changed = np.flatnonzero(np.abs(a - b).max(axis=(1, 2)) > 1e-9 * size) * m.frame_time
    ref = doc.refinements()
    spans = [(doc.pose_t[k - 1] + ref[k - 1].min(), doc.pose_t[k + 1] + ref[k + 1].max()) for k in (k1, k2)]
    assert changed.size
    inside = np.zeros(len(changed), dtype=bool)
    for lo, hi in spans:
        inside |= (changed > lo - 1e-9) & (changed < hi + 1e-9)
    assert inside.all()
    # every other pose keeps its knots bit for bit
    for tr_a, tr_b in zip(doc.tracks, out.tracks, strict=True):
        others = ~np.isin(tr_a.knot_pose, [k1, k2])
        assert np.array_equal(tr_a.knot_v[others], tr_b.knot_v[others])


def test_joints_restrict_what_all_applies(extracted, tmp_path):
    m, doc_path, doc = extracted
    sk = m.skeleton
    exported = parse_bvh(run(["export-poses", doc_path, "-o", "-"]).stdout_bytes)
    arm = _arm(sk)
    edited = _edit_two(exported, 1, 2, arm, 0.05 * m.figure_height())
    path = tmp_path / "edited.bvh"
    path.write_bytes(bvh_bytes(edited))
    r = run(["edit-pose", doc_path, "--from-bvh", path, "--all", "--joints", sk.names[arm], "-o", "-"])
    assert r.exit_code == 0, r.stderr
    assert f"2 of {doc.n_poses} poses changed (1 joint)" in r.stderr
    out = load(r.stdout_bytes)
    assert np.array_equal(out.tracks[0].knot_v, doc.tracks[0].knot_v)  # the root stays


def test_all_refuses_files_it_cannot_apply(extracted, tmp_path):
    m, doc_path, doc = extracted
    sk = m.skeleton
    exported = parse_bvh(run(["export-poses", doc_path, "-o", "-"]).stdout_bytes)
    short = tmp_path / "short.bvh"
    short.write_bytes(bvh_bytes(BvhMotion(sk, exported.channels[:-1], m.frame_time, m.frame_time_text)))
    one_line_error(
        run(["edit-pose", doc_path, "--from-bvh", short, "--all"]),
        2,
        f"has {doc.n_poses - 1} frames but the document has {doc.n_poses} poses",
    )
    # an up axis converted on import or export: offsets (y, z) -> (z, -y)
    from dataclasses import replace

    off = sk.offsets.copy()
    off[:, [1, 2]] = np.stack([sk.offsets[:, 2], -sk.offsets[:, 1]], axis=1)
    turned = tmp_path / "turned.bvh"
    turned.write_bytes(bvh_bytes(BvhMotion(replace(sk, offsets=off), exported.channels, m.frame_time)))
    first = next(j for j in range(sk.n_joints) if np.abs(sk.offsets[j, 1:]).max() > 1e-4 * m.figure_height())
    one_line_error(run(["edit-pose", doc_path, "--from-bvh", turned, "--all"]), 1, f"joint {sk.names[first]!r}", "axis")
    other = mocap("games105_idle.bvh")
    one_line_error(run(["edit-pose", doc_path, "--from-bvh", other, "--all"]), 1, "a different skeleton")
    one_line_error(run(["edit-pose", doc_path, "--all"]), 2, "--all needs --from-bvh")
    one_line_error(run(["edit-pose", doc_path, "--from-bvh", short, "--all", "--pose", "1"]), 2, "--all")


def test_all_refuses_to_translate_a_joint_without_position_channels(tmp_path):
    m = read_bvh(mocap("cmu_02_01_walk.bvh"))
    doc_path = tmp_path / "walk.stag"
    assert run(["extract", mocap("cmu_02_01_walk.bvh"), "-o", doc_path]).exit_code == 0
    exported = parse_bvh(run(["export-poses", doc_path, "-o", "-"]).stdout_bytes)
    sk = exported.skeleton
    # as Blender writes it with root_transform_only off: position channels on every joint
    channels = tuple(
        ch if any(c.endswith("position") for c in ch) else ("Xposition", "Yposition", "Zposition", *ch)
        for ch in sk.channels
    )
    from dataclasses import replace

    wide_sk = replace(sk, channels=channels)
    cols = []
    for j, ch in enumerate(sk.channels):
        start = sum(len(c) for c in sk.channels[:j])
        if channels[j] != ch:
            cols.append(np.broadcast_to(sk.offsets[j], (exported.n_frames, 3)))
        cols.append(exported.channels[:, start : start + len(ch)])
    wide = np.concatenate(cols, axis=1)
    wide_file = tmp_path / "wide.bvh"
    wide_file.write_bytes(bvh_bytes(BvhMotion(wide_sk, wide, m.frame_time, m.frame_time_text)))
    r = run(["edit-pose", doc_path, "--from-bvh", wide_file, "--all", "-o", "-"])
    assert r.exit_code == 0 and "0 of" in r.stderr, r.stderr  # offsets as translations: nothing changed
    knee = sk.index("LeftLeg")
    c = sum(len(ch) for ch in channels[:knee])
    wide[3, c + 1] += 0.1 * m.figure_height()
    wide_file.write_bytes(bvh_bytes(BvhMotion(wide_sk, wide, m.frame_time, m.frame_time_text)))
    one_line_error(
        run(["edit-pose", doc_path, "--from-bvh", wide_file, "--all"]),
        2,
        "frame 3 translates joint 'LeftLeg'",
        "no position channels",
    )


# --- new ------------------------------------------------------------------------


def _keys(name: str, frames: list[int]) -> tuple[BvhMotion, bytes]:
    m = read_bvh(mocap(name))
    data = bvh_bytes(BvhMotion(m.skeleton, m.channels[frames], m.frame_time, m.frame_time_text, m.number_format))
    return m, data


@pytest.mark.parametrize(
    "name,frames",
    [
        ("bandai1_walk_normal_001.bvh", [0, 20, 45, 70, 110, 150]),
        ("cmu_02_01_walk.bvh", [0, 50, 110, 170, 230, 300]),
        ("cmu3dsmax_131_02_start_walk_stop.bvh", [0, 150, 300, 500, 700, 960]),
    ],
)
def test_new_from_six_frames_bakes_through_them(name, frames, tmp_path):
    m, data = _keys(name, frames)
    times = ",".join(repr(f * m.frame_time) for f in frames)
    r = run(["new", "-", "--times", times, "-o", "-"], input=data)
    assert r.exit_code == 0, r.stderr
    doc = load(r.stdout_bytes)
    assert doc.n_poses == 6 and doc.n_frames == frames[-1] + 1
    assert all(len(tr.samp_s) == 0 for tr in doc.tracks)  # empty displacement maps
    baked = parse_bvh(run(["bake", "-", "-o", "-"], input=r.stdout_bytes).stdout_bytes)
    size = m.figure_height()
    assert np.abs(_world(baked)[frames] - _world(m)[frames]).max() <= 1e-6 * size
    # smooth: no joint moves in one frame more than three times its fastest
    # average speed between two keys (the tangents' overshoot limit)
    w = _world(m)[frames]
    secant = (np.linalg.norm(np.diff(w, axis=0), axis=-1) / np.diff(frames)[:, None]).max(axis=0)
    step = np.linalg.norm(np.diff(_world(baked), axis=0), axis=-1).max(axis=0)
    assert np.all(step <= 3.0 * secant + 1e-3 * size)
    # the other commands work on it
    doc_path = tmp_path / "new.stag"
    doc_path.write_bytes(r.stdout_bytes)
    mid = 0.5 * (frames[2] + frames[3]) * m.frame_time
    arm = m.skeleton.names[_arm(m.skeleton)]
    pipeline = [
        ["cull", doc_path, "--add-time", f"{mid:.4f}", "-o", "-"],
        ["succession", "-", "--joint", arm, "--offset", "0.03", "--power", "1.5", "--clamp", "-o", "-"],
        ["randomize", "-", "--joints", arm, "--tau", "0.02", "--seed", "1", "--clamp", "-o", "-"],
        ["edit-pose", "-", "--pose", "2", "--rotate", f"{arm}=0,0,15", "-o", "-"],
        ["bake", "-", "--fps", "24", "-o", "-"],
    ]
    data = None
    for step_args in pipeline:
        res = run(step_args, input=data)
        assert res.exit_code == 0, (step_args, res.stderr)
        data = res.stdout_bytes
    out = parse_bvh(data)
    assert out.n_frames == int(np.floor(frames[-1] * m.frame_time * 24 + 1e-3)) + 1


def test_new_uses_the_files_frame_times_by_default():
    m, data = _keys("bandai2_run_normal_001.bvh", [0, 10, 20, 30])
    r = run(["new", "-", "-o", "-"], input=data)
    assert r.exit_code == 0, r.stderr
    doc = load(r.stdout_bytes)
    assert np.allclose(doc.pose_t, np.arange(4) * m.frame_time) and doc.n_frames == 4


def test_succession_on_new_keys_shifts_extremes_by_s_d_power():
    frames = [0, 40, 95, 150, 205, 260, 342]
    m, data = _keys("cmu_02_01_walk.bvh", frames)
    times = ",".join(repr(f * m.frame_time) for f in frames)
    doc = load(run(["new", "-", "--times", times, "-o", "-"], input=data).stdout_bytes)
    offset, power = 0.02, 1.5
    from staggered_cli.ops import timing

    out = timing.succession(doc, offset, power, joint="LeftShoulder")
    sk = m.skeleton
    depth = sk.depth_below(sk.index("LeftShoulder"))
    a = local_rotations_from_channels(sk, bake(doc, ik=False).channels)
    b = local_rotations_from_channels(sk, bake(out, ik=False).channels)
    ft = doc.frame_time
    names = doc.variable_names
    cases = [
        (j, frames[k], offset * depth[j] ** power)
        for k in range(1, doc.n_poses - 1)
        for j in np.flatnonzero(depth > 0)
        if sk.names[j] in names
    ]
    hits, counted = shifted_within_a_frame(a, b, cases, ft, still=0.05)
    total = len(counted)
    for j, f, expect in counted:  # the key itself now sits at the shifted time
        g = int(round((doc.pose_t[frames.index(f)] + expect) / ft))
        assert np.degrees(quat.angle_between(b[g, j], a[f, j])) < 1.0
    assert total >= 10
    assert hits / total >= 0.8, (hits, total)


def test_blocking_tangents_do_not_overshoot_and_rest_at_extremes():
    t = np.array([0.0, 0.4, 0.5, 1.3, 2.0])
    p = np.array([0.0, 1.0, 3.0, 2.0, 2.0])[:, None]
    m = P.blocking_velocities(t, p)
    assert m[0, 0] == 0 and m[-1, 0] == 0  # ends at rest
    assert m[2, 0] == 0 and m[3, 0] == 0  # a peak and a flat key
    assert 0 < m[1, 0] <= 3 * (1.0 / 0.4)  # between rising slopes, limited
    a, b = P.blocking_translation_tangents(t, p[:, None, :].repeat(3, axis=2))
    from staggered_cli.model import bezier

    u = np.linspace(0, 1, 201)
    for s in range(len(t) - 1):
        c = bezier.bezier_eval(p[s : s + 1].repeat(3, 1), a[s, :, :], b[s, :, :], p[s + 1 : s + 2].repeat(3, 1), u)
        lo, hi = sorted((p[s, 0], p[s + 1, 0]))
        assert c.min() >= lo - 1e-12 and c.max() <= hi + 1e-12


@pytest.mark.parametrize(
    "times,needle",
    [
        ("0,0.5", "gives 2 times for the file's 3 frames"),
        ("0,0.5,0.5", "must increase strictly"),
        ("0,0.6,0.4", "must increase strictly"),
        ("0.1,0.5,1", "must start at 0"),
        ("0,0.5,1.01", "not on a frame"),
        ("0,x,1", "is not a number"),
    ],
)
def test_new_refuses_bad_times(times, needle):
    _, data = _keys("bandai2_run_normal_001.bvh", [0, 10, 20])
    one_line_error(run(["new", "-", "--times", times, "-o", "-"], input=data), 2, needle)


@pytest.mark.parametrize(
    "name,frame_time", [("cmu_02_01_walk.bvh", "0.008333"), ("bandai2_run_normal_001.bvh", "0.0333333")]
)
def test_new_takes_times_on_the_nominal_or_the_written_clock(name, frame_time):
    """2.2 s is frame 264 at 120 Hz and frame 66 at 30 Hz, although the files
    write 0.008333 and 0.0333333; times copied from `info` (the written
    clock, six digits) pass too.  Both land on the written clock."""
    m, data = _keys(name, [0, 10, 20, 30])
    assert m.frame_time_text.strip() == frame_time
    ft, rate = m.frame_time, round(1 / m.frame_time)
    last = round(2.2 * rate)
    for times, expect in [
        ([0, 0.4, 0.9, 2.2], np.array([0, 0.4, 0.9, 2.2]) * rate * ft),  # nominal: scaled onto the written clock
        ([0, 0.4, 0.9, last * ft], np.array([0, 0.4, 0.9, last * ft])),  # written: kept
        ([0, 0.4, 0.9, float(f"{last * ft:.6g}")], None),  # as `info` prints it
    ]:
        r = run(["new", "-", "--times", ",".join(map(repr, times)), "-o", "-"], input=data)
        assert r.exit_code == 0, r.stderr
        doc = load(r.stdout_bytes)
        assert doc.n_frames == last + 1
        assert doc.pose_t[-1] == last * ft
        if expect is not None:
            assert np.abs(doc.pose_t - expect).max() < 1e-12
    # a time between frames on both clocks is still refused
    one_line_error(run(["new", "-", "--times", "0,0.4,0.9,2.21", "-o", "-"], input=data), 2, "not on a frame")


def test_new_refuses_a_single_key_and_a_c3d():
    _, data = _keys("bandai2_run_normal_001.bvh", [5])
    one_line_error(run(["new", "-", "-o", "-"], input=data), 2, "at least two key poses")
    one_line_error(run(["new", mocap("c3dorg_sample01_Eb015pi_walk.c3d"), "-o", "-"]), 2, "BVH")


def test_the_keys_of_a_new_document_export_as_they_came():
    """The blocking loop: new, then export-poses gives the key file's frames back."""
    frames = [0, 20, 45, 70, 110, 150]
    m, data = _keys("bandai1_walk_normal_001.bvh", frames)
    times = ",".join(repr(f * m.frame_time) for f in frames)
    doc = run(["new", "-", "--times", times, "-o", "-"], input=data).stdout_bytes
    r = run(["export-poses", "-", "-o", "-"], input=doc)
    assert r.exit_code == 0, r.stderr
    back = parse_bvh(r.stdout_bytes)
    keys = parse_bvh(data)
    assert back.n_frames == 6
    assert np.abs(back.world()[1] - keys.world()[1]).max() <= 1e-6 * m.figure_height()
    r = run(["info", "-", "--json"], input=doc)
    assert [p["frame"] for p in json.loads(r.stdout)["poses"]] == frames


def test_export_poses_needs_a_bvh_document():
    r = run(["extract", mocap("c3dorg_sample01_Eb015pi_walk.c3d"), "-o", "-"])
    assert r.exit_code == 0, r.stderr
    one_line_error(run(["export-poses", "-", "-o", "-"], input=r.stdout_bytes), 2, "needs a BVH document")
