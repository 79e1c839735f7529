"""The contact layer: where a bake repairs what edits did to contacts.

Contacts are found by :mod:`.contacts` and solved by :mod:`.ik`; this module
decides which constraints an edit disturbed and what their effectors aim
at, then applies the solution, for a skeleton (:func:`joint_layer`) or for
markers (:func:`marker_layer`).  :func:`staggered_cli.ops.bake.bake` calls it
as the last layer.

A constraint whose effector is where the source had it (to 1e-6 of the
figure's size) over the constraint and its blend windows gets no layer, so
an unedited round trip stays lossless and an edit stays local.  During a
disturbed constraint the effector follows its own captured path: the edit
adds no sliding, the capture's own heel-to-toe roll is kept, and since the
path is the capture's, the effector never goes below the floor the capture
shows, whatever an edit did to the root or the chain above it.  A plant
moves only when the user moves the figure as a whole: asked for
(``move_plants``, ``bake --move-plants``: each plant moves by the
horizontal part of the mean offset the edits gave it over the contact), or
seen (every frame of the figure's root moved by one same offset: the plants
move by its horizontal part).  Horizontally only: never into or off the
floor.  Where a chain cannot reach its plant the effector comes as close as
it can (see :mod:`.ik`) and one warning line names the contacts, the miss
and the way out.  Pure functions of arrays and the document; nothing is
modified in place except the arrays they create.
"""

from __future__ import annotations

import numpy as np

from .. import quat
from ..errors import UsageError, arg, warn
from ..model.document import Document
from ..model.sampling import at_times
from ..motion import local_rotations_from_channels, local_translations_from_channels
from ..skeleton import body_joints, forward_kinematics
from .detect import up_direction
from .ik import ik_layer, two_bone_chain

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
    doc: Document,
    rot: np.ndarray,
    tr: np.ndarray,
    t: np.ndarray,
    blend: float,
    same_rate: bool,
    move_plants: bool = False,
) -> np.ndarray:
    """BVH: local rotations (N, J, 4) with the constraints the edits disturbed
    repaired by two-bone IK, given the pose ``rot``, ``tr`` at times ``t``
    (see the module docstring).  ``move_plants``: the plants follow the
    edits horizontally (the user moved the figure as a whole)."""
    src = doc.source
    sk = src.skeleton
    check_joints(doc)
    candidates = list(doc.constraints)
    changed = None
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
    up = up_direction(src_wp, size, body_joints(sk))
    root = int(body_joints(sk)[0])
    whole = _whole_shift(wp[:, root], at_times(src_wp[:, root], doc.frame_time, t), tolerance)

    def target(c):
        j = sk.names.index(c.joint)
        path = _source_path(src_wp[:, j], doc.frame_time, c, t)
        inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
        shift = _plant_shift(whole, move_plants, wp[inside, j], path[inside], tolerance)
        return path, path + _horizontal(shift, up)

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
    reached = _reached(sk, out, tr, t, todo, targets)
    goals = targets
    kept = [
        None
        if changed is None or c.source_span != (float(c.start), float(c.end))
        else ~changed[:, _root_path(sk, c.joint)].any(axis=1)
        for c in todo
    ]
    for _ in range(_EASING_PASSES):  # a leg that does not reach: its miss eased in and out, solved again
        eased = _eased(targets, reached, kept, _MISS_RATE * size, _MISS_WORTH_WARNING * size)
        if eased is None:
            break
        goals = eased
        out = ik_layer(sk, rot, tr, t, tuple(todo), blend=blend, targets=goals)
        reached = _reached(sk, out, tr, t, todo, targets)
    _warn_overridden(doc, rot, out, t, todo, blend)
    _warn_unreached(doc, todo, targets, reached, t, size)
    return out


#: A plant the layer misses by more than this fraction of the figure's height is reported.
_MISS_WORTH_WARNING = 1e-3


def _horizontal(v: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``v`` (3,) without its part along the unit ``up`` (3,)."""
    return v - np.dot(v, up) * up


def _whole_shift(pos: np.ndarray, path: np.ndarray, tolerance: float) -> np.ndarray | None:
    """The offset (3,) by which the edits moved the figure as a whole: the
    root's positions ``pos`` (N, 3) all off its source ``path`` (N, 3) by
    one same offset (within a tenth of ``tolerance`` of each other, and more
    than ``tolerance`` long); None otherwise."""
    d = pos - path
    ok = np.all(np.isfinite(d), axis=1)
    if not ok.any():
        return None
    d = d[ok]
    mean = d.mean(axis=0)
    if (
        np.linalg.norm(mean) <= tolerance
        or np.abs(d - mean).max() > 0.1 * max(tolerance, 1e-300) + 1e-9 * np.abs(mean).max()
    ):
        return None
    return mean


def _reached(sk, out: np.ndarray, tr: np.ndarray, t: np.ndarray, todo: list, targets: list) -> list:
    """Where each constraint's joint is (N, 3) in the layered pose ``out``
    (NaN outside its frames; None for a constraint without a target)."""
    frames = np.zeros(len(t), dtype=bool)
    for c, g in zip(todo, targets, strict=True):
        if g is not None:
            frames |= (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
    rows = np.flatnonzero(frames)
    wp = forward_kinematics(sk, out[rows], tr[rows])[1] if len(rows) else None
    at = np.full(len(t), -1)
    at[rows] = np.arange(len(rows))
    found = []
    for c, g in zip(todo, targets, strict=True):
        if g is None:
            found.append(None)
            continue
        inside = np.flatnonzero((t >= c.start - 1e-9) & (t <= c.end + 1e-9))
        p = np.full((len(t), 3), np.nan)
        p[inside] = wp[at[inside], sk.names.index(c.joint)]
        found.append(p)
    return found


#: Fastest a miss grows or shrinks (fraction of the figure's height per frame):
#: a leg that cannot reach lifts its foot no faster than this.
_MISS_RATE = 7.5e-4
#: Solves with eased misses at most (a toe's miss depends on its foot's).
_EASING_PASSES = 2


def _root_path(sk, joint: str) -> list[int]:
    """Joint indices from ``joint`` up to the root."""
    j = sk.names.index(joint)
    path = []
    while j >= 0:
        path.append(j)
        j = int(sk.parents[j])
    return path


def _eased(targets: list, reached: list, kept: list, rate: float, worth: float = 0.0) -> list | None:
    """Targets with each miss eased in and out, or None where every target
    is reached.

    The miss (the reached point's offset from the target, inside the
    constraint) is replaced by the smallest one that is at least as large at
    every frame and changes by at most ``rate`` per frame (the upper
    envelope of cones, two running maxima), along the direction of the
    nearest frame that misses: the foot lifts early and gradually rather
    than being dragged by the hips at the instant the leg runs out of reach.
    The edit stays local: where ``kept`` (N,) bool marks frames whose chain
    the edits left as captured, the eased miss is back to zero (the rate is
    raised as much as that needs).
    """
    out = list(targets)
    changed = False
    for i, (g, p) in enumerate(zip(targets, reached, strict=True)):
        if g is None:
            continue
        inside = np.flatnonzero(np.all(np.isfinite(p), axis=1))
        if len(inside) == 0:
            continue
        miss = p[inside] - g[inside]
        m = np.linalg.norm(miss, axis=1)
        if not np.any(m > worth):
            continue
        m = np.where(m > 0.1 * rate, m, 0.0)
        idx = np.arange(len(m))
        if kept[i] is not None and kept[i][inside].any():
            # distance (frames) from each frame to the nearest one the edits left alone
            still = kept[i][inside]
            last = np.maximum.accumulate(np.where(still, idx, -len(m) - 1))
            nxt = np.minimum.accumulate(np.where(still, idx, 3 * len(m) + 1)[::-1])[::-1]
            gap = np.minimum(idx - last, nxt - idx)
            rate_i = max(rate, float(np.max(m / np.maximum(gap, 1))))
        else:
            rate_i = rate
        x = rate_i * idx
        env = np.maximum(np.maximum.accumulate(m + x) - x, (np.maximum.accumulate((m - x)[::-1]) + x[::-1])[::-1])
        hit = m > 0
        before = np.maximum.accumulate(np.where(hit, idx, -1))
        after = np.minimum.accumulate(np.where(hit, idx, len(m))[::-1])[::-1]
        use_before = (before >= 0) & ((after >= len(m)) | (idx - before <= after - idx))
        near = np.where(use_before, before, np.minimum(after, len(m) - 1))
        u = miss[near] / m[near][:, None]
        eased = np.array(g, dtype=float, copy=True)
        eased[inside] = g[inside] + env[:, None] * u
        out[i] = eased
        changed = True
    return out if changed else None


def _warn_unreached(doc: Document, todo: list, targets: list, reached: list, t: np.ndarray, size: float) -> None:
    """One warning line for the plants the layer could not keep on their
    target (a leg that does not reach): which contacts, when, by how much
    (% of the figure's height), and the way out."""
    missed = []
    for c, g, p in zip(todo, targets, reached, strict=True):
        if g is None:
            continue
        with np.errstate(invalid="ignore"):
            miss = np.linalg.norm(p - g, axis=-1) / size
        far = np.flatnonzero(np.nan_to_num(miss) > _MISS_WORTH_WARNING)
        if len(far):
            missed.append((float(np.nanmax(miss)), c, float(t[far[0]]), float(t[far[-1]])))
    if not missed:
        return
    missed.sort(key=lambda m: (m[1].start, m[1].joint))
    listed = ", ".join(
        f"{c.joint} {a:.3f}-{b:.3f} s (up to {100 * m:.2f} % of the height)" for m, c, a, b in missed[:6]
    )
    more = f" and {len(missed) - 6} more" if len(missed) > 6 else ""
    # the way out: where no pose lies between the missed frames and the
    # contact's end (or start), the edit reaches in from a pose beyond it,
    # and a pose there keeps it out
    half = 0.5 * doc.frame_time
    ends = []
    for _, c, a, b in sorted(missed, key=lambda m: -m[0]):
        if not np.any((doc.pose_t >= b - 1e-9) & (doc.pose_t <= c.end + half)):
            ends.append(c.end)
        elif not np.any((doc.pose_t >= c.start - half) & (doc.pose_t <= a + 1e-9)):
            ends.append(c.start)
    if ends:
        way = (
            f"add a pose at the contact's end (`cull --add-time {ends[0]:.3f}`) "
            f"or bake with {arg('ik=False', '--no-ik')}"
        )
    else:
        way = (
            "the edits at poses inside the contacts ask more than the legs reach: "
            f"edit less, or bake with {arg('ik=False', '--no-ik')}"
        )
    warn(
        "the contact layer cannot keep %d planted contact%s on the captured path (the leg does not reach): %s%s; %s",
        len(missed),
        "" if len(missed) == 1 else "s",
        listed,
        more,
        way,
    )


#: Edits smaller than this (degrees) at a pose are not worth a warning.
_EDIT_WORTH_WARNING = 1.0


def _warn_overridden(
    doc: Document, before: np.ndarray, after: np.ndarray, t: np.ndarray, todo: list, blend: float = 0.0
) -> None:
    """Say so, in one warning line, where the contact layer does not keep an
    edited joint's rotation at a pose: a planted foot cannot keep a hip
    flexion, but the user must know.

    The edit is the joint's local change from the source at the pose's frame
    before the layer (``e = src⁻¹ · before``, axis ``a``, angle θ); what is
    got, the change after it (``g = src⁻¹ · after``), split into its turn
    about ``a`` (the part of the edit that survives) and the rest (off-axis).
    It is reported when less than half of θ survives along ``a``, or when
    ``after`` is more than θ/2 away from ``before``; at poses inside a
    repaired constraint or its ``blend`` windows (where the layer acts)."""
    src = doc.source
    sk = src.skeleton
    if len(t) == 0:
        return
    frames = np.clip(np.searchsorted(t, doc.pose_t), 0, len(t) - 1)
    near = np.clip(np.rint(t[frames] / doc.frame_time).astype(int), 0, doc.n_frames - 1)
    source = src.local_rotations()[near]  # (K, J, 4)
    cases: dict[tuple[int, int], tuple[float, float, float, int]] = {}  # (pose, joint) -> asked, got, off, constraint
    for c in todo:
        n = doc.constraints.index(c)
        chain = two_bone_chain(sk, c.joint)
        for k in range(doc.n_poses):
            f = frames[k]
            if not c.start - blend - 1e-9 < t[f] < c.end + blend + 1e-9:
                continue
            for j in (chain.upper, chain.middle, chain.lower):
                if (k, j) in cases:
                    continue
                asked, got, off, moved = _kept_along(source[k, j], before[f, j], after[f, j])
                if asked >= _EDIT_WORTH_WARNING and (got < 0.5 * asked or moved > 0.5 * asked):
                    cases[(k, j)] = (asked, got, off, n)
    if not cases:
        return
    removes = " ".join(f"--remove {n}" for n in sorted({v[3] for v in cases.values()}))

    def said(asked: float, got: float, off: float) -> str:
        return f"asked {asked:.1f}°, got {got:.1f}°" + (f" (and {off:.1f}° off-axis)" if off >= 0.05 else "")

    if len(cases) == 1:
        (((k, j), (asked, got, off, n)),) = cases.items()
        c = doc.constraints[n]
        warn(
            "pose %d (%.3f s) %s: %s: the contact layer changes the edit to keep %s planted "
            f"(constraint %d, %.3f to %.3f s); bake with {arg('ik=False', '--no-ik')}, "
            "or drop the constraint with `constraints %s`",
            k,
            doc.pose_t[k],
            sk.names[j],
            said(asked, got, off),
            c.joint,
            n,
            c.start,
            c.end,
            removes,
        )
        return
    shown = sorted(cases.items())
    listed = ", ".join(f"pose {k} {sk.names[j]} {said(a, g, o)} (constraint {n})" for (k, j), (a, g, o, n) in shown[:4])
    more = f" and {len(shown) - 4} more" if len(shown) > 4 else ""
    warn(
        "the contact layer changes %d edited joint rotations at poses to keep feet planted: %s%s; "
        f"bake with {arg('ik=False', '--no-ik')}, or drop the constraints with `constraints %s`",
        len(shown),
        listed,
        more,
        removes,
    )


def _kept_along(source: np.ndarray, before: np.ndarray, after: np.ndarray) -> tuple[float, float, float, float]:
    """Degrees: the edit's angle (``source`` to ``before``, local), the
    signed turn of ``source`` to ``after`` about the edit's own axis, the rest
    of that change (off the axis), and the angle from ``before`` to ``after``."""
    e = quat.mul(quat.conj(source), before)
    e = np.where(e[..., :1] < 0, -e, e)
    g = quat.mul(quat.conj(source), after)
    g = np.where(g[..., :1] < 0, -g, g)
    r = quat.log(e)  # the rotation vector
    ang = float(np.linalg.norm(r))
    asked = float(np.degrees(ang))
    if ang <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    axis = r / ang
    # swing-twist: the twist about the axis is the part of g that turns about it
    twist = np.concatenate([g[:1], np.dot(g[1:], axis) * axis])
    tn = float(np.linalg.norm(twist))
    twist = twist / tn if tn > 0 else quat.identity()
    got = float(np.degrees(2.0 * np.arctan2(np.dot(twist[1:], axis), twist[0])))
    off = float(np.degrees(quat.angle(quat.mul(g, quat.conj(twist)))))
    moved = float(np.degrees(quat.angle_between(before, after)))
    return asked, got, off, moved


def _plant_shift(
    whole: np.ndarray | None, move_plants: bool, pos: np.ndarray, path: np.ndarray, tolerance: float
) -> np.ndarray:
    """How far (3,) a plant moves off its captured path: with the figure
    where the figure moved as a whole (``whole``), by :func:`_plant_offset`
    under ``move_plants``, else not at all."""
    if whole is not None:
        return whole
    if move_plants:
        return _plant_offset(pos, path, tolerance)
    return np.zeros(3)


def _plant_offset(pos: np.ndarray, path: np.ndarray, tolerance: float) -> np.ndarray:
    """How far (3,) a disturbed plant moves from its captured path, given the
    point's positions ``pos`` and its path ``path`` (n, 3) over the constraint.

    Where the edits left part of the contact where it was, the plant stays
    on the captured path (offset 0): the layer then only undoes the sliding
    the edit brought, and frames the edit did not reach stay as they are.
    Only an edit that moved the whole contact moves the plant, by its mean
    offset (gaps ignored); the callers keep its horizontal part, and only
    when the plants are to move (``move_plants``).
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


def marker_layer(
    doc: Document, pts: np.ndarray, t: np.ndarray, blend: float, same_rate: bool, move_plants: bool = False
) -> np.ndarray:
    """C3D: a disturbed constrained marker follows its captured path, blended
    in and out; shifted horizontally by the edit's mean offset over the
    constraint with ``move_plants``, or by the whole marker set's offset when
    the edits moved every marker at every frame by one same offset.

    Markers that a timing edit retimed as a chain (the document's
    ``marker_tree``, see :mod:`.ops.marker_chain`) keep their segments: the
    marker's parent is moved by two-bone IK on points (grandparent fixed,
    both segment lengths kept, the middle marker on its side of the limb),
    or, where the parent is planted too or has no parent, the marker turns
    about its parent towards its plant; the markers below it move along.
    """
    src = doc.source
    size = src.figure_height()
    tolerance = _tolerance(size, same_rate)
    labels = list(src.labels)
    up = up_direction(src.points, size)
    whole = None
    if doc.constraints:
        # the whole set moved by one offset: the mean over markers, at every frame
        with np.errstate(invalid="ignore"):
            d = pts - at_times(src.points, doc.frame_time, t)
            seen = np.all(np.isfinite(d), axis=2)
            if seen.any() and np.all(np.abs(d[seen] - d[seen].mean(axis=0)).max(axis=0) <= 0.1 * tolerance):
                whole = _whole_shift(d[seen].mean(axis=0)[None], np.zeros((1, 3)), tolerance)
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
        shift = np.zeros(3) if c.pin else _plant_shift(whole, move_plants, pts[seen, m], path[seen], tolerance)
        target = path + _horizontal(shift, up)
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
