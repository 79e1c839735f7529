"""The representation round trip (SPEC invariant 1) on every real file."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli import quat
from staggered_cli.io.bvh import read_bvh
from staggered_cli.io.schema import from_parts, to_parts
from staggered_cli.model import sampling, variables
from staggered_cli.model.evaluate import evaluate
from staggered_cli.model.restructure import restructure, with_knot_times
from staggered_cli.motion import channels_from_local
from staggered_cli.skeleton import forward_kinematics

from .conftest import BVH_FILES, C3D_FILES, dev_document, mocap


def _bake_channels(doc):
    rot, tr = sampling.local_pose(doc, doc.frame_times)
    return channels_from_local(doc.source.skeleton, rot, tr, doc.source.channels), rot, tr


def _random_refinements(doc, rng, bound=0.1):
    V = sum(t.n_vars for t in doc.tracks)
    ref = rng.uniform(-bound, bound, (doc.n_poses, V))
    return ref


@pytest.fixture(scope="module", params=BVH_FILES)
def bvh(request):
    return read_bvh(mocap(request.param))


@pytest.mark.parametrize("refined", [False, True])
def test_bvh_round_trip(bvh, refined):
    rng = np.random.default_rng(7)
    pose_t = np.arange(0.0, (bvh.n_frames - 1) * bvh.frame_time - 0.2, 0.25)
    doc = variables.from_motion(bvh, pose_t)
    if refined:
        doc = variables.from_motion(bvh, doc.pose_t, _random_refinements(doc, rng))
        assert np.count_nonzero(doc.refinements()) > doc.n_poses
    ch, rot, tr = _bake_channels(doc)
    assert np.abs(ch - bvh.channels).max() < 1e-6
    _, wp = forward_kinematics(bvh.skeleton, rot, tr)
    _, wp0 = bvh.world()
    assert np.abs(wp - wp0).max() < 1e-6 * bvh.figure_height()


@pytest.mark.parametrize("name", C3D_FILES)
def test_c3d_round_trip(name):
    from staggered_cli.io.c3d import read_c3d

    m = read_c3d(mocap(name))
    rng = np.random.default_rng(3)
    pose_t = np.arange(0.0, (m.n_frames - 1) * m.frame_time - 0.2, 0.25)
    doc = variables.from_motion(m, pose_t)
    doc = variables.from_motion(m, doc.pose_t, _random_refinements(doc, rng))
    pts = sampling.marker_points(doc, doc.frame_times)
    gaps = np.isnan(m.points)
    np.testing.assert_array_equal(np.isnan(pts), gaps)
    assert np.nanmax(np.abs(pts - m.points)) < 1e-6 * m.figure_height()


def test_restructure_keeps_the_motion_and_retime_warps_it():
    m = read_bvh(mocap("cmu_02_01_walk.bvh"))
    doc = variables.from_motion(m, np.arange(0.0, (m.n_frames - 1) * m.frame_time, 0.2))
    rot = doc.tracks[1]
    before = evaluate(rot, doc.frame_times)
    # drop every other pose's knots (keeping the first and last): a cull
    keep = np.isin(rot.knot_pose, [0, 2, 4, 6, 8, 10, 12, doc.n_poses - 1])
    culled = restructure(rot, rot.knots.subset(keep))
    after = evaluate(culled, doc.frame_times)
    assert np.degrees(quat.angle_between(before, after)).max() < 1e-7
    # moving an interior knot changes the motion only between its neighbours
    kt = culled.knot_t.copy()
    i = 3
    j = culled.knot_ptr[i] + 2
    kt[j] += 0.03
    warped = evaluate(with_knot_times(culled, kt), doc.frame_times)
    changed = np.degrees(quat.angle_between(after[:, i], warped[:, i])) > 1e-9
    lo, hi = culled.knot_t[j - 1], culled.knot_t[j + 1]
    assert changed.any()
    assert np.all((doc.frame_times[changed] > lo) & (doc.frame_times[changed] < hi))
    others = np.delete(np.arange(culled.n_vars), i)
    assert np.degrees(quat.angle_between(after[:, others], warped[:, others])).max() < 1e-9


def test_parts_round_trip_exactly():
    m = read_bvh(mocap("bandai2_run_normal_001.bvh"))
    doc = variables.from_motion(m, np.arange(0.0, 2.0, 0.3))
    manifest, arrays = to_parts(doc)
    back = from_parts(manifest, arrays)
    m2, a2 = to_parts(back)
    assert m2 == manifest
    for k in arrays:
        np.testing.assert_array_equal(a2[k], arrays[k])


def test_restructure_places_samples_in_order_and_carries_kept_ones(monkeypatch):
    """The refitted layer's samples are written straight to their places:
    kept segments' samples are the old ones, moved; every variable's samples
    are in order of knot coordinate; and small groups of variables give the
    same bits as large ones."""
    from staggered_cli.model import fit
    from staggered_cli.model.restructure import _unchanged_segments
    from staggered_cli.ops import cull

    from .conftest import dev_document

    doc = dev_document("cmu_02_01_walk.bvh")
    mask = cull.choose(doc, keep="30%")
    new_index = np.cumsum(mask) - 1
    for tr in doc.tracks:
        knots = tr.knots.subset(mask[tr.knot_pose], new_index[tr.knot_pose])
        whole = restructure(tr, knots, frame_t=doc.frame_times).base
        with monkeypatch.context() as m:
            m.setattr(fit, "FIT_GROUP", 500)
            small = restructure(tr, knots, frame_t=doc.frame_times).base
        for name in ("tan_a", "tan_b", "samp_ptr", "samp_s", "samp_d"):
            np.testing.assert_array_equal(getattr(small, name), getattr(whole, name), err_msg=name)
        assert whole.samp_ptr[-1] == len(whole.samp_s) == len(whole.samp_d)
        for i in range(tr.n_vars):
            s_i = whole.samp_s[whole.samp_ptr[i] : whole.samp_ptr[i + 1]]
            assert np.all(np.diff(s_i) >= 0), tr.names[i]
        # a kept segment carries its samples over unchanged
        kept_old = _unchanged_segments(tr.base.knots, knots)
        for g in np.flatnonzero(kept_old >= 0)[:20]:
            i = int(knots.seg_var[g])
            old_s = tr.base.samp_s[tr.base.samples(i)]
            new_s = whole.samp_s[whole.samples(i)]
            o_local = kept_old[g] - tr.base.knots.seg_ptr[i]
            n_local = g - knots.seg_ptr[i]
            o_in = (old_s >= o_local) & (old_s < o_local + 1)
            n_in = (new_s >= n_local) & (new_s < n_local + 1)
            np.testing.assert_array_equal(new_s[n_in] - n_local, old_s[o_in] - o_local)
            np.testing.assert_array_equal(
                whole.samp_d[whole.samples(i)][n_in], tr.base.samp_d[tr.base.samples(i)][o_in]
            )


def test_restructure_reads_the_motion_it_is_given_to_the_bit():
    """With ``dense`` (the base motion at the frame times, as cull has it)
    restructure makes the same layer as when it evaluates the motion itself;
    a ``dense`` of another shape is refused."""
    from staggered_cli.ops import cull

    from .conftest import dev_document

    doc = dev_document("cmu_02_01_walk.bvh")
    mask = cull.choose(doc, keep="30%")
    new_index = np.cumsum(mask) - 1
    for tr in doc.tracks:
        knots = tr.knots.subset(mask[tr.knot_pose], new_index[tr.knot_pose])
        dense = evaluate(tr, doc.frame_times, depth=1)
        given = restructure(tr, knots, frame_t=doc.frame_times, dense=dense).base
        own = restructure(tr, knots, frame_t=doc.frame_times).base
        for name in ("tan_a", "tan_b", "samp_ptr", "samp_s", "samp_d"):
            np.testing.assert_array_equal(getattr(given, name), getattr(own, name), err_msg=name)
        with pytest.raises(ValueError, match="dense must be"):
            restructure(tr, knots, frame_t=doc.frame_times, dense=dense[1:])


def test_frame_and_knot_times_merge_as_unique_does():
    from staggered_cli.model.restructure import _with_knot_times

    frame_t = np.arange(10) * 0.1
    for knot_t in ([], [-0.05, 0.0], [0.1, 0.15, 0.16, 0.3], [0.85, 0.9, 0.95, 1.2], frame_t[[2, 5]]):
        knot_t = np.asarray(knot_t, dtype=float)
        st, frame = _with_knot_times(frame_t, knot_t)
        np.testing.assert_array_equal(st, np.unique(np.concatenate([frame_t, knot_t])))
        on = frame >= 0
        np.testing.assert_array_equal(st[on], frame_t[frame[on]])
        assert on.sum() == len(frame_t)


def test_extract_in_groups_and_blocks_gives_the_same_bits(monkeypatch):
    """The fit over groups of a few variables, forward kinematics, rotation
    steps and the placement proxy over small blocks of frames: the same
    document to the bit (every segment and frame is its own)."""
    from staggered_cli import motion
    from staggered_cli.io.container import document_bytes
    from staggered_cli.model import fit
    from staggered_cli.ops.extract import extract
    from staggered_cli.signals import placement, trails

    path = mocap("cmu_01_01_forward_jumps.bvh")
    once = document_bytes(*to_parts(extract(read_bvh(path))), "npz")
    monkeypatch.setattr(fit, "FIT_GROUP", 3000)  # about one variable a group
    monkeypatch.setattr(motion, "_FK_BLOCK", 31 * 100)
    monkeypatch.setattr(trails, "_STEP_BLOCK", 32 * 77)
    monkeypatch.setattr(placement, "_PROXY_BLOCK", 32 * 50)
    assert document_bytes(*to_parts(extract(read_bvh(path))), "npz") == once


def test_cull_and_succession_in_small_groups_give_the_same_bits(monkeypatch, tmp_path):
    """restructure writing its samples range of variables by range (fit
    groups of about one variable, carried variables one by one), the proxy's
    path and quat.unroll over small blocks of frames, and a document read in
    small pieces: the same documents to the bit as whole processing."""
    from staggered_cli.cli.common import read_document
    from staggered_cli.io import container
    from staggered_cli.io.container import document_bytes
    from staggered_cli.model import fit
    from staggered_cli.ops import cull, timing
    from staggered_cli.signals import placement

    doc = dev_document("cmu_01_01_forward_jumps.bvh")

    def steps(d):
        motion = cull.base_motion(d)
        culled = cull.keep_poses(d, cull.choose(d, keep="30%", motion=motion), motion)
        succ = timing.succession(d, 0.03, 1.5, joint="@left-arm", clamp=True)
        return [document_bytes(*to_parts(x), "npz") for x in (culled, succ)]

    whole = steps(doc)
    path = tmp_path / "doc.stag"
    path.write_bytes(document_bytes(*to_parts(doc), "npz"))
    read_whole = read_document(str(path))
    monkeypatch.setattr(fit, "FIT_GROUP", 3000)  # about one variable a group
    monkeypatch.setattr(placement, "_PROXY_BLOCK", 32 * 50)
    monkeypatch.setattr(quat, "_UNROLL_BLOCK", 31 * 4 * 7)
    monkeypatch.setattr(container, "_READ_CHUNK", 1000)
    assert steps(doc) == whole
    read_small = read_document(str(path))
    assert document_bytes(*to_parts(read_small), "npz") == document_bytes(*to_parts(read_whole), "npz")


def test_unroll_in_blocks_matches_the_flips_of_the_whole():
    """Blocked, in-place unroll = the sign of the cumulative parity of the
    negative dots over the whole clip, to the bit, along any axis."""
    rng = np.random.default_rng(4)
    q = quat.normalize(rng.normal(size=(300, 5, 4)))
    dots = np.sum(q[1:] * q[:-1], axis=-1)
    flips = np.cumsum(dots < 0.0, axis=0) % 2
    sign = np.concatenate([np.ones((1, 5)), 1.0 - 2.0 * flips], axis=0)
    want = q * sign[..., None]
    np.testing.assert_array_equal(quat.unroll(q, axis=0), want)
    np.testing.assert_array_equal(quat.unroll(np.moveaxis(q, 0, 1), axis=1), np.moveaxis(want, 0, 1))
    assert np.all(np.sum(quat.unroll(q)[1:] * quat.unroll(q)[:-1], axis=-1) >= 0.0)


def _knots_one_variable_at_a_time(pose_t, refine, value, edit_value):
    """The plain form of knots_from_poses: each variable's knots sorted on their own."""
    K, V = refine.shape
    ptr, ts, vs, ps, es = [0], [], [], [], []
    for i in range(V):
        k_ed = np.flatnonzero(refine[:, i] != 0.0)
        t = np.concatenate([pose_t + refine[:, i], pose_t[k_ed]])
        order = np.argsort(t, kind="stable")
        ts.append(t[order])
        vs.append(np.concatenate([value[:, i], edit_value[k_ed, i]])[order])
        ps.append(np.concatenate([np.arange(K), k_ed])[order])
        es.append(np.concatenate([np.zeros(K, dtype=bool), np.ones(len(k_ed), dtype=bool)])[order])
        ptr.append(ptr[-1] + len(t))
    return np.array(ptr), np.concatenate(ts), np.concatenate(vs), np.concatenate(ps), np.concatenate(es)


def test_knots_of_all_variables_at_once_are_each_variables_own():
    """Refinements of both signs, none, and an extreme knot on the next
    pose's time (a tie the stable sort keeps in pose order): the same knots
    as one variable at a time; crossing knots name the variable and pose."""
    from staggered_cli.errors import KnotOrderError
    from staggered_cli.model.fit import knots_from_poses

    rng = np.random.default_rng(5)
    K, V = 9, 6
    pose_t = np.arange(K) * 0.5
    refine = np.where(rng.random((K, V)) < 0.5, rng.uniform(-0.2, 0.2, (K, V)), 0.0)
    refine[[0, -1]] = 0.0
    refine[3, 2] = 0.5  # pose 3's extreme knot of variable 2 at pose 4's time
    value, edit = rng.normal(size=(K, V, 4)), rng.normal(size=(K, V, 4))
    got = knots_from_poses(pose_t, refine, value, edit)
    for x, y in zip(
        (got.ptr, got.t, got.v, got.pose, got.editing),
        _knots_one_variable_at_a_time(pose_t, refine, value, edit),
        strict=True,
    ):
        assert x.dtype.kind == y.dtype.kind and x.tobytes() == y.tobytes()
    refine[4, 5] = -0.9  # pose 4's extreme knot of variable 5 before pose 3's
    with pytest.raises(KnotOrderError, match="'variable 5' around pose 4"):
        knots_from_poses(pose_t, refine, value, edit)


def test_samples_inside_the_knots_are_those_off_every_knot():
    """One search for both the segment and the nearest knots: a time on a
    knot, within 1e-9 s of one, between, before and after the knots."""
    from staggered_cli.model.knots import _AT_KNOT, locate, locate_inside

    kt = np.array([0.0, 0.25, 0.5, 1.0])
    t = np.array([-0.1, 0.0, 0.5e-9, 0.1, 0.25 - 0.5e-9, 0.25, 0.25 + 2e-9, 0.7, 1.0 - 0.5e-9, 1.0, 1.2])
    seg, u, keep = locate_inside(kt, t)
    s2, u2 = locate(kt, t)
    assert seg.tobytes() == s2.tobytes() and u.tobytes() == u2.tobytes()
    near = np.min(np.abs(t[:, None] - kt[None]), axis=1) <= _AT_KNOT
    assert keep.tolist() == (~near & (t > 0.0) & (t < 1.0)).tolist()
    assert keep.tolist() == [False, False, False, True, False, False, True, True, False, False, False]
