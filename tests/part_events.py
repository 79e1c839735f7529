"""The arms' own feature peaks, found apart from the project (issue 37).

The judge of ``extract --partial``: where an arm makes a gesture of its own,
the hand stops or turns back relative to the body.  Like :mod:`tests.events`
this shares nothing with the project's signals (no local evidence, no
curvature, no pose probability): it reads only a clip's skeleton names and
parents, its world joint positions (T, J, 3), its frame time and figure
height ``H``, with numpy and scipy.

* **The body's frame** at each frame: the lowest joint both hands hang from
  (the chest) is its origin; its first axis runs from the right shoulder
  to the left (the first joint of each arm below that chest that lies
  away from it by more than 2 % of ``H``), its second is the chest's direction from the place
  joint (:func:`tests.events.place_joint`, the hips) made orthogonal to the
  first, the third their cross product.  A walking or bending body turns
  this frame; a hand that swings with it does not move in it.
* **A hand's gesture speed**: the speed of the hand joint
  (:func:`tests.events.hands`) in that frame, figure heights a second,
  averaged over :data:`SMOOTH` seconds.
* **Feature peaks**: the local minima of the gesture speed, where the hand
  stops or turns back, with a prominence of at least :data:`PROMINENCE`
  figure heights a second (a real move on both sides: a hand dawdling in
  place is not a gesture) and at least :data:`MIN_GAP` seconds apart (the
  slower kept).
* **Missed by the whole-body poses**: a feature peak farther than
  :data:`NEAR` seconds from every knot of the arm's joints in a document
  (a pose time, or a joint's refined extreme): no knot of the arm is there
  to key it.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import find_peaks

from . import events

#: Seconds over which the gesture speed is averaged.
SMOOTH = 0.05
#: Prominence of a feature peak, figure heights a second.
PROMINENCE = 0.5
#: Fewest seconds between two feature peaks of a hand.
MIN_GAP = 0.1
#: A knot within this many seconds of a feature peak keys it.
NEAR = 0.1


def _ancestors(parents, j: int) -> list[int]:
    out = []
    while parents[j] >= 0:
        j = int(parents[j])
        out.append(j)
    return out


def body_frame(names, parents, world: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray, dict[int, int]]:
    """The body's frame: origin (T, 3), axes (T, 3, 3) (rows), and each hand's arm root."""
    parents = np.asarray(parents)
    hs = events.hands(names, parents)
    if len(hs) != 2:
        raise ValueError("expected two hands by name")
    shared = set(_ancestors(parents, hs[0])) & set(_ancestors(parents, hs[1]))
    chest = max(shared, key=lambda j: len(_ancestors(parents, j)))
    roots = {}
    for h in hs:
        chain = [h] + _ancestors(parents, h)
        below = chain[: chain.index(chest)][::-1]  # the arm, root first
        # the first joint of the arm away from the chest (a CMU collar sits on it)
        away = [j for j in below if np.linalg.norm(world[:, j] - world[:, chest], axis=-1).mean() > 0.02 * height]
        roots[h] = away[0] if away else below[0]
    sides = events.feet(names, parents)
    place = events.place_joint(parents, world, height, sides)
    # which hand is left: the one whose name says so
    left = [h for h in hs if names[h].lower().startswith(("l", "left"))]
    lh = left[0] if left else hs[0]
    rh = [h for h in hs if h != lh][0]
    x = world[:, roots[lh]] - world[:, roots[rh]]
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    y = world[:, chest] - world[:, place]
    y -= np.einsum("tk,tk->t", y, x)[:, None] * x
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    z = np.cross(x, y)
    return world[:, chest], np.stack([x, y, z], axis=1), roots


def gesture_speed(names, parents, world: np.ndarray, frame_time: float, height: float) -> dict[int, np.ndarray]:
    """Hand joint -> (T,) its speed in the body's frame, figure heights a second."""
    origin, axes, roots = body_frame(names, parents, world, height)
    out = {}
    size = max(1, int(round(SMOOTH / frame_time)))
    for h in roots:
        rel = np.einsum("tij,tj->ti", axes, world[:, h] - origin)
        speed = np.linalg.norm(np.gradient(rel, frame_time, axis=0), axis=-1) / height
        out[h] = uniform_filter1d(speed, size, mode="nearest")
    return out


def feature_peaks(
    names, parents, world: np.ndarray, frame_time: float, height: float, first: int = 0
) -> dict[str, np.ndarray]:
    """Hand name -> (N,) times (seconds) of its feature peaks (see the module
    doc); frames before ``first`` take no part (a T-pose frame)."""
    out = {}
    for h, s in gesture_speed(names, parents, np.asarray(world, float), frame_time, height).items():
        gap = max(1, int(round(MIN_GAP / frame_time)))
        f, _ = find_peaks(-s[first:], prominence=PROMINENCE, distance=gap)
        out[names[h]] = (f + first) * frame_time
    return out


def missed(peaks: np.ndarray, knots: np.ndarray, near: float = NEAR) -> np.ndarray:
    """The ``peaks`` (times) farther than ``near`` seconds from every one of ``knots``."""
    peaks = np.asarray(peaks, float)
    knots = np.sort(np.asarray(knots, float))
    if len(knots) == 0:
        return peaks
    i = np.clip(np.searchsorted(knots, peaks), 1, len(knots) - 1) if len(knots) > 1 else np.zeros(len(peaks), int)
    d = np.minimum(np.abs(knots[i] - peaks), np.abs(knots[np.maximum(i - 1, 0)] - peaks))
    return peaks[d > near + 1e-9]


def hit(peaks: np.ndarray, times: np.ndarray, near: float = NEAR) -> np.ndarray:
    """(N,) bool: which ``peaks`` have one of ``times`` within ``near`` seconds."""
    peaks = np.asarray(peaks, float)
    times = np.asarray(times, float)
    if len(times) == 0:
        return np.zeros(len(peaks), bool)
    return np.min(np.abs(peaks[:, None] - times[None, :]), axis=1) <= near + 1e-9
