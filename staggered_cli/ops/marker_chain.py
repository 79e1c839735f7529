"""Markers retimed as a kinematic chain (SPEC section 5, C3D documents).

A C3D document has no hierarchy, and retiming every marker on its own in
world space tears limbs apart: a wrist shifted by 30 ms and a finger by 60 ms
are, mid-swing, a hand-length apart.  So a timing edit of markers goes
through a *marker tree*: every marker with a parent is represented by its
offset from that parent (``P_i - P_parent``), the timing edit warps those
offset trajectories, and positions are rebuilt from the anchors down
(``P_i = O_i + P_parent``).  A segment's length at any time is then a length
its offset had at some time of the source, so segments keep their lengths.

``succession --chain M1,M2,...`` and ``randomize --joints M1,M2,...`` use the
markers in the given order as a chain (each one's parent is the one before);
``randomize`` without ``--joints`` joins every marker into one tree by
:func:`rigid_tree`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..model.document import tree_has_loop
from ..model.evaluate import evaluate_at
from ..model.fit import fit_layer
from ..model.kinds import TRANSLATION
from ..model.knots import Layer, Track

#: Frames (evenly spread) that judge how rigid a pair of markers is: enough
#: for the spread of a distance, and (frames x markers²) stays small.
_TREE_FRAMES = 400
_TREE_VALUES = 4_000_000  # and at most this many distances at once (32 MB)


def chain_parents(n_markers: int, chain: list[int]) -> np.ndarray:
    """Parent index (M,) of every marker: ``chain[i-1]`` for ``chain[i]``, -1
    for the first one and for markers outside the chain."""
    parents = np.full(n_markers, -1, dtype=int)
    for a, b in zip(chain[:-1], chain[1:], strict=True):
        parents[b] = a
    return parents


def rigid_tree(points: np.ndarray) -> np.ndarray:
    """Parent index (M,) of every marker in the tree that joins the most
    rigid pairs: Prim's minimum spanning tree on the spread (standard
    deviation over frames, gaps ignored) of each pair's distance, rooted at
    the marker whose distances vary least overall.  ``points`` (T, M, 3)."""
    T, M, _ = points.shape
    if M < 2:
        return np.full(M, -1, dtype=int)
    frames = min(T, _TREE_FRAMES, max(10, _TREE_VALUES // (M * M)))
    points = points[np.unique(np.linspace(0, T - 1, frames).astype(int))]
    with np.errstate(invalid="ignore"):
        sq = np.sum(points * points, axis=-1)
        d2 = sq[:, :, None] + sq[:, None, :] - 2.0 * np.einsum("tmk,tnk->tmn", points, points)
        d = np.sqrt(np.maximum(d2, 0.0))  # (frames, M, M), NaN where a marker is missing
        seen = np.isfinite(d)
        n = seen.sum(axis=0)
        mean = np.where(seen, d, 0.0).sum(axis=0) / np.maximum(n, 1)
        var = np.where(seen, (d - mean) ** 2, 0.0).sum(axis=0) / np.maximum(n, 1)
    cost = np.where(n >= 2, np.sqrt(var), np.inf)
    np.fill_diagonal(cost, np.inf)
    ok = np.isfinite(cost)
    spread = np.where(ok, cost, 0.0).sum(axis=1) / np.maximum(ok.sum(axis=1), 1)
    spread[~ok.any(axis=1)] = np.inf
    root = int(np.argmin(spread))
    parents = np.full(M, -1, dtype=int)
    inside = np.zeros(M, dtype=bool)
    inside[root] = True
    best = cost[root].copy()
    via = np.full(M, root)
    for _ in range(M - 1):
        cand = np.where(inside, np.inf, best)
        j = int(np.argmin(cand))
        if not np.isfinite(cand[j]):
            break  # never seen together with the tree: left as its own anchor
        parents[j] = via[j]
        inside[j] = True
        closer = cost[j] < best
        best = np.where(closer, cost[j], best)
        via = np.where(closer, j, via)
    return parents


def _order(parents: np.ndarray) -> list[int]:
    """Markers with a parent, parents before children."""
    done = parents < 0
    out: list[int] = []
    while not done.all():
        ready = np.flatnonzero(~done & done[np.maximum(parents, 0)])
        if len(ready) == 0:
            raise ValueError("the marker tree has a cycle")
        out.extend(int(i) for i in ready)
        done[ready] = True
    return out


def recomposed(
    track: Track, parents: np.ndarray, frame_t: np.ndarray, *, to_offsets: bool, seen: np.ndarray | None = None
) -> Track:
    """The track with the markers of a tree as offsets from their parents
    (``to_offsets``) or back as positions, with the same knots.

    The motion is sampled at the source frames and at every knot time, then
    refitted, so it is exact at the frames that are baked and at the knots.
    ``seen`` (T, M) marks the source frames where each marker was captured:
    across a marker's gaps its *offset* is interpolated (the document fills
    gaps linearly in world space, which a walking foot does not follow), so
    that a retimed marker that lands in a gap keeps its segment's length.
    The positions where a marker was seen do not change.
    """
    if track.kind != TRANSLATION:
        raise ValueError("only marker (translation) tracks form marker trees")
    order = _order(parents)
    if not order:
        return track
    frame_t = np.asarray(frame_t, dtype=float)
    # only the markers of the tree are sampled and refitted; the others keep their fit
    keep = np.flatnonzero(parents < 0)
    keep = keep[~np.isin(keep, parents[parents >= 0])]
    involved = np.setdiff1d(np.arange(track.n_vars), keep)
    t = np.unique(np.concatenate([frame_t, track.knot_t[np.isin(track.knots.var, involved)]]))
    values = np.zeros((len(t), track.n_vars, 3))
    flat = evaluate_at(track, np.repeat(involved, len(t)), np.tile(t, len(involved)), depth=1)
    values[:, involved] = flat.reshape(len(involved), len(t), 3).transpose(1, 0, 2)
    out = values.copy()
    if to_offsets and seen is not None and not seen.all():
        values = _gaps_filled_down_the_tree(values, parents, order, _seen_at(seen, frame_t, t), t)
    for i in order:  # parents first: a parent's position is rebuilt before its child's
        p = parents[i]
        out[:, i] = values[:, i] - values[:, p] if to_offsets else values[:, i] + out[:, p]
    samples_t, samples_v = [], []
    knot_v = track.knot_v.copy()
    for i in range(track.n_vars):
        kt = track.knot_t[track.knot_slice(i)]
        if i in keep:  # refitted from nothing, then taken back from ``track``
            samples_t.append(np.zeros(0))
            samples_v.append(np.zeros((0, 3)))
            continue
        st = np.unique(np.concatenate([frame_t, kt]))
        rows = np.searchsorted(t, st)
        samples_t.append(st)
        samples_v.append(out[rows, i])
        knot_v[track.knot_slice(i)] = out[np.searchsorted(t, kt), i]
    fitted = fit_layer(track.kind, track.knots.with_values(knot_v), samples_t, samples_v)
    return track.with_base(_with_variables(fitted, track.base, keep))


def _seen_at(seen: np.ndarray, frame_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, M): whether each marker was seen at both source frames around each time."""
    ft = frame_t[1] - frame_t[0] if len(frame_t) > 1 else 1.0
    f = np.clip(t / ft, 0, len(frame_t) - 1)
    lo = np.floor(f + 1e-9).astype(int)
    hi = np.minimum(np.ceil(f - 1e-9).astype(int), len(frame_t) - 1)
    return seen[lo] & seen[np.maximum(hi, lo)]


def _gaps_filled_down_the_tree(
    values: np.ndarray, parents: np.ndarray, order: list[int], seen: np.ndarray, t: np.ndarray
) -> np.ndarray:
    """Positions (N, V, 3) where, across each gap of a marker with a parent,
    its offset from its (already filled) parent is interpolated in time."""
    out = values.copy()
    for i in order:
        ok = seen[:, i]
        if ok.all() or not ok.any():
            continue
        off = values[ok, i] - out[ok, parents[i]]
        filled = np.stack([np.interp(t[~ok], t[ok], off[:, ax]) for ax in range(3)], axis=1)
        out[~ok, i] = out[~ok, parents[i]] + filled
    return out


def _with_variables(new: Layer, old: Layer, keep: np.ndarray) -> Layer:
    """``new`` with the variables ``keep`` taken from ``old`` (same knots)."""
    if len(keep) == 0:
        return new
    V = new.knots.n_vars
    seg_var = new.knots.seg_var
    knot_v = np.where(np.isin(new.knots.var, keep)[:, None], old.knots.v, new.knots.v)
    tan_a = np.where(np.isin(seg_var, keep)[:, None], old.tan_a, new.tan_a)
    tan_b = np.where(np.isin(seg_var, keep)[:, None], old.tan_b, new.tan_b)
    s_parts, d_parts, counts = [], [], []
    for i in range(V):
        src = old if i in keep else new
        sl = src.samples(i)
        s_parts.append(src.samp_s[sl])
        d_parts.append(src.samp_d[sl])
        counts.append(sl.stop - sl.start)
    samp_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    return replace(
        new,
        knots=new.knots.with_values(knot_v),
        tan_a=tan_a,
        tan_b=tan_b,
        samp_ptr=samp_ptr,
        samp_s=np.concatenate(s_parts),
        samp_d=np.concatenate(d_parts),
    )


def with_marker_tree(parameters: dict, labels: tuple[str, ...], parents: np.ndarray) -> dict:
    """Document parameters with the tree's edges added to ``marker_tree``
    (``{child: parent}`` labels, which the contact layer of ``bake`` keeps
    whole).  A new edge replaces an older one of the same child; if the old
    edges would then close a loop, only the new tree is kept."""
    new = {labels[i]: labels[int(p)] for i, p in enumerate(parents) if p >= 0}
    merged = {**dict(parameters.get("marker_tree", {})), **new}
    if tree_has_loop(merged):
        merged = new
    return {**parameters, "marker_tree": merged}
