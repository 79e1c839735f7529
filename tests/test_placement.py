"""The placement proxy (staggered_cli/placement.py): computed faster for issue
17, its segment costs and variable weights keep every bit, since extract
places poses and cull ranks them by these numbers."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli import placement
from staggered_cli.io.bvh import read_bvh
from staggered_cli.ops import cull

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
    res = r - b1[..., None] * c1[:, None, :] - b2[..., None] * c2[:, None, :]
    cost = np.sum(np.sqrt(np.sum(res * res, axis=2)) * m, axis=1)
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
    assert np.all(want >= 0) and np.count_nonzero(want) > 0.9 * len(want)
    np.testing.assert_array_equal(placement.segment_costs(proxy, var, a, b), want)
    # the batches do not change a bit either
    monkeypatch.setattr(placement, "_COST_BATCH", 5 * placement.SAMPLES * 4)
    np.testing.assert_array_equal(placement.segment_costs(proxy, var, a, b), want)


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
    """The window costs as first written (np.sum over the channels)."""
    x = proxy.x[frames]
    G = len(frames)
    out = np.full((G, width), np.inf)
    node_f = frames.astype(np.float32)
    weight = proxy.w.astype(np.float32)
    for w in range(1, min(width, G - 1) + 1):
        n = G - w
        out[:n, w - 1] = 0.0
        if w == 1:
            continue
        i = np.arange(n)
        t = i[:, None] + np.arange(1, w)[None, :]
        fa, fb = node_f[i], node_f[i + w]
        u = (node_f[t] - fa[:, None]) / (fb - fa)[:, None]
        v = 1.0 - u
        b0, b1, b2, b3 = v**3, 3 * u * v * v, 3 * u * u * v, u**3
        xa, xb = x[i], x[i + w]
        r = x[t] - b0[..., None, None] * xa[:, None] - b3[..., None, None] * xb[:, None]
        g11 = np.sum(b1 * b1, axis=1)[:, None, None]
        g12 = np.sum(b1 * b2, axis=1)[:, None, None]
        g22 = np.sum(b2 * b2, axis=1)[:, None, None]
        h1 = np.einsum("nt,ntvc->nvc", b1, r)
        h2 = np.einsum("nt,ntvc->nvc", b2, r)
        det = g11 * g22 - g12 * g12
        if w - 1 >= 2:
            c1 = (g22 * h1 - g12 * h2) / det
            c2 = (g11 * h2 - g12 * h1) / det
        else:
            c1 = xa + (xb - xa) / 3.0
            c2 = xa + 2.0 * (xb - xa) / 3.0
        r = r - b1[..., None, None] * c1[:, None] - b2[..., None, None] * c2[:, None]
        err = np.sqrt(np.sum(r * r, axis=3))
        out[i, w - 1] = np.einsum("ntv,v->n", err, weight)
    return out


def test_window_costs_are_the_plain_formula_to_the_bit():
    """The node-to-node costs extract places poses with, on cmu_02_01's proxy every 4 frames."""
    doc = dev_document("cmu_02_01_walk.bvh")
    proxy, _ = cull.document_proxy(doc)
    frames = np.arange(0, proxy.n_frames, 4)
    want = _plain_window_costs(proxy, frames, 12)
    assert np.isfinite(want[:-12]).all() and (want[:-12, 1:] > 0).all()
    np.testing.assert_array_equal(placement.window_costs(proxy, frames, 12), want)
