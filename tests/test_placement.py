"""The placement proxy (staggered_cli/placement.py): computed faster for issue
17, its segment costs and variable weights keep every bit, since extract
places poses and cull ranks them by these numbers."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli.io.bvh import read_bvh
from staggered_cli.ops import cull
from staggered_cli.signals import placement

from .conftest import dev_document, mocap


def _plain_segment_costs(proxy: placement.Proxy, var, a, b) -> np.ndarray:
    """The costs as first written, on (n, L, C) arrays in one batch."""
    x = proxy.x
    T = x.shape[0]

    def values_at(v, f):
        f = np.clip(f, 0.0, T - 1)
        lo = np.minimum(np.floor(f).astype(int), T - 1)
        hi = np.minimum(lo + 1, T - 1)
        w = (f - lo)[:, None]
        return x[lo, v] * (1.0 - w) + x[hi, v] * w

    first = np.floor(a + 1e-9) + 1.0
    count = np.maximum(np.ceil(b - 1e-9) - first, 0.0).astype(int)
    L = placement.SAMPLES
    j = np.arange(L)[None, :]
    dense = count <= L
    spread = a[:, None] + (b - a)[:, None] * (j + 0.5) / L
    frames = np.where(dense[:, None], first[:, None] + j, spread)
    inside = np.where(dense[:, None], j < count[:, None], True)
    y = values_at(np.repeat(var, L), frames.ravel()).reshape(len(var), L, -1)
    u = np.where(inside, (frames - a[:, None]) / (b - a)[:, None], 0.0)
    m = inside.astype(float)
    v = 1.0 - u
    b0, b1, b2, b3 = v**3 * m, 3 * u * v * v * m, 3 * u * u * v * m, u**3 * m
    xa = values_at(var, a)[:, None, :]
    xb = values_at(var, b)[:, None, :]
    r = (y - b0[..., None] * xa - b3[..., None] * xb) * m[..., None]
    g11, g12, g22 = np.sum(b1 * b1, axis=1), np.sum(b1 * b2, axis=1), np.sum(b2 * b2, axis=1)
    h1 = np.einsum("nl,nlc->nc", b1, r)
    h2 = np.einsum("nl,nlc->nc", b2, r)
    det = g11 * g22 - g12 * g12
    fitted = (count >= 2) & (det > 1e-12 * np.maximum(g11 * g22, 1e-300))
    safe = np.where(fitted, det, 1.0)
    c1 = (g22[:, None] * h1 - g12[:, None] * h2) / safe[:, None]
    c2 = (g11[:, None] * h2 - g12[:, None] * h1) / safe[:, None]
    c1 = np.where(fitted[:, None], c1, xa[:, 0] + (xb[:, 0] - xa[:, 0]) / 3.0)
    c2 = np.where(fitted[:, None], c2, xa[:, 0] + 2.0 * (xb[:, 0] - xa[:, 0]) / 3.0)
    # one frame inside: the least change of the straight controls through it
    one = (count == 1)[:, None]
    miss = (r[:, 0] - b1[:, :1] * c1 - b2[:, :1] * c2) / np.maximum(b1[:, :1] ** 2 + b2[:, :1] ** 2, 1e-300)
    c1 = np.where(one, c1 + b1[:, :1] * miss, c1)
    c2 = np.where(one, c2 + b2[:, :1] * miss, c2)
    res = r - b1[..., None] * c1[:, None, :] - b2[..., None] * c2[:, None, :]
    cost = np.sum(np.sqrt(np.sum(res * res, axis=2)) * m, axis=1)
    # a segment with one frame inside meets it: what is left is rounding, not a misfit
    scale = np.sqrt(np.sum(r[:, 0] ** 2, axis=1)) + 1.0
    assert np.all(cost[count == 1] <= 1e-9 * scale[count == 1])
    cost = np.where(count == 1, 0.0, cost)
    return cost * np.where(dense, 1.0, count / L) * proxy.w[var]


def _segments(rng, T: int, V: int, n: int):
    """Segments of every kind: under a frame, 1 or 2 frames inside, up to
    16 (the frames themselves), longer (spread samples), on whole frames,
    reaching the last frame."""
    a = rng.uniform(0.0, T - 2.0, n)
    a[: n // 5] = np.floor(a[: n // 5])
    length = rng.choice([0.4, 1.5, 2.5, 9.0, 16.0, 17.5, 45.0, 130.0], n) * rng.uniform(0.95, 1.05, n)
    b = np.minimum(a + length, T - 1.0)
    b[n // 5 : 2 * n // 5] = np.ceil(b[n // 5 : 2 * n // 5])
    b = np.minimum(b, T - 1.0)
    ok = b > a + 1e-6
    return rng.integers(0, V, n)[ok], a[ok], b[ok]


def test_segment_costs_are_the_plain_formula_to_the_bit(monkeypatch):
    rng = np.random.default_rng(17)
    T, V = 400, 7
    x = np.cumsum(rng.normal(size=(T, V, 4)), axis=0).astype(np.float32)
    proxy = placement.Proxy(x, rng.uniform(0.5, 3.0, V), np.arange(V))
    var, a, b = _segments(rng, T, V, 6000)
    want = _plain_segment_costs(proxy, var, a, b)
    first = np.floor(a + 1e-9) + 1.0
    assert np.sum(np.maximum(np.ceil(b - 1e-9) - first, 0.0) == 1) > 300  # segments that meet their one frame
    assert np.all(want >= 0) and np.count_nonzero(want) > 0.8 * len(want)
    np.testing.assert_array_equal(placement.segment_costs(proxy, var, a, b), want)
    # the batches do not change a bit either
    monkeypatch.setattr(placement, "_COST_BATCH", 5 * placement.SAMPLES * 4)
    np.testing.assert_array_equal(placement.segment_costs(proxy, var, a, b), want)


def test_segment_costs_read_the_proxy_channel_first_made_once(monkeypatch):
    """Every call on a proxy reads the one channel-first copy of its values
    (a long clip's, made at each call, was most of the calls' time)."""
    rng = np.random.default_rng(4)
    T, V = 300, 5
    proxy = placement.Proxy(rng.normal(size=(T, V, 4)).astype(np.float32), np.ones(V), np.arange(V))
    made = []
    contiguous = np.ascontiguousarray

    def counted(a, *args, **kwargs):
        made.append(np.shape(a))
        return contiguous(a, *args, **kwargs)

    monkeypatch.setattr(placement.np, "ascontiguousarray", counted)
    var, a, b = _segments(rng, T, V, 500)
    first = placement.segment_costs(proxy, var, a, b)
    np.testing.assert_array_equal(placement.segment_costs(proxy, var, a, b), first)
    assert made.count((T * V, 4)[::-1]) == 1
    assert proxy.by_channel.tobytes() == proxy.x.reshape(T * V, 4).T.copy().tobytes()


def test_segment_costs_of_a_document_are_the_plain_formula_to_the_bit():
    """On the proxy cull ranks cmu_02_01's poses with (rotations unrolled, weights from the skeleton)."""
    doc = dev_document("cmu_02_01_walk.bvh")
    proxy, _ = cull.document_proxy(doc)
    var, a, b = _segments(np.random.default_rng(3), proxy.n_frames, proxy.x.shape[1], 3000)
    np.testing.assert_array_equal(placement.segment_costs(proxy, var, a, b), _plain_segment_costs(proxy, var, a, b))


@pytest.mark.parametrize("name", ["cmu_01_01_forward_jumps.bvh", "bandai1_walk_normal_001.bvh", "games105_idle.bvh"])
def test_variable_weights_take_the_middle_frame_alone_to_the_bit(name):
    fresh = read_bvh(mocap(name))
    mid = placement._middle_frame_positions(fresh)
    assert "_world" not in fresh.__dict__  # the clip's world transforms were not computed for it
    np.testing.assert_array_equal(mid, fresh.world()[1][fresh.n_frames // 2])


def _plain_window_costs(proxy: placement.Proxy, frames: np.ndarray, width: int) -> np.ndarray:
    """The window costs in float64, one segment at a time, the controls by np.linalg.lstsq."""
    x = proxy.x[frames].astype(float)
    f = np.asarray(frames, dtype=float)
    G = len(frames)
    out = np.full((G, width), np.inf)
    for i in range(G):
        for w in range(1, min(width, G - 1 - i) + 1):
            if w == 1:
                out[i, 0] = 0.0
                continue
            u = (f[i + 1 : i + w] - f[i]) / (f[i + w] - f[i])
            v = 1.0 - u
            b0, b1, b2, b3 = (q[:, None, None] for q in (v**3, 3 * u * v * v, 3 * u * u * v, u**3))
            y = x[i + 1 : i + w] - b0 * x[i] - b3 * x[i + w]  # (w-1, V, C)
            if w - 1 >= 2:
                basis = np.stack([b1[:, 0, 0], b2[:, 0, 0]], axis=1)
                c1, c2 = np.linalg.lstsq(basis, y.reshape(w - 1, -1), rcond=None)[0].reshape(2, *x.shape[1:])
            else:  # one inner node: the straight controls
                c1, c2 = x[i] + (x[i + w] - x[i]) / 3.0, x[i] + 2.0 * (x[i + w] - x[i]) / 3.0
            res = y - b1 * c1 - b2 * c2
            out[i, w - 1] = np.sum(np.sqrt(np.sum(res * res, axis=2)) * proxy.w)
    return out


def _assert_window_costs_close(got: np.ndarray, want: np.ndarray) -> None:
    """Float32 rounding: the values are float32, and where a cubic fits a
    segment's nodes (nearly) exactly its cost is rounding alone.  On extract's
    placements of the dev clips (8 of 9: the reference is slow on the largest)
    the float32 formula this replaced was off the float64 one by up to 4.3e-5
    of the median cost (4.1% of its costs of 3 inner nodes or more by over
    1e-5 of themselves), this one by up to 2.5e-5 (2.9%)."""
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
    finite = np.isfinite(want)
    positive = want[finite & (want > 0)]
    scale = np.median(positive) if len(positive) else 1.0
    np.testing.assert_allclose(got[finite], want[finite], rtol=1e-5, atol=1e-4 * scale)


def test_window_costs_are_the_plain_formula():
    """The node-to-node costs extract places poses with, on cmu_02_01's proxy
    every 4 frames and on nodes left by a mask (uneven gaps)."""
    doc = dev_document("cmu_02_01_walk.bvh")
    proxy, _ = cull.document_proxy(doc)
    frames = np.arange(0, proxy.n_frames, 4)
    want = _plain_window_costs(proxy, frames, 12)
    assert np.isfinite(want[:-12]).all() and (want[:-12, 1:] > 0).all()
    _assert_window_costs_close(placement.window_costs(proxy, frames, 12), want)
    keep = np.random.default_rng(5).random(proxy.n_frames) < 0.5
    frames = np.unique(np.concatenate([[0], np.flatnonzero(keep[::2]) * 2, [proxy.n_frames - 1]]))
    _assert_window_costs_close(placement.window_costs(proxy, frames, 9), _plain_window_costs(proxy, frames, 9))


def test_window_costs_in_batches_keep_every_bit(monkeypatch):
    """Each segment's cost is computed alone: the batch sizes change no bit;
    short node lists and wide windows run past the last node (inf)."""
    rng = np.random.default_rng(11)
    T, V = 300, 5
    x = np.cumsum(rng.normal(size=(T, V, 4)), axis=0).astype(np.float32)
    proxy = placement.Proxy(x, rng.uniform(0.5, 3.0, V), np.arange(V))
    frames = np.unique(np.concatenate([[0], rng.choice(T, 90, replace=False), [T - 1]]))
    want = placement.window_costs(proxy, frames, 15)
    _assert_window_costs_close(want, _plain_window_costs(proxy, frames, 15))
    for batch, basis in ((1, 1), (7 * V * 4, 1 << 16), (100 * V * 4, 1), (100 * V * 4, 300)):
        monkeypatch.setattr(placement, "_WINDOW_BATCH", batch)
        monkeypatch.setattr(placement, "_BASIS_BATCH", basis)
        np.testing.assert_array_equal(placement.window_costs(proxy, frames, 15), want)
    for G, width in ((1, 3), (2, 3), (3, 1), (3, 5), (6, 9)):
        got = placement.window_costs(proxy, frames[:G], width)
        _assert_window_costs_close(got, _plain_window_costs(proxy, frames[:G], width))
    empty = placement.Proxy(np.zeros((T, 0, 4), np.float32), np.zeros(0), np.zeros(0, dtype=int))
    want = _plain_window_costs(empty, frames[:6], 4)
    np.testing.assert_array_equal(placement.window_costs(empty, frames[:6], 4), want)
