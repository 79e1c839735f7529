"""Partial poses found by extract (issue 37): which candidates earn their knots.

:mod:`staggered_cli.signals.partial` proposes partial poses from each body
part's own evidence and the placement proxy; :func:`confirmed` adds those
that make the real spline layer better, judged in world space, to the
document (:func:`staggered_cli.ops.cull.add_poses` with the part).
"""

from __future__ import annotations

import heapq
import warnings

import numpy as np

from ..errors import StaggeredWarning, UsageError
from ..model.document import Document
from ..model.sampling import local_pose
from ..skeleton import forward_kinematics
from . import cull

#: A partial pose stays only where it lowers the spline layer's world error
#: by at least this share of what the knots of the whole-body pose a cull
#: would take first hold in place, per knot: 1.0, so that at the same
#: number of knots the trade is no loss (0.7 kept poses worth less than the
#: pose they stand in for: spliced clips 0.984 at equal knots, now 0.978).
WORLD_VALUE = 1.0


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
    doc: Document, candidates: list[tuple[str, int]], fits: list[tuple[str, int]] | None = None, *, gap: float = 0.0
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
    """
    if (not candidates and not fits) or doc.n_poses < 3:
        return doc
    every = np.arange(doc.n_frames)
    fewer = cull.keep_poses(doc, cull.choose(doc, keep=str(doc.n_poses - 1)))
    now = _errors(doc, every)  # (T, J), kept up to date as poses are added
    value = max(_error(fewer, every) - float(np.sum(now)), 0.0) / max(_knot_count(doc) - _knot_count(fewer), 1)
    if value <= 0.0:
        return doc
    masks = {part: doc.part_mask(part) for part, _ in list(candidates) + list(fits or [])}
    for part, frame in candidates:
        got = _trial(doc, part, frame, masks[part], now)
        if got is None:
            continue
        trial, frames, after, gain, added = got
        if gain >= WORLD_VALUE * value * added:
            doc = trial
            now[frames] = after
    if fits:
        doc = _best_first(doc, fits, masks, now, WORLD_VALUE * value, gap)
    return doc


def _best_first(doc: Document, fits, masks, now: np.ndarray, least: float, gap: float) -> Document:
    """Lazily greedy: the candidate of ``fits`` with the largest real gain
    per knot first, each worth ``least`` per knot and more than ``gap``
    seconds from its part's other partial poses.  A gain measured before the
    last pose was added is measured again when it comes up (a pose's gain
    only shrinks as others are added, nearly always)."""
    heap = []
    version = 0
    for n, (part, frame) in enumerate(fits):
        got = _trial(doc, part, frame, masks[part], now)
        if got is not None and got[3] >= least * got[4]:
            heapq.heappush(heap, (-got[3] / got[4], n, version, got))
    while heap:
        _, n, seen, got = heapq.heappop(heap)
        part, frame = fits[n]
        others = partial_times(doc).get(part, np.zeros(0))
        if np.any(np.abs(others - float(frame) * doc.frame_time) <= gap):
            continue
        if seen != version:  # measured on an older document
            got = _trial(doc, part, frame, masks[part], now)
            if got is not None and got[3] >= least * got[4]:
                heapq.heappush(heap, (-got[3] / got[4], n, version, got))
            continue
        trial, frames, after, _, _ = got
        doc = trial
        now[frames] = after
        version += 1
    return doc
