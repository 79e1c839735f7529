"""Temporal editing (paper section 5.2): refinements, succession, random offsets.

Changing a refinement follows the paper's Figure 6c: the pose's knots of the
variable (editing and extreme) move together by the change, which warps the
motion between the neighbouring knots with its detail in normalized time;
then the editing knot returns to ``t_k`` with the value the warped motion has
there, and the displacement maps are measured again so that nothing else
changes.
"""

from __future__ import annotations

import numpy as np

from ..errors import KnotOrderError, UsageError, arg, warn
from ..model.document import Document, check_pose_index, check_pose_move, check_time_range
from ..model.evaluate import evaluate_at
from ..model.fit import knots_from_poses
from ..model.kinds import ROTATION, TRANSLATION
from ..model.knots import Track, pose_arrays
from ..model.restructure import restructure, with_knot_times
from ..model.timewarp import warp
from ..signals.probability import reprioritized
from . import marker_chain
from .edit_pose import joint_mask

MAX_POWER = 10.0  # depth**power beyond this is no longer a succession pattern
_MARGIN_FRAMES = 0.5  # clamped knots keep at least this many frames from a neighbouring knot


def _longest_shift(doc: Document) -> float:
    """The largest timing change an option may ask for: the clip's length
    (at least a second, so that short clips accept ordinary values)."""
    return max(doc.duration, 1.0)


def select_poses(
    doc: Document, poses: list[int] | None = None, time_range: tuple[float, float] | None = None, interior: bool = True
) -> np.ndarray:
    """Boolean mask (K,) of the poses an edit applies to.

    ``poses`` are indices as ``info`` reports them; ``time_range`` keeps poses
    with ``a <= t_k <= b`` seconds; both None selects all.  With ``interior``
    the first and last pose are left out (they pin the clip's ends).
    """
    K = doc.n_poses
    mask = np.ones(K, dtype=bool)
    if poses is not None:
        mask[:] = False
        for k in poses:
            mask[check_pose_index(doc, k)] = True
    if time_range is not None:
        a, b = check_time_range(doc, time_range)
        mask &= (doc.pose_t >= a - 1e-9) & (doc.pose_t <= b + 1e-9)
    if interior and K:
        ends = poses is not None and (mask[0] or mask[-1])
        mask[0] = mask[-1] = False
        if not mask.any():
            # one line saying the edit changes nothing, rather than silence
            if K <= 2:
                warn(
                    "the document has only its first and last pose, which pin the clip's ends: "
                    "nothing to retime (add poses with `cull --add-time T`)"
                )
            else:
                warn("no inner pose is selected (the first and last pin the clip's ends): nothing to retime")
        elif ends:
            warn("the first and last pose pin the clip's ends: their timing is left alone")
    return mask


def change_refinements(
    doc: Document, delta: np.ndarray, *, clamp: bool = False, marker_parents: np.ndarray | None = None
) -> Document:
    """Add ``delta`` (K, V) seconds to the refinements, keeping the knots in order.

    A knot that would cross a neighbouring knot raises KnotOrderError, or
    with ``clamp`` stops half a frame short of it.  Knots that end closer
    to a neighbouring pose than to their own are warned about in one line
    (logging): how many, and the largest.
    Contact constraints move with the timing of the joint that carries them
    (see :func:`_warp_constraints`).  In a C3D document ``marker_parents``
    (M,) (-1: none) retimes markers as a kinematic chain or tree: each
    marker's offset from its parent is what is retimed (see
    :mod:`.marker_chain`).
    """
    delta = np.asarray(delta, dtype=float)
    if delta.shape != (doc.n_poses, len(doc.variable_names)):
        raise ValueError(f"delta must have shape {(doc.n_poses, len(doc.variable_names))}, got {delta.shape}")
    if not np.all(np.isfinite(delta)):
        raise UsageError("timing offsets must be finite")
    tracks, warps, col, far = [], {}, 0, []
    for tr, owns in zip(doc.tracks, doc.track_owns(), strict=True):
        # a variable that never moves has no timing: retiming it could only be
        # refused; a partial pose has no knot (no refinement) outside its part
        d = delta[:, col : col + tr.n_vars] * ~static_variables(tr)[None, :] * owns
        col += tr.n_vars
        if not np.any(d != 0.0):
            tracks.append(tr)
            continue
        tree = marker_parents is not None and doc.kind == "c3d" and bool(np.any(marker_parents >= 0))
        if tree:
            seen = np.all(np.isfinite(doc.source.points), axis=2)
            tr = marker_chain.recomposed(tr, marker_parents, doc.frame_times, to_offsets=True, seen=seen)
        track, old_ext, new_ext = _retime_track(doc, tr, d, clamp, owns)
        far += _far_knots(doc, tr, old_ext - doc.pose_t[:, None], new_ext - doc.pose_t[:, None])
        if tree:
            track = marker_chain.recomposed(track, marker_parents, doc.frame_times, to_offsets=False)
        tracks.append(track)
        for i in np.flatnonzero(np.any(old_ext != new_ext, axis=0)):
            own = owns[:, i]
            warps[(tr.kind, int(tr.targets[i]))] = (old_ext[own, i], new_ext[own, i])
    if far:
        r, k, name = max(far, key=lambda x: (abs(x[0]), -x[1]))
        many = len(far) > 1
        warn(
            "%d extreme knot%s closer to a neighbouring pose than to %s own (the largest: %s of pose %d, "
            "%s): the time warp there is steep",
            len(far),
            "s now lie" if many else " now lies",
            "their" if many else "its",
            name,
            k,
            doc.seconds(r, sign=True),
        )
    changes = {}
    if marker_parents is not None and doc.kind == "c3d" and bool(np.any(marker_parents >= 0)):
        changes["parameters"] = marker_chain.with_marker_tree(doc.parameters, doc.target_names, marker_parents)
    return doc.with_tracks(tuple(tracks), constraints=_warp_constraints(doc, warps), **changes)


def static_variables(tr: Track, tolerance: float = 1e-9) -> np.ndarray:
    """Mask (V,) of the variables that never move: all knot values equal and
    no displacement (e.g. Bandai's constant position channels on every joint)."""
    var = tr.knots.var
    owner = tr.base.samp_var
    first = tr.knot_v[tr.knot_ptr[:-1]]
    if tr.kind == ROTATION:
        knot_dev = 1.0 - np.abs(np.sum(tr.knot_v * first[var], axis=1))
        disp = 1.0 - np.abs(tr.samp_d[:, 0])
    else:
        knot_dev = np.max(np.abs(tr.knot_v - first[var]), axis=1)
        disp = np.max(np.abs(tr.samp_d), axis=1) if len(tr.samp_d) else np.zeros(0)
    moving = np.zeros(tr.n_vars, dtype=bool)
    moving[var[knot_dev > tolerance]] = True
    moving[owner[disp > tolerance]] = True
    return ~moving


def _warp_constraints(doc: Document, warps: dict) -> tuple:
    """Constraints moved with the retimed motion.

    A BVH contact on a joint follows the time warp of its nearest ancestor
    whose rotation was retimed (a foot's plant moves with its knee); a C3D
    marker's follows its own.  Others stay.
    """
    if not warps:
        return doc.constraints
    out = []
    for c in doc.constraints:
        warp = None
        if doc.kind == "bvh":
            sk = doc.source.skeleton
            j = sk.parents[sk.names.index(c.joint)] if c.joint in sk.names else -1
            while j >= 0 and warp is None:
                warp = warps.get((ROTATION, int(j)))
                j = sk.parents[j]
        elif c.joint in doc.source.labels:
            warp = warps.get((TRANSLATION, doc.source.labels.index(c.joint)))
        out.append(c if warp is None else c.warped(*warp))
    return tuple(out)


def _retime_track(
    doc: Document, tr: Track, delta: np.ndarray, clamp: bool, owns: np.ndarray | None = None
) -> tuple[Track, np.ndarray, np.ndarray]:
    """New refinements ``r + delta`` for one track (see :func:`change_refinements`).

    The motion is first warped in time, per variable, by the piecewise-linear
    map that takes each pose's old extreme knot time to its new one (the
    first and last poses stay put); every other knot, editing knots included,
    moves with the warp, so knot order is kept by construction and the detail
    near an extreme moves with it.  Then the editing knots return to ``t_k``
    with the value the warped motion has there (paper Figure 6c) and the
    displacement maps are measured again from the warped motion.

    ``owns`` (K, V): the variables each pose has knots in (partial poses;
    None: all); a pose's refinements elsewhere are 0 and stay so.

    Returns the track and the old and new extreme knot times (K, V) (the
    pose time where a pose has no knot).
    """
    K = doc.n_poses
    owns = np.ones((K, tr.n_vars), dtype=bool) if owns is None else np.asarray(owns, dtype=bool)
    ext_t, value, edit = pose_arrays(tr, K)
    refine = np.where(owns, ext_t - doc.pose_t[:, None], 0.0)
    new_refine = refine + np.where(owns, delta, 0.0)
    if clamp:
        new_refine = _clamped(doc.pose_t, refine, new_refine, _MARGIN_FRAMES * doc.frame_time, owns)
    new_refine[np.abs(new_refine) < 1e-12] = 0.0
    _check_final_order(doc, tr, new_refine, owns)
    old_ext = doc.pose_t[:, None] + refine
    new_ext = doc.pose_t[:, None] + new_refine
    warped_t = tr.knot_t.copy()
    for i in range(tr.n_vars):
        sl = tr.knot_slice(i)
        own = owns[:, i]
        warped_t[sl] = warp(tr.knot_t[sl], old_ext[own, i], new_ext[own, i])
    warped = with_knot_times(tr, warped_t, frame_time=doc.frame_time)
    # editing knots are measured again where a variable's timing changed; the
    # others keep their values to the bit, so that their segments are not refitted
    moved = np.any(new_refine != refine, axis=0)
    kk, ii = np.nonzero((new_refine != 0.0) & moved[None, :] & owns)
    edit = np.where((new_refine != 0.0)[..., None], edit, value)
    if len(kk):
        edit[kk, ii] = evaluate_at(warped, ii, doc.pose_t[kk], depth=1)
    knots = knots_from_poses(doc.pose_t, new_refine, value, edit, tr.names, owns=owns)
    return restructure(warped, knots, frame_t=doc.frame_times), old_ext, new_ext


def _previous_owner(owns: np.ndarray) -> np.ndarray:
    """(K, V) index of the last pose before ``k`` that owns variable ``i``
    (-1 for none)."""
    K = owns.shape[0]
    idx = np.where(owns, np.arange(K)[:, None], -1)
    last = np.maximum.accumulate(idx, axis=0)
    return np.concatenate([np.full((1, owns.shape[1]), -1), last[:-1]], axis=0)


def _check_final_order(doc: Document, tr: Track, refine: np.ndarray, owns: np.ndarray | None = None) -> None:
    """Refuse refinements whose knots would cross (SPEC invariant 3): each
    pose's knots against those of the previous pose with knots in the same
    variable."""
    t = doc.pose_t[:, None]
    lo = np.minimum(t, t + refine)  # (K, V): first knot of each pose
    hi = np.maximum(t, t + refine)
    if owns is None or owns.all():
        bad = lo[1:] <= hi[:-1]
        prev = np.broadcast_to(np.arange(len(t) - 1)[:, None], bad.shape)
    else:
        before = _previous_owner(owns)[1:]
        cols = np.broadcast_to(np.arange(refine.shape[1]), before.shape)
        bad = owns[1:] & (before >= 0) & (lo[1:] <= hi[np.maximum(before, 0), cols])
        prev = before
    if np.any(bad):
        k1, i = (int(x[0]) for x in np.nonzero(bad))
        k, k2 = int(prev[k1, i]), k1 + 1
        raise KnotOrderError(
            f"the knots of {tr.names[i]!r} would cross between poses {k} and {k2} "
            f"({doc.seconds(doc.pose_t[k])} and {doc.seconds(doc.pose_t[k2])}): the timing change is too large "
            f"(use {arg('clamp')} to stop short)"
        )


def _clamped(
    pose_t: np.ndarray, current: np.ndarray, wanted: np.ndarray, margin: float, owns: np.ndarray | None = None
) -> np.ndarray:
    """Refinements as close to ``wanted`` as the knot order allows.

    Left to right, each pose's knots stay ``margin`` seconds clear of the
    previous pose's (as already clamped) and of the next pose's as they are
    now, so no pose moves that was not asked to, and the current refinement
    is always allowed.  An extreme knot may pass its own pose time: the
    editing knot simply ends on its other side.  With ``owns`` (K, V) (partial
    poses) a pose's neighbours in a variable are the nearest poses with knots
    in it, and a pose without knots there keeps its 0.
    """
    out = current.copy()
    K = len(pose_t)
    if owns is not None and not owns.all():
        t = pose_t[:, None]
        lo_now = np.where(owns, np.minimum(t, t + current), np.inf)
        next_lo = np.minimum.accumulate(lo_now[::-1], axis=0)[::-1]  # the nearest owner's at or after k
        prev_hi = np.maximum(pose_t[0], pose_t[0] + out[0])  # the first pose owns every variable
        for k in range(1, K - 1):
            lo = np.minimum(prev_hi + margin - pose_t[k], current[k])
            hi = np.maximum(next_lo[k + 1] - margin - pose_t[k], current[k])
            out[k] = np.where(owns[k], np.clip(wanted[k], lo, hi), current[k])
            prev_hi = np.where(owns[k], np.maximum(pose_t[k], pose_t[k] + out[k]), prev_hi)
        return out
    for k in range(1, K - 1):
        prev_hi = np.maximum(pose_t[k - 1], pose_t[k - 1] + out[k - 1])
        next_lo = np.minimum(pose_t[k + 1], pose_t[k + 1] + current[k + 1])
        lo = np.minimum(prev_hi + margin - pose_t[k], current[k])
        hi = np.maximum(next_lo - margin - pose_t[k], current[k])
        out[k] = np.clip(wanted[k], lo, hi)
    return out


def _far_knots(doc: Document, tr: Track, before: np.ndarray, refine: np.ndarray) -> list[tuple[float, int, str]]:
    """(refinement, pose, variable) of the extreme knots an edit left closer
    to a neighbouring pose than to their own (the paper's warning; knots that
    were already there are not counted again)."""
    t = doc.pose_t
    gap_prev = np.concatenate([[np.inf], np.diff(t)])
    gap_next = np.concatenate([np.diff(t), [np.inf]])
    far = ((refine > 0) & (refine > gap_next[:, None] / 2)) | ((refine < 0) & (-refine > gap_prev[:, None] / 2))
    far &= refine != before
    return [(float(refine[k, i]), int(k), tr.names[i]) for k, i in zip(*np.nonzero(far), strict=True)]


def succession(
    doc: Document,
    offset: float,
    power: float,
    *,
    joint: str | None = None,
    chain: list[str] | None = None,
    poses: np.ndarray | None = None,
    clamp: bool = False,
) -> Document:
    """Nonlinear succession: ``r[k,i] += offset · d(i) ** power``.

    ``d(i)`` is the depth of the variable's joint below ``joint`` (0 at the
    joint; joints outside its subtree are untouched), or the position in an
    explicit ``chain`` of markers/joints (C3D documents have no hierarchy).
    ``poses`` is a (K,) mask; interior poses by default.
    """
    if not np.isfinite(offset):
        raise UsageError(f"{arg('offset')} must be a finite number of seconds")
    if not np.isfinite(power) or not 0 < power <= MAX_POWER:
        raise UsageError(f"{arg('power')} must be a positive number up to {MAX_POWER}, got {power}")
    if abs(offset) > _longest_shift(doc):
        raise UsageError(
            f"{arg('offset')} must not exceed {doc.seconds(_longest_shift(doc))} (the clip's length), got {offset:g}"
        )
    depth = _depths(doc, joint, chain)
    if poses is None:
        poses = select_poses(doc)
    with np.errstate(over="ignore", invalid="ignore"):
        step = np.where(depth > 0, offset * np.abs(depth.astype(float)) ** power, 0.0)
    if not np.all(np.isfinite(step)) or np.abs(step).max(initial=0.0) > _longest_shift(doc):
        raise UsageError(
            f"{arg('offset')} {offset:g} with {arg('power')} {power:g} shifts knots beyond the clip's length"
        )
    if not np.any(step) and poses.any():
        # one line saying the edit changes nothing, rather than silence
        if offset == 0.0:
            warn(f"{arg('offset')} 0: nothing to retime")
        elif chain:
            warn(
                f"{arg('chain')} %s: the first of a chain keeps its timing%s: nothing to retime "
                "(give two or more markers or joints, in order)",
                ",".join(chain),
                "" if len(chain) == 1 else " and the others have no variables",
            )
        else:
            warn(
                f"{arg('joint')} %s: no joint below it has a variable (the joint itself keeps its timing): "
                "nothing to retime (start higher up the limb)",
                joint,
            )
    delta = poses[:, None] * step[None, :]
    parents = None
    if doc.kind == "c3d" and chain:
        parents = marker_chain.chain_parents(len(doc.target_names), [doc.target_index(n) for n in chain])
    return change_refinements(doc, delta, clamp=clamp, marker_parents=parents)


def _depths(doc: Document, joint: str | None, chain: list[str] | None) -> np.ndarray:
    """Depth (V,) of every variable, -1 for variables left alone."""
    V = len(doc.variable_names)
    targets = np.concatenate([tr.targets for tr in doc.tracks])
    if chain:
        depth_of = {}
        for d, name in enumerate(chain):
            if name in chain[:d]:
                raise UsageError(f"{name!r} appears twice in {arg('chain')}")
            try:
                depth_of[doc.target_index(name)] = d
            except UsageError as err:
                raise UsageError(f"{arg('chain')}: {err.message}") from None
        return np.array([depth_of.get(int(t), -1) for t in targets], dtype=int)
    if joint is None:
        raise UsageError(f"succession needs {arg('joint')} (or {arg('chain')} for C3D documents)")
    if doc.kind != "bvh":
        raise UsageError(f"C3D documents have no hierarchy: give the markers in order with {arg('chain')} M1,M2,M3")
    sk = doc.source.skeleton
    depth = sk.depth_below(sk.index(joint))
    return depth[targets] if V else np.zeros(0, dtype=int)


def randomize(
    doc: Document,
    tau: float,
    seed: int,
    *,
    joints: list[str] | None = None,
    subtree: bool = False,
    poses: np.ndarray | None = None,
    clamp: bool = False,
) -> Document:
    """Random offsets: ``r[k,i] += uniform(-tau, tau)`` for the chosen joints
    (all by default; with ``subtree`` their descendants too), reproducible by
    ``seed``.  C3D markers are retimed as a kinematic chain: the markers of
    ``joints`` in the order given, or all markers joined by
    :func:`.marker_chain.rigid_tree`."""
    tau = float(tau) + 0.0  # -0.0 -> 0.0: uniform(0, -0.0) is refused
    if not np.isfinite(tau) or tau < 0 or tau > _longest_shift(doc):
        raise UsageError(
            f"{arg('tau')} must be between 0 and {doc.seconds(_longest_shift(doc))} (the clip's length), got {tau:g}"
        )
    mask = np.concatenate(joint_mask(doc, joints, subtree))  # the same partial poses as edit-pose
    if poses is None:
        poses = select_poses(doc)
    rng = np.random.default_rng(seed)
    noise = rng.uniform(-tau, tau, size=(doc.n_poses, len(doc.variable_names)))
    delta = noise * poses[:, None] * mask[None, :]
    parents = None
    if doc.kind == "c3d":
        names = doc.target_names
        parents = (
            marker_chain.chain_parents(len(names), list(dict.fromkeys(names.index(n) for n in joints)))
            if joints
            else marker_chain.rigid_tree(doc.source.points)
        )
    return change_refinements(doc, delta, clamp=clamp, marker_parents=parents)


def retime_pose(doc: Document, k: int, new_time: float) -> Document:
    """Move pose ``k`` as a unit to ``new_time`` seconds (paper 5.2): its
    knots keep their refinements; splines and displacement maps follow in
    normalized time."""
    check_pose_move(doc, k, new_time)
    dt = new_time - doc.pose_t[k]
    tracks = []
    for tr in doc.tracks:
        kt = np.where(tr.knot_pose == k, tr.knot_t + dt, tr.knot_t)
        try:
            tracks.append(with_knot_times(tr, kt, frame_time=doc.frame_time))
        except KnotOrderError as exc:
            raise KnotOrderError(f"moving pose {k} to {doc.seconds(new_time)}: {exc.message}") from None
    pose_t = doc.pose_t.copy()
    pose_t[k] = new_time
    constraints = tuple(c.warped(doc.pose_t, pose_t) for c in doc.constraints)
    return reprioritized(doc.with_tracks(tuple(tracks), pose_t=pose_t, constraints=constraints))
