"""The contact layer: analytic two-bone IK applied as the final displacement map.

Paper section 3 ("a final displacement map represents an inverse kinematic
solution that modifies the value to meet any such constraints"), Appendix B,
SPEC section 6.  :func:`ik_layer` takes the local pose of every frame (after
splines and displacement maps) and returns new local rotations in which each
constrained joint stays planted during its constraint.

Rules (chosen here, and the reason for each):

Chain
    Found from the hierarchy, never from names (:func:`two_bone_chain`).  The
    chain is *upper* (grandparent of the lower joint), *middle* (its parent,
    where the bend is) and *lower* (the joint whose position is solved).  Start
    with lower = the constrained joint.  A joint at zero distance from its
    parent is the same point as that parent, so it is replaced by the parent
    (CMU's ``LHipJoint`` or ``LeftFingerBase``).  If the last bone (middle to
    lower) is shorter than ``TIP_RATIO`` (one half) of the bone above it, the
    constrained joint is a *tip* hanging off a short bone, such as a toe on the
    foot (CMU ``LeftToeBase`` -> ``LeftFoot``, Bandai ``Toes_L`` -> ``Foot_L``,
    GAMES-105 ``lToeJoint`` -> ``lAnkle``), or a finger on the hand: the chain
    moves up one joint and the ankle (or wrist) is solved so that the tip stays
    planted.  A foot gives hip, knee, ankle; a toe gives the same leg chain.
    Only the upper and middle joints must carry rotation channels.

Target
    The constrained joint is planted at its **mean world position over the
    constraint** (frames with ``start <= t <= end``) in the motion being
    baked, edits included: the motion given to :func:`ik_layer`, or for a tip
    whose lower joint is planted too, that motion with the lower joint's layer
    applied (see below).  The mean keeps the plant where the edited motion
    puts the contact on average, so an edit that moves a whole contact moves
    the plant with it and an edit that varies during it leaves no slide.
    ``targets`` overrides it.

Lower joint orientation
    The lower joint (ankle, wrist) keeps its **world orientation** from the
    motion being baked: the inverse of the chain's change is applied to its
    local rotation.  Joints below it (the toe) keep their local rotations,
    hence their world orientations too.  For a tip constraint the ankle goal
    is, per frame, the tip's plant minus the ankle-to-tip vector of that
    frame, so the tip is planted exactly while the foot rolls as in the data.

A planted tip below a planted joint (toe and foot)
    Joints are processed in hierarchy order, so the foot's layer is in place
    when its toe is solved.  The toe's plant is its mean over the frames where
    both are planted, so the two plants agree.  Where the toe is held the
    ankle goal is kept at the toe's distance from the toe's plant and the
    foot turns (shortest arc) to point at it, so the toe stays put; within
    that, the goal moves from where the toe alone would put the ankle towards
    where the foot's layer put it, by the foot's weight.  Where both are
    inside their constraints the ankle thus stays on its plant and only the
    foot's orientation gives (keeping it is impossible there).

Knee pole and reach
    The bend plane is the current plane of upper, middle and lower joint, so
    the knee never swaps sides.  Where the limb is nearly straight that plane
    is undefined; its normal is then taken from the middle joint's typical bend
    axis (mean over the clip, in the middle joint's frame), mixed in with a
    small weight so the result is continuous.  The knee angle is solved
    exactly about that axis (the root nearest to the law-of-cosines change),
    the upper joint turns about the same axis as far as it helps and a
    shortest-arc swing does the rest, so no correction is made where none is
    needed.  An unreachable goal is reached as far as the limb allows: the
    upper-to-lower distance is capped at ``MAX_REACH`` (99.9 %) of the limb
    length, or at the current distance where the data are straighter than
    that, so the layer never straightens a limb beyond the data.

Blend
    The weight of a constraint is 1 from ``start`` to ``end`` and ramps to 0
    with a smoothstep (C1) over ``blend`` seconds on each side.  Outside those
    windows the layer is exactly zero: those frames are never written, so
    their rotations are bit-identical.  The correction of each chain joint is
    scaled by the weight (slerp from the identity), so nothing pops.  In the
    ramps the goal is the motion's own position shifted by the offset the
    plant needed at the constraint's boundary: the layer fades out from what
    it did at the boundary rather than dragging a lifting foot back.

Several constraints on one joint
    Each keeps its own plant.  Between two consecutive ones the goal moves
    from one boundary offset to the next with a smoothstep over the gap; when
    the gap is shorter than ``blend`` (a contact a detector split) or they
    overlap, over ``blend`` seconds centred on the gap: the joint may then
    drift for up to ``blend / 2`` inside each constraint rather than jump.
    Weights combine as ``1 - prod(1 - w_i)``: 1 inside any constraint, 0
    outside every window, and C1 where a plain maximum would kink.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .. import quat
from ..errors import UsageError
from ..skeleton import Skeleton

#: A last bone shorter than this fraction of the bone above makes its joint a tip.
TIP_RATIO = 0.5
#: Longest upper-to-lower distance the solver asks of a limb, as a fraction of its length.
MAX_REACH = 0.999
#: Weight of the typical bend axis in the bend-plane normal (the normal of the current
#: plane has the length sin(angle at the upper joint)): it only matters below ~3 degrees.
HINGE_WEIGHT = 0.05
_TINY = 1e-12


@dataclass(frozen=True)
class Chain:
    """Joint indices of a two-bone chain: ``upper`` -> ``middle`` -> ``lower``
    (``middle`` is the parent of ``lower`` or, through zero-length joints, its
    ancestor; ``upper`` is the parent of ``middle``), and the constrained
    ``effector`` (``lower`` itself or a joint below it)."""

    upper: int
    middle: int
    lower: int
    effector: int


def two_bone_chain(skeleton: Skeleton, joint: str | int) -> Chain:
    """The two-bone chain that plants ``joint``, found from the hierarchy.

    See the module docstring for the rule.  Raises ``UsageError`` for an
    unknown joint or one without a usable chain (fewer than two bones above
    it, or chain joints without rotation channels).
    """
    e = skeleton.index(joint) if isinstance(joint, str) else int(joint)
    name = skeleton.names[e]
    parents = skeleton.parents
    bone = np.linalg.norm(skeleton.offsets, axis=1)
    zero = 1e-6 * max(float(bone.max(initial=0.0)), _TINY)

    def fail(why: str) -> UsageError:
        return UsageError(f"joint {name!r} has no two-bone chain to plant it ({why})")

    c = e
    while True:
        if parents[c] < 0:
            raise fail("too few bones above it")
        if bone[c] <= zero:  # the same point as its parent
            c = int(parents[c])
            continue
        b = int(parents[c])
        while bone[b] <= zero and parents[b] >= 0:
            b = int(parents[b])
        if bone[b] <= zero or parents[b] < 0:
            raise fail("too few bones above it")
        if bone[c] < TIP_RATIO * bone[b]:  # a tip on a short bone: solve for its parent
            c = b
            continue
        a = int(parents[b])
        break
    for j in (a, b):
        if skeleton.channels and not skeleton.has_rotation(j):
            raise fail(f"{skeleton.names[j]!r} has no rotation channels")
    return Chain(a, b, c, e)


def smoothstep(u: np.ndarray) -> np.ndarray:
    """``3u² − 2u³`` of ``u`` clipped to [0, 1]: C1, 0 at 0 and 1 at 1."""
    u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def blend_weight(times: np.ndarray, start: float, end: float, blend: float) -> np.ndarray:
    """Weight ``(N,)`` of one constraint at ``times`` (seconds): 1 from ``start``
    to ``end``, a smoothstep ramp over ``blend`` seconds on each side, exactly 0
    beyond."""
    t = np.asarray(times, dtype=float)
    inside = (t >= start) & (t <= end)
    if blend <= 0.0:
        return inside.astype(float)
    u = np.minimum(t - (start - blend), (end + blend) - t) / blend
    return np.where(inside, 1.0, smoothstep(u))


def ik_layer(
    skeleton: Skeleton,
    rotations: np.ndarray,
    translations: np.ndarray,
    times: np.ndarray,
    constraints: Sequence,
    *,
    blend: float = 0.1,
    targets: Sequence[np.ndarray | None] | None = None,
) -> np.ndarray:
    """Local rotations with the contact layer applied (see the module docstring).

    Parameters
    ----------
    skeleton : Skeleton
    rotations : (N, J, 4) local rotations, w first (not modified).
    translations : (N, J, 3) local translations, file units.
    times : (N,) seconds of the frames.
    constraints : sequence of objects with ``joint`` (name), ``start`` and
        ``end`` (seconds), e.g. :class:`staggered_cli.model.document.Constraint`.
    blend : seconds of the smooth ramp on each side of a constraint.
    targets : optional, one entry per constraint: the world position (3,) in
        file units where its joint is planted, a position per frame (N, 3)
        of ``times`` to follow during the constraint, or None for the
        default (the joint's mean position over the constraint in this
        motion).

    Returns
    -------
    (N, J, 4) new local rotations.  Only the upper, middle and lower joints of
    constrained chains change, and only inside constraints and their blend
    windows.

    Raises
    ------
    UsageError for an unknown joint, a joint without a chain, ``start > end``
    or a negative ``blend``; ValueError for arrays of the wrong shape.
    """
    rotations = np.asarray(rotations, dtype=float)
    translations = np.asarray(translations, dtype=float)
    times = np.asarray(times, dtype=float)
    N, J = rotations.shape[:2] if rotations.ndim == 3 else (-1, -1)
    if rotations.shape != (N, skeleton.n_joints, 4):
        raise ValueError(f"rotations must have shape (N, {skeleton.n_joints}, 4), got {rotations.shape}")
    if translations.shape != (N, J, 3):
        raise ValueError(f"translations must have shape ({N}, {J}, 3), got {translations.shape}")
    if times.shape != (N,):
        raise ValueError(f"times must have shape ({N},), got {times.shape}")
    if not blend >= 0.0:
        raise UsageError(f"the IK blend must be a non-negative number of seconds, got {blend}")
    constraints = list(constraints)
    if targets is not None and len(targets) != len(constraints):
        raise ValueError(f"targets must have one entry per constraint ({len(constraints)}), got {len(targets)}")
    for c in constraints:
        if not c.start <= c.end:
            raise UsageError(f"constraint on {c.joint!r} ends ({c.end}) before it starts ({c.start})")

    out = rotations.copy()
    by_joint: dict[int, list[int]] = {}
    for i, c in enumerate(constraints):
        by_joint.setdefault(skeleton.index(c.joint), []).append(i)
    for e in sorted(by_joint):  # hierarchy order: a foot before its toe
        spans, given = _sorted(
            [constraints[i] for i in by_joint[e]], [None if targets is None else targets[i] for i in by_joint[e]]
        )
        chain = two_bone_chain(skeleton, e)
        weights = np.stack([blend_weight(times, c.start, c.end, blend) for c in spans])
        weight = 1.0 - np.prod(1.0 - weights, axis=0)
        frames = np.flatnonzero(weight > 0.0)
        if len(frames) == 0:
            continue
        path = _path(skeleton, e)
        # the bend axis is a property of the limb: take it from the whole clip
        g_in, p_in = _path_fk(skeleton, path, rotations, translations)
        hinge = _hinge_axis(path, chain, g_in, p_in)
        g, p = _path_fk(skeleton, path, out[frames], translations[frames])
        t_win = times[frames]
        # where the chain's lower joint is planted too (a foot, when this is its
        # toe), the plant is taken from the frames where both are, so the two agree
        shared = None
        held = np.zeros(len(frames), dtype=bool)
        if chain.lower != e and chain.lower in by_joint:
            lower = [constraints[i] for i in by_joint[chain.lower]]
            foot = 1.0 - np.prod([1.0 - blend_weight(t_win, c.start, c.end, blend) for c in lower], axis=0)
            toe = 1.0 - np.prod([1.0 - blend_weight(t_win, c.start, c.end, blend) for c in spans], axis=0)
            shared = (foot, toe)
            for c in lower:
                held |= (t_win >= c.start) & (t_win <= c.end)
        plants = []
        for c, tg in zip(spans, given, strict=True):
            inside = (t_win >= c.start) & (t_win <= c.end)
            if tg is not None and np.ndim(tg) == 2:  # a target per frame of ``times``
                plants.append(np.asarray(tg, dtype=float).reshape(N, 3)[frames])
            elif tg is not None:
                plants.append(np.asarray(tg, dtype=float).reshape(3))
            elif (inside & held).any():
                plants.append(p[inside & held, -1].mean(axis=0))
            else:
                plants.append(_mean_position(p[:, -1], t_win, c.start, c.end))
        tgt = _target_timeline(t_win, p[:, -1], spans, plants, blend)
        corr = _solve(path, chain, g, p, tgt, hinge, shared)
        w = weight[frames][:, None]
        for j, c in zip((chain.upper, chain.middle, chain.lower), corr, strict=True):
            if skeleton.channels and not skeleton.has_rotation(j):
                continue  # a joint without rotation channels cannot carry a correction
            out[frames, j] = quat.mul(out[frames, j], quat.exp(quat.log(c) * w))
    return out


# --- pieces ------------------------------------------------------------------------


def _path(skeleton: Skeleton, j: int) -> list[int]:
    """Joints from the root down to ``j``."""
    path = [j]
    while skeleton.parents[path[-1]] >= 0:
        path.append(int(skeleton.parents[path[-1]]))
    return path[::-1]


def _path_fk(
    skeleton: Skeleton, path: list[int], rotations: np.ndarray, translations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (N, P, 4) and positions (N, P, 3) of the joints on ``path``."""
    n = rotations.shape[0]
    g = np.empty((n, len(path), 4))
    p = np.empty((n, len(path), 3))
    g[:, 0] = rotations[:, path[0]]
    p[:, 0] = translations[:, path[0]]
    for k in range(1, len(path)):
        j = path[k]
        g[:, k] = quat.mul(g[:, k - 1], rotations[:, j])
        p[:, k] = p[:, k - 1] + quat.mul_vec(g[:, k - 1], translations[:, j])
    return g, p


def _mean_position(pos: np.ndarray, times: np.ndarray, start: float, end: float) -> np.ndarray:
    """Mean of ``pos (N, 3)`` over frames in [start, end]; the nearest frame to the
    middle when no frame falls inside."""
    inside = (times >= start) & (times <= end)
    if inside.any():
        return pos[inside].mean(axis=0)
    return pos[int(np.argmin(np.abs(times - 0.5 * (start + end))))]


def _target_timeline(
    times: np.ndarray, pos: np.ndarray, constraints: list, plants: list[np.ndarray], blend: float
) -> np.ndarray:
    """Where one joint should be (N, 3) at ``times``, given its position ``pos``
    (N, 3) in the motion being baked.

    Inside constraint k: its plant.  Before or after it: the motion's own
    position shifted by the offset it needs at the constraint's start or end
    (so the layer fades out from what it did at the boundary instead of
    dragging a lifting foot back to the plant).  Between consecutive
    constraints the target moves from one to the next with a smoothstep over
    the gap between them, or over ``blend`` seconds centred on the gap when
    the gap is shorter or they overlap.
    """

    def own(k: int) -> np.ndarray:
        c = constraints[k]
        plant = np.broadcast_to(plants[k], pos.shape)  # a fixed point, or a target per frame
        inside = (times >= c.start) & (times <= c.end)
        i0 = int(np.flatnonzero(inside)[0]) if inside.any() else int(np.argmin(np.abs(times - c.start)))
        i1 = int(np.flatnonzero(inside)[-1]) if inside.any() else int(np.argmin(np.abs(times - c.end)))
        tgt = pos + np.where((times < c.start)[:, None], plant[i0] - pos[i0], plant[i1] - pos[i1])
        tgt[inside] = plant[inside]
        return tgt

    tgt = own(0)
    for k in range(len(plants) - 1):
        lo, hi = sorted((constraints[k].end, constraints[k + 1].start))
        if hi - lo < blend:  # too short to move without a pop: widen into both
            mid = 0.5 * (lo + hi)
            lo, hi = mid - 0.5 * blend, mid + 0.5 * blend
        s = (times >= hi).astype(float) if hi <= lo else smoothstep((times - lo) / (hi - lo))
        tgt += s[:, None] * (own(k + 1) - own(k))
    return tgt


def _sorted(constraints: list, given: list) -> tuple[list, list]:
    """Constraints of one joint (as spans) and their given targets, by start time."""
    pairs = sorted(zip(constraints, given, strict=True), key=lambda cg: (cg[0].start, cg[0].end))
    return [_Span(c.start, c.end) for c, _ in pairs], [g for _, g in pairs]


@dataclass(frozen=True)
class _Span:
    start: float
    end: float


def _hinge_axis(path: list[int], chain: Chain, g: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The middle joint's typical bend axis (3,), in its own frame: the mean over
    frames of the bend-plane normal, weighted by how bent the limb is."""
    ia, ib, ic = (path.index(j) for j in (chain.upper, chain.middle, chain.lower))
    ac, ab = p[:, ic] - p[:, ia], p[:, ib] - p[:, ia]
    raw = np.cross(ac, ab) / np.maximum(
        np.linalg.norm(ac, axis=-1, keepdims=True) * np.linalg.norm(ab, axis=-1, keepdims=True), _TINY
    )
    axis = quat.mul_vec(quat.conj(g[:, ib]), raw).sum(axis=0)
    norm = np.linalg.norm(axis)
    if norm > _TINY:
        return axis / norm
    # never bent: any axis across the lower bone
    bone = quat.mul_vec(quat.conj(g[0, ib]), p[0, ic] - p[0, ib])
    axis = np.cross(bone, [1.0, 0.0, 0.0])
    if np.linalg.norm(axis) < 1e-6 * max(np.linalg.norm(bone), _TINY):
        axis = np.cross(bone, [0.0, 1.0, 0.0])
    return axis / max(np.linalg.norm(axis), _TINY)


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, _TINY), n[..., 0]


def _signed_angle(u: np.ndarray, v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Angle (radians) from ``u`` to ``v`` about unit ``n`` (right hand), in (-pi, pi]."""
    return np.arctan2(np.sum(np.cross(u, v) * n, axis=-1), np.sum(u * v, axis=-1))


def _axis_angle(n: np.ndarray, angle: np.ndarray) -> np.ndarray:
    return quat.exp(n * angle[..., None])


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _split(v: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Part of ``v`` along unit ``n``, part across it, and ``n`` × the part across."""
    along = np.sum(v * n, axis=-1, keepdims=True) * n
    across = v - along
    return along, across, np.cross(n, across)


def _best_turn(u: np.ndarray, v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Angle about ``n`` that turns ``u`` closest to the direction of ``v``."""
    _, across, side = _split(u, n)
    return np.arctan2(np.sum(side * v, axis=-1), np.sum(across * v, axis=-1))


def _rotation_for_distance(
    upper: np.ndarray, lower: np.ndarray, n: np.ndarray, dist: np.ndarray, guess: np.ndarray
) -> np.ndarray:
    """Angle φ about ``n`` that makes ``|upper + R(n, φ) lower| = dist``, the root
    nearest ``guess``; where no root exists, the φ that comes closest.

    ``upper · R lower = K + A cos φ + B sin φ`` with the parts of ``lower``
    along and across ``n``.
    """
    along, across, side = _split(lower, n)
    k = np.sum(upper * along, axis=-1)
    a = np.sum(upper * across, axis=-1)
    b = np.sum(upper * side, axis=-1)
    q = 0.5 * (dist**2 - np.sum(upper * upper, axis=-1) - np.sum(lower * lower, axis=-1))
    rho = np.hypot(a, b)
    centre = np.arctan2(b, a)
    half = np.arccos(np.clip((q - k) / np.maximum(rho, _TINY), -1.0, 1.0))
    r1, r2 = _wrap(centre + half), _wrap(centre - half)
    return np.where(np.abs(_wrap(r1 - guess)) <= np.abs(_wrap(r2 - guess)), r1, r2)


def _arc(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest rotation (N, 4) taking direction ``u`` to direction ``v``."""
    u, _ = _unit(u)
    v, _ = _unit(v)
    q = np.concatenate([1.0 + np.sum(u * v, axis=-1, keepdims=True), np.cross(u, v)], axis=-1)
    # opposite directions never occur for a planted limb near its pose; keep it finite anyway
    q = np.where(q[..., :1] < 1e-9, quat.identity(q.shape[:-1]), q)
    return quat.normalize(q)


def _solve(
    path: list[int],
    chain: Chain,
    g: np.ndarray,
    p: np.ndarray,
    target: np.ndarray,
    hinge: np.ndarray,
    shared: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local rotation corrections (N, 4) of upper, middle and lower joint that
    put the effector at ``target`` (N, 3).

    The lower joint keeps its world orientation, unless the effector is a tip
    below it and the lower joint is planted too: ``shared = (foot, toe)``
    gives per frame the weights (N,) of the lower joint's layer and of the
    tip's.  The lower joint's goal then moves from where the tip alone would
    put it towards where its own layer put it (by ``foot``) and, by ``toe``,
    onto the sphere of the tip's length around the tip's target; the lower
    joint turns to point at the target.
    """
    ia, ib, ic = (path.index(j) for j in (chain.upper, chain.middle, chain.lower))
    pa, pb, pc, pe = p[:, ia], p[:, ib], p[:, ic], p[:, -1]
    ga, gb, gc = g[:, ia], g[:, ib], g[:, ic]
    tip = pe - pc
    goal = target - tip  # where the lower joint must go for the effector to land
    aim = False
    if shared is not None and chain.effector != chain.lower:
        foot, toe = (w[:, None] for w in shared)
        free = goal + foot * (pc - goal)
        out, _ = _unit(target - free)
        on_sphere = target - np.linalg.norm(tip, axis=-1, keepdims=True) * out
        goal = free + toe * (on_sphere - free)
        aim = True
    l1 = np.linalg.norm(pb - pa, axis=-1)
    l2 = np.linalg.norm(pc - pb, axis=-1)
    d_now = np.linalg.norm(pc - pa, axis=-1)
    reach = np.minimum(np.maximum(MAX_REACH * (l1 + l2), d_now), (1.0 - 1e-9) * (l1 + l2))
    d_goal = np.clip(np.linalg.norm(goal - pa, axis=-1), np.abs(l1 - l2) + 1e-9 * (l1 + l2), reach)

    ac, ab = pc - pa, pb - pa
    raw = np.cross(ac, ab) / np.maximum(np.linalg.norm(ac, axis=-1) * np.linalg.norm(ab, axis=-1), _TINY)[:, None]
    n, _ = _unit(raw + HINGE_WEIGHT * quat.mul_vec(gb, hinge))
    # The interior angle at the middle joint, signed about n, says which way the
    # knee bends; the law of cosines gives the angle wanted.  Their difference
    # picks which of the two exact knee rotations about n to use (n may lean
    # off the limb's plane towards the bend axis, so the exact one is solved for).
    b0 = _signed_angle(pa - pb, pc - pb, n)
    b1 = np.arccos(np.clip((l1**2 + l2**2 - d_goal**2) / np.maximum(2.0 * l1 * l2, _TINY), -1.0, 1.0))
    phi = _rotation_for_distance(ab, pc - pb, n, d_goal, _wrap(b1 - b0))
    r_knee = _axis_angle(n, phi)  # world, about the middle joint
    c_knee = ab + quat.mul_vec(r_knee, pc - pb)  # lower joint from the upper one
    # the upper joint turns about the same axis as far as it brings the limb
    # towards the goal (so the knee plane does not tilt), the swing does the rest
    r_bend = _axis_angle(n, _best_turn(c_knee, goal - pa, n))
    r_swing = _arc(quat.mul_vec(r_bend, c_knee), goal - pa)
    r_upper = quat.mul(r_swing, r_bend)  # world change of the upper joint
    r_lower = quat.mul(r_upper, r_knee)  # world change of everything below the middle joint
    r_aim = None
    if aim:
        # point at the target from where the lower joint ends up; turn less as the
        # target gets out of the tip's reach (an unreachable goal), never wildly
        reached = pa + quat.mul_vec(r_upper, c_knee)
        to_target = target - reached
        length = np.linalg.norm(tip, axis=-1)
        miss = np.abs(np.linalg.norm(to_target, axis=-1) - length) / np.maximum(length, _TINY)
        r_aim = quat.exp(quat.log(_arc(tip, to_target)) * np.clip(1.0 - miss, 0.0, 1.0)[:, None])
    corr_a = quat.mul(quat.conj(ga), quat.mul(r_upper, ga))
    corr_b = quat.mul(quat.conj(gb), quat.mul(r_knee, gb))
    turn = quat.conj(r_lower) if r_aim is None else quat.mul(quat.conj(r_lower), r_aim)
    corr_c = quat.mul(quat.conj(gc), quat.mul(turn, gc))
    return corr_a, corr_b, corr_c
