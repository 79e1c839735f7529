"""Dense motion -> staggered-pose document (paper section 4, SPEC section 4).

1. Local evidence ``p_i`` and weights ``w_i`` from motion trails
   (:mod:`staggered_cli.signals`); contact constraints
   (:mod:`staggered_cli.contacts`).
2. Global evidence: a pulse of :data:`~staggered_cli.signals.probability.DEFAULT_PULSE`
   seconds at every contact start and end (not at the clip's ends, where
   nothing changes), weighted like the strongest variable.
3. ``P(t) = tent(Σ w_i p_i / Σ w_i)`` over the local evidence and the pulses.
4. How many poses: one per cluster of coordinated events
   (:func:`pose_count`): the significant local maxima of ``P`` at least
   ``min_spacing`` apart, or the clusters of contact changes if there are
   more.  The first and last frame, both sides of a one-frame
   discontinuity (the CMU T-pose), and the top of every flight phase
   (:func:`flight_frames`: no contact for :data:`MIN_FLIGHT` seconds or
   more while the figure's centre falls as a thrown body does, a hop's or
   a jump's time in the air) always carry a pose.  Unless the user gives
   them, ``filter_width`` and ``min_spacing`` follow the motion's tempo
   (:func:`tempo_scale`, issue 34): a clip that strides faster than once a
   second (a run, a dance, a sped-up walk) gets proportionally shorter
   ones, so a pose still marks each phase of the step, not one per stance.
5. Where they go (:func:`optimal_poses`; beyond the paper, whose poses sit
   on the maxima and whose priority ignores the fit): the frames near a
   feature (a peak of the combined evidence, or a contact cluster), chosen
   so that the spline layer alone fits the motion best, measured by the
   proxy of :mod:`staggered_cli.signals.placement`.  A pose that covers contact
   changes costs less, so contacts keep shaping the poses; so does one on a
   limb's swing (:data:`SWING_COVER` of the height or more along the
   heading) that the first placement left with no pose within the filter
   width (:func:`uncovered_swings`: a dance's slow arm swings, between
   poses the fit had spent where the motion is fast), placed again.
6. Refinements: the contact changes of a pose's cluster put the planted
   leg's knots on its contact frame (:func:`contact_refinements`); other
   variables take the local maximum of ``p_i`` nearest ``t_k`` within
   ``refine_window`` seconds and strictly closer to ``t_k`` than to the
   neighbouring poses (:func:`refinement_frames`), kept only where they earn
   their keep (:func:`prune_refinements`).  A BVH translation (the root's)
   takes, within the same bounds, its own largest extreme instead
   (:func:`strongest_frames`): where one of its coordinates turns back
   (:func:`trails.coordinate_extremes`: the crouch, the apex, a walk's down
   and up; the largest, not the nearest, since the nearest turn was often
   another axis's small one; the height's own extreme first, unless the
   largest other fits the root strictly better: :func:`better_fit`), kept unless it makes the fit
   worse (issue 34: the curvature of the root's 3-D path peaks where the
   path bends, not where the height turns, and the misfit rule, which asks
   a knot to cut the root's whole misfit to 40 %, kept 34 of 471; a vertical
   extreme removes the vertical misfit only).  A limb's rotations (an arm
   from the collar to the fingers, a leg from the hip, the neck and head:
   :func:`trails.limb_tops`) take the largest extreme of the limb near the
   pose (:func:`strongest_frames`) of its end's offset from the pelvis along
   the body's heading (:func:`trails.heading_offsets`: the hand's swing, the
   foot's step), else where its end, seen from the limb's top in the
   torso's frame, turns back (:func:`trails.limb_extremes`), all of the limb's joints together, kept
   unless they make the limb's summed misfit worse (issue 34: each arm joint
   on its own curvature peak, or on its own extreme, fitted its own angle
   better and the hand worse: staggered within a chain, the joints' errors
   stop cancelling; the torso's joints, whose counter-rotations cancel the
   same way, keep the curvature rule).  Refinements are whole frames;
   the "closer to its own pose" rule keeps every variable's knots in order.
   Priority ``w_k = P(t_k)(t_{k+1} - t_{k-1})`` (infinite for the first and
   last pose) stays for ``cull --by paper``.
7. Splines and displacement maps: :func:`staggered_cli.model.variables.from_motion`.

Significance gate
    The scaled curvature ignores amplitude: a figure swaying by a centimetre
    makes as many peaks as one walking.  A maximum of ``P`` counts as a pose
    only where the figure moves: the *amount of motion*
    (:attr:`LocalEvidence.speed`, the sum over variables of how fast each
    moves the body, in figure heights per second: limb length × angular
    speed for rotations, speed for translations), averaged with a tent
    filter of twice the refinement window (0.5 s, the paper's cluster
    width), must reach ``significance`` (default
    :data:`DEFAULT_SIGNIFICANCE` = 0.5 figure heights per second).  Walking
    and running move the body by 4-15 figure heights per second, a standing
    bow by 0.3-2, an idle stance by about 0.1.
"""

from __future__ import annotations

import bisect

import numpy as np

from ..contacts import detect as contact_detection
from ..contacts import ik
from ..errors import DataError, UsageError, arg
from ..model.document import Document
from ..model.kinds import ROTATION
from ..model.variables import dense_variables, fits_by_column, from_motion, variable_layout
from ..motion import BvhMotion, MarkerMotion, rate_problem
from ..signals import partial as partial_poses
from ..signals import placement, probability, trails
from ..signals.smoothing import DEFAULT_FILTER_WIDTH, DEFAULT_SMOOTHING, tent_filter
from ..skeleton import body_joints
from . import partial as partial_ops

#: Default significance gate, figure heights per second of motion.
DEFAULT_SIGNIFICANCE = 0.5
#: Poses are placed on a grid of this many frames per second (a pose frame
#: is then a whole 30 Hz frame, at any capture rate).
PLACEMENT_RATE = 30.0
#: The longest segment placement considers, in average segments.
SEGMENT_REACH = 3.0
#: A pose costs this share of the price less in placement for each contact
#: change within its cluster's reach (at most all of it).
CONTACT_REWARD = 0.15
#: A refinement stays only where it cuts the misfit around its pose to this share.
REFINE_GAIN = 0.4
#: A translation's refinement onto its own extreme stays unless it makes the
#: misfit around its pose worse.
EXTREME_GAIN = 1.0
#: A flight phase (no contact joint planted, between two contacts) at least
#: this long, seconds, gets a pose of its own at its top (issue 34: a
#: dance's short hops fell between the poses of the take-off and landing).
MIN_FLIGHT = 0.1
#: Default fewest seconds between two poses (issue 13), and the most allowed.
DEFAULT_MIN_SPACING = 0.1
MAX_MIN_SPACING = 10.0
#: Default refinement search window, seconds (paper: 0.25 s).
DEFAULT_REFINE_WINDOW = 0.25
#: Tempo scaling of the default ``filter_width`` and ``min_spacing``
#: (issue 34, fast motion): a clip whose stride (:func:`stride_period`) is
#: shorter than this many seconds scales both by ``stride / REFERENCE_STRIDE``.
#: The dev walks stride every 1.0-1.1 s and keep the defaults; the run
#: strides every 0.73 s, the dances every 0.65-0.67 s.
REFERENCE_STRIDE = 1.0
#: The smallest tempo scale: a motion three times as fast as a walk, or
#: faster, gets a third of the default durations (0.05 s and 0.033 s).
MIN_TEMPO_SCALE = 1.0 / 3.0


#: Largest clip extract takes, in values: frames x channels (BVH) or frames x
#: markers x 3 (C3D).  Extraction works over blocks of frames and groups of
#: variables, about 48 bytes per BVH value at an hour (measured: 1,978 MB for
#: 41.5 million, cmu_01_01 repeated to 432,064 frames), so this keeps it
#: under about 2.3 GB; 48 million values are one hour and 9 minutes of a
#: 31-joint skeleton (96 channels) at 120 Hz.
MAX_EXTRACT_VALUES = 48_000_000

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


def _open_windows(pose_f: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """For each inner pose, the open interval ``lo2 < 2τ < hi2`` an extreme
    ``τ`` must lie in: within ``window`` frames of its pose and strictly
    closer to it than to its neighbours (doubled to stay in integers)."""
    f = pose_f[1:-1]
    lo2 = np.maximum(pose_f[:-2] + f, 2 * (f - window) - 1)
    hi2 = np.minimum(f + pose_f[2:], 2 * (f + window) + 1)
    return lo2, hi2


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
    lo2, hi2 = _open_windows(pose_f, window)
    for i in range(V):
        peaks = probability.local_maxima(p[:, i])
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


def strongest_frames(e: np.ndarray, pose_f: np.ndarray, window: int) -> np.ndarray:
    """Refinements in frames (K, V) onto the strongest extreme near each pose.

    Like :func:`refinement_frames`, but of the frames where ``e`` (T, V) is
    positive within ``window`` frames of ``f_k`` and strictly closer to it
    than to its neighbours, the one of largest ``e`` (the largest swing; a
    tie goes to the nearer, then the earlier); 0 if there is none.
    """
    K = len(pose_f)
    V = e.shape[1]
    out = np.zeros((K, V), dtype=int)
    if K < 3:
        return out
    f = pose_f[1:-1]
    lo2, hi2 = _open_windows(pose_f, window)
    for i in range(V):
        at = np.flatnonzero(e[:, i] > 0)
        if len(at) == 0:
            continue
        a = np.searchsorted(at, (lo2 + 2) // 2)  # first frame with 2τ > lo2
        b = np.searchsorted(at, (hi2 + 1) // 2)  # first frame with 2τ >= hi2
        for k in np.flatnonzero(b > a):
            c = at[a[k] : b[k]]
            key = np.lexsort((c, np.abs(c - f[k]), -e[c, i]))
            out[k + 1, i] = c[key[0]] - f[k]
    return out


def contact_clusters(boundaries: np.ndarray, reach: int, n_frames: int) -> list[np.ndarray]:
    """Contact changes grouped so that one pose can cover each group: a pose
    covers a change within ``reach`` frames of it.  Returns, per cluster, the
    frames from which a pose covers all its changes (sorted)."""
    out = []
    b = np.sort(np.asarray(boundaries, dtype=int))
    i = 0
    while i < len(b):
        j = int(np.searchsorted(b, b[i] + 2 * reach, side="right"))
        lo, hi = max(int(b[j - 1]) - reach, 0), min(int(b[i]) + reach, n_frames - 1)
        out.append(np.arange(lo, hi + 1))
        i = j
    return out


def _spaced(frames: list[int], strength: np.ndarray, taken: np.ndarray, spacing: int) -> np.ndarray:
    """``taken`` plus the ``frames`` (strongest first) at least ``spacing`` from every frame taken."""
    kept = np.unique(np.asarray(taken, dtype=int)).tolist()  # sorted: a frame's nearest are beside its place
    for f in sorted(frames, key=lambda f: (-strength[f], f)):
        i = bisect.bisect_left(kept, f)
        if (i == len(kept) or kept[i] - f >= spacing) and (i == 0 or f - kept[i - 1] >= spacing):
            kept.insert(i, f)
    return np.array(kept, dtype=int)


def pose_count(P: np.ndarray, clusters: list[np.ndarray], gate: np.ndarray, forced: np.ndarray, spacing: int) -> int:
    """How many poses a clip gets: one per cluster of coordinated events.

    The clusters are the significant local maxima of ``P`` (where ``gate``
    passes) and the contact clusters (each at its strongest ``P``), taken in
    order of ``P`` and at least ``spacing`` frames apart, plus the ``forced``
    poses.  The larger of the two counts: the maxima of ``P`` (the paper's
    candidates) or the contact clusters.
    """
    maxima = [int(m) for m in probability.local_maxima(P) if gate[m]]
    on_contact = [int(c[np.argmax(P[c])]) for c in clusters]
    return max(len(_spaced(maxima, P, forced, spacing)), len(_spaced(on_contact, P, forced, spacing)))


def near_frames(frames: np.ndarray, reach: int, n_frames: int) -> np.ndarray:
    """(T,) how many of ``frames`` are within ``reach`` frames of each frame."""
    covers = np.zeros(n_frames + 1)
    np.add.at(covers, np.clip(np.asarray(frames, dtype=int) - reach, 0, n_frames), 1.0)
    np.add.at(covers, np.clip(np.asarray(frames, dtype=int) + reach + 1, 0, n_frames), -1.0)
    return np.cumsum(covers)[:n_frames]


def feature_sites(evidence: np.ndarray, reach: int) -> np.ndarray:
    """Frames where a pose may go: within ``reach`` frames of a local maximum
    of the combined local evidence (before the tent filter merges them)."""
    return np.flatnonzero(near_frames(probability.local_maxima(evidence), reach, len(evidence)) > 0)


def optimal_poses(
    proxy: placement.Proxy,
    forced: np.ndarray,
    allowed: np.ndarray,
    reward: np.ndarray,
    spacing: int,
    count: int,
    stride: int,
    reach: float,
    costs: dict | None = None,
) -> np.ndarray:
    """About ``count`` pose frames whose spline layer fits best.

    Parameters
    ----------
    forced : sorted frames every placement keeps (the first and last included).
    allowed : (T,) bool, the frames a pose may take (on a cluster of features).
    reward : (T,) in [0, 1], how much cheaper a pose is there (a pose that
        covers contact changes is the paper's global evidence at work).
    spacing : fewest frames between two poses (forced ones excepted).
    count : the number of poses wanted.
    stride : frames between the nodes of the grid poses are placed on.
    reach : the longest segment, in average segments.
    costs : a dict that keeps the segment costs of each stretch between two
        forced frames by its nodes, for a placement again with other rewards
        (or nodes near a few frames more: the stretches without them keep theirs).

    Between each two forced frames, a shortest path over a regular grid of
    nodes: an edge is a segment, its length the proxy cost of the segment
    (:func:`placement.window_costs`), and every pose on the way costs a price
    (less its reward).  The one price for the whole clip is bisected until
    the paths hold ``count`` poses (or the nearest count a price gives).
    Linear in the clip's length.
    """
    forced = np.unique(np.asarray(forced, dtype=int))
    T = len(allowed)
    if count <= len(forced) or len(forced) < 2:
        return forced
    nodes_all = (T - 1) // stride + 1
    W = max(2, int(np.ceil(reach * nodes_all / max(count - 1, 1))))
    pieces = []
    for f0, f1 in zip(forced[:-1], forced[1:], strict=True):
        grid = np.arange(f0 + stride, f1, stride)
        nodes = np.concatenate([[f0], grid[allowed[grid]], [f1]])
        G = len(nodes)
        if G < 3 or f1 - f0 < 2 * spacing:
            pieces.append((nodes, None, None))
            continue
        Wp = min(W, G - 1)
        key = (Wp, nodes.tobytes())
        seg = None if costs is None else costs.get(key)
        if seg is None:
            seg = placement.window_costs(proxy, nodes, Wp)
            if costs is not None:
                costs[key] = seg
        i = np.arange(G)[:, None]
        j = i + np.arange(1, Wp + 1)[None, :]
        jc = np.minimum(j, G - 1)
        gap = nodes[jc] - nodes[i]
        bad = (j >= G) | (gap < spacing)
        seg = np.where(bad, np.inf, seg)
        into = np.full((G, Wp), np.inf)  # into[n, w-1]: the segment from node n - w
        for w in range(1, Wp + 1):
            into[w:, w - 1] = seg[: G - w, w - 1]
        discount = 1.0 - np.clip(reward[nodes], 0.0, 1.0)
        discount[-1] = 0.0  # the piece's end is paid for as a forced pose
        pieces.append((nodes, into, discount))

    def paths(price: float) -> list[np.ndarray]:
        out = []
        for nodes, into, discount in pieces:
            if into is None:
                out.append(nodes[[0, -1]])
                continue
            G, Wp = into.shape
            best = np.full(G, np.inf)
            back = np.zeros(G, dtype=int)
            best[0] = 0.0
            cost = price * discount
            for n in range(1, G):
                k = min(n, Wp)
                # best[n - 1], best[n - 2], ..., best[n - k]: a reversed view
                v = best[n - k : n][::-1] + into[n, :k]
                w = int(v.argmin())
                best[n] = v[w] + cost[n]
                back[n] = n - 1 - w
            walk = [G - 1]
            while walk[-1] > 0:
                walk.append(int(back[walk[-1]]))
            out.append(nodes[walk[::-1]])
        return out

    def total(ps: list[np.ndarray]) -> int:
        return sum(len(p) for p in ps) - (len(ps) - 1)

    # bracket the price from a typical segment's cost, then bisect in log scale
    finite = np.concatenate([into[np.isfinite(into)] for _, into, _ in pieces if into is not None] or [np.ones(1)])
    price = max(float(np.median(finite)), 1e-12)
    found = {}

    def count_at(p: float) -> int:
        if p not in found:
            ps = paths(p)
            found[p] = (total(ps), ps)
        return found[p][0]

    lo, hi = price, price
    while count_at(lo) < count and lo > 1e-12 * price:
        lo /= 8.0
    while count_at(hi) > count and hi < 1e12 * price:
        hi *= 8.0
    for _ in range(30):
        if count_at(lo) == count or count_at(hi) == count or hi / lo < 1.0 + 1e-6:
            break
        mid = float(np.sqrt(lo * hi))
        if count_at(mid) > count:
            lo = mid
        else:
            hi = mid
    best_ps = min(found.values(), key=lambda v: (abs(v[0] - count), -v[0]))[1]
    return np.unique(np.concatenate(best_ps))


#: A limb's swing along the body's heading (:func:`trails.heading_offsets`:
#: the hand forward and back, the foot's step) of at least this share of the
#: figure height is an event an animator keys; a walking hand swings by
#: 10-20 % of the height each way.
SWING_COVER = 0.05


def heading_swings(
    heading: tuple[np.ndarray, np.ndarray] | None, ev: trails.LocalEvidence, smoothing: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """``(tops, swings)``: the limbs' top joints and, for each (T, L), the
    extremes of its end's offset along the heading (:func:`trails.coordinate_extremes`
    of ``heading``'s :func:`trails.heading_offsets`: the hand's swing forward
    and back, the foot's step); None without a heading."""
    if heading is None:
        return None
    tops, offsets = heading
    return tops, trails.coordinate_extremes(offsets[:, :, None], ev.figure_height, ev.rate, ev.breaks, smoothing)


def uncovered_swings(swings: tuple[np.ndarray, np.ndarray] | None, pose_f: np.ndarray, reach: int) -> np.ndarray:
    """Sorted frames of the limbs' swing extremes (:func:`heading_swings`) of
    at least :data:`SWING_COVER` of the figure height that have no pose
    within ``2 reach`` frames (the pose probability's filter width)."""
    if swings is None or len(pose_f) == 0:
        return np.zeros(0, dtype=int)
    big = np.flatnonzero((swings[1] >= SWING_COVER).any(axis=1))
    if len(big) == 0:
        return big
    j = np.clip(np.searchsorted(pose_f, big), 1, max(len(pose_f) - 1, 1))
    near = np.minimum(np.abs(big - pose_f[j - 1]), np.abs(pose_f[np.minimum(j, len(pose_f) - 1)] - big))
    return big[near > 2 * reach]


def contact_events(constraints, n_frames: int, rate: float, breaks: np.ndarray) -> list[tuple[str, int]]:
    """(joint, frame) of every contact start and end, leaving out the clip's
    first and last frame and frames next to a break (a T-pose frame): there
    nothing changes, the clip just begins or ends."""
    out = []
    for c in constraints:
        s = int(round(c.start * rate))
        e = int(round(c.end * rate))
        if 0 < s and not breaks[s - 1]:
            out.append((c.joint, s))
        if e < n_frames - 1 and not breaks[e]:
            out.append((c.joint, e))
    return out


#: A flight's body falls: the height of the figure's centre accelerates
#: downward by at least this share of gravity over it (a 1.75 m figure: 9.81
#: m/s² is 5.6 figure heights/s²).  Without a contact joint planted a body
#: may still rest on its hands or its back (a breakdance: its centre hardly
#: accelerates); a hop's, a jump's and a run's centre falls at about 1 g.
BALLISTIC = 0.5
_GRAVITY = 9.81 / 1.75


def center_height(motion: BvhMotion | MarkerMotion) -> np.ndarray:
    """(T,) the height of the mean of the figure's joints or seen markers, in
    figure heights (BVH: from its world positions, so before they are released)."""
    height = float(motion.figure_height())
    pts = motion.world_positions() if isinstance(motion, BvhMotion) else motion.points
    up = contact_detection.up_direction(pts, height)
    out = np.zeros(pts.shape[0])
    step = max(1, (1 << 16) // max(pts.shape[1], 1))
    for lo in range(0, pts.shape[0], step):
        h = pts[lo : lo + step] @ up  # (n, J)
        seen = np.isfinite(h)
        out[lo : lo + step] = np.where(seen, h, 0.0).sum(axis=1) / np.maximum(seen.sum(axis=1), 1)
    return out / height if height > 0 else out


def flight_frames(constraints, n_frames: int, rate: float, center: np.ndarray | None = None) -> np.ndarray:
    """The top of every flight phase: frames where no contact is
    planted, at least :data:`MIN_FLIGHT` seconds of them, with a contact
    before and after (not the clip's start or end, which is no flight), over
    which the figure's ``center`` height (figure heights, :func:`center_height`)
    falls as a thrown body does: the parabola fitted to it (a frame before
    and after included) accelerates down by :data:`BALLISTIC` g or more.
    The top is that parabola's vertex, a frame of the flight (without
    ``center``: the flight's middle frame); a hop rises faster than it
    falls, and its middle frame came a frame or two after the apex."""
    if not constraints or n_frames < 3:
        return np.zeros(0, dtype=int)
    held = np.zeros(n_frames + 1, dtype=int)
    for c in constraints:
        s = min(max(int(round(c.start * rate)), 0), n_frames - 1)
        e = min(max(int(round(c.end * rate)), s), n_frames - 1)
        held[s] += 1
        held[e + 1] -= 1
    off = np.cumsum(held)[:n_frames] == 0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], off.astype(int), [0]])))
    starts, ends = edges[0::2], edges[1::2] - 1  # airborne runs, first and last frame
    inner = (starts > 0) & (ends < n_frames - 1) & ((ends - starts + 1) / rate >= MIN_FLIGHT - 1e-9)
    starts, ends = starts[inner], ends[inner]
    if center is None:
        return (starts + ends) // 2
    falls = np.zeros(len(starts), dtype=bool)
    apex = (starts + ends) // 2
    for n, (a, b) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        t = np.arange(a - 1, b + 2) / rate
        c2, c1, _ = np.polyfit(t - t.mean(), center[a - 1 : b + 2], 2)
        falls[n] = 2.0 * c2 <= -BALLISTIC * _GRAVITY
        if falls[n]:  # the parabola's top, a frame of the flight
            apex[n] = min(max(int(round((t.mean() - c1 / (2.0 * c2)) * rate)), a), b)
    return apex[falls]


def chain_variables(motion: BvhMotion | MarkerMotion, names: tuple[str, ...], joint: str) -> np.ndarray:
    """Columns of the variables a contact of ``joint`` concerns: the rotations
    of its leg (the two-bone chain's upper joint down to the joint), or the
    marker itself."""
    if not isinstance(motion, BvhMotion):
        return np.array([names.index(joint)] if joint in names else [], dtype=int)
    sk = motion.skeleton
    e = sk.index(joint)
    try:
        top = ik.two_bone_chain(sk, e).upper
    except UsageError:
        top = e
    path, j = [], e
    while j >= 0:
        path.append(sk.names[j])
        if j == top:
            break
        j = int(sk.parents[j])
    return np.array([names.index(n) for n in path if n in names], dtype=int)


def _in_window(pose_f: np.ndarray, k: np.ndarray, f: np.ndarray, window: int) -> np.ndarray:
    """Whether frames ``f`` may be refinements of poses ``k``: within
    ``window`` frames and strictly closer to their own pose than to the
    neighbours (the rule that keeps knots in order)."""
    K = len(pose_f)
    d = f - pose_f[k]
    ok = (k > 0) & (k < K - 1) & (np.abs(d) <= window)
    prev = pose_f[np.maximum(k - 1, 0)]
    nxt = pose_f[np.minimum(k + 1, K - 1)]
    return ok & (2 * f > pose_f[k] + prev) & (2 * f < pose_f[k] + nxt)


def contact_refinements(
    motion, names: tuple[str, ...], pose_f: np.ndarray, events: list[tuple[str, int]], window: int
) -> tuple[np.ndarray, np.ndarray]:
    """Refinements (K, V) in frames that put the knots of a planted leg on its
    contact change, and the mask (K, V) of where one applies.  A change
    belongs to the nearest pose if it lies in that pose's refinement window;
    of two changes for one variable and pose, the nearer wins."""
    K, V = len(pose_f), len(names)
    out = np.zeros((K, V), dtype=int)
    best = np.full((K, V), np.iinfo(int).max)
    chains: dict[str, np.ndarray] = {}
    if not events or K < 2:
        return out, best < np.iinfo(int).max
    # each event's pose, and whether it lies in that pose's window, for all at once
    f_all = np.array([f for _, f in events])
    k_all = np.clip(np.searchsorted(pose_f, f_all), 1, K - 1)
    k_all -= np.abs(pose_f[k_all - 1] - f_all) < np.abs(pose_f[k_all] - f_all)
    inside = _in_window(pose_f, k_all, f_all, window)
    for (joint, f), k, ok in zip(events, k_all.tolist(), inside.tolist(), strict=True):
        if not ok:
            continue
        cols = chains.get(joint)
        if cols is None:  # (setdefault would find the chain again at every event)
            cols = chains[joint] = chain_variables(motion, names, joint)
        d = f - int(pose_f[k])
        nearer = abs(d) < best[k, cols]
        out[k, cols[nearer]] = d
        best[k, cols[nearer]] = abs(d)
    return out, best < np.iinfo(int).max


def translation_extremes(
    motion, variables, ev: trails.LocalEvidence, smoothing: float, up: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray] | None:
    """``(height_first, extremes)``, each (T, n): the extremes of a BVH
    clip's ``n`` translation variables (the first ``n`` columns,
    :func:`trails.coordinate_extremes`), or None (a C3D clip, no
    translations).  In ``height_first`` the extremes of the height (the
    translation along the world's ``up`` (3,)) are :func:`preferred`: the
    root's crouch and apex, not a larger sway of the hips near them
    (``extremes`` itself without ``up``)."""
    if not isinstance(motion, BvhMotion):
        return None
    groups = [dense for kind, _, _, dense in variables if kind != ROTATION]
    if not groups:
        return None
    dense = np.concatenate(groups, axis=1) if len(groups) > 1 else groups[0]
    out = np.zeros(dense.shape[:2])
    # only the translations that move (a Bandai skeleton's joints carry constant ones)
    moving = np.flatnonzero(np.any(dense != dense[:1], axis=(0, 2)))
    if len(moving):
        out[:, moving] = trails.coordinate_extremes(dense[:, moving], ev.figure_height, ev.rate, ev.breaks, smoothing)
        if up is not None:  # the height's own extremes first (issue 34: a dance's sway outswung them)
            h = (dense[:, moving] @ up)[:, :, None]
            vertical = trails.coordinate_extremes(h, ev.figure_height, ev.rate, ev.breaks, smoothing)
            first = out.copy()
            first[:, moving] = preferred(vertical, out[:, moving])
            return first, out
    return out, out


def better_fit(proxy: placement.Proxy, pose_f: np.ndarray, first: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Refinements (K, n) of the first ``n`` variables: ``first``'s, or
    ``other``'s where that knot makes the spline layer fit the variable
    between the neighbouring poses strictly better (issue 34: the root's
    height extremes, preferred, put its knots on a walk's bob rather than
    on its larger sway and made the Bandai walk's fit 4 % worse)."""
    out = np.array(first, dtype=int)
    K, n = out.shape
    cols = proxy.cols
    if K < 3 or len(cols) == 0:
        return out
    inner = np.flatnonzero(np.any(out[1:-1] != other[1:-1], axis=1)) + 1
    if len(inner) == 0:
        return out
    f = pose_f.astype(float)
    mine = np.flatnonzero(cols < n)  # the proxy's columns of these variables
    costs = []
    for r in (out, other):
        knots = np.broadcast_to(f[inner, None, None], (len(inner), len(cols), 4)).copy()
        e = f[inner, None] + r[inner][:, cols[mine]]
        knots[:, mine, 0] = f[inner - 1, None]
        knots[:, mine, 1] = np.minimum(f[inner, None], e)
        knots[:, mine, 2] = np.maximum(f[inner, None], e)
        knots[:, mine, 3] = f[inner + 1, None]
        costs.append(placement.span_costs(proxy, knots)[:, mine])
    take = costs[1] < costs[0]
    sub = out[inner][:, cols[mine]]
    out[np.ix_(inner, cols[mine])] = np.where(take, other[inner][:, cols[mine]], sub)
    return out


def preferred(first: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Extremes (T, n) for :func:`strongest_frames` in which every extreme of
    ``first`` outranks every one of ``other`` (the largest of ``first``
    near a pose wins; ``other``'s count where ``first`` has none)."""
    top = other.max(axis=0, initial=0.0)
    return np.where(first > 0, first + top, other)


def limbs_own_extremes(
    motion,
    variables,
    ev: trails.LocalEvidence,
    smoothing: float,
    swings: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The own extremes of a BVH clip's limbs: ``(limb, extremes)``, with
    ``limb`` (n,) the column in ``extremes`` of each of the ``n`` rotation
    variables (the last ``n`` columns; -1 for the torso's) and ``extremes``
    (T, L) :func:`trails.limb_extremes` of each limb's top joint (the hand
    seen from the collar, the foot from the hip); None for a C3D clip.
    ``swings``: :func:`heading_swings`, the extremes of the limbs' ends
    along the heading (the hand's swing forward and back), which are
    :func:`preferred` (issue 34: in a dance the largest turn of the hand
    near a pose was often a raise, not the swing)."""
    if not isinstance(motion, BvhMotion):
        return None
    found = [(np.asarray(t, dtype=int), dense) for kind, _, t, dense in variables if kind == ROTATION]
    if not found:
        return None
    targets, dense = found[0]
    tops = trails.limb_tops(motion.skeleton, ev.figure_height)[targets]
    col = {int(j): c for c, j in enumerate(targets)}
    used = sorted({int(t) for t in tops if t in col})
    limb = np.array([used.index(int(t)) if t in col else -1 for t in tops], dtype=int)
    cols = [col[t] for t in used]
    extremes = trails.limb_extremes(
        motion.skeleton, targets, dense, ev.figure_height, ev.rate, ev.breaks, smoothing, which=cols
    )
    if swings is not None:
        tops_all, swing = swings
        at = {int(t): i for i, t in enumerate(tops_all)}
        have = [c for c, t in enumerate(used) if t in at]
        if have:
            extremes[:, have] = preferred(swing[:, [at[used[c]] for c in have]], extremes[:, have])
    return limb, extremes


def prune_refinements(
    proxy: placement.Proxy,
    pose_f: np.ndarray,
    refine_f: np.ndarray,
    fixed: np.ndarray,
    gain: np.ndarray | float = REFINE_GAIN,
    groups: np.ndarray | None = None,
) -> np.ndarray:
    """Refinements (K, V) that earn their keep.

    A refinement stays where its extreme knot makes the spline layer fit the
    segments around the pose at most :data:`REFINE_GAIN` times as badly as
    the pose time alone does: a knot that only shifts the misfit around
    makes the body's parts miss together, not better.  ``gain`` (a number,
    or one per variable) replaces that share: :data:`EXTREME_GAIN` for a
    knot on the variable's own extreme.  ``groups`` (V,) joins variables
    that are judged together, on their summed misfit (a limb's joints).
    Variables too small
    to be in the proxy lose theirs; ``fixed`` (K, V) ones stay anyway.  Poses
    of one parity are decided together, then the other.
    """
    r = np.where(fixed, refine_f, 0).astype(int)
    K = r.shape[0]
    cols = proxy.cols
    if K < 3 or len(cols) == 0:
        return r
    rc = np.array(refine_f, dtype=int)[:, cols]
    fx = fixed[:, cols]
    gains = np.broadcast_to(np.asarray(gain, dtype=float), (r.shape[1],))[cols]
    f = pose_f.astype(float)
    for parity in (1, 0):
        ks = np.arange(1, K - 1)
        ks = ks[(ks % 2 == parity) & np.any(rc[ks] != 0, axis=1)]
        if len(ks) == 0:
            continue
        left = np.maximum(f[ks - 1, None], f[ks - 1, None] + rc[ks - 1])
        right = np.minimum(f[ks + 1, None], f[ks + 1, None] + rc[ks + 1])
        ext = f[ks, None] + rc[ks]
        here = np.broadcast_to(f[ks, None], ext.shape)
        lo, hi = np.minimum(here, ext), np.maximum(here, ext)
        with_r = placement.span_costs(proxy, np.stack([left, lo, hi, right], axis=-1))
        without = placement.span_costs(proxy, np.stack([left, here, here, right], axis=-1))
        if groups is not None:  # a limb's variables are judged together, by their summed misfit
            g = np.asarray(groups)[cols]
            _, inv = np.unique(g, return_inverse=True)
            sw = np.zeros((len(ks), inv.max() + 1))
            so = np.zeros_like(sw)
            np.add.at(sw.T, inv, with_r.T)
            np.add.at(so.T, inv, without.T)
            with_r, without = sw[:, inv], so[:, inv]
        drop = (with_r > gains * without) & ~fx[ks]
        rc[ks] = np.where(drop, 0, rc[ks])
    r[:, cols] = rc
    return r


def stride_period(constraints) -> float | None:
    """The motion's stride, seconds: the median time from one contact's
    start to the next start of the same joint, over every contact joint;
    ``None`` where no joint starts a contact three times (an idle stance, a
    bow, a clip with no contacts: nothing says how fast it steps)."""
    starts: dict[str, list[float]] = {}
    for c in constraints:
        starts.setdefault(c.joint, []).append(float(c.start))
    gaps = [np.diff(np.sort(v)) for v in starts.values() if len(v) >= 3]
    if not gaps:
        return None
    return float(np.median(np.concatenate(gaps)))


def tempo_scale(constraints) -> float:
    """How much shorter the default durations are for this motion: its
    :func:`stride_period` over :data:`REFERENCE_STRIDE`, clamped to
    [:data:`MIN_TEMPO_SCALE`, 1] (1 where it has no stride): a walk keeps the
    defaults, and only motion that steps faster gets shorter ones."""
    stride = stride_period(constraints)
    if stride is None:
        return 1.0
    return float(np.clip(stride / REFERENCE_STRIDE, MIN_TEMPO_SCALE, 1.0))


def check_options(
    *,
    smoothing: float | None = None,
    filter_width: float | None = None,
    refine_window: float = DEFAULT_REFINE_WINDOW,
    min_contact: float = contact_detection.DEFAULT_MIN_CONTACT,
    contact_tolerance: float = contact_detection.DEFAULT_TOLERANCE,
    significance: float = DEFAULT_SIGNIFICANCE,
    min_spacing: float | None = None,
) -> dict[str, float | None]:
    """:func:`extract`'s numeric options, checked (``UsageError``) without a
    clip: a batch checks its extract options so, once, before any file.
    ``filter_width`` and ``min_spacing`` stay ``None`` (the clip's tempo
    decides them, :func:`tempo_scale`) where not given."""
    return {
        "smoothing": _check(
            arg("smoothing"), DEFAULT_SMOOTHING if smoothing is None else smoothing, upper=MAX_SMOOTHING
        ),
        "filter_width": None
        if filter_width is None
        else _check(arg("filter_width"), filter_width, upper=MAX_FILTER_WIDTH),
        "refine_window": _check(arg("refine_window"), refine_window, upper=MAX_REFINE_WINDOW),
        "min_contact": _check(arg("min_contact"), min_contact, upper=MAX_MIN_CONTACT),
        "contact_tolerance": _check(arg("contact_tolerance"), contact_tolerance, positive=True),
        "significance": _check(arg("significance"), significance),
        "min_spacing": None if min_spacing is None else _check(arg("min_spacing"), min_spacing, upper=MAX_MIN_SPACING),
    }


def extract(
    motion: BvhMotion | MarkerMotion,
    *,
    source_name: str = "",
    source_bytes: bytes | None = None,
    contact_joints: tuple[str, ...] | list[str] | None = None,
    smoothing: float | None = None,
    filter_width: float | None = None,
    refine_window: float = DEFAULT_REFINE_WINDOW,
    min_contact: float = contact_detection.DEFAULT_MIN_CONTACT,
    contact_tolerance: float = contact_detection.DEFAULT_TOLERANCE,
    significance: float = DEFAULT_SIGNIFICANCE,
    min_spacing: float | None = None,
    partial: bool = False,
) -> Document:
    """Find staggered poses, refinements and contacts in a dense clip.

    Parameters
    ----------
    motion : a BVH or C3D clip.
    source_name, source_bytes : recorded in the document (name, SHA-256).
    contact_joints : joint names or marker labels; default feet and toes
        (BVH) or the lowest markers (C3D).
    smoothing : Laplacian smoothing of the local evidence, the standard
        deviation in seconds (default :data:`~staggered_cli.signals.DEFAULT_SMOOTHING`).
    filter_width : tent filter full base width, seconds; default
        :data:`DEFAULT_FILTER_WIDTH` times the clip's :func:`tempo_scale`.
    refine_window : largest refinement, seconds.
    min_contact : shortest contact, seconds.
    contact_tolerance : contact tolerance, a fraction of the figure height.
    significance : amount of motion (figure heights per second) a candidate
        pose needs; 0 keeps every local maximum of ``P``.
    min_spacing : fewest seconds between two poses; default
        :data:`DEFAULT_MIN_SPACING` times the clip's :func:`tempo_scale`.
    partial : after the whole-body poses, partition them among the body
        parts: a whole-body pose there for one part only becomes that part's
        partial pose, and the knots freed (no more) go to the parts' own
        partial poses where they earn them (:mod:`staggered_cli.signals.partial`,
        :func:`staggered_cli.ops.partial.confirmed`); BVH only (``UsageError``).

    Returns
    -------
    Document with signals ``P`` (T,), ``p`` (T, V), ``weights`` (V,) and
    ``contact`` (T,), and every option in ``parameters``.

    Raises
    ------
    UsageError for a bad option or an unknown contact joint.
    """
    checked = check_options(
        smoothing=smoothing,
        filter_width=filter_width,
        refine_window=refine_window,
        min_contact=min_contact,
        contact_tolerance=contact_tolerance,
        significance=significance,
        min_spacing=min_spacing,
    )
    smoothing, filter_width, refine_window = checked["smoothing"], checked["filter_width"], checked["refine_window"]
    min_contact, contact_tolerance = checked["min_contact"], checked["contact_tolerance"]
    significance, min_spacing = checked["significance"], checked["min_spacing"]
    if partial and not isinstance(motion, BvhMotion):
        raise UsageError(f"{arg('partial')} needs a BVH skeleton's body parts: a C3D clip has none")
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

    joints = contact_detection.contact_joints(motion, contact_joints)
    constraints = contact_detection.detect_contacts(
        motion, joints, min_duration=min_contact, tolerance=contact_tolerance
    )
    if contact_joints is not None:  # the user's choice: say which of them never rest
        contact_detection.warn_never_rested(joints, constraints, min_duration=min_contact, tolerance=contact_tolerance)
    center = center_height(motion) if constraints else None
    scale = tempo_scale(constraints)  # the user's durations win; the defaults follow the motion's tempo
    if filter_width is None:
        filter_width = round(DEFAULT_FILTER_WIDTH * scale, 3)
    if min_spacing is None:
        min_spacing = round(DEFAULT_MIN_SPACING * scale, 3)
    variables = dense_variables(motion)
    weights = placement.variable_weights(motion, variables)
    up = heading = None
    if isinstance(motion, BvhMotion):  # nothing below needs world positions (24 bytes a joint and frame)
        world = motion.world_positions()
        # the body's joints only: a still joint_Root (Bandai) widens a walk's frames along its path
        up = contact_detection.up_direction(world, motion.figure_height(), body_joints(motion.skeleton))
        tops = np.unique(trails.limb_tops(motion.skeleton, motion.figure_height()))
        tops = tops[tops >= 0]
        heading = (tops, trails.heading_offsets(motion.skeleton, world, tops, up, rate))
        del world
        motion.release_world()
    ev = trails.local_evidence(motion, smoothing)
    events = contact_events(constraints, T, rate, ev.breaks)
    boundaries = np.unique(np.array([f for _, f in events], dtype=int))
    contact = probability.contact_pulses(boundaries, T, rate, probability.DEFAULT_PULSE)
    contact_weight = float(ev.weights.max()) if len(ev.weights) else 0.0
    P = probability.pose_probability(ev, contact, contact_weight, filter_width)

    spacing = max(int(round(min_spacing * rate)), 1)
    reach = max(int(round(0.5 * filter_width * rate)), 1)
    window = int(np.floor(refine_window * rate + 1e-6))
    breaks = np.flatnonzero(ev.breaks)
    flights = flight_frames(constraints, T, rate, center)
    forced = np.unique(np.concatenate([[0, T - 1], breaks, breaks + 1, flights]).clip(0, max(T - 1, 0)))
    gate = np.ones(T, dtype=bool)
    if significance > 0:
        gate = tent_filter(ev.speed, 2.0 * refine_window, rate) >= significance
    proxy = placement.proxy_from_dense(variables, weights)
    own = translation_extremes(motion, variables, ev, smoothing, up)
    swings = heading_swings(heading, ev, smoothing)
    limbs = limbs_own_extremes(motion, variables, ev, smoothing, swings)
    del variables
    clusters = contact_clusters(boundaries, reach, T)
    count = pose_count(P, clusters, gate, forced, spacing)
    stride = max(1, int(round(rate / PLACEMENT_RATE)))
    allowed = np.zeros(T, dtype=bool)
    allowed[feature_sites(ev.p @ ev.weights, reach)] = True
    # a pose is cheaper by CONTACT_REWARD for each contact change it covers
    reward = np.minimum(near_frames(boundaries, reach, T) * CONTACT_REWARD, 1.0)
    allowed |= reward > 0
    costs: dict = {}
    pose_f = optimal_poses(proxy, forced, allowed, reward, spacing, count, stride, SEGMENT_REACH, costs)
    lone = uncovered_swings(swings, pose_f, reach)
    if len(lone):  # and for each limb's swing no pose was near, as for a contact change
        near = near_frames(lone, reach, T)
        allowed |= near > 0
        reward = np.minimum(reward + near * CONTACT_REWARD, 1.0)
        pose_f = optimal_poses(proxy, forced, allowed, reward, spacing, count, stride, SEGMENT_REACH, costs)
    del costs
    pose_t = pose_f * float(motion.frame_time)

    priority = probability.pose_priority(P, pose_f, pose_t)

    peaks = refinement_frames(ev.p, pose_f, window)
    gain = np.full(len(ev.names), REFINE_GAIN)
    groups = np.arange(len(ev.names))
    if own is not None:  # translations: their own extremes, kept unless they make the fit worse
        height_first, plain = own
        n = plain.shape[1]
        peaks[:, :n] = better_fit(
            proxy, pose_f, strongest_frames(height_first, pose_f, window), strongest_frames(plain, pose_f, window)
        )
        gain[:n] = EXTREME_GAIN
    if limbs is not None:  # a limb's rotations: the limb's own extremes, its joints together
        limb, extremes = limbs
        n = len(limb)
        on_limb = np.flatnonzero(limb >= 0)
        col = len(ev.names) - n + on_limb
        peaks[:, col] = strongest_frames(extremes, pose_f, window)[:, limb[on_limb]]
        gain[col] = EXTREME_GAIN
        groups[col] = len(ev.names) + limb[on_limb]
    on_contact, fixed = contact_refinements(motion, ev.names, pose_f, events, window)
    refine_f = prune_refinements(proxy, pose_f, np.where(fixed, on_contact, peaks), fixed, gain, groups)
    refine = refine_f * float(motion.frame_time)
    candidates, fits, demotions = [], [], []
    if partial:
        candidates, fits, demotions = partial_poses.find_partial(
            proxy,
            ev.p,
            ev.weights,
            partial_poses.part_columns(motion, variable_layout(motion)),
            pose_f,
            refine_f,
            rate=rate,
            height=ev.figure_height,
            filter_width=filter_width,
            refine_window=refine_window,
            significance=significance,
            spacing=spacing,
            stride=stride,
            fit=True,
            demote=True,
        )
    del proxy  # the placement's float32 copy of the variables: the fit below does not need it

    parameters = {
        "smoothing": smoothing,
        "filter_width": filter_width,
        "refine_window": refine_window,
        "min_contact": min_contact,
        "contact_tolerance": contact_tolerance,
        "significance": significance,
        "min_spacing": min_spacing,
        "contact_joints": list(joints),
        "contact_pulse": probability.DEFAULT_PULSE,
    }
    if partial:
        parameters["partial"] = True
    sigs = {"P": P, "p": ev.p, "weights": ev.weights, "contact": contact}
    if fits_by_column(motion):  # a long clip's fit makes its rotations a joint at a time
        motion.release_local()
    doc = from_motion(
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
    if partial:  # the candidates that earn their knots in the real spline layer
        doc = partial_ops.confirmed(doc, candidates, fits, demotions, gap=partial_poses.PART_SPACING, budget=True)
    if isinstance(motion, BvhMotion):  # the fit's local rotations: writing the document does not need them
        motion.release_local()
    return doc
