"""Motion events found apart from the project (issue 34's event benchmark).

The benchmark (bench/bench_events.py) and its tests (tests/test_events.py)
judge where the extracted poses and knots fall against events an animator
would key: the root's high and low points, the hands' swing extremes, the
flight phases of runs and jumps.  To be a fair judge this code shares
nothing with the project's signals: it reads only a clip's skeleton
(``names``, ``parents``), its world joint positions (T, J, 3), its frame
time and figure height (numpy and scipy, nothing from ``staggered_cli``).

The rules, each relative to the figure height ``H`` (never absolute units):

* **Up axis**: the world axis along which the head is above the feet (the
  sign included), from the data (Y up in BVH files as written, but not assumed).
* **Place joint**: the first joint (in file order) whose world position
  moves by more than 1 % of ``H`` over the clip (CMU ``Hips``; Bandai
  ``Hips`` under a still ``joint_Root``).
* **Root height extremes**: local maxima and minima of the place joint's
  height, ``scipy.signal.find_peaks`` on ``+h`` and ``-h`` with a prominence
  of 3 % of ``H``.
* **Hand swing extremes**: each hand's position relative to the place joint,
  projected on the figure's heading, extremes with a prominence of 5 % of
  ``H``.  The heading is the hips' forward axis (up x the right-to-left hip
  vector, horizontal), averaged over :data:`HEADING_SMOOTH` seconds: the
  direction of travel is undefined when the figure stands (idle, bow, a
  box lift), the hips' axis is not.  Its sign does not matter (a maximum
  forward is a minimum backward).
* **Flight phases**: both feet off the ground for at least :data:`MIN_FLIGHT`
  seconds.  A side (its foot, ankle and toe joints, found by name) is off
  when *every* one of its joints is higher than its own floor by more than
  :data:`OFF_HEIGHT` x ``H``.  A joint's floor is its own 2nd-percentile
  height over the clip: the ankle stands higher than the toe when planted,
  so one floor for all would call a planted ankle airborne or a lifted toe
  planted; the percentile ignores a few noisy frames.  Height alone, not
  speed: at take-off and landing the feet move fast while still on the
  ground, and a flat-footed run barely lifts them, so "moving" would blur
  the phase's ends; a threshold of 4 % of ``H`` (about 7 cm on a 1.75 m
  figure) is above the sway of a planted toe (heel-toe roll lifts the
  *ankle*, which is why all of a side's joints must be off) and below the
  lift of the lowest flight of the dev runs.

Frame 0 of the cgspeed CMU conversions is a T-pose (the MANIFEST names
them, :data:`TPOSE_FILES`): it is left out of every event.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import find_peaks

#: Files whose frame 0 is a T-pose (../shared/mocap/MANIFEST.md).
TPOSE_FILES = ("cmu_01_01_forward_jumps.bvh", "cmu_115_06_pick_up_box.bvh")
#: Prominence of a root height extreme, fraction of the figure height.
ROOT_PROMINENCE = 0.03
#: Prominence of a hand swing extreme, fraction of the figure height.
SWING_PROMINENCE = 0.05
#: A joint moving less than this (fraction of the figure height) over the clip is still.
STILL = 0.01
#: Seconds over which the hips' forward axis is averaged into the heading.
HEADING_SMOOTH = 0.5
#: A foot joint is off the ground above its floor by more than this (fraction of the figure height).
OFF_HEIGHT = 0.04
#: A joint higher than half :data:`OFF_HEIGHT` is off too when it moves faster than this (figure heights a second).
MOVING = 0.5
#: A joint's floor: this percentile of its height over the clip.
FLOOR_PERCENTILE = 2.0
#: Shortest flight phase, seconds.
MIN_FLIGHT = 0.1

_FOOT = re.compile(r"foot|toe|ankle", re.I)
_HAND_EXCLUDE = re.compile(r"index|finger|thumb", re.I)


@dataclass(frozen=True)
class Events:
    """The events of one clip, times in seconds (the clip's own time).

    Attributes
    ----------
    root_extremes : (N,) times of the place joint's height extremes.
    root_kinds : (N,) +1 for a maximum, -1 for a minimum.
    swings : hand joint name -> (M,) times of that hand's swing extremes.
    arms : hand joint name -> joint indices of that arm (collar/shoulder to hand).
    flights : (F, 2) start and end of each flight phase (first and last
        airborne frame).
    place : index of the place joint; up : (3,) unit up axis;
    feet : the foot joint indices of each side.
    """

    root_extremes: np.ndarray
    root_kinds: np.ndarray
    swings: dict[str, np.ndarray]
    arms: dict[str, np.ndarray]
    flights: np.ndarray
    place: int
    up: np.ndarray
    feet: tuple[np.ndarray, ...] = field(default=())


def _children(parents: np.ndarray) -> list[list[int]]:
    kids: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            kids[p].append(j)
    return kids


def _ancestors(parents: np.ndarray, j: int) -> list[int]:
    out = []
    while parents[j] >= 0:
        j = int(parents[j])
        out.append(j)
    return out


def _chains(names, parents, joints: list[int]) -> list[list[int]]:
    """``joints`` grouped into chains: two joints are in one chain when one is
    the other's ancestor (a foot and its toe)."""
    groups: list[list[int]] = []
    for j in joints:
        for g in groups:
            if any(j in _ancestors(parents, k) or k in _ancestors(parents, j) for k in g):
                g.append(j)
                break
        else:
            groups.append([j])
    return [sorted(g) for g in groups]


def feet(names, parents) -> list[list[int]]:
    """The foot joints (foot, toe, ankle by name) of each leg, one list per leg."""
    found = [j for j, n in enumerate(names) if _FOOT.search(n)]
    return _chains(names, parents, found)


def hands(names, parents) -> list[int]:
    """The hand joint of each arm: named ``hand`` (not a finger), else ``wrist``;
    the most proximal of a chain."""
    for word in ("hand", "wrist"):
        found = [j for j, n in enumerate(names) if word in n.lower() and not _HAND_EXCLUDE.search(n)]
        if len(found) >= 2:
            return [g[0] for g in _chains(names, parents, found)]
    return []


def arm(parents, hand: int, other: int) -> list[int]:
    """The hand and its ancestors below the lowest joint it shares with the
    ``other`` hand (collar or shoulder, upper arm, forearm, wrist, hand)."""
    shared = set(_ancestors(parents, other))
    return sorted([hand] + [j for j in _ancestors(parents, hand) if j not in shared])


def up_axis(names, world: np.ndarray, foot_joints: list[int]) -> np.ndarray:
    """(3,) the world axis (signed) along which the head is above the feet."""
    head = [j for j, n in enumerate(names) if "head" in n.lower()]
    if not head or not foot_joints:
        raise ValueError("no head or no feet by name")
    d = world[:, head].mean(axis=(0, 1)) - world[:, foot_joints].mean(axis=(0, 1))
    a = int(np.argmax(np.abs(d)))
    up = np.zeros(3)
    up[a] = np.sign(d[a])
    return up


def place_joint(parents, world: np.ndarray, height: float, sides: list[list[int]]) -> int:
    """The first joint, from the root down to the lowest joint both legs hang
    from, whose world position moves by more than :data:`STILL` x height
    (that lowest joint when none does: a figure standing still)."""
    chain = [sides[0][0], *_ancestors(parents, sides[0][0])]
    common = [j for j in reversed(chain) if j in _ancestors(parents, sides[1][0])]  # root first
    span = np.ptp(world[:, common], axis=0).max(axis=-1)
    moving = np.flatnonzero(span > STILL * height)
    return int(common[moving[0]] if len(moving) else common[-1])


def extremes(signal: np.ndarray, prominence: float) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices (sorted) of the local maxima and minima of ``signal``
    with at least ``prominence``, and +1 / -1 for each."""
    hi, _ = find_peaks(signal, prominence=prominence)
    lo, _ = find_peaks(-signal, prominence=prominence)
    f = np.concatenate([hi, lo])
    kind = np.concatenate([np.ones(len(hi), int), -np.ones(len(lo), int)])
    order = np.argsort(f, kind="stable")
    return f[order], kind[order]


def heading(world: np.ndarray, up: np.ndarray, hips: tuple[int, int], frame_time: float) -> np.ndarray:
    """(T, 3) unit horizontal forward axis of the hips, averaged over
    :data:`HEADING_SMOOTH` seconds (sign: up x (hip a - hip b))."""
    lateral = world[:, hips[0]] - world[:, hips[1]]
    lateral = lateral - (lateral @ up)[:, None] * up
    lateral /= np.maximum(np.linalg.norm(lateral, axis=-1, keepdims=True), 1e-12)
    size = max(1, int(round(HEADING_SMOOTH / frame_time)))
    lateral = uniform_filter1d(lateral, size, axis=0, mode="nearest")
    fwd = np.cross(up, lateral)
    return fwd / np.maximum(np.linalg.norm(fwd, axis=-1, keepdims=True), 1e-12)


def airborne(world: np.ndarray, up: np.ndarray, side: list[int], height: float, frame_time: float) -> np.ndarray:
    """(T,) True where every joint of ``side`` is off the ground (see the module doc)."""
    lift = world[:, side] @ up
    lift = lift - np.percentile(lift, FLOOR_PERCENTILE, axis=0)
    speed = np.linalg.norm(np.gradient(world[:, side], frame_time, axis=0), axis=-1)
    off = (lift > OFF_HEIGHT * height) | ((lift > 0.5 * OFF_HEIGHT * height) & (speed > MOVING * height))
    return np.all(off, axis=1)


def flights(world: np.ndarray, up: np.ndarray, sides: list[list[int]], height: float, frame_time: float) -> np.ndarray:
    """(F, 2) first and last airborne frame time of each flight phase (see the
    module doc); a phase of n airborne frames lasts n x frame_time."""
    off = np.ones(len(world), bool)
    for side in sides:
        off &= airborne(world, up, side, height, frame_time)
    edges = np.diff(np.concatenate([[0], off.astype(int), [0]]))
    start, stop = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    keep = (stop - start + 1) * frame_time >= MIN_FLIGHT - 1e-9
    return np.stack([start[keep], stop[keep]], axis=1) * frame_time if keep.any() else np.zeros((0, 2))


def find_events(
    names,
    parents,
    world: np.ndarray,
    frame_time: float,
    height: float,
    *,
    first: int = 0,
    root_prominence: float = ROOT_PROMINENCE,
) -> Events:
    """The events of a clip from its skeleton and world positions (T, J, 3).

    ``first``: frames before it take no part (1 after a T-pose frame); times
    stay the clip's own (frame f at f x frame_time).  ``root_prominence``:
    of the root height extremes, fraction of ``height`` (the benchmark uses
    the issue's 3 %; a walk's bob is smaller, see tests/test_events.py).
    """
    parents = np.asarray(parents)
    names = list(names)
    world = np.asarray(world, float)[first:]
    sides = feet(names, parents)
    if len(sides) != 2:
        raise ValueError(f"expected two legs' foot joints by name, found {[[names[j] for j in s] for s in sides]}")
    up = up_axis(names, world, [j for s in sides for j in s])
    place = place_joint(parents, world, height, sides)
    h = world[:, place] @ up
    f, kind = extremes(h, root_prominence * height)
    root_t = (f + first) * frame_time
    # the hips: the knee's parent above each leg's most proximal foot joint
    hips = tuple(_ancestors(parents, s[0])[1] for s in sides)
    fwd = heading(world, up, hips, frame_time)
    swings, arms = {}, {}
    both = hands(names, parents)
    for hand in both:
        s = np.einsum("tk,tk->t", world[:, hand] - world[:, place], fwd)
        hf, _ = extremes(s, SWING_PROMINENCE * height)
        swings[names[hand]] = (hf + first) * frame_time
        arms[names[hand]] = np.array(arm(parents, hand, [o for o in both if o != hand][0]))
    fl = flights(world, up, sides, height, frame_time) + first * frame_time
    return Events(root_t, kind, swings, arms, fl, place, up, tuple(np.array(s) for s in sides))


def clip_events(motion, name: str = "", **options) -> Events:
    """:func:`find_events` of a BVH clip read by ``staggered_cli.read``
    (``name``: its file name, to leave out a T-pose frame)."""
    sk = motion.skeleton
    first = 1 if name in TPOSE_FILES else 0
    return find_events(
        sk.names,
        sk.parents,
        motion.world_positions(),
        float(motion.frame_time),
        motion.figure_height(),
        first=first,
        **options,
    )
