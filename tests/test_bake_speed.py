"""The shortcuts that keep a bake linear in the clip's length give the same
bits as the plain computations: the writer comparing with the numbers the
reader read (no second parse), the evaluation gathering only the segments
its block meets, and the block-by-block contact test looking only at the
constraints' chains and windows."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from staggered_cli.contacts import layer as contact_layer
from staggered_cli.io import bvh
from staggered_cli.io.bvh import bvh_bytes, parse_bvh, read_bvh
from staggered_cli.model.evaluate import evaluate, evaluate_at
from staggered_cli.ops.bake import bake
from staggered_cli.ops.extract import extract

from .conftest import BVH_FILES, mocap

pytestmark = pytest.mark.skipif(not BVH_FILES, reason="../shared/mocap is missing")

CLIP = "cmu_02_01_walk.bvh"


def _edited(m, rng, frames: int, cols: int):
    """``m`` with a few numbers changed (by a hair and by a lot), some near
    the start, the middle and the end."""
    ch = np.array(m.channels, copy=True)
    rows = rng.choice(len(ch), size=min(frames, len(ch)), replace=False)
    for r in rows:
        c = rng.choice(ch.shape[1], size=cols, replace=False)
        ch[r, c] += rng.choice([1e-7, -3.25, 11.0], size=cols)
    return m.with_channels(ch)


def _without_values(m):
    return dataclasses.replace(m, source_values=None)


@pytest.mark.parametrize("name", BVH_FILES)
def test_writer_with_read_values_equals_parsing_again(name):
    m = read_bvh(mocap(name))
    assert m.source_values is m.channels
    rng = np.random.default_rng(17)
    for frames, cols in ((0, 0), (1, 1), (5, 3), (40, 10)):
        e = _edited(m, rng, frames, cols) if frames else m
        fast = bvh_bytes(e)
        assert fast == bvh_bytes(_without_values(e))
        if not frames:
            assert fast == mocap(name).read_bytes()


def _ragged(text: bytes, first: int, last: int) -> bytes:
    """``text`` with lines ``first .. last`` of its MOTION block shifted by
    one number (each takes the next line's first number; the last keeps one
    fewer): as many lines, the same numbers in the same order."""
    head, sep, body = text.partition(b"Frame Time:")
    line_end = body.index(b"\n") + 1
    rows = [line.split() for line in body[line_end:].split(b"\n")]
    for i in range(first, last):
        rows[i].append(rows[i + 1].pop(0))
    return head + sep + body[:line_end] + b"\n".join(b" ".join(r) for r in rows)


@pytest.mark.parametrize("changed", [5, 40, 150, 290])
def test_ragged_lines_fall_back_to_the_tokens(monkeypatch, changed):
    """A block whose lines are not its frames (T lines still) must not be
    rewritten on the rows' word: a piece kept whole is counted."""
    m = read_bvh(mocap(CLIP))
    src = parse_bvh(_ragged(mocap(CLIP).read_bytes(), 20, 300))
    np.testing.assert_array_equal(src.channels, m.channels)
    monkeypatch.setattr(bvh, "_WRITE_CHUNK_BYTES", 2048)  # many pieces, most kept whole
    ch = np.array(src.channels, copy=True)
    ch[changed, : 1 + changed % 7] += 1.0
    e = src.with_channels(ch)
    out = bvh_bytes(e)
    assert out == bvh_bytes(_without_values(e))
    np.testing.assert_allclose(parse_bvh(out).channels, ch, rtol=0, atol=1e-6)  # the written decimals


@pytest.fixture(scope="module")
def doc():
    return extract(read_bvh(mocap(CLIP)))


def test_evaluate_in_blocks_equals_evaluate_at(doc):
    t = doc.frame_times
    for track in doc.tracks:
        whole = evaluate(track, t)
        V = track.n_vars
        var = np.tile(np.arange(V), len(t))
        at = evaluate_at(track, var, np.repeat(t, V)).reshape(len(t), V, track.dim)
        np.testing.assert_array_equal(whole, at)
        # a block meets a few segments: the same bits as in the whole
        np.testing.assert_array_equal(evaluate(track, t[100:300]), whole[100:300])


def test_source_changed_on_chains_equals_all_joints(doc):
    from staggered_cli.model.sampling import local_pose

    src = doc.source
    rot, tr = local_pose(doc, doc.frame_times[:500])
    rot = rot.copy()
    rot[200:260, :] = rot[200:260, ::-1]  # disturb every joint somewhere
    chains = contact_layer.chain_joints(doc)
    assert 0 < len(chains) < src.skeleton.n_joints
    full = contact_layer.source_changed(src, rot, tr, 0)
    some = contact_layer.source_changed(src, rot, tr, 0, chains)
    np.testing.assert_array_equal(some[:, chains], full[:, chains])
    assert not some[:, np.setdiff1d(np.arange(src.skeleton.n_joints), chains)].any()
    t = doc.frame_times[:500]
    for lo, hi in ((0, 500), (0, 100), (190, 270), (400, 500)):
        assert contact_layer.disturbed_in(doc, some[lo:hi], t[lo:hi], 0.1) == contact_layer.disturbed_in(
            doc, full[lo:hi], t[lo:hi], 0.1
        )


@pytest.mark.parametrize("fmt", ["npz", "json"])
def test_round_trip_bake_is_the_source(doc, fmt):
    """Through a document file too: its source.channels are the numbers the
    writer compares with."""
    from staggered_cli.io.container import document_pieces, parse_document
    from staggered_cli.io.schema import from_parts, to_parts

    assert bvh_bytes(bake(doc)) == mocap(CLIP).read_bytes()
    data = b"".join(bytes(p) for p in document_pieces(*to_parts(doc), fmt))
    back = from_parts(*parse_document(data, "doc"))
    np.testing.assert_array_equal(back.source.source_values, doc.source.channels)
    assert bvh_bytes(bake(back)) == mocap(CLIP).read_bytes()


def test_layer_at_equals_the_spline_over_every_segment(doc):
    """layer_at gathers the segments its queries meet: the same bits as the
    spline evaluated with every segment of the layer."""
    from staggered_cli.model import kinds
    from staggered_cli.model.evaluate import layer_at
    from staggered_cli.model.knots import locate

    t = doc.frame_times[50:900]
    for track in doc.tracks:
        layer = track.base
        knots = layer.knots
        V = track.n_vars
        var = np.tile(np.arange(V), len(t))
        tt = np.repeat(t, V)
        gseg = np.zeros(len(tt), dtype=int)
        u = np.zeros(len(tt))
        for i in range(V):
            idx = np.flatnonzero(var == i)
            seg, u[idx] = locate(knots.t[knots.of(i)], tt[idx])
            gseg[idx] = seg + knots.seg_ptr[i]
        first = knots.seg_first
        ref = kinds.ops_for(track.kind).spline_at(knots.v[first], layer.tan_a, layer.tan_b, knots.v[first + 1], gseg, u)
        np.testing.assert_array_equal(layer_at(track.kind, layer, var, tt, detail=False), ref)


def test_to_euler_equals_the_full_matrix_and_argmin():
    """to_euler computes five matrix entries and picks between two
    candidates without stacking: the bits of the whole matrix and argmin."""
    from staggered_cli import quat

    rng = np.random.default_rng(5)
    lock = quat.from_euler(
        np.stack([rng.uniform(-180, 180, 300), np.full(300, -90.0), rng.uniform(-9, 9, 300)], -1), "ZXY"
    )
    q = quat.normalize(np.concatenate([rng.normal(size=(3000, 4)), lock]))
    ref = rng.uniform(-500, 500, size=(len(q), 3))
    for order in ("ZXY", "XYZ", "ZYX", "YZX"):
        i, j, k = ("XYZ".index(c) for c in order)
        m = quat.to_matrix(q)
        sign = 1.0 if (j - i) % 3 == 1 else -1.0
        cb = np.sqrt(m[:, i, i] * m[:, i, i] + m[:, i, j] * m[:, i, j])  # np.hypot to an ulp, 20x faster
        assert np.abs(cb - np.hypot(m[:, i, i], m[:, i, j])).max() <= 2 * np.finfo(float).eps
        got = quat.to_euler(q, order, ref)
        free = cb >= 1e-7  # away from gimbal lock the angles are the matrix's
        out = np.degrees(
            np.stack(
                [
                    np.arctan2(-sign * m[:, j, k], m[:, k, k]),
                    np.arctan2(np.clip(sign * m[:, i, k], -1.0, 1.0), cb),
                    np.arctan2(-sign * m[:, i, j], m[:, i, i]),
                ],
                -1,
            )
        )
        twin = out + np.array([180.0, 0.0, 180.0])
        twin[:, 1] = 180.0 - out[:, 1]
        cands = np.stack([out, twin])
        cands = cands + 360.0 * np.round((ref - cands) / 360.0)
        pick = np.argmin(np.sum((cands - ref) ** 2, axis=-1), axis=0)
        want = np.where(pick[:, None] == 0, cands[0], cands[1])
        np.testing.assert_array_equal(got[free], want[free])
        np.testing.assert_allclose(
            quat.from_euler(got, order), q * np.sign(np.sum(quat.from_euler(got, order) * q, -1))[:, None], atol=1e-9
        )


def test_stored_members_read_as_numpy_reads_them(doc, tmp_path):
    """The NPZ reader reads stored members itself: the arrays np.load gives,
    from bytes and from a file, and a flipped byte fails the CRC."""
    import io

    from staggered_cli.io.container import _read_npz, document_pieces
    from staggered_cli.io.schema import to_parts

    data = b"".join(bytes(p) for p in document_pieces(*to_parts(doc), "npz"))
    ref = np.load(io.BytesIO(data))
    path = tmp_path / "doc.stag"
    path.write_bytes(data)
    with open(path, "rb") as fh:
        for _, arrays in (_read_npz(data, "doc"), _read_npz(fh, "doc")):
            assert set(arrays) == set(ref.files) - {"manifest.json"}
            for k, v in arrays.items():
                np.testing.assert_array_equal(v, ref[k])
    at = data.index(doc.source.channels[len(doc.source.channels) // 2].tobytes())
    bad = bytearray(data)
    bad[at + 3] ^= 0x10
    with pytest.raises(Exception, match="CRC"):
        _read_npz(bytes(bad), "doc")
