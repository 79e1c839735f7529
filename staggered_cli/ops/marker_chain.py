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
        values = _gaps_filled_down_the_tree(values, parents, order, seen_at(seen, frame_t, t), t)
    for i in order:  # parents first: a parent's position is rebuilt before its child's
        p = parents[i]
        out[:, i] = values[:, i] - values[:, p] if to_offsets else values[:, i] + out[:, p]
    return refit_markers(track, frame_t, t, out, ~np.isin(np.arange(track.n_vars), keep))


def seen_at(seen: np.ndarray, frame_t: np.ndarray, t: np.ndarray) -> np.ndarray:
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



def segment_ranges(points: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shortest and longest length (M,) each marker's segment to its parent
    has over the frames that see both (NaN: no parent, or never seen together).
    ``points`` (T, M, 3)."""
    M = points.shape[1]
    lo = np.full(M, np.nan)
    hi = np.full(M, np.nan)
    for i in np.flatnonzero(parents >= 0):
        d = np.linalg.norm(points[:, i] - points[:, parents[i]], axis=1)
        d = d[np.isfinite(d)]
        if len(d):
            lo[i], hi[i] = d.min(), d.max()
    return lo, hi


def walk_from(parents: np.ndarray, fixed: np.ndarray) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """The tree ``parents`` walked outwards from its ``fixed`` markers.

    Returns ``steps``, (marker, via) in walking order: every marker of a
    component that holds a fixed marker is reached from the nearest one
    (breadth first), those of a component without one from its root; and
    ``meetings``, the tree's edges (a, b) that join two walks (between two
    fixed markers of one component), which the steps do not place.
    """
    M = len(parents)
    nbrs: list[list[int]] = [[] for _ in range(M)]
    for i, p in enumerate(parents):
        if p >= 0:
            nbrs[i].append(int(p))
            nbrs[int(p)].append(i)
    via = np.full(M, -2, dtype=int)  # -2: not reached yet, -1: a start
    steps: list[tuple[int, int]] = []
    meetings: list[tuple[int, int]] = []

    def bfs(starts: list[int]) -> None:
        queue = list(starts)
        for s in starts:
            via[s] = -1
        while queue:
            nxt = []
            for u in queue:
                for v in nbrs[u]:
                    if via[v] == -2:
                        via[v] = u
                        steps.append((v, u))
                        nxt.append(v)
            queue = nxt

    fixed = np.asarray(fixed, dtype=bool)
    bfs([int(i) for i in np.flatnonzero(fixed)])
    for r in np.flatnonzero(parents < 0):  # the components without a fixed marker, from their roots
        if via[r] == -2:
            bfs([int(r)])
    for i, p in enumerate(parents):
        if p >= 0 and via[i] != p and via[p] != i:
            meetings.append((int(p), i))
    return steps, meetings


def keep_segments(
    pos: np.ndarray,
    parents: np.ndarray,
    fixed: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    seen: np.ndarray,
) -> np.ndarray:
    """Positions (N, M, 3) with every segment of the tree ``parents`` at a
    length within its [``lo``, ``hi``] (per child marker, see
    :func:`segment_ranges`).

    The tree is walked from the ``fixed`` markers (:func:`walk_from`), which
    stay: each marker is put at the one it is reached from plus its own
    direction in ``pos`` times its length clamped into the range.  Where a
    walk meets another (a segment between two fixed markers' walks), the
    path between the two is moved as a chain with both ends held
    (:func:`_chain_between`), and what hangs from it follows.  A segment
    with a marker not ``seen`` (N, M) at a time, or no range, is left alone
    there.  Markers and times nothing moves keep their values bit for bit.
    """
    out = pos.copy()
    steps, meetings = walk_from(parents, fixed)

    def rng(a: int, b: int) -> tuple[float, float]:
        c = a if parents[a] == b else b
        return float(lo[c]), float(hi[c])

    below: dict[int, list[int]] = {}
    for c, v in steps:
        below.setdefault(v, []).append(c)
        a, b = rng(c, v)
        if not np.isfinite(a):
            continue
        d = pos[:, c] - pos[:, v]
        n = np.linalg.norm(d, axis=1)
        length = np.clip(n, a, b)
        moved = np.any(out[:, v] != pos[:, v], axis=1)
        act = seen[:, c] & seen[:, v] & ((length != n) | moved) & (n > 0)
        out[act, c] = out[act, v] + d[act] * (length[act] / n[act])[:, None]
    via = dict(steps)  # the markers reached from another: neither fixed nor a root

    def back(i: int) -> list[int]:  # i, the marker it was reached from, ... its start
        out_ = [i]
        while out_[-1] in via:
            out_.append(via[out_[-1]])
        return out_

    for _ in range(_MEETING_ROUNDS):  # a chain solved later can move a marker of one solved before
        for a, b in meetings:
            if a not in via and b not in via:
                continue  # both fixed (or starts): the capture's own length there
            path = back(a)[::-1] + back(b)
            lengths = [rng(u, v) for u, v in zip(path[:-1], path[1:], strict=True)]
            if not all(np.isfinite(r[0]) for r in lengths):
                continue
            ra = rng(a, b)
            gap = np.linalg.norm(out[:, b] - out[:, a], axis=1)
            wrong = seen[:, a] & seen[:, b] & ((gap < ra[0] * (1 - 1e-9)) | (gap > ra[1] * (1 + 1e-9)))
            if not wrong.any():
                continue
            on_path = set(path)
            at = path.index(a)
            pattern = seen[:, path]
            for pat in np.unique(pattern[wrong], axis=0):  # the markers of the path seen, frames alike
                act = wrong & np.all(pattern == pat, axis=1)
                lo_, hi_ = at, at + 1  # the stretch around the meeting that is seen
                while lo_ > 0 and pat[lo_ - 1]:
                    lo_ -= 1
                while hi_ < len(path) - 1 and pat[hi_ + 1]:
                    hi_ += 1
                part = path[lo_ : hi_ + 1]
                before = out[act][:, part]
                placed = _chain_between(before, np.array(lengths[lo_:hi_]), lo_ == 0, hi_ == len(path) - 1)
                shift = placed - before
                for n, node in enumerate(part):
                    out[act, node] = placed[:, n]
                    stack = [c for c in below.get(node, []) if c not in on_path]
                    while stack:  # what hangs from a marker of the path moves with it
                        c = stack.pop()
                        out[act, c] += shift[:, n]
                        stack.extend(below.get(c, []))
    return out


#: Passes of :func:`_chain_between` at most (each a forward and a backward sweep).
_CHAIN_PASSES = 50
#: Rounds over the meetings of :func:`keep_segments` at most.
_MEETING_ROUNDS = 4


def _chain_between(p: np.ndarray, ranges: np.ndarray, first: bool = True, last: bool = True) -> np.ndarray:
    """Points (N, n, 3) of a chain whose ends ``p[:, 0]`` and ``p[:, -1]``
    stay, moved so that each link's length lies within ``ranges`` (n-1, 2)
    (FABRIK: sweeps from either end, each link keeping its direction and
    its length clamped into its range, until every link is within its
    own).  The capture itself had such a chain between the same ends
    wherever they are held where it had them, so a solution exists.  With
    only one end held (``first``, ``last``: which), one sweep from it; with
    none, from the first."""
    out = p.copy()
    lo, hi = ranges[:, 0], ranges[:, 1]
    n = out.shape[1]

    def link(frm: np.ndarray, to: np.ndarray, i: int) -> np.ndarray:
        d = to - frm
        length = np.linalg.norm(d, axis=1, keepdims=True)
        return frm + d * (np.clip(length, lo[i], hi[i]) / np.maximum(length, 1e-12))

    if not (first and last):
        order = range(n - 2, -1, -1) if last else range(1, n)
        for i in order:
            out[:, i] = link(out[:, i + 1], out[:, i], i) if last else link(out[:, i - 1], out[:, i], i - 1)
        return out

    for _ in range(_CHAIN_PASSES):
        length = np.linalg.norm(np.diff(out, axis=1), axis=2)
        if np.all((length >= lo * (1 - 1e-9)) & (length <= hi * (1 + 1e-9))):
            break
        for i in range(n - 2, 0, -1):  # from the far end back
            out[:, i] = link(out[:, i + 1], out[:, i], i)
        for i in range(1, n - 1):  # and from the near end out
            out[:, i] = link(out[:, i - 1], out[:, i], i - 1)
    return out


def refit_markers(track: Track, frame_t: np.ndarray, t: np.ndarray, values: np.ndarray, changed: np.ndarray) -> Track:
    """The track with the markers ``changed`` refitted to ``values`` (N, V, 3)
    at times ``t`` (the source frames and every knot time among them), with
    the same knots: exact at the frames that are baked and at the knots."""
    changed = np.asarray(changed, dtype=bool)
    if not changed.any():
        return track
    keep = np.flatnonzero(~changed)
    samples_t, samples_v = [], []
    knot_v = track.knot_v.copy()
    for i in range(track.n_vars):
        if not changed[i]:
            samples_t.append(np.zeros(0))
            samples_v.append(np.zeros((0, 3)))
            continue
        kt = track.knot_t[track.knot_slice(i)]
        st = np.unique(np.concatenate([frame_t, kt]))
        rows = np.searchsorted(t, st)
        samples_t.append(st)
        samples_v.append(values[rows, i])
        knot_v[track.knot_slice(i)] = values[np.searchsorted(t, kt), i]
    fitted = fit_layer(track.kind, track.knots.with_values(knot_v), samples_t, samples_v)
    return track.with_base(_with_variables(fitted, track.base, keep))


def document_tree(doc) -> np.ndarray:
    """Parent index (M,) of every marker of a C3D document: its
    ``marker_tree`` (from succession or randomize) where it has one, else
    :func:`rigid_tree` of its source (what ``randomize`` joins every marker
    with)."""
    labels = list(doc.target_names)
    tree = dict(doc.parameters.get("marker_tree", {}))
    parents = np.full(len(labels), -1, dtype=int)
    for child, parent in tree.items():
        if child in labels and parent in labels:
            parents[labels.index(child)] = labels.index(parent)
    if (parents >= 0).any():
        return parents
    return rigid_tree(doc.source.points)


def centre_marker(points: np.ndarray) -> int:
    """The marker (index) nearest the body's centre: the least median
    distance to the centroid of the markers seen with it, over the frames
    (evenly spread, gaps ignored).  ``points`` (T, M, 3)."""
    T = points.shape[0]
    pts = points[np.unique(np.linspace(0, T - 1, min(T, _TREE_FRAMES)).astype(int))]
    seen = np.all(np.isfinite(pts), axis=2)
    n = seen.sum(axis=1, keepdims=True)
    centre = np.where(seen[..., None], pts, 0.0).sum(axis=1) / np.maximum(n, 1)
    with np.errstate(invalid="ignore"):
        d = np.linalg.norm(pts - centre[:, None], axis=2)
    d = np.where(seen, d, np.nan)
    ok = seen.any(axis=0)
    med = np.full(points.shape[1], np.inf)
    med[ok] = np.nanmedian(d[:, ok], axis=0)
    return int(np.argmin(med))


def tree_path(parents: np.ndarray, a: int, b: int) -> list[int]:
    """The markers on the tree's path from ``a`` to ``b`` (both included;
    empty when they are in different components)."""

    def up(i: int) -> list[int]:
        out = [i]
        while parents[out[-1]] >= 0 and len(out) <= len(parents):
            out.append(int(parents[out[-1]]))
        return out

    ua, ub = up(a), up(b)
    common = set(ua) & set(ub)
    if not common:
        return []
    meet = next(i for i in ua if i in common)
    return ua[: ua.index(meet) + 1] + ub[: ub.index(meet)][::-1]
