"""Culling and adding staggered poses (paper section 4.1, prioritized poses).

Removing or adding a pose changes the splines; the displacement maps are
measured again from the motion as it was, so the baked motion does not
change (SPEC invariant 2).
"""

from __future__ import annotations

import numpy as np

from ..document import Document, reprioritized
from ..errors import KnotOrderError, UsageError
from ..representation import evaluate_at, restructure


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
            if not -K <= k < K:
                raise UsageError(f"pose {k} is out of range (the document has poses 0 to {K - 1})")
            sel[k % K] = True
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
    motion has there), motion unchanged."""
    if not np.isfinite(time) or not 0.0 <= time <= doc.duration + 1e-9:
        raise UsageError(f"--add-time must lie within the clip (0 to {doc.duration:.4f} s), got {time}")
    if np.any(np.abs(doc.pose_t - time) < 1e-9):
        raise UsageError(f"there is already a pose at {time:.4f} s")
    k_new = int(np.searchsorted(doc.pose_t, time))
    tracks = []
    for tr in doc.tracks:
        var = np.repeat(np.arange(tr.n_vars), np.diff(tr.knot_ptr))
        value = evaluate_at(tr, np.arange(tr.n_vars), np.full(tr.n_vars, time))
        pose = np.where(tr.knot_pose >= k_new, tr.knot_pose + 1, tr.knot_pose)
        # insert one knot per variable, keeping each variable's knots sorted
        ins = np.array(
            [tr.knot_ptr[i] + np.searchsorted(tr.knot_t[tr.knots(i)], time) for i in range(tr.n_vars)], dtype=int
        )
        for i in range(tr.n_vars):
            kt = tr.knot_t[tr.knots(i)]
            if np.any(np.abs(kt - time) < 1e-9):
                raise KnotOrderError(f"a knot of {tr.names[i]!r} already sits at {time:.4f} s; choose another time")
        knot_t = np.insert(tr.knot_t, ins, time)
        knot_v = np.insert(tr.knot_v, ins, value, axis=0)
        knot_pose = np.insert(pose, ins, k_new)
        knot_editing = np.insert(tr.knot_editing, ins, False)
        ptr = tr.knot_ptr + np.arange(tr.n_vars + 1)
        del var
        for i in range(tr.n_vars):
            # a pose's knots must stay together: not between another pose's editing and extreme knot
            p = knot_pose[ptr[i] : ptr[i + 1]]
            if np.any(np.diff(p) < 0):
                other = k_new - 1 if k_new > 0 and np.any(p == k_new - 1) else k_new + 1
                lo, hi = tr.knot_t[tr.knots(i)][np.isin(tr.knot_pose[tr.knots(i)], [other - (other > k_new)])][[0, -1]]
                raise KnotOrderError(
                    f"--add-time {time:.4f} s falls inside the staggered span of {tr.names[i]!r} around pose "
                    f"{other - (other > k_new)} ({lo:.4f} to {hi:.4f} s); choose a time outside it"
                )
        tracks.append(restructure(tr, ptr, knot_t, knot_v, knot_pose, knot_editing, frame_t=doc.frame_times))
    pose_t = np.insert(doc.pose_t, k_new, time)
    priority = np.insert(doc.priority, k_new, 0.0)
    return reprioritized(doc.with_tracks(tuple(tracks), pose_t=pose_t, priority=priority))
