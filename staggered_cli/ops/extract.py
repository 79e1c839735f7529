"""Dense motion -> staggered-pose document (paper section 4, SPEC section 4).

1. Local evidence ``p_i`` and weights ``w_i`` from motion trails
   (:mod:`staggered_cli.signals`); contact constraints
   (:mod:`staggered_cli.contacts`).
2. Global evidence: a pulse of :data:`~staggered_cli.signals.DEFAULT_PULSE`
   seconds at every contact start and end (not at the clip's ends, where
   nothing changes), weighted like the strongest variable.
3. ``P(t) = tent(Σ w_i p_i / Σ w_i)`` over the local evidence and the pulses.
4. Candidate poses at the local maxima of ``P``, plus the first and last
   frame, kept when the *significance gate* passes (below), and a pose on
   every contact change (below).  Priority ``w_k = P(t_k)(t_{k+1} - t_{k-1})``
   over the kept list (infinite for the first and last pose).
5. Refinements: for every pose and variable, the local maximum of ``p_i``
   nearest ``t_k`` within ``refine_window`` seconds and strictly closer to
   ``t_k`` than to the neighbouring poses; none -> 0.  Refinements are whole
   frames, and the "closer to its own pose" rule keeps every variable's knots
   in order (extreme knots stay between the midpoints of their neighbours).
6. Splines and displacement maps: :func:`staggered_cli.document.from_motion`.

Significance gate
    The scaled curvature ignores amplitude: a figure swaying by a centimetre
    makes as many peaks as one walking.  A candidate is kept only where the
    figure moves: the *amount of motion* (:attr:`LocalEvidence.speed`, the
    sum over variables of how fast each moves the body, in figure heights
    per second: limb length × angular speed for rotations, speed for
    translations), averaged with a tent filter of twice the refinement
    window (0.5 s, the paper's cluster width), must reach ``significance``
    (default :data:`DEFAULT_SIGNIFICANCE` = 0.5 figure heights per second).
    Walking and running move the body by 4-15 figure heights per second, a
    standing bow by 0.3-2, an idle stance by about 0.1.

Poses on contact changes
    Contact starts and ends are the paper's global evidence, and poses are
    expected on them.  But the tent filter merges changes closer than its
    width (heel strike and foot flat are 0.05-0.1 s apart) and the slope of
    the local evidence shifts the merged maximum, so at 120 Hz most maxima
    would miss the change by more than two frames.  Every contact change is
    therefore a candidate itself (changes at most four frames apart share
    one pose in their middle, :func:`contact_poses`); a maximum of ``P``
    within half the filter width of such a pose is taken to be the same
    event and dropped.  These poses bypass the significance gate.
"""

from __future__ import annotations

import numpy as np

from .. import contacts as contact_detection
from .. import signals
from ..document import Document, from_motion
from ..errors import DataError, UsageError
from ..motion import BvhMotion, MarkerMotion, rate_problem

#: Default significance gate, figure heights per second of motion.
DEFAULT_SIGNIFICANCE = 0.5
#: Contact changes at most this many seconds apart share one pose, placed
#: between them (a duration, so 30 and 120 Hz captures of one motion keep the
#: same contact poses: 1 frame at 30 Hz, 4 at 120 Hz; every change is then
#: within 2 frames of its pose at any rate).
CONTACT_MERGE = 1.0 / 30.0
#: Default refinement search window, seconds (paper: 0.25 s).
DEFAULT_REFINE_WINDOW = 0.25


#: Largest clip extract takes, in values: frames x channels (BVH) or frames x
#: markers x 3 (C3D).  Extraction needs about 160 bytes per BVH value
#: (measured: 1.1 GB for 6.6 million), so this keeps it under about 1.4 GB;
#: 8 million values are 23 minutes of a 31-joint skeleton at 60 Hz.
MAX_EXTRACT_VALUES = 8_000_000

#: Largest values of the options that are durations, seconds: far beyond any
#: use (the defaults are 0.025 to 0.25 s), and they bound the filters' cost.
MAX_SMOOTHING = 10.0
MAX_FILTER_WIDTH = 10.0
MAX_REFINE_WINDOW = 10.0
MAX_MIN_CONTACT = 60.0


def _check(name: str, value: float, *, positive: bool = False, upper: float | None = None) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise UsageError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(value) or value < 0 or (positive and value == 0):
        raise UsageError(f"{name} must be a {'positive' if positive else 'non-negative'} number, got {value}")
    if upper is not None and value > upper:
        raise UsageError(f"{name} must be at most {upper:g} s, got {value:g}")
    return value + 0.0  # -0.0 -> 0.0


def contact_boundaries(constraints, n_frames: int, rate: float, breaks: np.ndarray) -> np.ndarray:
    """Frames (sorted, unique) where a contact starts or ends, leaving out the
    clip's first and last frame and frames next to a break (a T-pose frame):
    there nothing changes, the clip just begins or ends."""
    frames = []
    for c in constraints:
        s = int(round(c.start * rate))
        e = int(round(c.end * rate))
        if s > 0 and not breaks[s - 1]:
            frames.append(s)
        if e < n_frames - 1 and not breaks[e]:
            frames.append(e)
    return np.unique(np.array(frames, dtype=int))


def contact_poses(boundaries: np.ndarray, merge: int = 4) -> np.ndarray:
    """Pose frames for the contact changes: each change gets its own pose,
    except that changes at most ``merge`` frames apart share one in the
    middle of them (so each is within ``merge / 2`` frames of its pose)."""
    out = []
    b = np.sort(np.asarray(boundaries, dtype=int))
    i = 0
    while i < len(b):
        j = int(np.searchsorted(b, b[i] + merge, side="right"))
        out.append((b[i] + b[j - 1]) // 2)
        i = j
    return np.array(out, dtype=int)


def refinement_frames(p: np.ndarray, pose_f: np.ndarray, window: int) -> np.ndarray:
    """Refinements in frames (K, V) from local evidence peaks.

    Parameters
    ----------
    p : (T, V) local evidence.
    pose_f : (K,) strictly increasing pose frames.
    window : largest refinement, frames.

    For pose ``k`` and variable ``i`` the refinement is ``τ - f_k`` for the
    local maximum ``τ`` of ``p_i`` nearest ``f_k`` with ``|τ - f_k| <= window``
    and strictly closer to ``f_k`` than to ``f_{k-1}`` and ``f_{k+1}`` (a
    tie goes to the higher peak, then the earlier); 0 if there is none.  The
    first and last poses are 0.
    """
    K = len(pose_f)
    V = p.shape[1]
    out = np.zeros((K, V), dtype=int)
    if K < 3:
        return out
    f = pose_f[1:-1]
    # the open interval a peak must lie in, doubled to stay in integers
    lo2 = np.maximum(pose_f[:-2] + f, 2 * (f - window) - 1)  # 2τ > lo2
    hi2 = np.minimum(f + pose_f[2:], 2 * (f + window) + 1)  # 2τ < hi2
    for i in range(V):
        peaks = signals.local_maxima(p[:, i])
        if len(peaks) == 0:
            continue
        j = np.searchsorted(peaks, f, side="right")  # peaks[j-1] <= f < peaks[j]
        left = peaks[np.maximum(j - 1, 0)]
        right = peaks[np.minimum(j, len(peaks) - 1)]
        ok_l = (j > 0) & (2 * left > lo2)
        ok_r = (j < len(peaks)) & (2 * right < hi2)
        dl = np.where(ok_l, f - left, np.iinfo(int).max)
        dr = np.where(ok_r, right - f, np.iinfo(int).max)
        take_r = (dr < dl) | ((dr == dl) & (p[right, i] > p[left, i]))
        tau = np.where(take_r, right, left)
        out[1:-1, i] = np.where(ok_l | ok_r, tau - f, 0)
    return out


def extract(
    motion: BvhMotion | MarkerMotion,
    *,
    source_name: str = "",
    source_bytes: bytes | None = None,
    contact_joints: tuple[str, ...] | list[str] | None = None,
    smoothing: float | None = None,
    filter_width: float = signals.DEFAULT_FILTER_WIDTH,
    refine_window: float = DEFAULT_REFINE_WINDOW,
    min_contact: float = contact_detection.DEFAULT_MIN_CONTACT,
    contact_tolerance: float = contact_detection.DEFAULT_TOLERANCE,
    significance: float = DEFAULT_SIGNIFICANCE,
) -> Document:
    """Find staggered poses, refinements and contacts in a dense clip.

    Parameters
    ----------
    motion : a BVH or C3D clip.
    source_name, source_bytes : recorded in the document (name, SHA-256).
    contact_joints : joint names or marker labels; default feet and toes
        (BVH) or the lowest markers (C3D).
    smoothing : Laplacian smoothing of the local evidence, the standard
        deviation in seconds (default :data:`signals.DEFAULT_SMOOTHING`).
    filter_width : tent filter full base width, seconds.
    refine_window : largest refinement, seconds.
    min_contact : shortest contact, seconds.
    contact_tolerance : contact tolerance, a fraction of the figure height.
    significance : amount of motion (figure heights per second) a candidate
        pose needs; 0 keeps every local maximum of ``P``.

    Returns
    -------
    Document with signals ``P`` (T,), ``p`` (T, V), ``weights`` (V,) and
    ``contact`` (T,), and every option in ``parameters``.

    Raises
    ------
    UsageError for a bad option or an unknown contact joint.
    """
    smoothing = _check(
        "--smoothing", signals.DEFAULT_SMOOTHING if smoothing is None else smoothing, upper=MAX_SMOOTHING
    )
    filter_width = _check("--filter-width", filter_width, upper=MAX_FILTER_WIDTH)
    refine_window = _check("--refine-window", refine_window, upper=MAX_REFINE_WINDOW)
    min_contact = _check("--min-contact", min_contact, upper=MAX_MIN_CONTACT)
    contact_tolerance = _check("--contact-tolerance", contact_tolerance, positive=True)
    significance = _check("--significance", significance)
    T = motion.n_frames
    rate = float(motion.rate)
    size = motion.channels.size if isinstance(motion, BvhMotion) else motion.points.size
    if size > MAX_EXTRACT_VALUES:
        raise DataError(
            f"is too long to extract: {size:,} values, more than the limit of {MAX_EXTRACT_VALUES:,} "
            "(frames x channels, or frames x markers x 3): cut it into parts"
        )
    problem = rate_problem(rate) if np.isfinite(rate) else "is not a finite number"
    if problem is not None:
        raise DataError(f"frame rate {rate:g} Hz {problem}")

    ev = signals.local_evidence(motion, smoothing)
    joints = contact_detection.contact_joints(motion, contact_joints)
    constraints = contact_detection.detect_contacts(
        motion, joints, min_duration=min_contact, tolerance=contact_tolerance
    )
    boundaries = contact_boundaries(constraints, T, rate, ev.breaks)
    contact = signals.contact_pulses(boundaries, T, rate, signals.DEFAULT_PULSE)
    contact_weight = float(ev.weights.max()) if len(ev.weights) else 0.0
    P = signals.pose_probability(ev, contact, contact_weight, filter_width)

    on_contact = contact_poses(boundaries, max(int(round(CONTACT_MERGE * rate + 1e-9)), 0))
    cand = signals.local_maxima(P)
    if len(on_contact):
        # a maximum of P this close to a contact change is that change
        reach = 0.5 * filter_width * rate
        j = np.searchsorted(on_contact, cand)
        before = on_contact[np.maximum(j - 1, 0)]
        after = on_contact[np.minimum(j, len(on_contact) - 1)]
        cand = cand[np.minimum(np.abs(cand - before), np.abs(cand - after)) > reach]
    if significance > 0 and len(cand):
        amount = signals.tent_filter(ev.speed, 2.0 * refine_window, rate)
        cand = cand[amount[cand] >= significance]
    cand = np.concatenate([cand, on_contact])
    pose_f = np.unique(np.concatenate([[0, T - 1], cand]).astype(int))
    pose_t = pose_f * float(motion.frame_time)

    priority = np.full(len(pose_f), np.inf)
    if len(pose_f) > 2:
        priority[1:-1] = P[pose_f[1:-1]] * (pose_t[2:] - pose_t[:-2])

    window = int(np.floor(refine_window * rate + 1e-6))
    refine = refinement_frames(ev.p, pose_f, window) * float(motion.frame_time)

    parameters = {
        "smoothing": smoothing,
        "filter_width": filter_width,
        "refine_window": refine_window,
        "min_contact": min_contact,
        "contact_tolerance": contact_tolerance,
        "significance": significance,
        "contact_joints": list(joints),
        "contact_pulse": signals.DEFAULT_PULSE,
    }
    sigs = {"P": P, "p": ev.p, "weights": ev.weights, "contact": contact}
    return from_motion(
        motion,
        pose_t,
        refine,
        priority=priority,
        source_name=source_name,
        source_bytes=source_bytes,
        constraints=constraints,
        signals=sigs,
        parameters=parameters,
    )
