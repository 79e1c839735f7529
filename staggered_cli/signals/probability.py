"""Pose probability and pose priorities (paper 4.1, SPEC 4).

``P(t)`` is the tent-filtered weighted mean of the variables' local
evidence (:mod:`.trails`), with contacts as one more weighted term; staggered
poses sit at its local maxima, and a pose's priority (what culling keeps
first) is ``P(t_k)(t_{k+1} - t_{k-1})``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..model.document import Document
from .smoothing import DEFAULT_FILTER_WIDTH, tent_filter
from .trails import LocalEvidence

#: Default duration of a contact pulse, seconds.
DEFAULT_PULSE = 0.05


def local_maxima(x: np.ndarray) -> np.ndarray:
    """Frames of the local maxima of a 1-D signal (interior; a plateau gives
    its middle frame; plateaus of zero are ignored)."""
    # numpy rather than scipy.signal.find_peaks (same rule): importing
    # scipy.signal costs 0.4 s of start-up on every extract
    x = np.asarray(x, dtype=float).ravel()
    if len(x) < 3:
        return np.zeros(0, dtype=int)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(x) != 0.0) + 1])  # runs of equal values
    ends = np.concatenate([starts[1:] - 1, [len(x) - 1]])
    v = x[starts]
    inner = np.arange(1, len(starts) - 1)
    peak = inner[(v[inner - 1] < v[inner]) & (v[inner + 1] < v[inner])]
    frames = (starts[peak] + ends[peak]) // 2
    return frames[x[frames] > 0.0]


def contact_pulses(boundaries: np.ndarray, n_frames: int, rate: float, duration: float = DEFAULT_PULSE) -> np.ndarray:
    """A binary signal (T,) that is 1 within ``duration`` seconds (full width)
    centred on each boundary frame.  A fixed duration, not one frame, so the
    pulse weighs the same at every frame rate."""
    half = max(0.5 * duration * rate, 0.5)
    b = np.asarray(boundaries, dtype=float)
    lo = np.clip(np.ceil(b - half + 1e-9), 0, n_frames).astype(int)  # frames with |f - b| < half
    hi = np.clip(np.floor(b + half - 1e-9) + 1, 0, n_frames).astype(int)
    edges = np.zeros(n_frames + 1)
    np.add.at(edges, lo, 1.0)
    np.add.at(edges, hi, -1.0)
    return (np.cumsum(edges)[:n_frames] > 0).astype(float)


def pose_probability(
    ev: LocalEvidence,
    contact: np.ndarray | None = None,
    contact_weight: float = 0.0,
    filter_width: float = DEFAULT_FILTER_WIDTH,
) -> np.ndarray:
    """``P(t) = tent(Σ w_i p_i / Σ w_i)`` with the contact signal as one more
    weighted term (T,)."""
    num = ev.p @ ev.weights
    den = float(np.sum(ev.weights))
    if contact is not None and contact_weight > 0:
        num = num + contact_weight * np.asarray(contact, dtype=float)
        den += contact_weight
    mean = num / den if den > 0 else np.zeros(len(num))
    return tent_filter(mean, filter_width, ev.rate)


def pose_priority(
    P: np.ndarray, frames: np.ndarray, pose_t: np.ndarray, parts: tuple | None = None
) -> np.ndarray:
    """The paper's pose priorities ``P(t_k)(t_{k+1} - t_{k-1})`` (K,) (4.1):
    ``P`` (T,) the pose probability, ``frames`` (K,) the poses' frames,
    ``pose_t`` (K,) their times; infinite for the first and last pose, which
    culling always keeps.

    ``parts`` (K,): each pose's body part, None for a whole-body pose (see
    :attr:`staggered_cli.model.document.Document.pose_part`).  A pose's
    neighbours ``k-1`` and ``k+1`` are then the nearest poses that share its
    variables and are as whole: a whole-body pose's are whole-body poses, a
    partial pose's whole-body poses or partial poses of its own part.
    Adding partial poses thus leaves the whole-body poses' priorities as
    they were."""
    K = len(pose_t)
    priority = np.full(K, np.inf)
    if K <= 2:
        return priority
    if parts is None or all(p is None for p in parts):
        priority[1:-1] = P[frames[1:-1]] * (pose_t[2:] - pose_t[:-2])
        return priority
    for k in range(1, K - 1):
        mine = parts[k]

        def near(j: int, mine=mine) -> bool:
            return parts[j] is None or parts[j] == mine

        prev = next(j for j in range(k - 1, -1, -1) if near(j))
        after = next(j for j in range(k + 1, K) if near(j))
        priority[k] = P[frames[k]] * (pose_t[after] - pose_t[prev])
    return priority


def reprioritized(doc: Document) -> Document:
    """Priorities recomputed for the current poses from the stored pose
    probability, after poses were culled, added or retimed; unchanged when
    the document has no ``P`` signal."""
    P = doc.signals.get("P")
    if P is None or len(P) != doc.n_frames or doc.n_poses < 3:
        return doc
    frames = np.clip(np.rint(doc.pose_t / doc.frame_time).astype(int), 0, doc.n_frames - 1)
    return replace(doc, priority=pose_priority(np.asarray(P, dtype=float), frames, doc.pose_t, doc.pose_part))
