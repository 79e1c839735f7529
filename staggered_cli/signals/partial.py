"""Partial poses: where a body part keys itself (issue 37; the paper's section 6).

The paper leaves partial poses (poses that control a subset of the
variables) unfinished: its poses own every variable.  When the arms move to
their own rhythm (a gesture over a walk), their extremes fall between the
whole-body poses.  After the whole-body poses are placed, each body part
(``@left-arm``, ``@right-arm``, ``@left-leg``, ``@right-leg``, ``@spine``,
``@head``, :func:`part_columns`) is looked at alone:

1. **The part's pose probability** ``P_part(t) = tent(Σ w_i p_i / Σ w_i)``
   over the part's variables only: the construction of ``P`` (paper 4.1)
   restricted to the part.  Its local maxima are the part's feature
   clusters.
2. **The part's feature sites**: the frames within half the filter width
   of a maximum of ``P_part`` where the part moves (its own amount of
   motion, the weighted speed of its variables averaged as the whole-body
   gate is, reaches the same ``significance`` in figure heights a second),
   on the placement grid, and not covered: the variables holding
   :data:`COVERED_SHARE` of the part's weight have no knot (a whole-body
   pose time or a refined extreme) within ``min_spacing`` there, and no
   part variable is inside a pose's staggered span there (between its
   editing and its extreme knot: a knot there would reorder them).
3. **Placed by the fit, restricted to the part**: greedily, the site where
   one more knot of every part variable cuts the part's spline misfit most
   (the placement proxy of :mod:`.placement` on the part's variables: the
   segments from each variable's knot before to its knot after) is a
   *candidate*, as long as one cuts the misfit of those segments to
   :data:`PART_GAIN` of what it was or less and removes per knot at least
   :data:`PART_VALUE` times what a whole-body pose that a cull would take
   first holds in place per knot (:func:`pose_value`).  A part's
   candidates are at least :data:`PART_SPACING` seconds apart.
4. **Confirmed in the real spline layer**
   (:func:`staggered_cli.ops.partial.confirmed`): the candidates, best
   first, become partial poses where they earn their knots in world space.
5. **Then fit-driven** (``fit``): anywhere the part moves, farther than
   ``min_spacing`` from the whole-body poses and :data:`PART_SPACING` from
   the part's candidates, the same greedy rule without the features
   proposes more; :func:`~staggered_cli.ops.partial.confirmed` adds those
   that earn their knots, the largest real gain per knot first.

6. **Whole-body poses there for one part** (:func:`demotions`, the
   partitioning of the degrees of freedom the paper leaves open): a
   whole-body pose may become a partial pose of one part, alone (where the
   part has a feature site at the pose and the pose's knots outside the
   part hold little in place per knot in the proxy,
   :func:`demotion_costs`) or together with partial poses of the other
   parts at their own best frames near it (:func:`replacements`: a pose
   between the two arms' extremes keeps one arm, the other arm gets a pose
   at its own extreme, the body's knots go);
   :func:`staggered_cli.ops.partial.confirmed` makes those moves whose net
   cost per knot freed is below a cull's in the real spline layer, then
   spends the knots freed (``extract --partial`` never has more knots than
   plain extract) on steps 3 to 5.

Parts whose features the whole-body poses already cover get none: a plain
walk gains few or none.  C3D clips have no body parts.
"""

from __future__ import annotations

import numpy as np

from .. import names as joint_names
from ..errors import UsageError
from ..model.document import part_of_targets
from ..motion import BvhMotion
from . import placement
from .probability import local_maxima
from .smoothing import tent_filter

#: Fewest seconds between two partial poses of one part.
PART_SPACING = 0.3
#: The whole-body poses a cull would take away first: this percentile of their value per knot.
VALUE_PERCENTILE = 25.0
#: A feature of a part is covered where the variables of at least this share
#: of the part's weight have a knot within ``min_spacing``.
COVERED_SHARE = 0.5
#: A candidate cuts the part's misfit around it to this share or less ...
PART_GAIN = 0.75
#: ... and removes, per knot, at least this share of the misfit a
#: whole-body pose's knot holds in place (:func:`pose_value`): loose, the
#: real spline layer decides (:func:`staggered_cli.ops.partial.confirmed`).
PART_VALUE = 0.25
#: A whole-body pose is proposed as a partial pose of (at most) this many
#: parts, those whose knots elsewhere cost the least per knot ...
DEMOTE_PARTS = 2
#: ... where that cost is at most this many times what a whole pose's knots
#: hold in place per knot (:data:`VALUE_PERCENTILE`): the real spline layer
#: decides (:func:`staggered_cli.ops.partial.demoted`).
DEMOTE_SLACK = 1.5
#: Of those, the cheapest :data:`DEMOTE_SHARE` of the inner poses' number
#: (at least :data:`DEMOTE_LEAST`) are tried: each is a refit of the document.
DEMOTE_SHARE = 0.125
#: The other parts' partial poses near a demoted pose (:func:`replacements`)
#: are tried with it where the demotion alone costs at most this many times
#: what it may cost (on the spliced clips and the bow the moves within the
#: bar cost up to 2.8 times that alone).
DEMOTE_REACH = 3.0
DEMOTE_LEAST = 16


def part_roots(motion: BvhMotion) -> dict[str, int]:
    """Body part (``'@left-arm'``, ...) -> its root joint
    (:func:`staggered_cli.names.body_part`), for the parts the skeleton has."""
    sk = motion.skeleton
    roots = {}
    for part in joint_names.PARTS:
        try:
            roots["@" + part] = joint_names.body_part(part, sk.names, sk.parents)
        except UsageError:
            continue
    return roots


def part_joints(motion: BvhMotion) -> dict[str, np.ndarray]:
    """Body part -> the indices of its joints, as
    :func:`staggered_cli.model.document.part_of_targets` has them (the
    subtree of the part's root less the other parts' inside it; never the
    root joint)."""
    every = np.arange(motion.skeleton.n_joints)
    out = {}
    for part in part_roots(motion):
        try:
            out[part] = every[part_of_targets(motion, every, part)]
        except UsageError:  # a part with no joints of its own
            continue
    return out


def part_columns(motion: BvhMotion, layout) -> dict[str, np.ndarray]:
    """Body part -> the columns (in the document's variable order:
    translations first, then rotations) of the variables it owns
    (:func:`staggered_cli.model.document.part_of_targets`); ``layout``: the
    variables' ``(kind, names, targets, ...)``."""
    targets = np.concatenate([np.asarray(v[2], dtype=int) for v in layout]) if layout else np.zeros(0, int)
    out = {}
    for part in part_roots(motion):
        try:
            out[part] = np.flatnonzero(part_of_targets(motion, targets, part))
        except UsageError:
            continue
    return out


def part_probability(
    p: np.ndarray, weights: np.ndarray, cols: np.ndarray, filter_width: float, rate: float
) -> np.ndarray:
    """``P_part`` (T,): the pose probability over the columns ``cols`` alone."""
    w = np.asarray(weights, dtype=float)[cols]
    den = float(w.sum())
    mean = p[:, cols] @ w / den if den > 0 else np.zeros(p.shape[0])
    return tent_filter(mean, filter_width, rate)


def part_speed(proxy: placement.Proxy, sel: np.ndarray, rate: float, height: float) -> np.ndarray:
    """(T,) how fast the proxy variables ``sel`` move the body, figure heights
    a second (the weighted length of each step of their values)."""
    x = proxy.x[:, sel].astype(float)
    T = x.shape[0]
    out = np.zeros(T)
    if T < 2 or len(sel) == 0:
        return out
    step = np.linalg.norm(np.diff(x, axis=0), axis=2) @ proxy.w[sel] * rate / max(height, 1e-12)
    out[:-1] += 0.5 * step
    out[1:] += 0.5 * step
    return out


def _neighbours(knots: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate frame (n,) and variable (columns of ``knots (K, m)``,
    each sorted): the knot before and the knot after."""
    K = knots.shape[0]
    a = np.empty((len(f), knots.shape[1]))
    b = np.empty_like(a)
    for i in range(knots.shape[1]):
        j = np.clip(np.searchsorted(knots[:, i], f, side="left"), 1, K - 1)
        a[:, i] = knots[j - 1, i]
        b[:, i] = knots[j, i]
    return a, b


def pose_value(proxy: placement.Proxy, pose_f: np.ndarray, refine_f: np.ndarray) -> float:
    """The misfit a whole-body pose that a cull would take first holds in
    place, per knot: the proxy cost its removal adds (the segments around it
    joined) over its variables, at the :data:`VALUE_PERCENTILE` of the
    interior poses."""
    K = len(pose_f)
    V = len(proxy.cols)
    if K < 3 or V == 0:
        return 0.0
    kn = pose_f[:, None] + refine_f[:, proxy.cols].astype(float)
    ks = np.arange(1, K - 1)
    chains = np.stack([kn[ks - 1], kn[ks], kn[ks + 1]], axis=-1)  # (n, V, 3)
    with_k = placement.span_costs(proxy, chains)
    without = placement.span_costs(proxy, chains[..., [0, 2]])
    per = np.sum(without - with_k, axis=1) / V
    return float(np.percentile(per, VALUE_PERCENTILE))


def _greedy(
    sub: placement.Proxy,
    knots: np.ndarray,
    grid: np.ndarray,
    taken: list[int],
    spacing: int,
    gap: int,
    least: float,
    *,
    covered: bool,
    found: list,
    part: str,
) -> np.ndarray:
    """Greedily, the frames of ``grid`` where one more knot of every variable
    of ``sub`` cuts its proxy misfit most (at least :data:`PART_GAIN` of the
    segments' and ``least`` in all), each more than ``gap`` frames from the
    others in ``taken``; appended to ``found`` as (gain, part, frame) and to
    ``taken``.  ``covered``: leave out the frames where the variables of
    :data:`COVERED_SHARE` of the weight have a knot within ``spacing``.
    Returns ``knots`` with theirs."""
    n = knots.shape[1]
    while len(grid):
        free = np.ones(len(grid), dtype=bool)
        if covered:
            near = (np.abs(knots[:, None, :] - grid[None, :, None]) <= spacing).any(axis=0)  # (G, n)
            free = near.astype(float) @ sub.w < COVERED_SHARE * sub.w.sum()
        for f in taken:
            free &= np.abs(grid - f) >= gap
        grid = grid[free]
        if len(grid) == 0:
            break
        a, b = _neighbours(knots, grid.astype(float))
        old = placement.span_costs(sub, np.stack([a, b], axis=-1)).sum(axis=1)
        split = np.stack([a, np.broadcast_to(grid[:, None].astype(float), a.shape), b], axis=-1)
        new = placement.span_costs(sub, split).sum(axis=1)
        ok = (new <= PART_GAIN * old) & (old - new >= PART_VALUE * least)
        if not ok.any():
            break
        best = int(np.argmax(np.where(ok, old - new, -np.inf)))
        f = int(grid[best])
        taken.append(f)
        found.append((float(old[best] - new[best]), part, f))
        knots = np.sort(np.concatenate([knots, np.full((1, n), float(f))]), axis=0)
    return knots


def find_partial(
    proxy: placement.Proxy,
    p: np.ndarray,
    weights: np.ndarray,
    columns: dict[str, np.ndarray],
    pose_f: np.ndarray,
    refine_f: np.ndarray,
    *,
    rate: float,
    height: float,
    filter_width: float,
    refine_window: float,
    significance: float,
    spacing: int,
    stride: int,
    fit: bool = False,
    demote: bool = False,
):
    """The candidate partial poses (see the module doc), (part, frame), the
    most misfit removed first: :func:`staggered_cli.ops.partial.confirmed`
    keeps those that earn their knots in the real spline layer.

    Parameters
    ----------
    proxy : the placement proxy of the clip's variables.
    p, weights : the local evidence (T, V) and its weights (V,).
    columns : body part -> its variables' columns (:func:`part_columns`).
    pose_f, refine_f : the whole-body poses' frames (K,) and refinements (K, V) in frames.
    spacing : ``min_spacing`` in frames; stride: the placement grid, frames.
    fit : also return the fit-driven candidates (step 5 of the module doc):
        then ``(features, fits)``, each (part, frame), the most misfit removed first.
    demote : also return the whole-body poses that may become partial poses
        (step 6 of the module doc) as a last item, (part, frame), the
        cheapest per knot in the proxy first.
    """
    T = p.shape[0]
    found: list[tuple[float, str, int]] = []
    fits: list[tuple[float, str, int]] = []
    reach = max(int(round(0.5 * filter_width * rate)), 1)
    # strictly more than PART_SPACING in frames: a clip's rate and its frame
    # time may disagree in the last digits (120 Hz and 0.008333 s)
    gap = int(np.floor(PART_SPACING * rate)) + 1
    value = pose_value(proxy, pose_f, refine_f)
    where = {int(c): k for k, c in enumerate(proxy.cols)}
    feature_at: dict[str, np.ndarray] = {}
    for part, cols in columns.items():
        sel = np.array([where[int(c)] for c in cols if int(c) in where], dtype=int)
        if len(sel) == 0 or T < 3:
            continue
        sub = placement.Proxy(proxy.x[:, sel], proxy.w[sel], proxy.cols[sel])
        P = part_probability(p, weights, cols, filter_width, rate)
        gate = tent_filter(part_speed(proxy, sel, rate, height), 2.0 * refine_window, rate) >= significance
        ext = pose_f[:, None] + refine_f[:, sub.cols].astype(float)  # (K, n) the extreme knots
        edit = np.broadcast_to(pose_f[:, None].astype(float), ext.shape)  # and the editing knots
        knots = np.sort(np.concatenate([ext, edit]), axis=0)  # (2K, n), a knot twice where unrefined
        # a frame inside a pose's staggered span (between its editing and its
        # extreme knot) of a part variable cannot take a knot: the knots keep their order
        lo, hi = np.minimum(ext, edit), np.maximum(ext, edit)
        inside = np.zeros(T, dtype=bool)
        for k, i in zip(*np.nonzero(hi > lo), strict=True):
            inside[int(lo[k, i]) : int(hi[k, i]) + 1] = True
        sites = np.zeros(T, dtype=bool)
        for m in local_maxima(P):
            if gate[m]:
                sites[max(m - reach, 1) : min(m + reach, T - 2) + 1] = True
        feature_at[part] = sites
        grid = np.arange(0, T, stride)
        grid = grid[sites[grid] & ~inside[grid]]
        n = len(sel)
        taken: list[int] = []
        knots = _greedy(sub, knots, grid, taken, spacing, gap, value * n, covered=True, found=found, part=part)
        if fit:  # then anywhere the part moves, away from the whole-body poses and the part's candidates
            grid = np.arange(0, T, stride)
            far = np.min(np.abs(grid[:, None] - pose_f[None, :]), axis=1) > spacing
            grid = grid[gate[grid] & ~inside[grid] & far & (grid >= 1) & (grid <= T - 2)]
            _greedy(sub, knots, grid, taken, spacing, gap, value * n, covered=False, found=fits, part=part)
    out = [[(part, f) for _, part, f in sorted(found, key=lambda g: -g[0])]]
    if fit:
        out.append([(part, f) for _, part, f in sorted(fits, key=lambda g: -g[0])])
    if demote:
        out.append(demotions(proxy, pose_f, refine_f, columns, feature_at, stride, spacing))
    return out[0] if len(out) == 1 else tuple(out)


def demotions(
    proxy: placement.Proxy,
    pose_f: np.ndarray,
    refine_f: np.ndarray,
    columns: dict[str, np.ndarray],
    feature_at: dict[str, np.ndarray],
    stride: int = 1,
    spacing: int = 0,
) -> list[tuple[str, int, list[tuple[str, int]]]]:
    """The whole-body poses that may become partial poses (step 6 of the
    module doc), (part, frame, alternatives), the cheapest per knot in the
    proxy first.  Two lists, each at most the cheapest :data:`DEMOTE_SHARE`
    of the inner poses (at least :data:`DEMOTE_LEAST`), each with at most
    :data:`DEMOTE_PARTS` parts per pose, at most :data:`DEMOTE_SLACK` times
    the :data:`VALUE_PERCENTILE` of what a whole pose's knots hold in place
    per knot (the *unit*):

    * **alone**: the parts whose knots elsewhere cost the least per knot
      (:func:`demotion_costs`), where the part has a feature
      (``feature_at[part]`` (T,) bool) at the pose;
    * **with the other parts' own poses**: each other part's best frame
      near the pose (:func:`replacements`) where one more knot of its
      variables there removes a unit per knot, the move's cost being the
      knots lost less what those poses win back, over the knots it frees
      net of theirs.  A pose between two arms' extremes a few frames apart
      keeps one arm and the other gets a pose at its own extreme, and the
      rest of the body's knots go: the real spline layer measures such a
      move at a fifth to a half of a cull's cost per knot on the spliced
      clips where the demotion alone costs more than a cull.

    Each comes with those other parts' frames (the alternatives), tried
    with it by :func:`staggered_cli.ops.partial.demoted`.  A pose whose
    cheapest demotion alone costs more than :data:`DEMOTE_REACH` times the
    bound is left out."""
    parts, cost, whole = demotion_costs(proxy, pose_f, refine_f, columns)
    K = len(pose_f)
    if K < 3 or not parts:
        return []
    unit = float(np.percentile(whole[1:-1], VALUE_PERCENTILE))
    least = DEMOTE_SLACK * unit
    where = {int(c): i for i, c in enumerate(proxy.cols)}
    size = {p: sum(int(c) in where for c in columns[p]) for p in parts}
    freed = _freed(refine_f, columns, parts)  # (K, n_parts) the knots each demotion frees
    out, alone = [], []
    for k in range(1, K - 1):
        if np.min(cost[k]) > DEMOTE_REACH * least:
            continue  # the other parts' own poses near it would not win back enough
        # the other parts' own partial poses near the pose, where one holds in
        # place what a whole pose's knots do per knot in the proxy
        near = replacements(proxy, pose_f, refine_f, columns, None, int(pose_f[k]), stride, spacing)
        near = [(q, f, g) for q, f, g in near if g >= unit * size[q]]
        mine, own = [], []
        for j, p in enumerate(parts):
            if not np.isfinite(cost[k, j]):
                continue
            alts = [(q, f, g) for q, f, g in near if q != p]
            if p in feature_at and bool(feature_at[p][pose_f[k]]) and cost[k, j] <= least:
                own.append((float(cost[k, j]), p, int(pose_f[k]), [(q, f) for q, f, _ in alts]))
            net = freed[k, j] - sum(size[q] for q, _, _ in alts)
            if net <= 0 or not alts:
                continue
            c = (cost[k, j] * freed[k, j] - sum(g for _, _, g in alts)) / net
            if c <= least:
                mine.append((float(c), p, int(pose_f[k]), [(q, f) for q, f, _ in alts]))
        out += sorted(mine, key=lambda g: g[0])[:DEMOTE_PARTS]
        alone += sorted(own, key=lambda g: g[0])[:DEMOTE_PARTS]
    most = max(DEMOTE_LEAST, int(np.ceil(DEMOTE_SHARE * (K - 2))))
    chosen = sorted(out, key=lambda g: g[0])[:most] + sorted(alone, key=lambda g: g[0])[:most]
    seen, res = set(), []
    for _, p, f, alts in chosen:
        if (p, f) not in seen:
            seen.add((p, f))
            res.append((p, f, alts))
    return res


def _freed(refine_f: np.ndarray, columns: dict[str, np.ndarray], parts: list[str]) -> np.ndarray:
    """(K, n_parts): the knots a whole-body pose loses as a partial pose of each part."""
    knots = 1.0 + (refine_f != 0)  # (K, V)
    out = np.zeros((refine_f.shape[0], len(parts)))
    for j, p in enumerate(parts):
        other = np.ones(refine_f.shape[1], dtype=bool)
        other[columns[p]] = False
        out[:, j] = knots[:, other].sum(axis=1)
    return out


def replacements(
    proxy: placement.Proxy,
    pose_f: np.ndarray,
    refine_f: np.ndarray,
    columns: dict[str, np.ndarray],
    part: str | None,
    frame: int,
    stride: int,
    spacing: int = 0,
) -> list[tuple[str, int, float]]:
    """Once the whole-body pose at ``frame`` is a partial pose of ``part``
    (None: of any part), each other part's best frame for a partial pose of
    its own between its knots around it: on the placement grid
    (``stride``), not the pose's own frame and farther than ``spacing``
    frames from the other poses, the one where one more knot of every
    variable of the part cuts its proxy misfit most, (other part, frame,
    the proxy misfit it removes) where it cuts any."""
    k = int(np.searchsorted(pose_f, frame))
    K = len(pose_f)
    if not 0 < k < K - 1:
        return []
    where = {int(c): i for i, c in enumerate(proxy.cols)}
    f = pose_f.astype(float)
    out = []
    others = np.delete(pose_f, k)
    for other, cols in columns.items():
        sel = np.array([where[int(c)] for c in cols if int(c) in where], dtype=int)
        if other == part or len(sel) == 0:
            continue
        sub = placement.Proxy(proxy.x[:, sel], proxy.w[sel], proxy.cols[sel])
        r = refine_f[:, sub.cols].astype(float)
        prev = np.maximum(f[k - 1], f[k - 1] + r[k - 1])  # (n,) each variable's knot before and after
        nxt = np.minimum(f[k + 1], f[k + 1] + r[k + 1])
        grid = np.arange(int(np.ceil(prev.min())) + 1, int(np.floor(nxt.max())), 1)
        far = np.min(np.abs(grid[:, None] - others[None, :]), axis=1) > spacing
        grid = grid[(grid % stride == 0) & (grid != frame) & far]
        if len(grid) == 0:
            continue
        at = np.clip(grid[:, None].astype(float), prev[None, :], nxt[None, :])  # (G, n)
        a = np.broadcast_to(prev, at.shape)
        b = np.broadcast_to(nxt, at.shape)
        old = placement.span_costs(sub, np.stack([a[:1], b[:1]], axis=-1)).sum()
        new = placement.span_costs(sub, np.stack([a, at, b], axis=-1)).sum(axis=1)
        best = int(np.argmin(new))
        if new[best] < old:
            out.append((other, int(grid[best]), float(old - new[best])))
    return out


def demotion_costs(
    proxy: placement.Proxy, pose_f: np.ndarray, refine_f: np.ndarray, columns: dict[str, np.ndarray]
) -> tuple[list[str], np.ndarray, np.ndarray]:
    """What making each whole-body pose a partial pose of each part costs in
    the placement proxy, per knot it frees: the misfit its knots outside the
    part hold in place (the segments around them joined), over how many they
    are.  Returns the parts, (K, n_parts) and (K,) the same for all the
    pose's knots (a cull of it), infinite for the first and last pose (they
    stay whole)."""
    K = len(pose_f)
    parts = list(columns)
    out = np.full((K, len(parts)), np.inf)
    whole = np.full(K, np.inf)
    V = refine_f.shape[1]
    if K < 3 or V == 0:
        return parts, out, whole
    f = pose_f.astype(float)
    ks = np.arange(1, K - 1)
    knots = 1.0 + (refine_f[ks] != 0)  # (n, V) the knots each variable has at each pose
    delta = np.zeros((len(ks), V))
    if len(proxy.cols):
        r = refine_f[:, proxy.cols].astype(float)
        ext = f[:, None] + r
        prev = np.maximum(f[ks - 1, None], ext[ks - 1])
        nxt = np.minimum(f[ks + 1, None], ext[ks + 1])
        here = np.broadcast_to(f[ks, None], prev.shape)
        lo, hi = np.minimum(here, ext[ks]), np.maximum(here, ext[ks])
        with_k = placement.span_costs(proxy, np.stack([prev, lo, hi, nxt], axis=-1))
        without = placement.span_costs(proxy, np.stack([prev, nxt], axis=-1))
        delta[:, proxy.cols] = without - with_k
    for j, part in enumerate(parts):
        other = np.ones(V, dtype=bool)
        other[columns[part]] = False
        out[ks, j] = delta[:, other].sum(axis=1) / np.maximum(knots[:, other].sum(axis=1), 1.0)
    whole[ks] = delta.sum(axis=1) / knots.sum(axis=1)
    return parts, out, whole
