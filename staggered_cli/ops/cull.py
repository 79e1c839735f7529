"""Culling and adding staggered poses (paper section 4.1, prioritized poses).

Removing or adding a pose changes the splines; the displacement maps are
measured again from the motion as it was, so the baked motion does not
change (SPEC invariant 2).
"""

from __future__ import annotations

import logging

import numpy as np

from ..document import Document, check_pose_index, reprioritized
from ..errors import UsageError
from ..representation import evaluate_at, knots_from_poses, pose_arrays, restructure

log = logging.getLogger(__name__)


def contact_poses(doc: Document, frames: int = 2) -> np.ndarray:
    """Mask (K,) of poses within ``frames`` frames of a constraint start or end."""
    mask = np.zeros(doc.n_poses, dtype=bool)
    tol = frames * doc.frame_time + 1e-9
    for c in doc.constraints:
        for t in (c.start, c.end):
            mask |= np.abs(doc.pose_t - t) <= tol
    return mask


def choose(
    doc: Document,
    *,
    keep: str | None = None,
    interval: tuple[float, float] | None = None,
    select: list[int] | None = None,
    ignore_contacts: bool = False,
) -> np.ndarray:
    """Mask (K,) of the poses to keep.

    ``keep`` is ``'40%'`` or a count of the highest-priority poses;
    ``interval`` keeps poses with times in [a, b]; ``select`` lists indices.
    The criteria combine (intersection).  The first and last pose are always
    kept and, unless ``ignore_contacts``, so are the poses on contact starts
    and ends.
    """
    K = doc.n_poses
    mask = np.ones(K, dtype=bool)
    if keep is not None:
        mask &= _top(doc, keep)
    if interval is not None:
        a, b = interval
        if np.isnan(a) or np.isnan(b) or a > b:
            raise UsageError(f"--interval must be A:B with A <= B seconds, got {a}:{b}")
        mask &= (doc.pose_t >= a - 1e-9) & (doc.pose_t <= b + 1e-9)
    if select is not None:
        sel = np.zeros(K, dtype=bool)
        for k in select:
            sel[check_pose_index(doc, k)] = True
        mask &= sel
    if not ignore_contacts:
        mask |= contact_poses(doc)
    mask[0] = mask[-1] = True
    return mask


def _top(doc: Document, keep: str) -> np.ndarray:
    K = doc.n_poses
    text = keep.strip()
    try:
        if text.endswith("%"):
            pct = float(text[:-1])
            if not np.isfinite(pct) or not 0 < pct <= 100:
                raise UsageError(f"--keep percentage must be in (0, 100], got {keep!r}")
            n = int(np.ceil(K * pct / 100.0))
        else:
            n = int(text)
            if n < 1:
                raise UsageError(f"--keep must keep at least one pose, got {keep!r}")
    except ValueError:
        raise UsageError(f"--keep takes a percentage like 40% or a count like 12, got {keep!r}") from None
    n = max(2, min(n, K))
    # priorities are infinite on the first and last pose; ties keep the earlier pose
    order = np.lexsort((np.arange(K), -np.nan_to_num(doc.priority, posinf=np.finfo(float).max)))
    mask = np.zeros(K, dtype=bool)
    mask[order[:n]] = True
    return mask


def keep_poses(doc: Document, mask: np.ndarray) -> Document:
    """The document with only the poses in ``mask`` (K,), motion unchanged."""
    mask = np.array(mask, dtype=bool)  # a copy: the caller's mask stays as it was
    mask[0] = mask[-1] = True
    if mask.all():
        return doc
    new_index = np.cumsum(mask) - 1
    tracks = []
    for tr in doc.tracks:
        k = mask[tr.knot_pose]
        var = np.repeat(np.arange(tr.n_vars), np.diff(tr.knot_ptr))
        ptr = np.concatenate([[0], np.cumsum(np.bincount(var[k], minlength=tr.n_vars))])
        knots = (ptr, tr.knot_t[k], tr.knot_v[k], new_index[tr.knot_pose[k]], tr.knot_editing[k])
        tracks.append(restructure(tr, *knots, frame_t=doc.frame_times))
    signals = dict(doc.signals)
    return reprioritized(
        doc.with_tracks(tuple(tracks), pose_t=doc.pose_t[mask], priority=doc.priority[mask], signals=signals)
    )


def add_pose(doc: Document, time: float) -> Document:
    """A new unrefined pose at ``time`` seconds (its knots take the values the
    motion has there), motion unchanged.

    Where ``time`` falls inside another pose's staggered span (between its
    editing knot and its extreme knot) for some variable, that refinement is
    collapsed to zero (the knot returns to its pose time, with the value the
    motion has there), so the poses' knots stay in order; a warning names them.
    """
    half = 0.5 * doc.frame_time  # times as info prints them (4 decimals) must be accepted
    if not np.isfinite(time) or not -half <= time <= doc.duration + half:
        raise UsageError(f"--add-time must lie within the clip (0 to {doc.seconds(doc.duration)}), got {time:g}")
    time = float(min(max(time, 0.0), doc.duration))
    if np.any(np.abs(doc.pose_t - time) < 1e-9):
        raise UsageError(f"there is already a pose at {doc.seconds(time)}")
    k_new = int(np.searchsorted(doc.pose_t, time))
    pose_t = np.insert(doc.pose_t, k_new, time)
    tracks = []
    for tr in doc.tracks:
        ext_t, value, edit = pose_arrays(tr, doc.n_poses)
        refine = ext_t - doc.pose_t[:, None]
        lo = np.minimum(doc.pose_t[:, None], ext_t)
        hi = np.maximum(doc.pose_t[:, None], ext_t)
        conflict = (refine != 0.0) & (lo <= time + 1e-9) & (time - 1e-9 <= hi)
        for k in np.flatnonzero(conflict.any(axis=1)):
            names = ", ".join(tr.names[i] for i in np.flatnonzero(conflict[k]))
            log.warning(
                "--add-time %s: pose %d's refinements of %s collapse to 0 to make room", doc.seconds(time), k, names
            )
        refine = np.where(conflict, 0.0, refine)
        value = np.where(conflict[..., None], edit, value)
        here = evaluate_at(tr, np.arange(tr.n_vars), np.full(tr.n_vars, time))
        knots = knots_from_poses(
            pose_t,
            np.insert(refine, k_new, 0.0, axis=0),
            np.insert(value, k_new, here, axis=0),
            np.insert(edit, k_new, here, axis=0),
            tr.names,
        )
        tracks.append(restructure(tr, *knots, frame_t=doc.frame_times))
    priority = np.insert(doc.priority, k_new, 0.0)
    return reprioritized(doc.with_tracks(tuple(tracks), pose_t=pose_t, priority=priority))
