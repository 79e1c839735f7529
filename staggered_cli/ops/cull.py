"""Culling and adding staggered poses (paper section 4.1, prioritized poses).

Removing or adding a pose changes the splines; the displacement maps are
measured again from the motion as it was, so the baked motion does not
change (SPEC invariant 2).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .. import quat
from ..errors import UsageError, arg, warn
from ..model.document import MIN_POSE_GAP_FRAMES, Document, check_pose_index, pose_near, with_poses
from ..model.evaluate import evaluate, evaluate_at
from ..model.fit import knots_from_poses
from ..model.kinds import ROTATION
from ..model.knots import pose_arrays
from ..model.restructure import restructure
from ..signals import placement
from ..signals.probability import reprioritized

#: A pose this close (seconds) to a contact start or end is a pose on that
#: contact change (half the pose probability's tent width: the cluster's reach).
CONTACT_REACH = 0.075
RANKINGS = ("error", "paper")
PRECEDENCE = 1.0


def contact_poses(doc: Document, reach: float = CONTACT_REACH) -> np.ndarray:
    """Mask (K,) of the interior poses within ``reach`` seconds of a contact
    start or end (not the clip's own ends, where nothing changes)."""
    mask = np.zeros(doc.n_poses, dtype=bool)
    tol = reach + 1e-9
    for c in doc.constraints:
        for t in (c.start, c.end):
            if doc.frame_time * 0.5 < t < doc.duration - doc.frame_time * 0.5:
                mask |= np.abs(doc.pose_t - t) <= tol
    mask[0] = mask[-1] = False
    return mask


def keep_count(keep: str, n_poses: int) -> int:
    """Poses asked for by ``--keep``: a count ``N`` or ``P%`` (``round(P·K)``
    of the document's ``K`` poses, the first and last counted)."""
    text = str(keep).strip()
    try:
        if text.endswith("%"):
            pct = float(text[:-1])
            if not np.isfinite(pct) or not 0 < pct <= 100:
                raise UsageError(f"{arg('keep')} percentage must be in (0, 100], got {keep!r}")
            return int(np.floor(n_poses * pct / 100.0 + 0.5))
        n = int(text)
    except ValueError:
        raise UsageError(f"{arg('keep')} takes a percentage like 40% or a count like 12, got {keep!r}") from None
    if n < 1:
        raise UsageError(f"{arg('keep')} must keep at least one pose, got {keep!r}")
    return n


def choose(
    doc: Document,
    *,
    keep: str | None = None,
    interval: tuple[float, float] | None = None,
    select: list[int] | None = None,
    ignore_contacts: bool = False,
    by: str = "error",
    motion: tuple[np.ndarray, ...] | None = None,
) -> np.ndarray:
    """Mask (K,) of the poses to keep: exactly what was asked.

    ``interval`` keeps the poses with times in [a, b] and ``select`` the
    listed indices (both: the poses in both); the first and last pose are
    always kept.  ``keep`` (``'40%'`` or a count, see :func:`keep_count`)
    then keeps exactly that many of those, ranked ``by``:

    * ``'error'``: the ``n`` poses whose spline layer fits the motion best
      (:func:`best_subset`);
    * ``'paper'``: the paper's priority ``P(t_k)(t_{k+1} - t_{k-1})``.

    Unless ``ignore_contacts``, poses on contact changes take precedence
    inside the count: the others go first.  When fewer poses are there than
    asked for, all are kept and a warning says so.  ``motion``: the
    document's :func:`base_motion`, when the caller has it.
    """
    if by not in RANKINGS:
        raise UsageError(f"{arg('by')} must be one of {', '.join(RANKINGS)}, got {by!r}")
    K = doc.n_poses
    mask = np.ones(K, dtype=bool)
    if interval is not None:
        a, b = interval
        if np.isnan(a) or np.isnan(b) or a > b:
            raise UsageError(f"{arg('interval')} must be A:B with A <= B seconds, got {a}:{b}")
        mask &= (doc.pose_t >= a - 1e-9) & (doc.pose_t <= b + 1e-9)
    if select is not None:
        sel = np.zeros(K, dtype=bool)
        for k in select:
            sel[check_pose_index(doc, k)] = True
        mask &= sel
    mask[0] = mask[-1] = True
    if keep is None:
        return mask
    asked = keep_count(keep, K)
    n = max(asked, min(2, K))
    have = int(mask.sum())
    if asked < n:
        warn(f"{arg('keep')} %s: keeping %d poses, the first and last always stay", keep, n)
    if n >= have:
        if n > have:
            warn(
                f"{arg('keep')} %s asks for %d poses but there are only %d to choose from: kept them all", keep, n, have
            )
        return mask
    contact = np.zeros(K, dtype=bool) if ignore_contacts else contact_poses(doc)
    if by == "paper":
        inner = np.flatnonzero(mask[1:-1]) + 1
        pr = np.nan_to_num(doc.priority[inner], posinf=np.finfo(float).max)
        ranked = inner[np.lexsort((inner, -pr, ~contact[inner]))]
        out = np.zeros(K, dtype=bool)
        out[ranked[: n - 2]] = True
        out[0] = out[-1] = True
        return out
    return best_subset(doc, mask, n, contact, motion)


def base_motion(doc: Document) -> tuple[np.ndarray, ...]:
    """The motion (T, V, D) of each track's base layer at the frame times
    (``evaluate(track, doc.frame_times, depth=1)``).

    Ranking the poses (:func:`choose`) and refitting the splines around the
    removed ones (:func:`keep_poses`) both need it, and it is most of their
    time: a caller that does both evaluates it once and gives it to each.
    """
    t = doc.frame_times
    dense = tuple(evaluate(tr, t, depth=1) for tr in doc.tracks)
    for d in dense:  # shared between its callers
        d.flags.writeable = False
    return dense


def document_proxy(doc: Document, motion: tuple[np.ndarray, ...] | None = None) -> tuple[placement.Proxy, np.ndarray]:
    """The proxy of the motion a document bakes to (without the contact
    layer; ``motion``: its :func:`base_motion`, when at hand), and the
    extreme knot frames (K, V) of the proxy's variables."""
    variables, ext = [], []
    for tr, dense in zip(doc.tracks, base_motion(doc) if motion is None else motion, strict=True):
        if tr.kind == ROTATION:
            dense = quat.unroll(dense, axis=0)
        variables.append((tr.kind, tr.names, tr.targets, dense))
        ext_t = pose_arrays(tr, doc.n_poses)[0]
        # a partial pose has no knot outside its part: there it spans nothing
        ext.append(np.where(np.isnan(ext_t), doc.pose_t[:, None], ext_t))
    proxy = placement.proxy_from_dense(variables, placement.variable_weights(doc.source, variables))
    ext_f = (np.concatenate(ext, axis=1) if ext else np.zeros((doc.n_poses, 0))) / doc.frame_time
    return proxy, ext_f[:, proxy.cols]


def best_subset(
    doc: Document,
    mask: np.ndarray,
    n: int,
    last: np.ndarray | None = None,
    motion: tuple[np.ndarray, ...] | None = None,
) -> np.ndarray:
    """Mask (K,) of the ``n`` poses of ``mask`` (the first and last among
    them) whose spline layer fits the document's motion best.

    Every variable keeps its own knots (refinements included): the misfit of
    a kept set is, in the proxy of :mod:`staggered_cli.signals.placement`, the sum of
    each kept pose's own staggered span and of the segments between the last
    knot of one kept pose and the first knot of the next, found by dynamic
    programming over the poses (a segment spans at most a few times the
    average).  Poses in ``last`` (K,) take precedence: the fewest of them
    are dropped, then the misfit decides.
    """
    K = doc.n_poses
    last = np.zeros(K, dtype=bool) if last is None else np.asarray(last, dtype=bool)
    c = np.flatnonzero(mask)
    M = len(c)
    if n >= M:
        return np.asarray(mask, dtype=bool).copy()
    proxy, ext = document_proxy(doc, motion)
    f = doc.pose_t / doc.frame_time
    lo = np.minimum(f[c, None], ext[c])
    hi = np.maximum(f[c, None], ext[c])
    own = placement.span_costs(proxy, np.stack([lo, hi], axis=-1)).sum(axis=1) if ext.shape[1] else np.zeros(M)
    W = int(min(M - 1, max(4, 3 * int(np.ceil((M - 1) / max(n - 1, 1))))))
    a = np.repeat(np.arange(M), W)
    b = a + np.tile(np.arange(1, W + 1), M)
    ok = b < M
    a, b = a[ok], b[ok]
    pair = np.full((M, W), np.inf)
    if ext.shape[1]:
        knots = np.stack([np.maximum(f[c[a], None], ext[c[a]]), np.minimum(f[c[b], None], ext[c[b]])], axis=-1)
        pair[a, b - a - 1] = placement.span_costs(proxy, knots).sum(axis=1)
    else:
        pair[a, b - a - 1] = 0.0
    # dropping a pose that takes precedence costs PRECEDENCE typical segments
    before = np.concatenate([[0], np.cumsum(last[c])])
    skipped = before[b] - before[a + 1]
    typical = float(np.mean(pair[:, 0][np.isfinite(pair[:, 0])])) if M > 1 else 0.0
    pair[a, b - a - 1] += PRECEDENCE * typical * skipped
    best = np.full(M, np.inf)
    best[0] = own[0]
    back = np.zeros((n, M), dtype=np.int64)
    for m in range(1, n):
        # into node j from node j - w
        cand = np.full((M, W), np.inf)
        for w in range(1, W + 1):
            cand[w:, w - 1] = best[: M - w] + pair[: M - w, w - 1]
        w = np.argmin(cand, axis=1)
        best = cand[np.arange(M), w] + own
        back[m] = np.arange(M) - (w + 1)
    out = np.zeros(K, dtype=bool)
    j = M - 1
    for m in range(n - 1, -1, -1):
        out[c[j]] = True
        j = int(back[m, j])
    return out


def keep_poses(doc: Document, mask: np.ndarray, motion: tuple[np.ndarray, ...] | None = None) -> Document:
    """The document with only the poses in ``mask`` (K,), motion unchanged
    (``motion``: the document's :func:`base_motion`, when the caller has it)."""
    mask = np.array(mask, dtype=bool)  # a copy: the caller's mask stays as it was
    mask[0] = mask[-1] = True
    if mask.all():
        return doc
    new_index = np.cumsum(mask) - 1
    tracks = []
    for tr, dense in zip(doc.tracks, base_motion(doc) if motion is None else motion, strict=True):
        knots = tr.knots.subset(mask[tr.knot_pose], new_index[tr.knot_pose])
        tracks.append(restructure(tr, knots, frame_t=doc.frame_times, dense=dense))
    signals = dict(doc.signals)
    parts = tuple(p for p, m in zip(doc.pose_part, mask, strict=True) if m)
    return reprioritized(
        with_poses(doc, doc.pose_t[mask], doc.priority[mask], parts, tracks=tuple(tracks), signals=signals)
    )


def demote_pose(doc: Document, k: int, part: str, motion: tuple[np.ndarray, ...] | None = None) -> Document:
    """The document with the whole-body pose ``k`` made a partial pose of
    ``part``: its knots (extreme and editing, refinements kept) stay in the
    part's variables and go from every other variable, whose splines then
    pass through its time; motion unchanged (SPEC invariant 2).
    ``motion``: the document's :func:`base_motion`, when the caller has it.
    The first and last pose stay whole (UsageError)."""
    from ..model.document import canonical_part

    k = check_pose_index(doc, k)
    if k in (0, doc.n_poses - 1) or doc.pose_part[k] is not None:
        raise UsageError(f"pose {k} is not an inner whole-body pose: it cannot become a partial pose")
    part = canonical_part(part)
    mine = doc.part_mask(part)
    tracks, col = [], 0
    for tr, dense in zip(doc.tracks, base_motion(doc) if motion is None else motion, strict=True):
        own = mine[col : col + tr.n_vars]
        col += tr.n_vars
        keep = (tr.knot_pose != k) | own[tr.knots.var]
        tracks.append(restructure(tr, tr.knots.subset(keep), frame_t=doc.frame_times, dense=dense))
    parts = list(doc.pose_part)
    parts[k] = part
    return reprioritized(with_poses(doc, doc.pose_t, doc.priority, tuple(parts), tracks=tuple(tracks)))


def add_pose(doc: Document, time: float, part: str | None = None) -> Document:
    """A new unrefined pose at ``time`` seconds (see :func:`add_poses`)."""
    return add_poses(doc, [time], part)


def add_poses(
    doc: Document, times, part: str | None | Sequence[str | None] = None
) -> Document:
    """New unrefined poses at ``times`` seconds (their knots take the values
    the motion has there), motion unchanged (SPEC invariant 2).

    ``part``: None adds whole-body poses; a body part (``'@left-arm'``, see
    :func:`staggered_cli.model.document.part_variables`) adds *partial
    poses*, with knots (an extreme knot at the pose time, no refinement) in
    that part's variables only: the other variables keep their knots, values
    and segments to the bit.  A sequence gives each time its own part.

    A time within half a frame of an existing pose (or of another of
    ``times``), or outside the clip, is refused (UsageError).  Where a time
    falls inside another pose's staggered span (between its editing knot and
    its extreme knot) for a variable the new pose owns, that refinement is
    collapsed to zero (the knot returns to its pose time, with the value the
    motion has there), so the poses' knots stay in order; a warning names
    them.  Refinements of the new poses are set afterwards with
    :func:`staggered_cli.ops.timing.change_refinements` (or
    :func:`staggered_cli.ops.timing.set_refinements`).
    """
    from ..model.document import canonical_part, with_poses

    times = [float(t) for t in np.atleast_1d(np.asarray(times, dtype=float))]
    if isinstance(part, str) or part is None:
        parts = [part] * len(times)
    else:
        parts = list(part)
        if len(parts) != len(times):
            raise UsageError(f"{arg('part')} gives {len(parts)} parts for {len(times)} times")
    parts = [None if p is None else canonical_part(p) for p in parts]
    if not times:
        return doc
    half = 0.5 * doc.frame_time  # times as info prints them (4 decimals) must be accepted
    clipped = []
    for time in times:
        if not np.isfinite(time) or not -half <= time <= doc.duration + half:
            raise UsageError(
                f"{arg('add_time')} must lie within the clip (0 to {doc.seconds(doc.duration)}), got {time:g}"
            )
        time = float(min(max(time, 0.0), doc.duration))
        near = pose_near(doc, time)
        if near is not None:
            if abs(doc.pose_t[near] - time) < 1e-9:
                raise UsageError(f"there is already a pose at {doc.seconds(time)} (pose {near})")
            raise UsageError(
                f"{arg('add_time')} {time:g}: pose {near} is at {doc.seconds(doc.pose_t[near])}, less than half a "
                "frame away (poses keep at least half a frame apart)"
            )
        clipped.append(time)
    order = np.argsort(clipped, kind="stable")
    new_t = np.asarray(clipped)[order]
    new_parts = [parts[i] for i in order]
    if len(new_t) > 1 and np.min(np.diff(new_t)) < MIN_POSE_GAP_FRAMES * doc.frame_time:
        j = int(np.argmin(np.diff(new_t)))
        raise UsageError(
            f"{arg('add_time')} {new_t[j]:g} and {new_t[j + 1]:g} are less than half a frame apart "
            "(poses keep at least half a frame apart)"
        )
    # where each new pose goes among the old: np.insert's positions
    at = np.searchsorted(doc.pose_t, new_t)
    pose_t = np.insert(doc.pose_t, at, new_t)
    new_index = np.searchsorted(pose_t, new_t)
    new_owns = np.stack([doc.part_mask(p) for p in new_parts])  # (N, V)
    old_owns = doc.track_owns()
    tracks, col = [], 0
    for tr, owns in zip(doc.tracks, old_owns, strict=True):
        mine = new_owns[:, col : col + tr.n_vars]
        col += tr.n_vars
        ext_t, value, edit = pose_arrays(tr, doc.n_poses)
        refine = np.where(owns, ext_t - doc.pose_t[:, None], 0.0)
        ext = np.where(owns, ext_t, doc.pose_t[:, None])
        lo = np.minimum(doc.pose_t[:, None], ext)
        hi = np.maximum(doc.pose_t[:, None], ext)
        conflict = np.zeros(refine.shape, dtype=bool)
        for time, m in zip(new_t, mine, strict=True):
            here = owns & (refine != 0.0) & (lo <= time + 1e-9) & (time - 1e-9 <= hi) & m[None, :] & ~conflict
            for k in np.flatnonzero(here.any(axis=1)):
                names = ", ".join(tr.names[i] for i in np.flatnonzero(here[k]))
                warn(
                    f"{arg('add_time')} %s: pose %d's refinements of %s collapse to 0 to make room",
                    doc.seconds(time),
                    k,
                    names,
                )
            conflict |= here
        refine = np.where(conflict, 0.0, refine)
        value = np.where(conflict[..., None], edit, value)
        V = tr.n_vars
        here = evaluate_at(tr, np.tile(np.arange(V), len(new_t)), np.repeat(new_t, V), depth=1).reshape(
            len(new_t), V, tr.dim
        )
        knots = knots_from_poses(
            pose_t,
            np.insert(refine, at, 0.0, axis=0),
            np.insert(value, at, here, axis=0),
            np.insert(edit, at, here, axis=0),
            tr.names,
            owns=np.insert(owns, at, mine, axis=0),
        )
        knots = _exact_times(knots, np.insert(np.where(conflict, np.nan, ext_t), at, np.nan, axis=0))
        tracks.append(restructure(tr, knots, frame_t=doc.frame_times))
    priority = np.insert(doc.priority, at, 0.0)
    pose_part = list(doc.pose_part)
    for k, p in zip(new_index, new_parts, strict=True):
        pose_part.insert(int(k), p)
    return reprioritized(with_poses(doc, pose_t, priority, tuple(pose_part), tracks=tuple(tracks)))


def place_extremes(doc: Document, refine: np.ndarray) -> Document:
    """The document with its extreme knots at ``pose_t + refine``, motion
    unchanged (SPEC invariant 2): where to put the knots, not a retiming.

    ``refine`` (K, V) seconds over all variables (0 or anything where a
    partial pose has no knot: ignored there).  Where a pose's refinement of
    a variable changes, its extreme knot moves to ``t_k + r`` with the value
    the motion (base layer) has there, and its editing knot (``r != 0``)
    holds the value at ``t_k``; the changed segments are refitted and their
    displacement maps measured again, so the baked motion is the same.  Knots
    whose refinement stays keep their values, and every other variable its
    knots, splines and displacement maps, bit for bit.  This is how
    ``extract`` places knots on extremes, for poses added later (e.g. partial
    poses after :func:`add_poses`); :func:`staggered_cli.ops.timing.change_refinements`
    instead retimes the motion.  KnotOrderError where knots would cross or
    leave the clip; the first and last pose stay unrefined.
    """
    from ..errors import KnotOrderError

    refine = np.asarray(refine, dtype=float)
    V = len(doc.variable_names)
    if refine.shape != (doc.n_poses, V):
        raise UsageError(f"refinements must have shape ({doc.n_poses}, {V}), got {refine.shape}")
    if not np.all(np.isfinite(refine)):
        raise UsageError("refinements must be finite")
    tracks, col = [], 0
    for tr, owns in zip(doc.tracks, doc.track_owns(), strict=True):
        want = np.where(owns, refine[:, col : col + tr.n_vars], 0.0)
        col += tr.n_vars
        want[[0, -1]] = 0.0
        ext_t, value, edit = pose_arrays(tr, doc.n_poses)
        have = np.where(owns, ext_t - doc.pose_t[:, None], 0.0)
        # unchanged where the knot stays (a - b + b need not be a to the bit)
        moved = owns & (np.abs(want - have) > 1e-12)
        if not moved.any():
            tracks.append(tr)
            continue
        new = np.where(moved, want, have)
        ext = doc.pose_t[:, None] + new
        if np.any(ext[moved] < -1e-9) or np.any(ext[moved] > doc.duration + 1e-9):
            raise KnotOrderError("extreme knots must lie within the clip")
        kk, ii = np.nonzero(moved)
        value = value.copy()
        value[kk, ii] = evaluate_at(tr, ii, ext[kk, ii], depth=1)
        edit = np.where((new != 0.0)[..., None], edit, value)
        ek, ei = np.nonzero(moved & (new != 0.0))
        edit[ek, ei] = evaluate_at(tr, ei, doc.pose_t[ek], depth=1)
        knots = knots_from_poses(doc.pose_t, new, value, edit, tr.names, owns=owns)
        knots = _exact_times(knots, np.where(moved, np.nan, ext_t))
        tracks.append(restructure(tr, knots, frame_t=doc.frame_times))
    return doc.with_tracks(tuple(tracks))


def _exact_times(knots, ext_t: np.ndarray):
    """``knots`` with the extreme knots that stay at their old times
    ``ext_t`` (K, V) (NaN: new or moved) to the bit: ``t_k + (e - t_k)`` may
    differ from ``e`` in the last place, and a segment whose knot moved by
    that is refitted."""
    keep = ext_t[knots.pose, knots.var]
    same = ~knots.editing & ~np.isnan(keep)
    if not same.any():
        return knots
    t = knots.t.copy()
    t[same] = keep[same]
    return knots.with_times(t)

