"""Motion trails and their scaled curvature: the local evidence for staggered poses (paper 4.1, SPEC 4).

Local evidence
    Every control variable gets one or more *motion trails*, curves of
    points ``(T, 3)`` over the frames:

    * a rotation variable (joint ``j``): for each child joint and End Site
      of ``j``, ``m1`` = the unit axis toward it rotated by ``j``'s *local*
      rotation, and ``m2`` = a unit axis orthogonal to that limb rotated the
      same way (it sees twist about the limb).  A child at zero distance
      (CMU's ``LHipJoint`` sits on ``Hips``) is replaced by the first
      descendant at a nonzero rest distance; a joint with no tip at all uses
      its own bone direction;
    * a BVH translation variable: the joint's local translation (for the
      root, its position);
    * a C3D marker: its trajectory.

    The *scaled curvature* of a trail at a sample is ``κ = n · e / |e|``
    with ``n`` the discrete Frenet normal (the bisector of the turn) and
    ``e`` each adjacent edge pointing away from the sample, averaged over the
    two edges weighted by their lengths: the sine of half the turning angle,
    in [0, 1].  A sample with a zero-length (or invalid) adjacent edge
    scores 0.  Edges join samples :data:`CURVATURE_EDGE` seconds apart (one
    frame at 30 Hz, four at 120 Hz), so that a turn scores the same at every
    frame rate.  Per variable ``p_i = max`` over its trails, then iterated
    Laplacian smoothing.

Weights (``w_i``, file units: how far the variable moves things)
    Rotation: ``Σ_j |x_i - x_j| · arclength(m_j)`` over the variable's limbs,
    with the rest length of the limb and, for each limb, the longer of its
    two trails (so that pure twist counts).  ``limb length × angle`` is the
    distance the limb's end travels relative to the joint.
    Translation (root, C3D marker): the arc length of the trail itself, the
    same quantity, the distance travelled: with the figure height ``h`` this
    is ``(arclength / h) · h``, a travel relative to the figure times a limb
    scale of one figure height, so units cancel against the rotation
    weights and it does not depend on the file's units.  (A walk's root
    weighs about as much as one leg joint.)  Arc lengths are measured
    along the same fixed-duration edges as the curvature, so that sampling
    noise does not make them grow with the frame rate.

Amount of motion
    ``speed`` (T,): the rate at which the weights accumulate, summed over
    the variables and divided by the figure height (figure heights per
    second).  It is what the significance gate of
    :mod:`staggered_cli.ops.extract` looks at.

Discontinuities
    An edge between two frames where any rotation variable turns by more
    than :data:`JUMP_DEGREES` (CMU's T-pose first frame), or any position
    trail moves by more than :data:`JUMP_FIGURE_HEIGHTS` of the figure, is a
    *break*: no trail edge crosses it (no curvature, no arc length, no
    speed) and smoothing does not diffuse across it.  C3D samples in a gap
    are not used either (the filled values are straight lines).

Smoothing (:mod:`.smoothing`) is in seconds, the same at every frame rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import quat
from ..model.kinds import ROTATION
from ..model.variables import dense_variables
from ..motion import BvhMotion, MarkerMotion
from ..skeleton import Skeleton
from .smoothing import DEFAULT_SMOOTHING, laplacian_smooth

#: A rotation step larger than this between two frames is a discontinuity of
#: that variable (degrees): no joint turns 100° in one frame, even at 30 Hz.
JUMP_DEGREES = 100.0
#: A whole-pose jump (CMU's T-pose first frame, whose largest step can be
#: under 100°): at least this share of the moving rotation variables ...
POSE_JUMP_SHARE = 0.25
#: ... each turn by more than this (degrees) and by more than ten times
#: their own median step.
POSE_JUMP_DEGREES = 10.0
#: A position step larger than this fraction of the figure height between two
#: frames is a discontinuity (no body part moves a quarter of its height in 4 ms-33 ms).
JUMP_FIGURE_HEIGHTS = 0.25
#: Duration of a curvature edge, seconds: at 30 Hz one frame, at 120 Hz four.
#: The turning angle between edges of a fixed duration measures the same turn
#: at every frame rate (one-frame edges turn four times less at 120 Hz, and
#: their directions are noisier), so 30 Hz and 120 Hz captures agree.
CURVATURE_EDGE = 1.0 / 30.0
_ZERO_EDGE = 1e-12  # relative to the trail's scale: an edge this short has no direction


@dataclass(frozen=True)
class LocalEvidence:
    """Per-variable evidence of a clip.

    Attributes
    ----------
    names : (V,) variable names in the document's global order
        (translations first, then rotations).
    p : (T, V) smoothed local evidence, in [0, 1].
    weights : (V,) variable weights, file units.
    speed : (T,) amount of motion: ``Σ_i`` (rate of change of ``w_i``) per
        frame, in figure heights per second (0 across breaks).
    breaks : (T-1,) bool, edges between frames that are discontinuities.
    rate : frames per second.
    figure_height : file units.
    """

    names: tuple[str, ...]
    p: np.ndarray
    weights: np.ndarray
    speed: np.ndarray
    breaks: np.ndarray
    rate: float
    figure_height: float


def scaled_curvature(
    trail: np.ndarray, valid: np.ndarray | None = None, scale: float = 1.0, span: int = 1
) -> np.ndarray:
    """Scaled curvature ``κ = n · e / |e|`` of trails, in [0, 1].

    Parameters
    ----------
    trail : (T, n, 3) points of ``n`` trails over ``T`` frames.
    valid : (T-1, n) bool or None, which one-frame edges may be used.
    scale : an edge shorter than ``1e-12 · scale`` counts as zero length.
    span : frames per edge: the sample at frame ``f`` is joined to those at
        ``f - span`` and ``f + span`` (an edge is valid when all the one-frame
        edges it covers are).

    Returns
    -------
    (T, n), zero within ``span`` frames of the ends and wherever an adjacent
    edge is invalid or of zero length.
    """
    trail = np.asarray(trail, dtype=float)
    T = trail.shape[0]
    span = max(int(span), 1)
    out = np.zeros(trail.shape[:2])
    if T < 2 * span + 1:
        return out
    e = trail[span:] - trail[:-span]  # (T-span, n, 3): edge from f to f+span
    length = quat.norm(e)
    ok = length > _ZERO_EDGE * scale
    if valid is not None:
        bad = np.cumsum(np.concatenate([np.zeros((1,) + valid.shape[1:]), ~valid]), axis=0)
        ok &= (bad[span:] - bad[:-span]) == 0
    unit = e / np.where(ok, length, 1.0)[..., None]
    prev, nxt = unit[:-span], unit[span:]  # edges before and after each interior sample
    turn = nxt - prev
    tlen = quat.norm(turn)
    n = turn / np.where(tlen > 0, tlen, 1.0)[..., None]
    # both edges point away from the sample: -prev and nxt
    k_prev = quat.dot(n, -prev)
    k_next = quat.dot(n, nxt)
    lp, ln = length[:-span], length[span:]
    good = ok[:-span] & ok[span:] & (tlen > 0)
    k = (lp * k_prev + ln * k_next) / np.where(good, lp + ln, 1.0)
    out[span:-span] = np.where(good, np.clip(k, 0.0, 1.0), 0.0)
    return out


def edge_span(rate: float) -> int:
    """Frames per curvature edge: the nearest whole number of frames to
    :data:`CURVATURE_EDGE` seconds, at least one."""
    return max(int(round(CURVATURE_EDGE * rate)), 1)


# --- trails ---------------------------------------------------------------------


def _orthogonal(axis: np.ndarray) -> np.ndarray:
    """A unit vector orthogonal to unit ``axis`` (3,): the principal axis
    least aligned with it, made orthogonal."""
    e = np.zeros(3)
    e[int(np.argmin(np.abs(axis)))] = 1.0
    v = e - np.dot(e, axis) * axis
    return v / np.linalg.norm(v)


def limb_axes(skeleton: Skeleton, j: int, scale: float) -> list[tuple[np.ndarray, float]]:
    """Rest-pose limbs of joint ``j``: (unit axis in ``j``'s frame, length).

    Toward each child and End Site; a tip at zero distance is replaced by
    the first descendants at a nonzero rest distance (summing offsets).  A
    joint with no tip uses its own bone direction (length 0: no weight).
    """
    eps = 1e-9 * scale
    out = []
    stack = [(c, skeleton.offsets[c]) for c in skeleton.children(j)]
    stack += [(-1, o) for p, o in zip(skeleton.end_parents, skeleton.end_offsets, strict=True) if p == j]
    while stack:
        c, vec = stack.pop(0)
        n = float(np.linalg.norm(vec))
        if n > eps:
            out.append((vec / n, n))
        elif c >= 0:
            stack += [(g, vec + skeleton.offsets[g]) for g in skeleton.children(c)]
            stack += [(-1, vec + o) for p, o in zip(skeleton.end_parents, skeleton.end_offsets, strict=True) if p == c]
    if not out:
        own = skeleton.offsets[j]
        n = float(np.linalg.norm(own))
        out.append((own / n if n > eps else np.array([1.0, 0.0, 0.0]), 0.0))
    return out


def rotation_steps(rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Discontinuities of rotation tracks ``rot (T, V, 4)``.

    Returns
    -------
    breaks : (T-1,) bool, whole-pose jumps (a T-pose frame): at least
        :data:`POSE_JUMP_SHARE` of the variables that move at all turn by more
        than :data:`POSE_JUMP_DEGREES` and ten times their median step.
    jumps : (T-1, V) bool, single-variable jumps of more than
        :data:`JUMP_DEGREES` (a flipping thumb), or a whole-pose break.
    """
    T, V = rot.shape[:2]
    if T < 2 or V == 0:
        return np.zeros(max(T - 1, 0), dtype=bool), np.zeros((max(T - 1, 0), V), dtype=bool)
    step = np.empty((T - 1, V))  # (T-1, V), in blocks of frames: no (T, V, 4) temporaries
    rows = max(1, _STEP_BLOCK // V)
    for lo in range(0, T - 1, rows):
        hi = min(lo + rows, T - 1)
        step[lo:hi] = np.degrees(quat.angle_between(rot[lo:hi], rot[lo + 1 : hi + 1]))
    typical = np.median(step, axis=0)  # (V,)
    big = step > np.maximum(POSE_JUMP_DEGREES, 10.0 * typical)
    moving = int(np.count_nonzero(step.max(axis=0) > 0))
    breaks = big.sum(axis=1) >= max(2, int(np.ceil(POSE_JUMP_SHARE * moving)))
    return breaks, (step > JUMP_DEGREES) | breaks[:, None]


#: Rotations compared at once by :func:`rotation_steps`.
_STEP_BLOCK = 1 << 16


def _span_valid(valid: np.ndarray, span: int) -> np.ndarray:
    """(T-span, n) validity of edges spanning ``span`` frames from one-frame validity (T-1, n)."""
    bad = np.cumsum(np.concatenate([np.zeros((1,) + valid.shape[1:]), ~valid]), axis=0)
    return (bad[span:] - bad[:-span]) == 0


def trail_measures(
    trail: np.ndarray, valid: np.ndarray, span: int, rate: float, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Curvature, arc length and speed of trails.

    Parameters
    ----------
    trail : (T, n, 3).
    valid : (T-1, n) bool, usable one-frame edges.
    span : frames per edge (:func:`edge_span`).
    rate : frames per second.
    scale : length scale of the trail (zero-length edges).

    Returns
    -------
    kappa : (T, n) scaled curvature.
    arc : (n,) arc length along edges of ``span`` frames (divided by
        ``span``: the mean over the ``span`` interleaved polylines), so that
        sampling noise does not make it grow with the frame rate.
    speed : (T, n) trail units per second, from the same edges (0 where no
        valid edge covers a frame).
    """
    T, n = trail.shape[:2]
    width = max(2, _MEASURE_BLOCK // max(T, 1))
    if n <= width:
        return _trail_measures(trail, valid, span, rate, scale)
    # a few trails at a time (each trail is its own), at least two, so that
    # the sums over frames add in the order of the whole (a single column
    # would be summed pairwise): temporaries of a few MB
    parts = [_trail_measures(trail[:, c], valid[:, c], span, rate, scale) for c in _column_starts(n, width)]
    return tuple(np.concatenate(m, axis=-1 if m[0].ndim > 1 else 0) for m in zip(*parts, strict=True))


def _trail_measures(
    trail: np.ndarray, valid: np.ndarray, span: int, rate: float, scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`trail_measures` of trails measured together."""
    T, n = trail.shape[:2]
    kappa = scaled_curvature(trail, valid, scale, span)
    if T <= span:
        return kappa, np.zeros(n), np.zeros((T, n))
    ok = _span_valid(valid, span)
    step = np.where(ok, quat.norm(trail[span:] - trail[:-span]), 0.0)  # (T-span, n)
    arc = step.sum(axis=0) / span
    # each edge covers frames f .. f+span: spread its speed over them
    acc = np.zeros((T + 1, n))
    cnt = np.zeros((T + 1, n))
    acc[: T - span] += step
    acc[span + 1 :] -= step
    cnt[: T - span] += ok
    cnt[span + 1 :] -= ok
    acc, cnt = np.cumsum(acc, axis=0)[:T], np.cumsum(cnt, axis=0)[:T]
    speed = np.where(cnt > 0, acc / np.maximum(cnt, 1), 0.0) * rate / span
    return kappa, arc, speed


#: Trail points :func:`trail_measures` measures at once: a long clip's
#: trails a few at a time, their temporaries (ten arrays of three
#: coordinates a point) about 25 MB.
_MEASURE_BLOCK = 1 << 17


def _column_starts(n: int, width: int) -> list[slice]:
    """Slices of ``width`` of ``n`` columns, none of one column alone (the
    last takes it)."""
    starts = list(range(0, n, width))
    if len(starts) > 1 and n - starts[-1] < 2:
        starts.pop()
    ends = starts[1:] + [n]
    return [slice(a, b) for a, b in zip(starts, ends, strict=True)]


#: Trail coordinates :func:`_rotated_columns` makes at once (256 kB).
_TRAIL_BLOCK = 1 << 15


def _limb_trails(sk, targets, dense, jumps, height, span, rate, kappa, weights, speed) -> None:
    """The limb trails of rotation variables ``dense`` (T, V, 4) driving
    joints ``targets``: each variable's curvature into ``kappa[:, n]``, its
    weight into ``weights[n]``, its speed added to ``speed`` (T,).

    The trails of several variables are measured in one call, in groups of
    about :data:`_TRAIL_GROUP` trail points (each trail's numbers are its
    own: the same bits as one variable at a time, which a short clip paid
    numpy's call overhead for 30 times over)."""
    T = len(dense)
    limbs = [limb_axes(sk, int(j), height) for j in targets]
    width = [2 * len(lb) for lb in limbs]
    n0 = 0
    while n0 < len(limbs):
        n1, size = n0 + 1, width[n0]
        while n1 < len(limbs) and (size + width[n1]) * T <= _TRAIL_GROUP:
            size += width[n1]
            n1 += 1
        axes = np.array([a for lb in limbs[n0:n1] for a in [a for a, _ in lb] + [_orthogonal(a) for a, _ in lb]])
        owner = np.repeat(np.arange(n0, n1), width[n0:n1])
        trail = _rotated_columns(dense, owner, axes)  # (T, A, 3)
        k, arc, sp = trail_measures(trail, ~jumps[:, owner], span, rate)
        c = 0
        for n in range(n0, n1):
            L = width[n] // 2
            lengths = np.array([ln for _, ln in limbs[n]])
            longer = np.where(arc[c : c + L] >= arc[c + L : c + 2 * L], np.arange(L), np.arange(L) + L) + c
            weights[n] = float(np.dot(lengths, arc[longer]))
            speed += sp[:, longer] @ lengths
            kappa[:, n] = k[:, c : c + 2 * L].max(axis=1)
            c += 2 * L
        n0 = n1


#: Trail points (frames x limb axes) measured at once by :func:`_limb_trails`.
_TRAIL_GROUP = 1 << 13


def _rotated_columns(q: np.ndarray, owner: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``axes[a]`` (A, 3) turned by the rotations ``q[:, owner[a]]`` of
    (T, V, 4): (T, A, 3), a block of frames at a time (the products of a long
    clip's whole track, out of cache, took 2.5x the time per frame); each
    value is its own, so the same bits."""
    out = np.empty((len(q), len(axes), 3))
    step = max(1, _TRAIL_BLOCK // max(3 * len(axes), 1))
    for lo in range(0, len(q), step):
        out[lo : lo + step] = quat.mul_vec(q[lo : lo + step, owner], axes[None])
    return out


#: A coordinate's extreme counts when the coordinate swings by at least this
#: share of the figure height to a neighbouring extreme (or the clip's end):
#: about 2 cm on a 1.75 m figure, under a walk's vertical bob (4-5 cm), over
#: the jitter of a standing root.
EXTREME_SWING = 0.01


def coordinate_extremes(
    trail: np.ndarray, height: float, rate: float, breaks: np.ndarray | None = None, smoothing: float | None = None
) -> np.ndarray:
    """Where translations turn back along an axis: their own extremes.

    Parameters
    ----------
    trail : (T, n, 3) positions of ``n`` translation variables.
    height : figure height (file units).
    rate : frames per second.
    breaks : (T-1,) bool, discontinuities (nothing is smoothed across them).
    smoothing : seconds, as for the local evidence (default :data:`DEFAULT_SMOOTHING`).

    Returns
    -------
    (T, n), zero except at the frames where a coordinate of the variable has
    a local maximum or minimum (of the smoothed coordinate) that swings by at
    least :data:`EXTREME_SWING` of the figure height to one of its
    neighbouring extremes; the value there is the larger swing in figure
    heights (the larger of the axes if several turn on one frame).  A root's
    height extremes are the crouch, the apex and a walk's down and up; a
    horizontal extreme is a lunge or a sway.
    """
    trail = np.asarray(trail, dtype=float)
    T, n = trail.shape[:2]
    out = np.zeros((T, n))
    if T < 3 or n == 0 or not height > 0:
        return out
    smoothing = DEFAULT_SMOOTHING if smoothing is None else float(smoothing)
    x = laplacian_smooth(trail, smoothing, rate, breaks)
    for v in range(n):
        for a in range(trail.shape[2]):
            c = x[:, v, a]
            starts = np.concatenate([[0], np.flatnonzero(np.diff(c) != 0.0) + 1])  # runs of equal values
            ends = np.concatenate([starts[1:] - 1, [T - 1]])
            r = c[starts]
            if len(r) < 3:
                continue
            inner = np.arange(1, len(r) - 1)
            turn = inner[(r[inner] - r[inner - 1]) * (r[inner + 1] - r[inner]) < 0]
            if len(turn) == 0:
                continue
            frames = (starts[turn] + ends[turn]) // 2
            # neighbours: the adjacent extremes, or the clip's ends
            vals = np.concatenate([[c[0]], c[frames], [c[-1]]])
            swing = np.maximum(np.abs(vals[1:-1] - vals[:-2]), np.abs(vals[1:-1] - vals[2:])) / height
            keep = swing >= EXTREME_SWING
            out[frames[keep], v] = np.maximum(out[frames[keep], v], swing[keep])
    return out


def local_evidence(motion: BvhMotion | MarkerMotion, smoothing: float | None = None) -> LocalEvidence:
    """Trails, curvature, weights and the amount of motion of a clip.

    Parameters
    ----------
    motion : a BVH or C3D clip.
    smoothing : standard deviation (seconds) of the Laplacian smoothing of
        ``p``; default :data:`DEFAULT_SMOOTHING`.
    """
    smoothing = DEFAULT_SMOOTHING if smoothing is None else float(smoothing)
    T = motion.n_frames
    rate = float(motion.rate)
    span = edge_span(rate)
    variables = dense_variables(motion)
    names = tuple(n for _, ns, _, _ in variables for n in ns)
    V = len(names)
    kappa = np.zeros((T, V))
    weights = np.zeros(V)
    speed = np.zeros(T)
    breaks = np.zeros(max(T - 1, 0), dtype=bool)
    if isinstance(motion, BvhMotion):
        sk = motion.skeleton
        height = motion.figure_height()
        rot_vals = next((d for k, _, _, d in variables if k == ROTATION), np.zeros((T, 0, 4)))
        breaks, rot_jumps = rotation_steps(rot_vals)
        col = 0
        for kind, vnames, targets, dense in variables:
            if kind == ROTATION:
                _limb_trails(sk, targets, dense, rot_jumps, height, span, rate, kappa[:, col:], weights[col:], speed)
                col += len(vnames)
                continue
            for n in range(len(vnames)):  # a position's trail is the position itself
                trail = dense[:, n, None, :]
                jump = quat.norm(np.diff(trail, axis=0)) > JUMP_FIGURE_HEIGHTS * height
                k, arc, sp = trail_measures(trail, ~jump & ~breaks[:, None], span, rate, height)
                weights[col + n] = float(arc[0])
                speed += sp[:, 0]
                kappa[:, col + n] = k.max(axis=1)
            col += len(vnames)
    else:
        height = float(motion.figure_height())
        _, _, _, dense = variables[0]  # gaps filled; samples in a gap are not used
        seen = np.all(np.isfinite(motion.points), axis=2)  # (T, M)
        jump = quat.norm(np.diff(dense, axis=0)) > JUMP_FIGURE_HEIGHTS * height  # (T-1, M)
        kappa, weights, sp = trail_measures(dense, seen[:-1] & seen[1:] & ~jump, span, rate, height)
        speed = sp.sum(axis=1)
    if T > 1:
        speed = speed / height
    p = laplacian_smooth(kappa, smoothing, rate, breaks)
    return LocalEvidence(names, p, weights, speed, breaks, rate, float(height))


def _limb_chains(sk: Skeleton, j: int) -> list[tuple[list[int], np.ndarray]]:
    """The limbs of joint ``j`` followed to their ends: per tip of ``j``
    (child joint or End Site), the joints of the chain below ``j`` and the
    offset of its end in the last joint's frame.  A chain goes on while its
    joint has exactly one tip (an arm from the shoulder to the hand, a leg
    to the toe) and ends at a joint that branches (the hand, at its
    fingers) or at an End Site."""
    kids = [int(c) for c in sk.children(j)]
    ends = [o for p, o in zip(sk.end_parents, sk.end_offsets, strict=True) if p == j]
    out: list[tuple[list[int], np.ndarray]] = [([], np.asarray(o, dtype=float)) for o in ends]
    for c in kids:
        chain = [c]
        while True:
            nxt = [int(g) for g in sk.children(chain[-1])]
            tips = [o for p, o in zip(sk.end_parents, sk.end_offsets, strict=True) if p == chain[-1]]
            if len(nxt) + len(tips) != 1:
                out.append((chain, np.zeros(3)))
                break
            if tips:
                out.append((chain, np.asarray(tips[0], dtype=float)))
                break
            chain.append(nxt[0])
    return out


def limb_extremes(
    sk: Skeleton,
    targets: np.ndarray,
    rot: np.ndarray,
    height: float,
    rate: float,
    breaks: np.ndarray | None = None,
    smoothing: float | None = None,
    which: np.ndarray | None = None,
) -> np.ndarray:
    """Where rotation variables' limbs turn back: their own extremes.

    Parameters
    ----------
    sk : the skeleton.
    targets : (V,) the joint each rotation variable turns.
    rot : (T, V, 4) the variables' local rotations.
    height, rate, breaks, smoothing : as for :func:`coordinate_extremes`.
    which : the variables (columns of ``rot``) to measure; default all.

    Returns
    -------
    (T, len(which)): for each variable, the :func:`coordinate_extremes` of the ends
    of its limbs relative to its joint, in the frame of the joint's parent
    (the hand seen from the shoulder in the body's frame: an arm's swing
    turns back where the hand does; the foot from the hip; a spine joint's
    limb ends where the body branches), the largest over its limbs.  The
    chain's own joints turn it too (the elbow bends the swing), so the
    extreme is the limb's, as an animator sees it, not the one joint's.
    """
    T, V = rot.shape[:2]
    which = np.arange(V) if which is None else np.asarray(which, dtype=int)
    out = np.zeros((T, len(which)))
    if T < 3 or V == 0:
        return out
    targets = np.asarray(targets, dtype=int)
    col = {int(j): n for n, j in enumerate(targets)}
    for i, n in enumerate(which):
        j = targets[n]
        trails = []
        for chain, end in _limb_chains(sk, int(j)):
            p = np.broadcast_to(end, (T, 3))
            for c in reversed(chain):  # the end in c's parent's frame, up to j's frame
                if c in col:
                    p = quat.mul_vec(rot[:, col[c]], p)
                p = p + sk.offsets[c]
            trails.append(quat.mul_vec(rot[:, n], p))
        if trails:
            out[:, i] = coordinate_extremes(np.stack(trails, axis=1), height, rate, breaks, smoothing).max(axis=1)
    return out


#: A joint branches into limbs when two or more of its tips lead to chains
#: at least this long (figure heights): the pelvis to both legs and the
#: spine, the chest to the arms and the neck; a hand's fingers are shorter.
LIMB_BRANCH = 0.1


def limb_tops(sk: Skeleton, height: float) -> np.ndarray:
    """(J,) int: for each joint of a limb, the limb's top joint; -1 for the
    torso.  A limb is what hangs below the torso without branching into
    limbs again (an arm from the collar down, a leg from the hip, the neck
    and head); the torso is every joint at or above a joint that branches
    into two or more chains of at least :data:`LIMB_BRANCH` of the figure
    height (the pelvis, the spine up to the chest).  A hand's fingers are
    shorter: the hand is the arm's."""
    J = sk.n_joints
    reach = np.zeros(J)  # the farthest rest point below each joint
    branches = np.zeros(J, dtype=int)
    for e, o in zip(sk.end_parents, sk.end_offsets, strict=True):
        length = float(np.linalg.norm(o))
        reach[e] = max(reach[e], length)
        branches[e] += length >= LIMB_BRANCH * height
    torso = np.zeros(J, dtype=bool)
    for c in range(J - 1, -1, -1):  # parents come before children
        torso[c] |= branches[c] >= 2
        p = int(sk.parents[c])
        if p < 0:
            continue
        length = float(np.linalg.norm(sk.offsets[c])) + reach[c]
        reach[p] = max(reach[p], length)
        branches[p] += length >= LIMB_BRANCH * height
        torso[p] |= torso[c]
    top = np.full(J, -1)
    for j in range(J):
        if not torso[j]:
            p = int(sk.parents[j])
            top[j] = j if p < 0 or torso[p] else top[p]
    return top


#: Seconds over which the hips' lateral axis is averaged into the heading of
#: :func:`heading_offsets` (a step's sway is not a turn of the body).
HEADING_SMOOTH = 0.5


def _apart(world: np.ndarray, a: list[int], b: list[int]) -> tuple[int, int] | None:
    """The first joints, going down two legs' chains together, that stand
    apart (their median distance over the clip is more than a thousandth of
    the largest): the hips.  A CMU skeleton's ``LHipJoint`` and
    ``RHipJoint`` sit on the pelvis, and the line between them has no
    direction; its ``LeftUpLeg`` and ``RightUpLeg`` do.  None if no pair does."""
    pairs = list(zip(a, b, strict=False))
    if not pairs:
        return None
    gaps = np.array([np.median(np.linalg.norm(world[:, i] - world[:, j], axis=-1)) for i, j in pairs])
    apart = np.flatnonzero(gaps > 1e-3 * gaps.max()) if gaps.max() > 0 else []
    return pairs[int(apart[0])] if len(apart) else None


def heading_offsets(sk: Skeleton, world: np.ndarray, tops: np.ndarray, up: np.ndarray, rate: float) -> np.ndarray:
    """How far limbs' ends are ahead of the pelvis along the body's heading.

    Parameters
    ----------
    sk : the skeleton.
    world : (T, J, 3) world joint positions.
    tops : (L,) the top joints of the limbs (:func:`limb_tops`).
    up : (3,) unit up axis.
    rate : frames per second.

    Returns
    -------
    (T, L): for each limb, the position of its end (the last joint of its
    chain: the hand, the toe) relative to the pelvis, along the heading:
    the horizontal axis orthogonal to the line between the hips, averaged
    over :data:`HEADING_SMOOTH` seconds.  The legs are the two limbs whose
    ends are lowest (by their median height) and hang from one joint, the
    pelvis; the hips are their first joints that stand apart (:func:`_apart`:
    a CMU skeleton's hip joints sit on the pelvis, and their line gave no
    heading, so every CMU clip's offsets were zero); zeros when there are no
    such two.  The sign of the
    heading is arbitrary (a maximum forward is a minimum backward).  An
    arm swings forward and back along it whatever else it does: a dance's
    raised arm turns back on other axes too, often by more.
    """
    T = world.shape[0]
    tops = np.asarray(tops, dtype=int)
    out = np.zeros((T, len(tops)))
    if T == 0 or len(tops) < 2:
        return out
    ends, chains_of = [], []
    for t in tops:
        p = int(sk.parents[t])
        chains = _limb_chains(sk, p) if p >= 0 else []
        chain = next((c for c, _ in chains if c and c[0] == t), [int(t)])
        ends.append(chain[-1])
        chains_of.append(chain)
    ends = np.array(ends)
    up = np.asarray(up, dtype=float)
    low = np.argsort(np.median(world[:, ends] @ up, axis=0), kind="stable")[:2]
    pelvis = int(sk.parents[tops[low[0]]])
    if pelvis < 0 or int(sk.parents[tops[low[1]]]) != pelvis:
        return out
    hips = _apart(world, chains_of[low[0]], chains_of[low[1]])
    if hips is None:
        return out
    lateral = world[:, hips[0]] - world[:, hips[1]]
    lateral = lateral - (lateral @ up)[:, None] * up
    lateral = lateral / np.maximum(quat.norm(lateral)[:, None], 1e-12)
    size = max(1, int(round(HEADING_SMOOTH * rate)))
    csum = np.cumsum(np.concatenate([np.zeros((1, 3)), lateral]), axis=0)
    lo = np.clip(np.arange(T) - size // 2, 0, T)
    hi = np.clip(np.arange(T) + size - size // 2, 0, T)
    lateral = (csum[hi] - csum[lo]) / (hi - lo)[:, None]  # a moving mean, shorter at the clip's ends
    forward = np.cross(up, lateral)
    forward = forward / np.maximum(quat.norm(forward)[:, None], 1e-12)
    for i, e in enumerate(ends):
        out[:, i] = np.einsum("tk,tk->t", world[:, e] - world[:, pelvis], forward)
    return out
