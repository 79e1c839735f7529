"""Partial poses (issue #37): poses that own one body part's variables.

Real files: the CMU walk (cmu_02_01, 120 Hz, 31 joints) with left-arm poses
inserted by hand between its whole-body poses; the bundled march; a
version 2 document written before partial poses existed
(tests/fixtures/march_v2.stag, ``staggered extract data/samples/march.bvh``
at the commit before this change) with the SHA-256 of its bakes then.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import staggered_cli as st
from staggered_cli.cli.main import cli
from staggered_cli.errors import UsageError
from staggered_cli.io.schema import DOCUMENT_VERSION, from_parts, to_parts
from staggered_cli.ops import cull, timing
from staggered_cli.ops.bake import bake

from .conftest import dev_document, document_file, staggered_warnings

FIXTURES = Path(__file__).resolve().parent / "fixtures"
WALK = "cmu_02_01_walk.bvh"
#: bakes of tests/fixtures/march_v2.stag by the code before partial poses:
#: as it is, and after ``edit-pose --pose 3 --rotate LeftArm=10,0,5``
V2_BAKE = "7efad085b8375b3161c942825ce22dabb1874b0fd40e3981d706dc1ffcf6f0f8"
V2_EDITED_BAKE = "f20c2a30f0eae48a50b8d2d4fedbb394259fed029e9591b94b89807ca203958e"


def run(args, input=None):
    return CliRunner().invoke(cli, [str(a) for a in args], input=input)


def midpoints(doc, n: int, start: int = 2) -> list[float]:
    """Times halfway between whole-body poses start, start+2, ... (n of them)."""
    t = doc.pose_t
    return [float(0.5 * (t[k] + t[k + 1])) for k in range(start, start + 2 * n, 2)]


@pytest.fixture(scope="module")
def walk():
    return dev_document(WALK)


@pytest.fixture(scope="module")
def arm_walk(walk):
    """The walk with four @left-arm poses between its whole-body poses."""
    return cull.add_poses(walk, midpoints(walk, 4), "@left-arm")


def channel_columns(doc, mask: np.ndarray) -> np.ndarray:
    """(C,) bool: the BVH channels of the joints whose variables ``mask`` (V,) selects."""
    sk = doc.source.skeleton
    targets = np.concatenate([tr.targets for tr in doc.tracks])
    joints = np.zeros(sk.n_joints, dtype=bool)
    joints[targets[mask]] = True
    return np.repeat(joints, [len(c) for c in sk.channels])


def variable_arrays(doc, i: int) -> tuple:
    """Knot times, values, poses and displacement samples of global variable ``i``."""
    for tr in doc.tracks:
        if i < tr.n_vars:
            k, s = tr.knots.of(i), tr.samples(i)
            return tr.knot_t[k], tr.knot_v[k], tr.samp_s[s], tr.samp_d[s], tr.tan_a[tr.seg_ptr[i] : tr.seg_ptr[i + 1]]
        i -= tr.n_vars
    raise IndexError(i)


def same_variables(a, b, mask: np.ndarray) -> bool:
    return all(
        all(np.array_equal(x, y) for x, y in zip(variable_arrays(a, i), variable_arrays(b, i), strict=True))
        for i in np.flatnonzero(mask)
    )


# --- the representation ----------------------------------------------------------


def test_parts_own_their_limbs_and_the_root_belongs_to_none(walk):
    names = walk.variable_names
    arm = [n for n, m in zip(names, walk.part_mask("@left-arm"), strict=True) if m]
    assert arm[:4] == ["LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"]
    assert all(n.startswith(("Left", "LThumb")) for n in arm)
    spine = [n for n, m in zip(names, walk.part_mask("@spine"), strict=True) if m]
    assert "Spine" in spine and "Neck" not in spine and "LeftShoulder" not in spine and "Hips" not in spine
    masks = [walk.part_mask(p) for p in ("@left-arm", "@right-arm", "@left-leg", "@right-leg", "@spine", "@head")]
    assert np.all(np.sum(masks, axis=0) <= 1)  # the parts do not overlap
    root = [i for i, n in enumerate(names) if n in ("Hips", "Hips.position")]
    assert len(root) == 2 and not np.any(np.array(masks)[:, root])
    assert walk.part_mask(None).all()


def test_a_partial_pose_is_inserted_losslessly_and_only_in_its_part(walk, arm_walk):
    mask = walk.part_mask("@left-arm")
    assert arm_walk.n_poses == walk.n_poses + 4
    assert [p for p in arm_walk.pose_part if p] == ["@left-arm"] * 4
    owns = arm_walk.owns()
    new = [k for k, p in enumerate(arm_walk.pose_part) if p]
    assert np.array_equal(owns[new], np.tile(mask, (4, 1)))
    for tr, own in zip(arm_walk.tracks, arm_walk.track_owns(), strict=True):
        has = np.zeros_like(own)
        has[tr.knot_pose, tr.knots.var] = True
        assert np.array_equal(has, own)  # knots exactly where the poses own variables
    # the other variables' knots, tangents and displacement maps are the same, bit for bit
    assert same_variables(walk, arm_walk, ~mask)
    # the motion is unchanged
    np.testing.assert_allclose(bake(arm_walk, ik=False).channels, bake(walk, ik=False).channels, atol=1e-9)
    # whole-body priorities do not change; the partial poses get their own
    whole = [k for k, p in enumerate(arm_walk.pose_part) if p is None]
    np.testing.assert_array_equal(arm_walk.priority[whole], walk.priority)
    assert np.all(np.isfinite(arm_walk.priority[new])) and np.all(arm_walk.priority[new] > 0)


def test_partial_poses_are_refused_where_they_cannot_be(walk):
    with pytest.raises(UsageError, match="already a pose"):
        cull.add_poses(walk, [float(walk.pose_t[3])], "@left-arm")
    with pytest.raises(UsageError, match="part must be one of"):
        cull.add_poses(walk, [0.5], "@tail")
    with pytest.raises(UsageError, match="half a frame apart"):
        cull.add_poses(walk, [0.5, 0.5 + 0.2 * walk.frame_time], "@left-arm")
    march_c3d = st.extract(st.read("data/samples/march.c3d"))
    with pytest.raises(UsageError, match="need a BVH document"):
        st.cull(march_c3d, add_time=1.0, part="@left-arm")
    with pytest.raises(UsageError, match="add_time"):
        st.cull(walk, keep=5, part="@left-arm")


def test_refinements_of_a_partial_pose_move_only_its_part(arm_walk):
    k = arm_walk.pose_part.index("@left-arm")
    mask = arm_walk.part_mask("@left-arm")
    delta = np.zeros((arm_walk.n_poses, len(mask)))
    delta[k] = 0.02  # asked of every variable: only the part's have knots to move
    with staggered_warnings():
        moved = timing.change_refinements(arm_walk, delta)
    r = moved.refinements()
    moving = ~np.concatenate([timing.static_variables(tr) for tr in arm_walk.tracks])  # a still finger has no timing
    np.testing.assert_allclose(r[k, mask & moving], 0.02, atol=1e-12)
    assert (mask & moving).sum() >= 5 and np.all(r[k, mask & ~moving] == 0.0)
    assert np.all(r[k, ~mask] == 0.0)
    assert same_variables(arm_walk, moved, ~mask)
    a, b = bake(arm_walk, ik=False).channels, bake(moved, ik=False).channels
    cols = channel_columns(arm_walk, mask)
    assert np.array_equal(a[:, ~cols], b[:, ~cols])
    changed = np.flatnonzero(np.any(np.abs(a - b) > 1e-9, axis=1))
    t, r0 = arm_walk.pose_t, arm_walk.refinements()
    # only between the pose's neighbouring knots in its part (the knots of the
    # whole-body poses around it: a neighbour's extreme knot may lie outside its pose time)
    first = t[k - 1] + min(0.0, r0[k - 1, mask].min())
    last = t[k + 1] + max(0.0, r0[k + 1, mask].max())
    ft = arm_walk.frame_time
    assert len(changed) and first <= changed[0] * ft and changed[-1] * ft <= last


# --- the format ---------------------------------------------------------------------


def test_version_3_round_trip_keeps_the_parts(arm_walk, tmp_path):
    manifest, arrays = to_parts(arm_walk)
    assert manifest["version"] == DOCUMENT_VERSION == 3
    assert manifest["pose_parts"] == list(arm_walk.pose_part) and manifest["layer_pose_parts"] == []
    back = from_parts(json.loads(json.dumps(manifest)), arrays)
    assert back.pose_part == arm_walk.pose_part
    assert same_variables(arm_walk, back, np.ones(len(arm_walk.variable_names), dtype=bool))
    path = document_file(arm_walk, tmp_path / "arm.stag")
    r = run(["info", path, "--json"])
    assert r.exit_code == 0, r.stderr
    poses = json.loads(r.stdout)["poses"]
    assert [p["part"] for p in poses] == list(arm_walk.pose_part)
    text = run(["info", path]).stdout
    assert text.count("part @left-arm") == 4 and "part -" not in text


def test_a_manifest_with_bad_parts_is_refused(arm_walk):
    manifest, arrays = to_parts(arm_walk)
    bad = dict(manifest, pose_parts=manifest["pose_parts"][:-1])
    with pytest.raises(st.DataError, match="pose_parts must be a list"):
        from_parts(bad, arrays)
    bad = dict(manifest, pose_parts=["@tail" if p else p for p in manifest["pose_parts"]])
    with pytest.raises(st.DataError, match="neither null nor a body part"):
        from_parts(bad, arrays)
    # knots that do not match what the poses own
    bad = dict(manifest, pose_parts=["@right-arm" if p else p for p in manifest["pose_parts"]])
    with pytest.raises(st.DataError, match="one extreme knot per pose that owns it"):
        from_parts(bad, arrays)


def test_a_version_2_document_reads_edits_and_bakes_as_before(tmp_path):
    old = FIXTURES / "march_v2.stag"
    doc = st.read(old)
    assert doc.pose_part == (None,) * doc.n_poses
    out = tmp_path / "b.bvh"
    assert run(["bake", old, "-o", out]).exit_code == 0
    assert hashlib.sha256(out.read_bytes()).hexdigest() == V2_BAKE
    edited = tmp_path / "e.stag"
    r = run(["edit-pose", old, "--pose", "3", "--rotate", "LeftArm=10,0,5", "-o", edited])
    assert r.exit_code == 0, r.stderr
    assert run(["bake", edited, "-o", out, "--force"]).exit_code == 0
    assert hashlib.sha256(out.read_bytes()).hexdigest() == V2_EDITED_BAKE


# --- the commands -------------------------------------------------------------------


def test_an_edit_of_a_partial_pose_changes_only_its_part_between_its_neighbours(arm_walk):
    k = arm_walk.pose_part.index("@left-arm")
    mask = arm_walk.part_mask("@left-arm")
    cols = channel_columns(arm_walk, mask)
    before = bake(arm_walk).channels  # with the contact layer: the feet do not notice an arm
    t = arm_walk.pose_t
    ft = arm_walk.frame_time
    for kw in (
        {"rotate": {"LeftArm": (10.0, 0.0, 15.0)}},
        {"exaggerate": 1.6},
        {"exaggerate": 1.6, "relative_to": "prev"},
        {"exaggerate": 1.4, "relative_to": k + 2, "on": "extreme"},
    ):
        edited = st.edit_pose(arm_walk, k, **kw)
        assert same_variables(arm_walk, edited, ~mask), kw
        after = bake(edited).channels
        assert np.array_equal(before[:, ~cols], after[:, ~cols]), kw
        changed = np.flatnonzero(np.any(before != after, axis=1)) * ft
        assert changed.size and changed[0] > t[k - 1] - 1e-9 and changed[-1] < t[k + 1] + 1e-9, kw
    with pytest.raises(UsageError, match="partial pose of @left-arm: 'RightArm' is not in it"):
        st.edit_pose(arm_walk, k, rotate={"RightArm": (0.0, 0.0, 10.0)})
    with staggered_warnings() as seen:
        st.edit_pose(arm_walk, k, exaggerate=1.2, root=True)
    assert any("owns only @left-arm" in w for w in seen)


def test_exaggeration_references_are_the_poses_of_the_same_part():
    from staggered_cli.ops.edit_pose import _reference_pose

    parts = (None, "@left-arm", None, "@right-arm", "@left-arm", None)
    assert _reference_pose("prev", 4, 6, parts) == 2 and _reference_pose("next", 1, 6, parts) == 2
    assert _reference_pose("next", 2, 6, parts) == 5 and _reference_pose("prev", 5, 6, parts) == 2
    assert _reference_pose("prev", 3, 6, parts) == 2 and _reference_pose("3", 1, 6, parts) == 3


@pytest.mark.parametrize("by", ["error", "paper"])
def test_cull_keeps_exactly_n_counting_partial_poses(arm_walk, by):
    base = bake(arm_walk, ik=False).channels
    partial = np.array([p is not None for p in arm_walk.pose_part])
    kept_partial = 0
    for n in range(2, arm_walk.n_poses + 1, 3):
        mask = cull.choose(arm_walk, keep=str(n), by=by, ignore_contacts=True)
        assert mask.sum() == n
        kept_partial += int((mask & partial).sum())
        culled = cull.keep_poses(arm_walk, mask)
        assert culled.pose_part == tuple(p for p, m in zip(arm_walk.pose_part, mask, strict=True) if m)
        np.testing.assert_allclose(bake(culled, ik=False).channels, base, atol=1e-9)
    assert kept_partial > 0  # they compete with the others
    # --select names them by index, as info lists them
    k = [i for i, p in enumerate(arm_walk.pose_part) if p]
    sel = st.cull(arm_walk, select=k[:2])
    assert sel.pose_part == (None, "@left-arm", "@left-arm", None)


def test_succession_shifts_the_partial_poses_knots_within_a_frame():
    from staggered_cli.motion import local_rotations_from_channels

    from .test_ops import shifted_within_a_frame

    doc = dev_document(WALK)
    doc = cull.keep_poses(doc, cull.choose(doc, keep="50%", ignore_contacts=True))
    doc = cull.add_poses(doc, midpoints(doc, 2, start=1), "@left-arm")
    offset, power = 0.02, 1.5
    with staggered_warnings():
        out = timing.succession(doc, offset, power, joint="LeftShoulder")
    sk = doc.source.skeleton
    depth = sk.depth_below(sk.index("LeftShoulder"))
    a = local_rotations_from_channels(sk, bake(doc, ik=False).channels)
    b = local_rotations_from_channels(sk, bake(out, ik=False).channels)
    ref, names, owns, ft = doc.refinements(), doc.variable_names, doc.owns(), doc.frame_time
    cases, partial_cases = [], []
    for k in range(1, doc.n_poses - 1):
        for j in np.flatnonzero(depth > 0):
            if sk.names[j] not in names or not owns[k, names.index(sk.names[j])]:
                continue
            f = int(round((doc.pose_t[k] + ref[k, names.index(sk.names[j])]) / ft))
            if 4 <= f <= doc.n_frames - 5:
                (partial_cases if doc.pose_part[k] else cases).append((j, f, offset * depth[j] ** power))
    hits, counted = shifted_within_a_frame(a, b, cases + partial_cases, ft, still=0.5)
    assert len(counted) >= 10 and hits / len(counted) >= 0.8, (hits, len(counted))
    p_hits, p_counted = shifted_within_a_frame(a, b, partial_cases, ft, still=0.5)
    assert len(p_counted) >= 4 and p_hits / len(p_counted) >= 0.75, (p_hits, len(p_counted))
    # every pose with knots in the chain was shifted, by its refinements
    r = out.refinements() - ref
    chain = np.isin(np.concatenate([tr.targets for tr in doc.tracks]), np.flatnonzero(depth > 0))
    moving = ~np.concatenate([timing.static_variables(tr) for tr in doc.tracks])
    inner = np.arange(1, doc.n_poses - 1)
    want = np.where(owns & (chain & moving)[None, :], 1.0, 0.0)[inner]
    assert np.array_equal(r[inner] != 0, want != 0)


def test_randomize_retimes_partial_poses_in_their_part_only(arm_walk):
    with staggered_warnings():
        out = st.randomize(arm_walk, tau=0.01, seed=3, clamp=True)
    r = out.refinements() - arm_walk.refinements()
    owns = arm_walk.owns()
    assert np.all(r[~owns] == 0.0)
    k = [i for i, p in enumerate(arm_walk.pose_part) if p]
    assert np.any(r[k] != 0.0)


def test_a_layer_from_partial_poses_is_partial(arm_walk, tmp_path):
    n = arm_walk.n_poses
    layered = st.add_layer(arm_walk, keep=n)  # every pose: the partial ones stay partial
    assert layered.layer_pose_part == (arm_walk.pose_part,)
    mask = arm_walk.part_mask("@left-arm")
    for tr, own in zip(layered.tracks, layered.track_owns(1), strict=True):
        has = np.zeros_like(own)
        has[tr.layers[1].knots.pose, tr.layers[1].knots.var] = True
        assert np.array_equal(has, own)
    k = arm_walk.pose_part.index("@left-arm")
    edited = st.edit_pose(layered, k, layer=1, exaggerate=1.5)
    a, b = bake(layered, ik=False).channels, bake(edited, ik=False).channels
    cols = channel_columns(arm_walk, mask)
    assert np.array_equal(a[:, ~cols], b[:, ~cols]) and not np.array_equal(a, b)
    back = st.read(document_file(edited, tmp_path / "layered.stag"))
    assert back.layer_pose_part == layered.layer_pose_part
    np.testing.assert_array_equal(bake(back, ik=False).channels, b)
    assert st.remove_layer(back, 1).layer_pose_part == ()


def test_export_poses_and_back_with_partial_poses(arm_walk):
    from staggered_cli.ops import pose_file

    k = arm_walk.pose_part.index("@left-arm")
    exported = pose_file.export_poses(arm_walk)
    assert exported.n_frames == arm_walk.n_poses
    # a partial pose's frame is the whole figure at its time (as baked, without the contact layer)
    baked = bake(arm_walk, ik=False)
    f = int(round(arm_walk.pose_t[k] / arm_walk.frame_time))
    if abs(f * arm_walk.frame_time - arm_walk.pose_t[k]) < 1e-9:
        np.testing.assert_allclose(exported.channels[k], baked.channels[f], atol=1e-6)
    same, poses, joints = pose_file.apply_pose_file(arm_walk, exported)
    assert (poses, joints) == (0, 0)
    # the whole frame of the partial pose turned: only its part comes back, with a warning
    sk = arm_walk.source.skeleton
    channels = exported.channels.copy()
    rot_cols = [i for i, c in enumerate(c for ch in sk.channels for c in ch) if c.endswith("rotation")]
    channels[k, rot_cols] += 3.0
    with staggered_warnings() as seen:
        back, poses, joints = pose_file.apply_pose_file(arm_walk, exported.with_channels(channels, same_text=False))
    assert poses == 1 and any("outside its partial pose's part" in w for w in seen)
    mask = arm_walk.part_mask("@left-arm")
    assert same_variables(arm_walk, back, ~mask) and not same_variables(arm_walk, back, mask)


def test_timing_plot_and_preview_show_partial_poses(arm_walk):
    fig = st.plot(arm_walk, kind="timing")
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "partial pose (knots in its part's rows)" in labels
    # the partial poses' knots are drawn on the part's rows only: squares
    ax = fig.axes[0]
    rows = [t.get_text() for t in ax.get_yticklabels()]
    part_names = {n for n, m in zip(arm_walk.variable_names, arm_walk.part_mask("@left-arm"), strict=True) if m}
    at = arm_walk.pose_t[[i for i, p in enumerate(arm_walk.pose_part) if p]]
    partial = [
        c.get_offsets()
        for c in ax.collections
        if hasattr(c, "get_offsets")
        and len(c.get_offsets())
        and np.isin(np.round(c.get_offsets()[:, 0], 9), np.round(at, 9)).all()
    ]
    assert len(partial) == 1  # their own scatter (unrefined: at their pose times)
    drawn_rows = {rows[int(y)] for y in np.asarray(partial[0])[:, 1]}
    assert drawn_rows and drawn_rows <= part_names
    k = arm_walk.pose_part.index("@left-arm")
    fig = st.preview(arm_walk)
    titles = [ax.get_title() for ax in fig.axes]
    assert any(t.startswith(f"pose {k} (@left-arm)") for t in titles)
    plain = st.plot(dev_document(WALK), kind="timing")
    assert "partial pose (knots in its part's rows)" not in [t.get_text() for t in plain.legends[0].get_texts()]


def test_the_cull_command_adds_partial_poses(tmp_path):
    src = tmp_path / "march.stag"
    assert run(["extract", "data/samples/march.bvh", "-o", src]).exit_code == 0
    out = tmp_path / "arm.stag"
    r = run(["cull", src, "--add-time", "0.55", "--add-time", "1.0", "--part", "@Left-Arm", "-o", out])
    assert r.exit_code == 0, r.stderr
    info = json.loads(run(["info", out, "--json"]).stdout)
    assert [p["part"] for p in info["poses"] if p["part"]] == ["@left-arm", "@left-arm"]
    r = run(["cull", src, "--keep", "5", "--part", "@left-arm", "-o", tmp_path / "x.stag"])
    assert r.exit_code == 2 and "--part says what the poses of --add-time own" in r.stderr
    r = run(["cull", src, "--add-time", "1", "--part", "@tail", "-o", tmp_path / "x.stag"])
    assert r.exit_code == 2 and "--part must be one of @left-arm" in r.stderr
    assert not (tmp_path / "x.stag").exists()


def test_place_extremes_moves_partial_knots_without_changing_the_motion(walk, arm_walk):
    ks = [k for k, p in enumerate(arm_walk.pose_part) if p]
    mask = arm_walk.part_mask("@left-arm")
    r = arm_walk.refinements().copy()
    r[ks[0], mask] = 0.03
    r[ks[1], mask] = -0.02
    r[ks[1], ~mask] = 0.5  # outside the part: no knot, ignored
    placed = cull.place_extremes(arm_walk, r)
    got = placed.refinements()
    np.testing.assert_allclose(got[ks[0], mask], 0.03, atol=1e-12)
    np.testing.assert_allclose(got[ks[1], mask], -0.02, atol=1e-12)
    assert np.all(got[ks[1], ~mask] == 0.0)
    assert same_variables(arm_walk, placed, ~mask)
    np.testing.assert_allclose(bake(placed, ik=False).channels, bake(walk, ik=False).channels, atol=1e-9)
    # a knot placed across a neighbour is refused
    r[ks[0], mask] = 0.5
    with pytest.raises(st.UsageError, match="cross"):
        cull.place_extremes(arm_walk, r)


def test_from_motion_builds_partial_poses_as_add_poses_does(walk, arm_walk):
    from staggered_cli.model.variables import from_motion

    motion = walk.source
    new = midpoints(walk, 4)
    t = np.concatenate([walk.pose_t, new])
    refine = np.concatenate([walk.refinements(), np.zeros((4, len(walk.variable_names)))])
    built = from_motion(motion, t, refine, pose_part=[None] * walk.n_poses + ["@left-arm"] * 4)
    assert built.pose_part == arm_walk.pose_part
    for a, b in zip(built.tracks, arm_walk.tracks, strict=True):
        assert np.array_equal(a.knot_t, b.knot_t) and np.array_equal(a.knot_pose, b.knot_pose)
    np.testing.assert_allclose(bake(built, ik=False).channels, motion.channels, atol=1e-6)
    with pytest.raises(UsageError, match="first and last pose"):
        from_motion(motion, t, refine, pose_part=["@left-arm"] + [None] * (len(t) - 1))


@pytest.mark.parametrize(
    "name",
    ["cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu3dsmax_131_02_start_walk_stop.bvh", "games105_idle.bvh"],
)
def test_partial_poses_of_every_part_on_real_skeletons(name):
    """On skeletons of four naming schemes: a partial pose of each part the
    skeleton has, lossless, bit-identical outside the part, through a file
    and a cull --keep."""
    from staggered_cli.names import PARTS

    doc = dev_document(name)
    t = doc.pose_t
    spare = [x for x in np.linspace(0.05, 0.95, 40) * doc.duration if np.min(np.abs(t - x)) > 2 * doc.frame_time]
    parts, times = [], []
    for p, x in zip(PARTS, spare[:: max(1, len(spare) // 6)], strict=False):
        try:
            doc.part_mask("@" + p)
        except UsageError:
            continue
        parts.append("@" + p)
        times.append(float(x))
    assert len(parts) >= 4, parts
    with staggered_warnings():  # a time inside another pose's staggered span collapses it
        out = cull.add_poses(doc, times, parts)
    assert sorted(p for p in out.pose_part if p) == sorted(parts)
    owned = np.zeros(len(doc.variable_names), dtype=bool)
    for p in parts:
        owned |= doc.part_mask(p)
    assert same_variables(doc, out, ~owned)
    np.testing.assert_allclose(bake(out, ik=False).channels, bake(doc, ik=False).channels, atol=1e-9)
    back = from_parts(*to_parts(out))
    assert back.pose_part == out.pose_part
    n = (out.n_poses + 2) // 2
    assert cull.choose(out, keep=str(n), ignore_contacts=True).sum() == n
