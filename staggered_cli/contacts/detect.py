"""Environmental contact constraints (paper Appendix B, SPEC section 6).

Detection
    End effectors: by default the feet and toes.  For a BVH skeleton these
    are the joints whose names say so (``LeftFoot``, ``LeftToeBase``,
    ``Foot_L``, ``Toes_L``, ``lAnkle``, ``lToeJoint``, ``LeftToe``, ``heel``
    ...) and lie in the lower half of the figure, together with the lowest
    joints: those whose median height is within :data:`LOWEST_SHARE` of the
    figure height of the lowest joint's.  For a C3D marker set, the lowest
    markers of the body by the same rule (heel, toe, ankle and metatarsal
    markers): markers of a carried or nearby object (another subject
    prefix, or far from the figure most of the time) are left out first,
    and the figure's up axis and height are measured without them (see
    :func:`body_markers`).

    Height is measured along the *up axis*, found without assuming Y or Z:
    the world axis along which the figure's per-frame extent is largest
    (median over frames; a standing, walking or dancing figure is taller
    than it is wide or deep), pointing to the side where the figure's median
    position lies (capture volumes put their origin on the floor).  When that
    median is within 5 % of the figure height of zero, the side whose lowest
    points move least is the floor (feet rest more than heads).

    A joint or marker is *planted* while its world position stays inside a
    box whose diagonal is at most ``tolerance × figure height`` for at least
    ``min_duration`` seconds; the constraint then grows forward while the
    position keeps within tolerance over every further ``min_duration``
    window (the paper's incremental forward search, see
    :func:`planted_intervals`).

    Defaults: ``tolerance`` :data:`DEFAULT_TOLERANCE` (3 % of the figure
    height, about 5 cm for a 1.7 m actor: above marker noise and heel-to-toe
    roll of the ankle in the first half of stance, below the distance a
    swinging foot covers in 0.1 s) and ``min_duration``
    :data:`DEFAULT_MIN_CONTACT` = 0.1 s instead of the paper's 0.25 s:
    running stance lasts 0.1-0.2 s (bandai2_run has no 0.25 s plant at all),
    and a foot that moves less than 3 % of the figure in 0.1 s is resting.

    A planted point must also be near the floor: within
    :data:`GROUND_BAND` (8 %) of the figure height of its own lowest level
    (its 5th-percentile height over the clip), so that the instant a lifted
    foot turns around at the top of a step is not taken for a contact.

    C3D gaps (NaN) end a constraint: a missing marker is not known to rest.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import replace

import numpy as np

from .. import quat
from ..errors import UsageError, arg, warn
from ..motion import BvhMotion, MarkerMotion
from ..names import resolve
from ..skeleton import body_joints
from .constraint import Constraint

#: Default minimum contact duration, seconds (the paper's 0.25 s misses running stance).
DEFAULT_MIN_CONTACT = 0.1
#: Default tolerance: diagonal of the box a planted effector stays in, as a
#: fraction of the figure height.
DEFAULT_TOLERANCE = 0.03
#: Joints or markers whose median height is within this fraction of the
#: figure height of the lowest one's are "lowest end effectors".
LOWEST_SHARE = 0.1
#: A planted effector is within this fraction of the figure height of its own
#: lowest level (5th percentile of its height over the clip): the apex of a
#: lifted foot, slow for an instant, is not a contact.
GROUND_BAND = 0.08

_FOOT_NAME = re.compile(r"foot|toe|ankle|heel", re.IGNORECASE)


def effector_positions(
    motion: BvhMotion | MarkerMotion, names: tuple[str, ...] | None = None
) -> tuple[tuple[str, ...], np.ndarray, float]:
    """World positions of joints (BVH) or markers (C3D).

    Parameters
    ----------
    names : joint names or marker labels; all of them if None.

    Returns
    -------
    names : (n,) the names, in the order asked.
    positions : (T, n, 3) file units (NaN where a marker is missing).
    figure_height : file units.
    """
    if isinstance(motion, BvhMotion):
        sk = motion.skeleton
        wp = motion.world_positions()  # computed once per clip
        height = motion.figure_height()
        if names is None:  # all of them: the cached array itself (read-only), not a copy
            return tuple(sk.names), wp, float(height)
        idx = np.array([sk.index(n) for n in names], dtype=int)
        return tuple(sk.names[i] for i in idx), wp[:, idx], float(height)
    labels = motion.labels
    if names is None:
        idx = np.arange(len(labels))
    else:
        idx = np.array([resolve(n, labels, None, what="marker") for n in names], dtype=int)
    return tuple(labels[i] for i in idx), motion.points[:, idx], float(motion.figure_height())


def up_direction(points: np.ndarray, height: float, columns: np.ndarray | None = None) -> np.ndarray:
    """Unit up vector (3,) of a figure given its points ``(T, n, 3)`` (NaN allowed).

    The world axis of largest median per-frame extent, signed toward the
    figure's median position; see the module docstring.  ``columns``: only
    these of the points (without a copy of them all: a joint's positions
    are 24 bytes a frame).
    """
    cols = slice(None) if columns is None else np.asarray(columns, dtype=int)
    T = points.shape[0]
    n = points.shape[1] if columns is None else len(cols)
    ext = np.empty((T, 3))
    step = max(1, _UP_BLOCK // max(n, 1))
    with np.errstate(invalid="ignore"):
        for lo in range(0, T, step):  # each frame's extent on its own: the same numbers as at once
            p = points[lo : lo + step, cols]
            ext[lo : lo + step] = np.fmax.reduce(p, axis=1) - np.fmin.reduce(p, axis=1)
    ok = np.all(np.isfinite(ext), axis=1)
    axis = int(np.argmax(np.median(ext[ok], axis=0))) if ok.any() else 1
    coord = points[:, cols, axis]  # with columns, a copy of them
    finite = np.isfinite(coord)
    # the median partitions what it is given in place: a copy of the seen
    # coordinates, or the copy of the columns itself when all are seen (in
    # its memory order: the median does not depend on it)
    seen = coord.ravel(order="K") if columns is not None and finite.all() else coord[finite]
    del finite
    median = float(np.median(seen, overwrite_input=True)) if len(seen) else 0.0
    del seen
    sign = 1.0
    if abs(median) > 0.05 * height:
        sign = float(np.sign(median))
    elif points.shape[0] > 1:
        coord = points[:, cols, axis]  # (again: the median may have reordered it)
        # the floor is the end whose lowest points rest most
        lo = np.argmin(np.where(np.isfinite(coord), coord, np.inf), axis=1)
        hi = np.argmax(np.where(np.isfinite(coord), coord, -np.inf), axis=1)
        rows = np.arange(len(coord) - 1)
        v = quat.norm(np.diff(points[:, cols], axis=0))  # (T-1, n)
        v_lo, v_hi = v[rows, lo[:-1]], v[rows, hi[:-1]]
        v_lo, v_hi = v_lo[np.isfinite(v_lo)], v_hi[np.isfinite(v_hi)]
        if len(v_lo) and len(v_hi) and np.median(v_hi) < np.median(v_lo):
            sign = -1.0
    up = np.zeros(3)
    up[axis] = sign
    return up


#: Point positions :func:`up_direction` measures at once (its temporaries:
#: a few MB whatever the clip's length).
_UP_BLOCK = 1 << 16


def _median_height(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Median height (n,) of each point over the frames it is seen in; inf
    for a point never seen."""
    h = points @ up  # (T, n)
    never = ~np.any(np.isfinite(h), axis=0)
    if never.any():  # (h is this function's own)
        h[:, never] = np.inf
    return np.nanmedian(h, axis=0)


def _lowest_of(h: np.ndarray, height: float) -> np.ndarray:
    """Indices of the median heights ``h`` (n,) within LOWEST_SHARE of the
    figure height of the lowest one."""
    return np.flatnonzero(h <= np.min(h) + LOWEST_SHARE * height)


def contact_joints(
    motion: BvhMotion | MarkerMotion, names: tuple[str, ...] | list[str] | None = None
) -> tuple[str, ...]:
    """The end effectors to detect contacts on.

    Parameters
    ----------
    names : the user's choice (joint names or marker labels; checked), or
        None for the default feet and toes (see the module docstring).

    Returns
    -------
    Names in skeleton (or marker) order; the user's order when given.
    """
    if names is not None:
        names = tuple(dict.fromkeys(effector_positions(motion, tuple(str(n) for n in names))[0]))  # own names
        if isinstance(motion, BvhMotion):
            from .ik import two_bone_chain

            for n in names:
                two_bone_chain(motion.skeleton, n)  # bake must be able to keep it planted
        return names
    all_names, pos, height = effector_positions(motion)
    if isinstance(motion, BvhMotion):
        body = body_joints(motion.skeleton)
        up = up_direction(pos, height, body)
        h = _median_height(pos, up)
        root_h = h[body[0]]
        by_name = {j for j, n in enumerate(all_names) if _FOOT_NAME.search(n) and h[j] < root_h}
        # the body's median heights are those of all joints (each column's
        # own): not measured again on a copy of the body's positions
        lowest = {int(body[j]) for j in _lowest_of(h[body], height)}
        chosen = [j for j in sorted(by_name | lowest) if _has_chain(motion.skeleton, j)]
    else:
        body, height = _body(motion)
        body = np.arange(len(all_names)) if body is None else body
        up = up_direction(pos, height, body)  # a prop beside the figure must not turn it
        chosen = sorted(int(body[j]) for j in _lowest_of(_median_height(pos[:, body], up), height))
        shared = [all_names[j] for j in chosen if motion.labels.count(all_names[j]) > 1]
        if shared:  # a constraint names its marker: it must name one
            warn("no contact detection on marker %r: its label is shared by other markers", shared[0])
            chosen = [j for j in chosen if all_names[j] not in shared]
    return tuple(all_names[j] for j in chosen)


def body_markers(labels, points: np.ndarray) -> np.ndarray:
    """Indices of the markers on the figure's body, the ones its default
    contacts are chosen from (and its up axis found on): a marker set may
    also hold the markers of a carried or nearby object (a box, a prop),
    which can rest lower than the feet (on the floor while the figure walks
    elsewhere) and would take every default contact.  Two kinds of evidence:

    * the subject prefix: when the labels carry more than one prefix
      (``Male:LTOE`` beside ``Box:C1``, or beside unprefixed ``BOX1``), the
      body is the largest group (no choice on a tie: two subjects);
    * staying with the figure: in the frames where most markers are seen,
      a marker whose median distance from the figure's centre (each frame's
      median marker) is more than :data:`BODY_REACH` times the typical
      marker's (the median of those distances) is not on it.  The scale is
      the markers' own, not the figure height: a prop far away makes the
      figure look taller.

    All markers when these would leave none.
    """
    from ..names import base_name

    labels = list(labels)
    idx = np.arange(len(labels))
    groups: dict[str, list[int]] = {}
    for j, name in enumerate(labels):
        groups.setdefault(name[: len(name) - len(base_name(name))], []).append(j)
    if len(groups) > 1:
        sizes = sorted((len(g) for g in groups.values()), reverse=True)
        if sizes[0] > sizes[1]:
            idx = np.array(max(groups.values(), key=len), dtype=int)
    if len(idx) < 3:
        return idx
    count = np.isfinite(points[:, idx]).all(axis=2).sum(axis=1)  # (T,)
    frames = np.flatnonzero(count >= max(2, count.max() // 2))
    # evenly spread frames are enough for a median distance
    frames = frames[np.unique(np.linspace(0, len(frames) - 1, min(len(frames), _BODY_FRAMES)).astype(int))]
    pts = points[frames[:, None], idx[None, :]]  # (T', n, 3)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # markers never seen there
        centre = np.nanmedian(pts, axis=1)  # (T', 3)
        far = np.nanmedian(quat.norm(pts - centre[:, None]), axis=0)  # (n,), NaN for a marker not seen
        typical = np.nanmedian(far)
    near = idx[~(far > BODY_REACH * typical)]
    return near if len(near) else idx


#: Frames (evenly spread) :func:`body_markers` measures distances on.
_BODY_FRAMES = 500


def _body(motion: MarkerMotion) -> tuple[np.ndarray | None, float]:
    """:func:`body_markers` of a clip (None for all of them) and the height
    of the figure they make (that of the clip when they are all of it)."""
    body = body_markers(motion.labels, motion.points)
    if len(body) == len(motion.labels):
        return None, float(motion.figure_height())
    own = replace(motion, labels=tuple(motion.labels[j] for j in body), points=motion.points[:, body])
    return body, float(own.figure_height())


#: A marker whose median distance from the figure's centre is more than this
#: many times the typical marker's is not on the body (see
#: :func:`body_markers`).  Body markers measure at most 3.5 on the dev C3D
#: files (c7 on the BTS walk, whose markers crowd the pelvis and legs; 2.4
#: for a toe of the breakdance, 1.8 on the lower-body c3d.org walk): a prop
#: must rest away from the figure (about 1 to 2 figure heights) for most of
#: the clip to be told apart this way.
BODY_REACH = 5.0


def _has_chain(skeleton, j: int) -> bool:
    """Whether bake's IK can keep joint ``j`` planted (a two-bone chain above it)."""
    from ..errors import UsageError
    from .ik import two_bone_chain

    try:
        two_bone_chain(skeleton, j)
    except UsageError:
        return False
    return True


def planted_intervals(positions: np.ndarray, tolerance: float, min_frames: int) -> list[tuple[int, int]]:
    """Frame intervals ``[start, end]`` (inclusive) over which a point rests.

    Parameters
    ----------
    positions : (T, 3) world positions (NaN where unknown).
    tolerance : largest diagonal of the box the point stays in, file units.
    min_frames : shortest interval, frames (>= 2).

    A *still window* is a run of ``min_frames`` frames whose positions fit
    in a box of diagonal ``tolerance``.  Searching forward, the first still
    window starts a constraint, which grows while the following still
    windows overlap it: a frame is planted when some still window holds it.
    Growing by windows rather than by one box over the whole contact keeps a
    foot that rolls from heel to flat (a few centimetres in half a second)
    in one constraint instead of splitting it.
    """
    from numpy.lib.stride_tricks import sliding_window_view

    positions = np.asarray(positions, dtype=float)
    T = positions.shape[0]
    n = max(int(min_frames), 2)
    if T < n:
        return []
    win = sliding_window_view(positions, n, axis=0)  # (T-n+1, 3, n)
    with np.errstate(invalid="ignore"):
        diag = np.linalg.norm(win.max(axis=-1) - win.min(axis=-1), axis=-1)
    still = (diag <= tolerance).astype(int)  # NaN compares False: a gap is never still
    # frame f is covered by windows starting in [f-n+1, f]
    edges = np.zeros(T + 1, dtype=int)
    edges[: T - n + 1] += still
    edges[n : T + 1] -= still
    covered = np.cumsum(edges)[:T] > 0
    step = np.diff(np.concatenate([[0], covered.astype(int), [0]]))
    return list(zip(np.flatnonzero(step == 1).tolist(), (np.flatnonzero(step == -1) - 1).tolist(), strict=True))


def detect_contacts(
    motion: BvhMotion | MarkerMotion,
    joints: tuple[str, ...] | list[str] | None = None,
    *,
    min_duration: float = DEFAULT_MIN_CONTACT,
    tolerance: float = DEFAULT_TOLERANCE,
) -> tuple[Constraint, ...]:
    """Contact constraints of a clip.

    Parameters
    ----------
    joints : joint names or marker labels; default :func:`contact_joints`.
    min_duration : seconds a point must rest to make a constraint.
    tolerance : fraction of the figure height (see :func:`planted_intervals`).

    Returns
    -------
    Constraints (start and end in seconds, on frames), sorted by start, then
    by joint order.
    """
    if not np.isfinite(min_duration) or min_duration < 0:
        raise UsageError(f"{arg('min_contact')} must be a non-negative number of seconds, got {min_duration}")
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise UsageError(
            f"{arg('contact_tolerance')} must be a positive fraction of the figure height, got {tolerance}"
        )
    names = contact_joints(motion, joints)
    if not names:
        return ()
    names, pos, height = effector_positions(motion, names)
    every = effector_positions(motion)[1]
    if isinstance(motion, BvhMotion):
        body = body_joints(motion.skeleton)
    else:
        body, height = _body(motion)
    up = up_direction(every, height, body)
    with np.errstate(invalid="ignore"):
        h = pos @ up  # (T, n)
        floor = np.array([np.percentile(c[np.isfinite(c)], 5) if np.isfinite(c).any() else np.nan for c in h.T])
        near_floor = h <= floor[None, :] + GROUND_BAND * height
    pos = np.where(near_floor[..., None], pos, np.nan)
    ft = float(motion.frame_time)
    # the nominal rate: 0.0333333 s frames must give 3 frame steps for 0.1 s
    min_frames = max(int(np.ceil(min_duration * float(motion.rate) - 1e-6)) + 1, 2)
    found = []
    for n, name in enumerate(names):
        for s, e in planted_intervals(pos[:, n], tolerance * height, min_frames):
            found.append((s, n, e, name))
    found.sort()
    return tuple(Constraint(name, s * ft, e * ft) for s, _, e, name in found)


def never_rested(names, constraints) -> tuple[str, ...]:
    """The ``names`` (in their order) that no constraint of ``constraints`` is on."""
    on = {c.joint for c in constraints}
    return tuple(n for n in names if n not in on)


def rest_rule(min_duration: float, tolerance: float) -> str:
    """The detector's rule in words, for a message: what "at rest" means."""
    return (
        f"never still within {100 * tolerance:g} % of the figure height for {min_duration:g} s "
        "near the lowest level each reaches"
    )


def warn_never_rested(
    names, constraints, *, min_duration: float = DEFAULT_MIN_CONTACT, tolerance: float = DEFAULT_TOLERANCE
) -> tuple[str, ...]:
    """One warning line naming the chosen joints or markers ``names`` that
    never come to rest (no constraint in ``constraints``): without it a
    ``--contact-joints`` that names a heel which never touches gives no
    constraint and no word.  Returns those names."""
    idle = never_rested(names, constraints)
    if idle:
        share = "all" if len(idle) == len(names) else f"{len(idle)} of the"
        warn(
            f"no contact on %s (%s %d named): %s (see {arg('contact_tolerance')}, {arg('min_contact')})",
            ", ".join(idle),
            share,
            len(names),
            rest_rule(min_duration, tolerance),
        )
    return idle
