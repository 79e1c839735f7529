"""Partial poses found by extract (issue 37): which candidates earn their knots.

:mod:`staggered_cli.signals.partial` proposes partial poses from each body
part's own evidence and the placement proxy, and the whole-body poses that
may become partial poses; :func:`confirmed` makes partial those whose other
knots cost the real spline layer little (:func:`demoted`,
:func:`staggered_cli.ops.cull.demote_pose`) and adds the partial poses that
make it better, judged in world space
(:func:`staggered_cli.ops.cull.add_poses` with the part).
"""

from __future__ import annotations

import heapq
import warnings

import numpy as np

from ..errors import StaggeredWarning, UsageError
from ..model.document import Document
from ..model.sampling import local_pose
from ..signals.partial import DEMOTE_REACH
from ..skeleton import forward_kinematics
from . import cull

#: A partial pose stays only where it lowers the spline layer's world error
#: by at least this share of what the knots of the whole-body pose a cull
#: would take first hold in place, per knot: 1.0, so that at the same
#: number of knots the trade is no loss (0.7 kept poses worth less than the
#: pose they stand in for: spliced clips 0.984 at equal knots, now 0.978).
WORLD_VALUE = 1.0
#: A whole-body pose becomes a partial pose of one part (:func:`demoted`)
#: where the knots it loses cost the spline layer at most this share of what
#: the knots of the whole-body pose a cull would take first hold in place,
#: per knot.
DEMOTE_VALUE = 1.0


def partial_times(doc: Document) -> dict[str, np.ndarray]:
    """Body part (``'@left-arm'``, ...) -> the times (seconds, sorted) of its
    partial poses in the base layer."""
    out: dict[str, list[float]] = {}
    for t, p in zip(doc.pose_t, doc.pose_part, strict=True):
        if p is not None:
            out.setdefault(p, []).append(float(t))
    return {p: np.array(ts) for p, ts in out.items()}


def _errors(doc: Document, frames: np.ndarray) -> np.ndarray:
    """(n, J) over ``frames`` (n,), the distance (file units) of each joint
    of the spline layer from the source's, divided by the clip's frame count:
    their sum is the part of ``bake --layers splines``'s mean error (times
    the joint count) those frames hold."""
    rot, tr = local_pose(doc, frames * doc.frame_time, "splines")
    pos = forward_kinematics(doc.source.skeleton, rot, tr)[1]
    return np.linalg.norm(pos - doc.source.world_positions()[frames], axis=-1) / doc.n_frames


def _error(doc: Document, frames: np.ndarray) -> float:
    """The sum of :func:`_errors`."""
    return float(np.sum(_errors(doc, frames)))


def _knot_count(doc: Document) -> int:
    return int(sum(len(tr.knots.t) for tr in doc.tracks))


def _span(doc: Document, mask: np.ndarray, t: float) -> tuple[float, float]:
    """The times between which a knot at ``t`` of the variables ``mask``
    (V,) changes their splines: their knots before and after it."""
    lo, hi, col = t, t, 0
    for tr in doc.tracks:
        for i in np.flatnonzero(mask[col : col + tr.n_vars]):
            kt = tr.knots.t[tr.knots.of(int(i))]
            j = int(np.searchsorted(kt, t))
            lo = min(lo, float(kt[max(j - 1, 0)]))
            hi = max(hi, float(kt[min(j, len(kt) - 1)]))
        col += tr.n_vars
    return lo, hi


def _trial(doc: Document, part: str, frame: int, mask: np.ndarray, now: np.ndarray):
    """``doc`` with a partial pose of ``part`` at ``frame``, the frames its
    knot changes and their errors (:func:`_errors`) and the gain against
    ``now`` and the knots it adds; None where the pose cannot be added."""
    every = np.arange(doc.n_frames)
    t = float(frame) * doc.frame_time
    lo, hi = _span(doc, mask, t)
    frames = every[int(np.floor(lo / doc.frame_time)) : int(np.ceil(hi / doc.frame_time)) + 1]
    with warnings.catch_warnings():  # a refinement of the part in the way: the candidate is not taken
        warnings.simplefilter("error", StaggeredWarning)
        try:
            trial = cull.add_poses(doc, [t], part)
        except (UsageError, StaggeredWarning):
            return None
    after = _errors(trial, frames)
    gain = float(np.sum(now[frames])) - float(np.sum(after))
    return trial, frames, after, gain, _knot_count(trial) - _knot_count(doc)


def confirmed(
    doc: Document,
    candidates: list[tuple[str, int]],
    fits: list[tuple[str, int]] | None = None,
    demotions: list[tuple[str, int, list[tuple[str, int]]]] | None = None,
    *,
    gap: float = 0.0,
    budget: bool = False,
) -> Document:
    """``doc`` with the partial poses of ``candidates`` ((part, frame), best
    first, from :func:`staggered_cli.signals.partial.find_partial`) that earn
    their knots in the real spline layer.

    Each, added in turn, must lower the error of the spline layer alone
    (world joint positions, summed over the joints) by at least
    :data:`WORLD_VALUE` times, per knot it adds, what the knots of the
    whole-body pose a cull would take first hold in place.  The proxy that
    proposed it cannot see this: where a joint's spline error cancels its
    parent's (a walk's spine against its pelvis), a knot of the one alone
    can make the figure worse.

    Then the candidates ``fits`` (anywhere the part moves), the one whose
    real gain per knot is largest first, each by the same rule and more
    than ``gap`` seconds from the part's other partial poses.

    With ``budget`` (``extract --partial``) the result has no more knots
    than ``doc``: first the ``demotions`` ((part, frame, alternatives) of
    whole-body poses from :func:`staggered_cli.signals.partial.find_partial`):
    a whole-body pose that is there for one part only becomes a partial pose
    of that part where the knots it loses elsewhere cost the spline layer at
    most :data:`DEMOTE_VALUE` times that same value per knot, the cheapest
    per knot first (:func:`demoted`).  Then the knots freed so (and only
    those) go to ``candidates``, then to the alternatives of the poses
    demoted ((part, frame): the other parts' own partial poses near them)
    and ``fits``, by the rules above.
    """
    if (not candidates and not fits and not demotions) or doc.n_poses < 3:
        return doc
    every = np.arange(doc.n_frames)
    n0 = _knot_count(doc)
    motion = cull.base_motion(doc)  # the motion every change below keeps
    fewer = cull.keep_poses(doc, cull.choose(doc, keep=str(doc.n_poses - 1), motion=motion), motion)
    now = _errors(doc, every)  # (T, J), kept up to date as poses are added
    value = max(_error(fewer, every) - float(np.sum(now)), 0.0) / max(n0 - _knot_count(fewer), 1)
    if value <= 0.0:
        return doc
    adds = list(candidates) + list(fits or [])
    masks = {part: doc.part_mask(part) for part, _ in adds}
    if not budget:
        doc = _added(doc, candidates, masks, now, value, gap=gap)
        return _best_first(doc, fits, masks, now, WORLD_VALUE * value, gap) if fits else doc
    # the demotions first: what they free is what the partial poses may spend
    demote = [(part, float(f) * doc.frame_time, alts) for part, f, alts in (demotions or [])]
    doc = demoted(doc, demote, now, motion, least=DEMOTE_VALUE * value, gap=gap, value=WORLD_VALUE * value)
    made = {(p, round(float(t) / doc.frame_time)) for t, p in zip(doc.pose_t, doc.pose_part, strict=True) if p}
    alts = [alt for part, f, alts in (demotions or []) for alt in alts if (part, int(f)) in made]
    masks.update({part: doc.part_mask(part) for part, _ in alts if part not in masks})
    doc = _added(doc, candidates, masks, now, value, n0, gap)
    return _best_first(doc, alts + list(fits or []), masks, now, WORLD_VALUE * value, gap, n0)


def _added(
    doc: Document, candidates, masks, now: np.ndarray, value: float, limit: int | None = None, gap: float = 0.0
) -> Document:
    """``doc`` with the ``candidates`` that earn :data:`WORLD_VALUE` times
    ``value`` per knot, each in turn, more than ``gap`` seconds from its
    part's other partial poses (while the knots stay within ``limit``)."""
    for part, frame in candidates:
        if np.any(np.abs(partial_times(doc).get(part, np.zeros(0)) - float(frame) * doc.frame_time) <= gap):
            continue
        if limit is not None and _knot_count(doc) + int(masks[part].sum()) > limit:
            continue  # a partial pose has a knot in every variable of its part at least
        got = _trial(doc, part, frame, masks[part], now)
        if got is None:
            continue
        trial, frames, after, gain, added = got
        if gain >= WORLD_VALUE * value * added and (limit is None or _knot_count(trial) <= limit):
            doc = trial
            now[frames] = after
    return doc


def _best_first(
    doc: Document, fits, masks, now: np.ndarray, least: float, gap: float, limit: int | None = None
) -> Document:
    """Lazily greedy: the candidate of ``fits`` with the largest real gain
    per knot first, each worth ``least`` per knot, more than ``gap``
    seconds from its part's other partial poses and within ``limit`` knots
    in all.  A gain measured before the
    last pose was added is measured again when it comes up (a pose's gain
    only shrinks as others are added, nearly always)."""
    heap = []
    version = 0
    room = np.inf if limit is None else limit - _knot_count(doc)
    for n, (part, frame) in enumerate(fits):
        if masks[part].sum() > room:
            continue  # a partial pose has a knot in every variable of its part at least
        got = _trial(doc, part, frame, masks[part], now)
        if got is not None and got[3] >= least * got[4] and got[4] <= room:
            heapq.heappush(heap, (-got[3] / got[4], n, version, got))
    while heap:
        _, n, seen, got = heapq.heappop(heap)
        part, frame = fits[n]
        others = partial_times(doc).get(part, np.zeros(0))
        if np.any(np.abs(others - float(frame) * doc.frame_time) <= gap) or masks[part].sum() > room:
            continue
        if seen != version:  # measured on an older document
            got = _trial(doc, part, frame, masks[part], now)
            if got is not None and got[3] >= least * got[4] and got[4] <= room:
                heapq.heappush(heap, (-got[3] / got[4], n, version, got))
            continue
        if got[4] > room:
            continue
        trial, frames, after, _, added = got
        doc = trial
        now[frames] = after
        room -= added
        version += 1
    return doc


def _pose_at(doc: Document, t: float) -> int | None:
    k = int(np.argmin(np.abs(doc.pose_t - t)))
    return k if abs(float(doc.pose_t[k]) - t) < 0.5 * doc.frame_time else None


def _demotion(doc: Document, k: int, part: str, now: np.ndarray, motion):
    """``doc`` with the whole-body pose ``k`` a partial pose of ``part``, the
    frames that changes (from the knot before the knots it loses to the knot
    after), their errors (:func:`_errors`), the cost against ``now`` and the
    knots freed; None where it loses none."""
    mask = doc.part_mask(part)
    lo, hi, col = np.inf, -np.inf, 0
    for tr in doc.tracks:
        own = mask[col : col + tr.n_vars]
        col += tr.n_vars
        idx = np.flatnonzero((tr.knot_pose == k) & ~own[tr.knots.var])  # never a variable's first or last knot
        if len(idx):
            lo = min(lo, float(np.min(tr.knots.t[idx - 1])))
            hi = max(hi, float(np.max(tr.knots.t[idx + 1])))
    if not np.isfinite(lo):
        return None
    first = max(int(np.floor(lo / doc.frame_time)), 0)
    frames = np.arange(first, min(int(np.ceil(hi / doc.frame_time)) + 1, doc.n_frames))
    trial = cull.demote_pose(doc, k, part, motion)
    after = _errors(trial, frames)
    cost = float(np.sum(after)) - float(np.sum(now[frames]))
    return trial, frames, after, cost, _knot_count(doc) - _knot_count(trial)


def _with_replacements(doc: Document, got, alts, now: np.ndarray, masks, least: float, gap: float):
    """A demotion ``got`` (:func:`_demotion`) together with the other parts'
    partial poses ``alts`` ((part, frame), near the pose) that each win back
    at least ``least`` per knot they add, in turn: the document, the frames
    changed (from the first to the last), their errors and the net cost and
    knots freed."""
    trial, frames, after, _, _ = got
    lo, hi = int(frames[0]), int(frames[-1])
    mine = now.copy()
    mine[frames] = after
    kept: list[tuple[str, int]] = []
    for part, frame in alts:
        t = float(frame) * trial.frame_time
        if np.any(np.abs(partial_times(trial).get(part, np.zeros(0)) - t) <= gap):
            continue
        if part not in masks:
            masks[part] = trial.part_mask(part)
        more = _trial(trial, part, frame, masks[part], mine)
        if more is None or more[3] < least * more[4]:
            continue
        trial, fr, af = more[0], more[1], more[2]
        mine[fr] = af
        kept.append((part, frame))
        lo, hi = min(lo, int(fr[0])), max(hi, int(fr[-1]))
    frames = np.arange(lo, hi + 1)
    after = mine[frames]
    cost = float(np.sum(after)) - float(np.sum(now[frames]))
    return trial, frames, after, cost, _knot_count(doc) - _knot_count(trial), kept


def demoted(
    doc: Document,
    options: list,
    now: np.ndarray,
    motion,
    *,
    least: float,
    value: float,
    gap: float = 0.0,
) -> Document:
    """Lazily greedy: of ``options`` ((part, time, alternatives)), the
    whole-body pose at ``time`` whose knots outside
    ``part`` cost the spline layer least per knot first becomes a partial
    pose of ``part`` (:func:`staggered_cli.ops.cull.demote_pose`), each
    costing at most ``least`` per knot freed and more than ``gap`` seconds
    from the part's other partial poses.  The ``alternatives`` ((other
    part, frame): the other parts' own best frames near the pose) are part
    of the move: each that wins back ``value`` per knot it adds is added
    with the demotion, and the move's cost and knots are net of them (a
    pose there for both arms at two nearby times becomes a partial pose of
    one arm and one of the other, and the body's knots go).  ``now``
    (T, J): the errors of ``doc`` (:func:`_errors`), kept up to date;
    ``motion``: its :func:`staggered_cli.ops.cull.base_motion`.  A cost
    measured before a change whose frames it overlaps is measured again
    when it comes up."""
    heap: list = []
    changed: list[tuple[int, int]] = []  # the frames each change touched
    masks: dict = {}

    def usable(part: str, t: float) -> int | None:
        k = _pose_at(doc, t)
        if k is None or k in (0, doc.n_poses - 1) or doc.pose_part[k] is not None:
            return None
        if np.any(np.abs(partial_times(doc).get(part, np.zeros(0)) - t) <= gap):
            return None
        return k

    def measure(n: int) -> None:
        part, t, alts = options[n]
        k = usable(part, t)
        got = None if k is None else _demotion(doc, k, part, now, motion)
        if got is not None and got[4] > 0:
            # the other parts' own poses win back a share of the cost at best
            near = alts if got[3] <= DEMOTE_REACH * least * got[4] else []
            got = _with_replacements(doc, got, near, now, masks, value, gap)
        if got is None or got[4] <= 0 or got[3] > least * got[4]:
            return
        _, frames, after, cost, knots, kept = got
        heapq.heappush(heap, (cost / knots, n, len(changed), int(frames[0]), int(frames[-1]), after, kept))

    for n in range(len(options)):
        measure(n)
    while heap:
        _, n, seen, lo, hi, after, kept = heapq.heappop(heap)
        part, t, _ = options[n]
        k = usable(part, t)
        if k is None:
            continue
        if any(a <= hi + 1 and lo - 1 <= b for a, b in changed[seen:]):
            measure(n)  # measured on an older document where it now differs
            continue
        doc = cull.demote_pose(doc, k, part, motion)
        if kept:  # the other parts' partial poses that came with it
            doc = cull.add_poses(doc, [float(f) * doc.frame_time for _, f in kept], [q for q, _ in kept])
        now[lo : hi + 1] = after
        changed.append((lo, hi))
    return doc
