"""Temporal editing (paper section 5.2): refinements, succession, random offsets.

Changing a refinement follows the paper's Figure 6c: the pose's knots of the
variable (editing and extreme) move together by the change, which warps the
motion between the neighbouring knots with its detail in normalized time;
then the editing knot returns to ``t_k`` with the value the warped motion has
there, and the displacement maps are measured again so that nothing else
changes.
"""

from __future__ import annotations

import logging

import numpy as np

from ..document import Document
from ..errors import KnotOrderError, UsageError
from ..representation import Track, evaluate_at, knots_from_poses, pose_arrays, restructure, with_knot_times

log = logging.getLogger(__name__)

_MARGIN_FRAMES = 0.5  # clamped knots keep at least this many frames from a neighbouring knot


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
            if not -K <= k < K:
                raise UsageError(f"pose {k} is out of range (the document has poses 0 to {K - 1})")
            mask[k % K] = True
    if time_range is not None:
        a, b = time_range
        if not (np.isfinite(a) and np.isfinite(b)) or a > b:
            raise UsageError(f"--time must be A:B with A <= B, got {a}:{b}")
        if b < 0 or a > doc.duration + 1e-9:
            raise UsageError(f"--time {a}:{b} lies outside the clip (0 to {doc.duration:.4f} s)")
        mask &= (doc.pose_t >= a - 1e-9) & (doc.pose_t <= b + 1e-9)
    if interior and K:
        mask[0] = mask[-1] = False
    return mask


def change_refinements(doc: Document, delta: np.ndarray, *, clamp: bool = False) -> Document:
    """Add ``delta`` (K, V) seconds to the refinements, keeping the knots in order.

    A knot that would cross a neighbouring knot raises KnotOrderError, or
    with ``clamp`` stops half a frame short of it.  A knot that ends closer
    to a neighbouring pose than to its own is warned about (logging).
    """
    delta = np.asarray(delta, dtype=float)
    if delta.shape != (doc.n_poses, len(doc.variable_names)):
        raise ValueError(f"delta must have shape {(doc.n_poses, len(doc.variable_names))}, got {delta.shape}")
    if not np.all(np.isfinite(delta)):
        raise UsageError("timing offsets must be finite")
    tracks, col = [], 0
    for tr in doc.tracks:
        d = delta[:, col : col + tr.n_vars]
        col += tr.n_vars
        tracks.append(_retime_track(doc, tr, d, clamp) if np.any(d != 0.0) else tr)
    return doc.with_tracks(tuple(tracks))


def _retime_track(doc: Document, tr: Track, delta: np.ndarray, clamp: bool) -> Track:
    K = doc.n_poses
    ft = doc.frame_time
    var = np.repeat(np.arange(tr.n_vars), np.diff(tr.knot_ptr))
    shift = delta[tr.knot_pose, var]  # per knot: both knots of a (pose, variable) move together
    ext_t, value, _ = pose_arrays(tr, K)
    refine = ext_t - doc.pose_t[:, None]
    if clamp:
        shift = _clamped_shift(tr, refine, shift, doc.pose_t, var, ft)
    moved = tr.knot_t + shift
    try:
        warped = with_knot_times(tr, moved)
    except KnotOrderError as exc:
        raise KnotOrderError(
            f"{exc}: the timing change is too large for the neighbouring knots (use --clamp to stop short)"
        ) from None
    new_refine = refine + _per_pose(tr, shift, K)
    new_refine[np.abs(new_refine) < 1e-12] = 0.0
    # the editing knots go back to t_k with the value the warped motion has there
    Kk, V = new_refine.shape
    kk, ii = np.nonzero(new_refine != 0.0)
    edit = value.copy()
    if len(kk):
        edit[kk, ii] = evaluate_at(warped, ii, doc.pose_t[kk])
    knots = knots_from_poses(doc.pose_t, new_refine, value, edit)
    _warn_far_knots(doc, tr, new_refine)
    try:
        return restructure(warped, *knots)
    except KnotOrderError as exc:
        raise KnotOrderError(
            f"{exc}: the new refinement would cross the pose's own editing knot or a neighbour (use --clamp)"
        ) from None


def _per_pose(tr: Track, shift: np.ndarray, K: int) -> np.ndarray:
    out = np.zeros((K, tr.n_vars))
    var = np.repeat(np.arange(tr.n_vars), np.diff(tr.knot_ptr))
    ext = ~tr.knot_editing
    out[tr.knot_pose[ext], var[ext]] = shift[ext]
    return out


def _clamped_shift(
    tr: Track, refine: np.ndarray, shift: np.ndarray, pose_t: np.ndarray, var: np.ndarray, ft: float
) -> np.ndarray:
    """Shrink each (pose, variable) shift so its knots stay inside the gap
    between the neighbouring poses' knots, and so the extreme knot does not
    cross ``t_k`` (where the editing knot returns)."""
    margin = _MARGIN_FRAMES * ft
    out = shift.copy()
    kt = tr.knot_t
    for i in range(tr.n_vars):
        sl = tr.knots(i)
        t = kt[sl]
        p = tr.knot_pose[sl]
        s = out[sl]
        poses = np.unique(p)
        for k in poses:
            own = np.flatnonzero(p == k)
            lo_t = t[own[0] - 1] + margin if own[0] > 0 else -np.inf
            hi_t = t[own[-1] + 1] - margin if own[-1] + 1 < len(t) else np.inf
            sk = s[own[0]]
            sk = min(max(sk, lo_t - t[own[0]]), hi_t - t[own[-1]])
            # the extreme knot must stay on its side of t_k or land on it, never swap
            r = refine[k, i]
            if r != 0.0 and np.sign(r + sk) == -np.sign(r):
                sk = -r
            s[own] = sk
        out[sl] = s
    return out


def _warn_far_knots(doc: Document, tr: Track, refine: np.ndarray) -> None:
    t = doc.pose_t
    gap_prev = np.concatenate([[np.inf], np.diff(t)])
    gap_next = np.concatenate([np.diff(t), [np.inf]])
    far = ((refine > 0) & (refine > gap_next[:, None] / 2)) | ((refine < 0) & (-refine > gap_prev[:, None] / 2))
    for k in np.flatnonzero(far.any(axis=1)):
        which = ", ".join(f"{tr.names[i]} {refine[k, i]:+.3f} s" for i in np.flatnonzero(far[k]))
        log.warning("pose %d: extreme knots closer to a neighbouring pose than to their own: %s", k, which)


def variables_of_joints(doc: Document, joints: np.ndarray) -> np.ndarray:
    """Boolean mask (V,) of the variables that drive any of ``joints`` (indices)."""
    targets = np.concatenate([tr.targets for tr in doc.tracks]) if doc.tracks else np.zeros(0, dtype=int)
    return np.isin(targets, joints)


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
        raise UsageError("--offset must be a finite number of seconds")
    if not np.isfinite(power) or power <= 0:
        raise UsageError(f"--power must be a positive number, got {power}")
    depth = _depths(doc, joint, chain)
    if poses is None:
        poses = select_poses(doc)
    step = np.where(depth > 0, offset * np.abs(depth.astype(float)) ** power, 0.0)
    delta = poses[:, None] * step[None, :]
    return change_refinements(doc, delta, clamp=clamp)


def _depths(doc: Document, joint: str | None, chain: list[str] | None) -> np.ndarray:
    """Depth (V,) of every variable, -1 for variables left alone."""
    V = len(doc.variable_names)
    targets = np.concatenate([tr.targets for tr in doc.tracks])
    if chain:
        names = _target_names(doc)
        depth_of = {}
        for d, name in enumerate(chain):
            if name not in names:
                raise UsageError(f"unknown joint or marker {name!r} in --chain")
            depth_of[names.index(name)] = d
        return np.array([depth_of.get(int(t), -1) for t in targets], dtype=int)
    if joint is None:
        raise UsageError("succession needs --joint (or --chain for C3D documents)")
    if doc.kind != "bvh":
        raise UsageError("C3D documents have no hierarchy: give the markers in order with --chain M1,M2,M3")
    sk = doc.source.skeleton
    depth = sk.depth_below(sk.index(joint))
    return depth[targets] if V else np.zeros(0, dtype=int)


def _target_names(doc: Document) -> list[str]:
    src = doc.source
    return list(src.skeleton.names) if doc.kind == "bvh" else list(src.labels)


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
    ``seed``."""
    if not np.isfinite(tau) or tau < 0:
        raise UsageError(f"--tau must be a non-negative number of seconds, got {tau}")
    names = _target_names(doc)
    if joints:
        chosen = []
        for name in joints:
            if name not in names:
                raise UsageError(f"unknown joint or marker {name!r}")
            j = names.index(name)
            chosen.extend(doc.source.skeleton.subtree(j).tolist() if subtree and doc.kind == "bvh" else [j])
        mask = variables_of_joints(doc, np.array(chosen))
    else:
        mask = np.ones(len(doc.variable_names), dtype=bool)
    if poses is None:
        poses = select_poses(doc)
    rng = np.random.default_rng(seed)
    noise = rng.uniform(-tau, tau, size=(doc.n_poses, len(doc.variable_names)))
    delta = noise * poses[:, None] * mask[None, :]
    return change_refinements(doc, delta, clamp=clamp)


def retime_pose(doc: Document, k: int, new_time: float) -> Document:
    """Move pose ``k`` as a unit to ``new_time`` seconds (paper 5.2): its
    knots keep their refinements; splines and displacement maps follow in
    normalized time."""
    K = doc.n_poses
    if k in (0, K - 1):
        raise UsageError("the first and last pose pin the clip's ends and cannot be retimed")
    if not np.isfinite(new_time) or not doc.pose_t[k - 1] < new_time < doc.pose_t[k + 1]:
        lo, hi = doc.pose_t[k - 1], doc.pose_t[k + 1]
        raise UsageError(f"pose {k} can move only between its neighbours ({lo:.4f} s and {hi:.4f} s), got {new_time}")
    dt = new_time - doc.pose_t[k]
    tracks = []
    for tr in doc.tracks:
        kt = np.where(tr.knot_pose == k, tr.knot_t + dt, tr.knot_t)
        try:
            tracks.append(with_knot_times(tr, kt))
        except KnotOrderError as exc:
            raise KnotOrderError(f"moving pose {k} to {new_time:.4f} s: {exc}") from None
    pose_t = doc.pose_t.copy()
    pose_t[k] = new_time
    return doc.with_tracks(tuple(tracks), pose_t=pose_t)
