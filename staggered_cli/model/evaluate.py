"""Evaluating a track: splines ⊕ displacement maps, layer over layer (paper 3, SPEC 3).

``v_i(t) = s_i(u) ⊕ d_i(u)`` for every variable ``i`` of every layer, the
layers folded from the base up.
"""

from __future__ import annotations

import numpy as np

from . import kinds, segments
from .knots import Layer, Track, locate

# --- evaluation --------------------------------------------------------------


def evaluate(track: Track, t: np.ndarray, layers: str = "all", depth: int | None = None) -> np.ndarray:
    """Values of every variable at times ``t``.

    Parameters
    ----------
    t : (N,) seconds.
    layers : ``'all'`` (spline ⊕ displacement, every layer) or ``'splines'``
        (the splines of every layer, without their displacement maps).
    depth : fold only the bottom ``depth`` layers (None: all; 1: the base).

    Returns
    -------
    (N, V, D) values (unit quaternions w first for rotations).
    """
    if layers not in ("all", "splines"):
        raise ValueError(f"layers must be 'all' or 'splines', got {layers!r}")
    t = np.asarray(t, dtype=float)
    V, N = track.n_vars, len(t)
    stack = track.layers if depth is None else track.layers[:depth]
    out = np.empty((N, V, track.dim))
    # in blocks of frames, so that the temporaries stay small whatever the length
    rows = max(1, _BLOCK // max(V, 1))
    for lo in range(0, N, rows):
        tb = t[lo : lo + rows]
        n = len(tb)
        var = np.broadcast_to(np.arange(V)[None, :], (n, V)).ravel()
        # the queries grouped by variable without sorting: variable i's are i, i + V, ...
        order = np.arange(n * V).reshape(n, V).T.ravel()
        bounds = np.arange(V + 1) * n
        out[lo : lo + n] = _fold(track, stack, layers == "all", var, np.repeat(tb, V), order, bounds).reshape(
            n, V, track.dim
        )
    return out


def evaluate_at(
    track: Track,
    var: np.ndarray,
    t: np.ndarray,
    layers: str = "all",
    depth: int | None = None,
) -> np.ndarray:
    """Values of variable ``var[n]`` at time ``t[n]``: (N, D), the layers
    folded bottom up (``v = l_0 ⊕ l_1 ⊕ ...``)."""
    if layers not in ("all", "splines"):
        raise ValueError(f"layers must be 'all' or 'splines', got {layers!r}")
    var = np.asarray(var, dtype=int)
    t = np.asarray(t, dtype=float)
    order = np.argsort(var, kind="stable")
    bounds = np.searchsorted(var[order], np.arange(track.n_vars + 1))
    stack = track.layers if depth is None else track.layers[:depth]
    return _fold(track, stack, layers == "all", var, t, order, bounds)


#: Queries evaluated at once by :func:`evaluate` (its temporaries: a few
#: arrays of this many values and their (N, 4) companions, about 10 MB).
_BLOCK = 1 << 16


def _fold(track: Track, stack, detail: bool, var, t, order, bounds) -> np.ndarray:
    """``l_0 ⊕ l_1 ⊕ ...`` over ``stack`` (with their displacement maps, or
    the splines alone)."""
    out = None
    for layer in stack:
        val = layer_at(track.kind, layer, var, t, order, bounds, detail=detail)
        out = val if out is None else track.ops.oplus(out, val)
    return track.ops.normalize(out) if len(stack) > 1 else out


def layer_at(
    kind: str,
    layer: Layer,
    var: np.ndarray,
    t: np.ndarray,
    order: np.ndarray | None = None,
    bounds: np.ndarray | None = None,
    detail: bool = True,
) -> np.ndarray:
    """Values (N, D) of one layer (spline ⊕ displacement, or the spline alone
    without ``detail``) of variable ``var[n]`` at time ``t[n]``.  ``order``
    and ``bounds`` group the queries by variable (computed when not given)."""
    knots = layer.knots
    V = knots.n_vars
    if order is None:
        order = np.argsort(var, kind="stable")
        bounds = np.searchsorted(var[order], np.arange(V + 1))
    N = len(t)
    gseg = np.zeros(N, dtype=int)
    u = np.zeros(N)
    s = np.zeros(N)
    seg_ptr = knots.seg_ptr
    for i in range(V):
        idx = order[bounds[i] : bounds[i + 1]]
        if len(idx) == 0:
            continue
        seg, uu = locate(knots.t[knots.of(i)], t[idx])
        gseg[idx] = seg + seg_ptr[i]
        u[idx] = uu
        s[idx] = seg + uu
    if int(seg_ptr[-1]) == 0:  # single-knot variables (a 1-frame clip): the knot itself
        return knots.v[knots.ptr[var]]
    # only the segments the queries meet are gathered (and the spline's
    # per-segment work done for them): a block of frames meets a few of a
    # long clip's segments, and all of them at every block would make a
    # bake quadratic in the clip's length.  Each segment's numbers are its
    # own, so they are the same bits as with every segment.
    ops = kinds.ops_for(kind)
    fitted = fitted_spline(layer) if detail and layer.has_detail else None
    if fitted is None:
        val = _spline_at(ops, layer, gseg, u)
    else:
        # at a sample the spline is the fit's (the same numbers); elsewhere
        # (at the knots, between frames) it is evaluated
        disp, hit_q, hit_sample = _displacement_at(kind, layer, s, order, bounds, hits=True)
        val = np.empty((N, ops.dim))
        val[hit_q] = fitted[hit_sample]
        miss = np.ones(N, dtype=bool)
        miss[hit_q] = False
        miss = np.flatnonzero(miss)
        if miss.size:
            val[miss] = _spline_at(ops, layer, gseg[miss], u[miss])
    single = np.diff(knots.ptr)[var] < 2
    if np.any(single):
        val[single] = knots.v[knots.ptr[var[single]]]
    if not detail or not layer.has_detail:
        return val
    return ops.oplus(val, disp if fitted is not None else _displacement_at(kind, layer, s, order, bounds))


def _spline_at(ops, layer: Layer, gseg: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The layer's spline on its segments ``gseg`` at times ``u`` (N, D)."""
    seg_ptr, v = layer.knots.seg_ptr, layer.knots.v
    used, at = segments.compact_segments(gseg)
    # the first knot of segment g of variable i is g + i (seg_ptr = ptr - i)
    first = used + (np.searchsorted(seg_ptr, used, side="right") - 1)
    return ops.spline_at(v[first], layer.tan_a[used], layer.tan_b[used], v[first + 1], at, u)


def fitted_spline(layer: Layer) -> np.ndarray | None:
    """The spline at ``layer``'s samples as its fit computed it (NS, D), or
    None: when the layer was not fitted in this process, or was made from a
    fitted one with other knots, tangents or sample coordinates."""
    f = layer.fitted
    if f is None:
        return None
    mine = (f.knots, f.tan_a, f.tan_b, f.samp_ptr, f.samp_s)
    theirs = (layer.knots, layer.tan_a, layer.tan_b, layer.samp_ptr, layer.samp_s)
    return f.values if all(x is y for x, y in zip(mine, theirs, strict=True)) else None


def _displacement_at(kind: str, layer: Layer, s: np.ndarray, order: np.ndarray, bounds: np.ndarray, hits: bool = False):
    """Displacement (N, D) at knot coordinates ``s``, identity at integers.

    Each variable's samples are sorted by knot coordinate (the fit makes
    them so and reading checks it); the identity at the knots is not stored
    but met where the nearest sample lies in another segment, so nothing
    is copied.  With ``hits``, also the queries that lie on a sample (at its
    very knot coordinate, in its segment) and those samples: (out, queries,
    samples).
    """
    ops = kinds.ops_for(kind)
    N = len(s)
    D = ops.dim
    ident = ops.identity()
    # per variable only the search among its own samples; the rest is done
    # for all queries at once (the same numbers, one query at a time)
    q = order[: bounds[-1]]  # the queries, grouped by variable
    k = np.zeros(len(q), dtype=np.intp)  # the first sample of the variable after s
    first = np.zeros(len(q), dtype=np.intp)  # the variable's first sample
    stop = np.zeros(len(q), dtype=np.intp)  # one past its last
    ptr = layer.samp_ptr
    xs_all = layer.samp_s
    for i in range(layer.knots.n_vars):
        a, b = int(bounds[i]), int(bounds[i + 1])
        if a == b:
            continue
        lo, hi = int(ptr[i]), int(ptr[i + 1])
        if hi > lo:
            k[a:b] = np.searchsorted(xs_all[lo:hi], s[order[a:b]], side="right") + lo
        else:
            k[a:b] = lo
        first[a:b] = lo
        stop[a:b] = hi
    si = s[q]
    j = np.floor(si)
    below = k > first
    has = stop > first
    kb = np.where(below, k - 1, first)
    ka = np.minimum(k, stop - 1)
    if len(layer.samp_s):
        np.copyto(kb, 0, where=~has)  # no sample at all: any index (masked below)
        np.copyto(ka, 0, where=~has)
        xb, xa = xs_all[kb], xs_all[ka]
        left = has & below & (xb > j)  # a sample of this segment at or before s
        right = has & (k < stop) & (xa < j + 1.0)  # a sample of this segment after s
        del k, first, stop, below, has  # (a query's temporaries go as soon as they are used)
        if hits:
            on = left & (xb == si)
            hit_q, hit_sample = q[on], kb[on]
            del on
        x_lo = np.where(left, xb, j)  # the knots around each query, identity there
        x_hi = np.where(right, xa, j + 1.0)
        del xb, xa
        lo_g = layer.samp_d[kb]
        del kb
        lo_g[~left] = ident
        hi_g = layer.samp_d[ka]
        del ka
        hi_g[~right] = ident
        del left, right
    else:
        x_lo, x_hi = j, j + 1.0
        lo_g = np.broadcast_to(ident, (len(q), D)).copy()
        hi_g = lo_g.copy()
        hit_q = hit_sample = np.zeros(0, dtype=np.intp)
    # computed in the queries' grouped order, then put in place
    w_g = np.clip((si - x_lo) / (x_hi - x_lo), 0.0, 1.0)
    del si, j, x_lo, x_hi
    out_g = ops.interpolate(lo_g, hi_g, w_g)
    del lo_g, hi_g, w_g
    if len(q) == N:
        out = np.empty((N, D))
    else:  # queries of no variable: the identity
        out = np.broadcast_to(ident, (N, D)).copy()
    out[q] = out_g
    return (out, hit_q, hit_sample) if hits else out
