"""The contact layer: where a bake repairs what edits did to contacts.

Contacts are found by :mod:`.contacts` and solved by :mod:`.ik`; this module
decides which constraints an edit disturbed and what their effectors aim
at, then applies the solution, for a skeleton (:func:`joint_layer`) or for
markers (:func:`marker_layer`).  :func:`staggered_cli.ops.bake.bake` calls it
as the last layer.

A constraint whose effector is where the source had it (to 1e-6 of the
figure's size) over the constraint and its blend windows gets no layer, so
an unedited round trip stays lossless and an edit stays local.  During a
disturbed constraint the effector follows its own captured path, shifted by
the mean offset the edit gave it over the constraint: the edit adds no
sliding, the capture's own heel-to-toe roll is kept, and an edit that moves
the whole figure moves its plants along.  Pure functions of arrays and the
document; nothing is modified in place except the arrays they create.
"""

from __future__ import annotations

import logging

import numpy as np

from . import quat
from .errors import UsageError
from .ik import ik_layer, two_bone_chain
from .model.document import Document
from .model.sampling import at_times
from .motion import local_rotations_from_channels, local_translations_from_channels
from .skeleton import forward_kinematics

log = logging.getLogger(__name__)

_UNDISTURBED = 1e-6  # of figure height
_RESAMPLED = 1e-3  # of figure height, when baking at another rate


def _source_path(points: np.ndarray, frame_time: float, c, t: np.ndarray) -> np.ndarray:
    """Where a constrained point was in the source (T', 3) at output times ``t``.

    Inside the constraint, its source span is stretched onto its current
    span (timing edits move constraints); before and after, the source is
    shifted by the same amount as the nearer end.  Linear between source
    frames (NaN where a neighbouring frame is a gap).
    """
    s0, s1 = c.source_span
    span = c.end - c.start
    inside = s0 + (t - c.start) * ((s1 - s0) / span if span > 0 else 0.0)
    s = np.where(t < c.start, t + (s0 - c.start), np.where(t > c.end, t + (s1 - c.end), inside))
    return at_times(points, frame_time, s)


def _disturbed(pos: np.ndarray, path: np.ndarray, t: np.ndarray, c, blend: float, tolerance: float) -> bool:
    """Whether the edits moved a constrained point off its source path over
    the constraint and its blend windows."""
    window = (t >= c.start - blend - 1e-9) & (t <= c.end + blend + 1e-9)
    if not window.any():
        return False
    with np.errstate(invalid="ignore"):
        d = np.linalg.norm(pos[window] - path[window], axis=-1)
    return bool(np.nanmax(d) > tolerance) if np.isfinite(d).any() else False


def _check_blend(blend: float, same_rate: bool) -> float:
    # resampled frames differ from the source by interpolation, which is large
    # where a lifting foot moves fast: judge a resampled bake inside the
    # constraint only, where a planted point is still
    return blend if same_rate else 0.0


def _tolerance(size: float, same_rate: bool) -> float:
    # resampled output differs from the source by interpolation alone, which a
    # planted point (nearly still) keeps far below a thousandth of the figure
    return (_UNDISTURBED if same_rate else _RESAMPLED) * size


def _chain_changed(sk, changed: np.ndarray, t: np.ndarray, c, blend: float) -> bool:
    """Whether any joint from the root down to ``c.joint`` differs from the
    source over the constraint's window (``changed`` (T, J) bool), or the
    constraint was moved by a timing edit."""
    if c.source_span != (float(c.start), float(c.end)):
        return True
    window = (t >= c.start - blend - 1e-9) & (t <= c.end + blend + 1e-9)
    j = sk.names.index(c.joint)
    chain = []
    while j >= 0:
        chain.append(j)
        j = int(sk.parents[j])
    return bool(changed[np.ix_(window, chain)].any())


def check_joints(doc: Document) -> None:
    """``UsageError`` for a constraint on a joint the skeleton does not have."""
    names = doc.source.skeleton.names
    for c in doc.constraints:
        if c.joint not in names:
            raise UsageError(f"constraint on unknown joint {c.joint!r}")


def source_changed(src, rot: np.ndarray, tr: np.ndarray, lo: int, joints: np.ndarray | None = None) -> np.ndarray:
    """(n, J) bool: where local rotations ``rot`` (n, J, 4) and translations
    ``tr`` (n, J, 3) at source frames ``lo .. lo + n`` differ from the
    source's.  Sign-blind, so the source's rotations need no unrolling:
    any block of frames is compared on its own.  ``joints`` (int): compare
    these joints only (False elsewhere)."""
    sk = src.skeleton
    ch = src.channels[lo : lo + len(rot)]
    if joints is None:
        return _differs(
            rot, local_rotations_from_channels(sk, ch, unroll=False), tr, local_translations_from_channels(sk, ch)
        )
    out = np.zeros(rot.shape[:2], dtype=bool)
    if len(joints):
        # each joint's numbers are its own: the same as over all joints
        src_rot = local_rotations_from_channels(sk, ch, unroll=False, joints=joints)[:, joints]
        out[:, joints] = _differs(
            rot[:, joints], src_rot, tr[:, joints], local_translations_from_channels(sk, ch)[:, joints]
        )
    return out


def _differs(rot: np.ndarray, src_rot: np.ndarray, tr: np.ndarray, src_tr: np.ndarray) -> np.ndarray:
    """(n, J) bool: a rotation (sign-blind) or translation that is not the source's."""
    return (1.0 - np.abs(np.sum(rot * src_rot, axis=-1)) > 1e-12) | np.any(np.abs(tr - src_tr) > 1e-9, axis=-1)


def chain_joints(doc: Document) -> np.ndarray:
    """The joints (increasing) from the root down to any constraint's joint:
    the only ones :func:`disturbed_in` looks at."""
    sk = doc.source.skeleton
    seen: set[int] = set()
    for c in doc.constraints:
        j = sk.names.index(c.joint)
        while j >= 0 and j not in seen:
            seen.add(j)
            j = int(sk.parents[j])
    return np.array(sorted(seen), dtype=int)


def repairs_unseen(doc: Document) -> bool:
    """Whether the joint layer may repair a constraint whatever the baked
    pose: a pinned one, or one a timing edit moved."""
    return any(c.pin or c.source_span != (float(c.start), float(c.end)) for c in doc.constraints)


def disturbed_in(doc: Document, changed: np.ndarray, t: np.ndarray, blend: float) -> bool:
    """Whether ``changed`` (n, J), the comparison with the source at frames
    ``t`` (n,) (a block of a same-rate bake), puts any constraint among the
    joint layer's candidates: its chain changed within its window.  Over
    consecutive blocks, the same test as :func:`joint_layer`'s first pass."""
    sk = doc.source.skeleton
    if len(t) == 0:
        return False
    first, last = float(np.min(t)), float(np.max(t))
    for c in doc.constraints:
        # a long clip has constraints all along it: only those whose window
        # reaches the block's span are looked at frame by frame (else a
        # bake block by block is quadratic in the clip's length)
        if c.start - blend - 1e-9 > last or c.end + blend + 1e-9 < first:
            continue
        window = (t >= c.start - blend - 1e-9) & (t <= c.end + blend + 1e-9)
        if window.any() and _chain_changed(sk, changed, t, c, blend):
            return True
    return False


def _linked(sk, a: str, b: str) -> bool:
    """Whether one joint is the other's parent (a foot and its toe)."""
    ia, ib = sk.names.index(a), sk.names.index(b)
    return ia != ib and (sk.parents[ia] == ib or sk.parents[ib] == ia)


def _overlap(c, d, blend: float) -> bool:
    return c.start - blend <= d.end + blend and d.start - blend <= c.end + blend


def joint_layer(
    doc: Document, rot: np.ndarray, tr: np.ndarray, t: np.ndarray, blend: float, same_rate: bool
) -> np.ndarray:
    """BVH: local rotations (N, J, 4) with the constraints the edits disturbed
    repaired by two-bone IK, given the pose ``rot``, ``tr`` at times ``t``
    (see the module docstring)."""
    src = doc.source
    sk = src.skeleton
    check_joints(doc)
    candidates = list(doc.constraints)
    if same_rate:
        # cheap first pass without forward kinematics: a constraint whose
        # chain keeps the source's local values over its window is untouched
        changed = np.empty(rot.shape[:2], dtype=bool)
        step = max(1, (1 << 16) // max(sk.n_joints, 1))
        for lo in range(0, len(rot), step):  # no temporaries of the whole clip
            changed[lo : lo + step] = source_changed(src, rot[lo : lo + step], tr[lo : lo + step], lo)
        candidates = [c for c in candidates if c.pin or _chain_changed(sk, changed, t, c, blend)]
    if not candidates:
        return rot
    _, wp = forward_kinematics(sk, rot, tr)
    src_wp = src.world_positions()
    size = src.figure_height()  # cached with the clip's world positions

    tolerance = _tolerance(size, same_rate)

    def target(c):
        j = sk.names.index(c.joint)
        path = _source_path(src_wp[:, j], doc.frame_time, c, t)
        inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
        return path, path + _plant_offset(wp[inside, j], path[inside], tolerance)

    todo = [
        c
        for c in candidates
        if c.pin
        or _disturbed(
            wp[:, sk.names.index(c.joint)],
            target(c)[0],
            t,
            c,
            _check_blend(blend, same_rate),
            tolerance,
        )
    ]
    # a foot and its toe share a chain: solving one moves the other, so a
    # planted neighbour overlapping a repaired constraint is held on its path too
    for c in [c for c in todo if not c.pin]:  # a pinned joint is the user's word: its neighbours follow it
        for d in doc.constraints:
            if d not in todo and _linked(sk, c.joint, d.joint) and _overlap(c, d, blend):
                todo.append(d)
    if not todo:
        return rot
    targets = [None if c.pin else target(c)[1] for c in todo]  # None: held at its mean position
    out = ik_layer(sk, rot, tr, t, tuple(todo), blend=blend, targets=targets)
    _warn_overridden(doc, rot, out, t, todo)
    return out


#: Edits smaller than this (degrees) at a pose are not worth a warning.
_EDIT_WORTH_WARNING = 1.0


def _warn_overridden(doc: Document, before: np.ndarray, after: np.ndarray, t: np.ndarray, todo: list) -> None:
    """Say so, in one warning line, where the contact layer takes back more
    than half of an edited joint's rotation at a pose: a planted foot cannot
    keep a hip flexion, but the user must know.  The edit is the motion's
    difference from the source at the pose before the layer; what is kept,
    the difference after it."""
    src = doc.source
    sk = src.skeleton
    if len(t) == 0:
        return
    frames = np.clip(np.searchsorted(t, doc.pose_t), 0, len(t) - 1)
    near = np.clip(np.rint(t[frames] / doc.frame_time).astype(int), 0, doc.n_frames - 1)
    source = src.local_rotations()[near]  # (K, J, 4)
    cases: dict[tuple[int, int], tuple[float, float, int]] = {}  # (pose, joint) -> kept, edit, constraint
    for c in todo:
        n = doc.constraints.index(c)
        chain = two_bone_chain(sk, c.joint)
        for k in range(doc.n_poses):
            f = frames[k]
            if not c.start - 1e-9 <= t[f] <= c.end + 1e-9:
                continue
            for j in (chain.upper, chain.middle, chain.lower):
                edit = float(np.degrees(quat.angle_between(before[f, j], source[k, j])))
                kept = float(np.degrees(quat.angle_between(after[f, j], source[k, j])))
                if edit >= _EDIT_WORTH_WARNING and kept < 0.5 * edit and (k, j) not in cases:
                    cases[(k, j)] = (kept, edit, n)
    if not cases:
        return
    removes = " ".join(f"--remove {n}" for n in sorted({n for _, _, n in cases.values()}))
    if len(cases) == 1:
        (((k, j), (kept, edit, n)),) = cases.items()
        c = doc.constraints[n]
        log.warning(
            "pose %d (%.3f s): the contact layer leaves %s %.1f° of its %.1f° edit to keep %s planted "
            "(constraint %d, %.3f to %.3f s); bake with --no-ik, or drop the constraint with `constraints %s`",
            k,
            doc.pose_t[k],
            sk.names[j],
            kept,
            edit,
            c.joint,
            n,
            c.start,
            c.end,
            removes,
        )
        return
    shown = sorted(cases.items())
    listed = ", ".join(
        f"pose {k} {sk.names[j]} {kept:.1f}° of {edit:.1f}° (constraint {n})" for (k, j), (kept, edit, n) in shown[:4]
    )
    more = f" and {len(shown) - 4} more" if len(shown) > 4 else ""
    log.warning(
        "the contact layer takes back more than half of %d edited joint rotations at poses: %s%s; "
        "bake with --no-ik, or drop the constraints with `constraints %s`",
        len(shown),
        listed,
        more,
        removes,
    )


def _plant_offset(pos: np.ndarray, path: np.ndarray, tolerance: float) -> np.ndarray:
    """How far (3,) a disturbed plant moves from its captured path, given the
    point's positions ``pos`` and its path ``path`` (n, 3) over the constraint.

    Where the edits left part of the contact where it was, the plant stays
    on the captured path (offset 0): the layer then only undoes the sliding
    the edit brought, and frames the edit did not reach stay as they are.
    Only an edit that moved the whole contact moves the plant, by its mean
    offset (gaps ignored).
    """
    with np.errstate(invalid="ignore"):
        d = pos - path
        dist = np.linalg.norm(d, axis=-1)
    ok = np.isfinite(dist)
    if not ok.any() or np.any(dist[ok] <= tolerance):
        return np.zeros(3)
    return d[ok].mean(axis=0)


def _smooth_weight(t: np.ndarray, start: float, end: float, blend: float) -> np.ndarray:
    """1 inside [start, end], a C1 smoothstep ramp to 0 over ``blend`` seconds outside."""
    w = ((t >= start) & (t <= end)).astype(float)
    if blend > 0:
        for edge, side in ((start, -1.0), (end, 1.0)):
            x = side * (t - edge) / blend
            ramp = (x > 0) & (x < 1)
            s = 1.0 - x[ramp]
            w[ramp] = np.maximum(w[ramp], s * s * (3.0 - 2.0 * s))
    return w


def marker_layer(doc: Document, pts: np.ndarray, t: np.ndarray, blend: float, same_rate: bool) -> np.ndarray:
    """C3D: a disturbed constrained marker follows its captured path shifted by
    the edit's mean offset over the constraint, blended in and out.

    Markers that a timing edit retimed as a chain (the document's
    ``marker_tree``, see :mod:`.ops.marker_chain`) keep their segments: the
    marker's parent is moved by two-bone IK on points (grandparent fixed,
    both segment lengths kept, the middle marker on its side of the limb),
    or, where the parent is planted too or has no parent, the marker turns
    about its parent towards its plant; the markers below it move along.
    """
    src = doc.source
    tolerance = _tolerance(src.figure_height(), same_rate)
    labels = list(src.labels)
    parents = marker_tree_parents(doc)
    depth = np.zeros(len(labels), dtype=int)
    for i in range(len(labels)):
        j = parents[i]
        while j >= 0 and depth[i] <= len(labels):
            depth[i] += 1
            j = parents[j]
    out = pts.copy()
    held: dict[int, np.ndarray] = {}  # marker -> frames where a pin moved it
    for c in doc.constraints:
        if c.joint not in src.labels:
            raise UsageError(f"constraint on unknown marker {c.joint!r}")
    for c in sorted(doc.constraints, key=lambda c: depth[labels.index(c.joint)]):  # parents first
        m = labels.index(c.joint)
        path = _source_path(src.points[:, m], doc.frame_time, c, t)
        if c.pin:  # planted by the user: held at its mean position over the constraint
            inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
            seen = pts[inside, m][np.all(np.isfinite(pts[inside, m]), axis=1)]
            if not len(seen):
                continue
            path = np.broadcast_to(seen.mean(axis=0), path.shape)
        elif not _disturbed(pts[:, m], path, t, c, _check_blend(blend, same_rate), tolerance):
            continue
        inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
        seen = inside & np.all(np.isfinite(pts[:, m]), axis=1) & np.all(np.isfinite(path), axis=1)
        if not seen.any():
            continue
        target = path + _plant_offset(pts[seen, m], path[seen], tolerance)
        w = _smooth_weight(t, c.start, c.end, blend)[:, None]
        # in the blend windows the correction fades from its value at the boundary
        i0, i1 = np.flatnonzero(seen)[[0, -1]]
        corr = np.where((t < c.start)[:, None], target[i0] - pts[i0, m], target[i1] - pts[i1, m])
        corr[inside] = (target - pts[:, m])[inside]
        frames = np.flatnonzero(w[:, 0] > 0)
        goal = pts[frames, m] + w[frames] * np.nan_to_num(corr[frames])
        _place_in_tree(out, parents, m, frames, goal, held)
        held[m] = np.union1d(held.get(m, np.zeros(0, dtype=int)), frames)
    return out


def marker_tree_parents(doc: Document) -> np.ndarray:
    """Parent index (M,) of each marker in the document's ``marker_tree`` (-1: none)."""
    labels = list(doc.source.labels)
    parents = np.full(len(labels), -1, dtype=int)
    for child, parent in dict(doc.parameters.get("marker_tree", {})).items():
        if child in labels and parent in labels:
            parents[labels.index(child)] = labels.index(parent)
    return parents


def _place_in_tree(
    out: np.ndarray, parents: np.ndarray, m: int, frames: np.ndarray, goal: np.ndarray, held: dict
) -> None:
    """Move marker ``m`` towards ``goal`` (n, 3) at ``frames`` in ``out``
    (T, M, 3), in place, keeping its tree's segments (see :func:`marker_layer`)."""
    p = int(parents[m])
    before = out[frames].copy()  # (n, M, 3)
    cur = before[:, m]
    new = goal
    if p >= 0:
        g = int(parents[p])
        planted_parent = p in held and np.isin(frames, held[p]).any()
        if g >= 0 and not planted_parent:
            knee = _two_bone_points(before[:, g], before[:, p], cur, goal)
            ok = np.all(np.isfinite(knee), axis=1)
            _move_subtree(out, parents, p, frames[ok], knee[ok] - before[ok, p], skip=m)
            out[frames[ok], p] = knee[ok]
            anchor = np.where(ok[:, None], knee, before[:, p])
        else:
            anchor = before[:, p]
        # the marker turns about its parent, at its own distance, towards its goal
        length = np.linalg.norm(cur - before[:, p], axis=1, keepdims=True)
        aim = goal - anchor
        n = np.linalg.norm(aim, axis=1, keepdims=True)
        turned = anchor + length * aim / np.where(n > 0, n, 1.0)
        new = np.where(np.isfinite(turned) & (n > 0), turned, goal)
    _move_subtree(out, parents, m, frames, np.nan_to_num(new - cur))
    out[frames, m] = np.where(np.isfinite(cur), new, cur)


def _move_subtree(out: np.ndarray, parents: np.ndarray, m: int, frames: np.ndarray, shift: np.ndarray, skip=-1) -> None:
    """Translate the markers below ``m`` (not ``m`` itself, nor ``skip`` and
    the markers below it) by ``shift`` (n, 3) at ``frames``, in place."""
    below = _below(parents, m)
    if skip >= 0:
        below = below[(below != skip) & ~np.isin(below, _below(parents, skip))]
    if len(below):
        out[np.ix_(frames, below)] += shift[:, None, :]


def _below(parents: np.ndarray, m: int) -> np.ndarray:
    """Indices of the markers below ``m`` in the tree ``parents`` (M,)."""
    found = np.zeros(len(parents), dtype=bool)
    front = np.flatnonzero(parents == m)
    while len(front):
        front = front[~found[front]]
        found[front] = True
        front = np.flatnonzero(np.isin(parents, front))
    return np.flatnonzero(found)


def _two_bone_points(a: np.ndarray, b: np.ndarray, c: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Where the middle point of the chain a-b-c goes (n, 3) when its end c
    moves to ``goal``, with ``a`` fixed, both lengths kept and ``b`` on its side
    of the line from ``a`` to the goal (as far as the lengths reach)."""
    l1 = np.linalg.norm(b - a, axis=1)
    l2 = np.linalg.norm(c - b, axis=1)
    to_goal = goal - a
    d = np.linalg.norm(to_goal, axis=1)
    u = to_goal / np.where(d > 0, d, 1.0)[:, None]
    d = np.clip(d, np.abs(l1 - l2) + 1e-9, l1 + l2 - 1e-9)
    side = (b - a) - np.sum((b - a) * u, axis=1, keepdims=True) * u
    sn = np.linalg.norm(side, axis=1, keepdims=True)
    v = side / np.where(sn > 0, sn, 1.0)
    cos = np.clip((l1**2 + d**2 - l2**2) / np.maximum(2 * l1 * d, 1e-300), -1.0, 1.0)
    return a + l1[:, None] * (cos[:, None] * u + np.sqrt(1 - cos**2)[:, None] * v)
