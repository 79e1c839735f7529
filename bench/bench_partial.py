"""Partial poses (issue 37): what ``extract --partial`` finds and what it is worth.

For the spliced clips of tests/splice.py (the arms of a dance on the body
of a walk or a box lift) and every dev BVH file:

* the partial poses per part, and per part per second;
* the arms' own feature peaks (tests/part_events.py) that the whole-body
  poses of plain extract miss (no knot of the arm within 0.1 s), and how
  many of them have a partial pose of that arm within 0.1 s (goal: 80 %);
  the same for the whole-body poses ``--partial`` leaves (some plain ones
  are partial poses there), hit by a knot of an arm's partial pose; and the
  peaks no arm knot keys at all, without and with ``--partial``;
* the most partial poses of one part in any 0.3 s (goal: 1);
* the spline layer alone (``bake --layers splines``: world joint positions
  against the source, mean over joints and frames, % of figure height) of
  the ``--partial`` document at its own total number of knots (never more
  than plain extract's), against the whole-body extract culled (``cull
  --keep``, by error) to the same number of knots, read linearly between
  the two culls around it (tests/partial_knots.py).  Goal: geometric mean
  of the ratios <= 0.9 on the spliced clips, <= 1.0 on the dev BVH files,
  no file above 1.05;
* extract's time with and without ``partial``.

    python bench/bench_partial.py [FILE ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from staggered_cli.io.bvh import read_bvh  # noqa: E402
from staggered_cli.ops import partial as partial_ops  # noqa: E402
from staggered_cli.ops.extract import extract  # noqa: E402
from staggered_cli.signals import partial as partial_signals  # noqa: E402
from tests import part_events, partial_knots  # noqa: E402
from tests.conftest import MOCAP  # noqa: E402
from tests.events import TPOSE_FILES  # noqa: E402
from tests.splice import SPLICES, spliced  # noqa: E402

#: A knot this close to an arm's feature peak keys it, seconds.
NEAR = part_events.NEAR
#: The window of "one partial pose per part per 0.3 s".
WINDOW = 0.3


def most_in_window(times: np.ndarray, window: float = WINDOW) -> int:
    """The most of ``times`` in any half-open window of ``window`` seconds."""
    t = np.sort(np.asarray(times, float))
    if len(t) == 0:
        return 0
    return int(np.max(np.searchsorted(t, t + window - 1e-9, side="left") - np.arange(len(t))))


def arm_knots(doc, hand: str, whole_only: bool = False, partial_only: bool = False) -> np.ndarray:
    """The knot times of the arm's joints, from the hand up to the arm's root
    (the joint below the lowest one both hands share); ``whole_only``: of the
    whole-body poses only, ``partial_only``: of the partial poses only."""
    sk = doc.source.skeleton
    j = sk.names.index(hand)
    chain = [j]
    roots = partial_signals.part_roots(doc.source)
    while chain[-1] not in roots.values() and sk.parents[chain[-1]] >= 0:
        chain.append(int(sk.parents[chain[-1]]))
    tr = [t for t in doc.tracks if t.kind == "rotation"][0]
    is_whole = np.array([p is None for p in doc.pose_part])
    keep = np.ones(len(tr.knots.t), dtype=bool)
    if whole_only:
        keep = is_whole[tr.knots.pose]
    elif partial_only:
        keep = ~is_whole[tr.knots.pose]
    sl = [tr.knots.of(tr.index(sk.names[c])) for c in chain]
    return np.concatenate([tr.knots.t[s][keep[s]] for s in sl])


def hand_part(doc, hand: str) -> str:
    """The body part (``@left-arm`` or ``@right-arm``) a hand joint is in."""
    sk = doc.source.skeleton
    j = sk.names.index(hand)
    for part, root in partial_signals.part_roots(doc.source).items():
        if part.endswith("-arm") and j in sk.subtree(root):
            return part
    return ""


def coverage(motion, name: str, whole, with_parts) -> tuple[int, int, int, int, int, int]:
    """(hit, missed): the arms' feature peaks the whole-body poses of the
    plain extract ``whole`` miss, and of them those with a partial pose of
    their arm within :data:`NEAR`; (hit, missed) again for the whole-body
    poses of the ``--partial`` extract (some of the plain ones are partial
    poses there), hit by a knot of an arm's partial pose (its time or its
    refined extreme); and how many peaks no knot of the arm keys at all in
    each document."""
    found = partial_ops.partial_times(with_parts)
    sk = motion.skeleton
    first = 1 if name in TPOSE_FILES else 0
    peaks = part_events.feature_peaks(
        sk.names, sk.parents, motion.world_positions(), float(motion.frame_time), motion.figure_height(), first=first
    )
    hit = missed = own_hit = own_missed = bare = bare_parts = 0
    for hand, t in peaks.items():
        miss = part_events.missed(t, arm_knots(whole, hand))
        missed += len(miss)
        hit += int(part_events.hit(miss, found.get(hand_part(whole, hand), np.zeros(0))).sum())
        own = part_events.missed(t, arm_knots(with_parts, hand, whole_only=True))
        own_missed += len(own)
        own_hit += len(own) - len(part_events.missed(own, arm_knots(with_parts, hand, partial_only=True)))
        bare += len(miss)
        bare_parts += len(part_events.missed(t, arm_knots(with_parts, hand)))
    return hit, missed, own_hit, own_missed, bare, bare_parts


def measure(name: str, motion) -> dict:
    t0 = time.perf_counter()
    whole = extract(motion)
    t_whole = time.perf_counter() - t0
    t0 = time.perf_counter()
    with_parts = extract(motion, partial=True)
    t_partial = time.perf_counter() - t0
    found = partial_ops.partial_times(with_parts)
    hit, missed, own_hit, own_missed, bare, bare_parts = coverage(motion, name, whole, with_parts)
    worst = max((most_in_window(t) for t in found.values()), default=0)
    ratio, knots = partial_knots.equal_knots_ratio(whole, with_parts)
    return {
        "file": name,
        "K": whole.n_poses,
        "partial": {p: len(t) for p, t in found.items()},
        "per_s": {p: len(t) / whole.duration for p, t in found.items()},
        "hit": hit,
        "missed": missed,
        "own_hit": own_hit,
        "own_missed": own_missed,
        "bare": bare,
        "bare_parts": bare_parts,
        "worst": worst,
        "ratio": ratio,
        "knots": knots,
        "t_whole": t_whole,
        "t_partial": t_partial,
    }


def report(rows: list[dict], label: str) -> tuple[float, float]:
    ratios = np.array([r["ratio"] for r in rows])
    gm = float(np.exp(np.mean(np.log(ratios)))) if len(ratios) else float("nan")
    worst = float(ratios.max()) if len(ratios) else float("nan")
    print(
        f"{label}: spline layer with / without partial poses at equal knots, "
        f"geometric mean {gm:.3f} (worst {worst:.3f})"
    )
    return gm, worst


def main(argv: list[str]) -> None:
    clips = [(n, lambda n=n: spliced(n)) for n in SPLICES]
    files = [Path(a) for a in argv] or sorted(MOCAP.glob("*.bvh"))
    clips += [(p.name, lambda p=p: read_bvh(p)) for p in files]
    print(
        f"{'clip':38s} {'K':>4s} {'knots':>11s} {'ratio':>6s} {'peaks hit/missed':>16s} {'max/0.3s':>8s} "
        f"{'ext s':>6s} {'+part s':>7s}  partial poses (per s)"
    )
    rows = []
    for name, make in clips:
        r = measure(name, make())
        rows.append(r)
        parts = ", ".join(f"{p} {n} ({r['per_s'][p]:.2f})" for p, n in sorted(r["partial"].items())) or "none"
        print(
            f"{name:38s} {r['K']:4d} {r['knots'][0]:5d}/{r['knots'][1]:5d} {r['ratio']:6.3f} "
            f"{r['hit']:7d}/{r['missed']:<8d} {r['worst']:8d} {r['t_whole']:6.2f} {r['t_partial']:7.2f}  {parts}"
        )
    spliced_rows = [r for r in rows if r["file"] in SPLICES]
    dev_rows = [r for r in rows if r["file"] not in SPLICES]
    hit = sum(r["hit"] for r in spliced_rows)
    missed = sum(r["missed"] for r in spliced_rows)
    print(
        f"spliced clips: arm feature peaks the whole-body poses miss, with an arm pose within {NEAR:g} s: "
        f"{hit}/{missed} ({100.0 * hit / max(missed, 1):.0f} %)"
    )
    own_hit = sum(r["own_hit"] for r in spliced_rows)
    own_missed = sum(r["own_missed"] for r in spliced_rows)
    print(
        f"spliced clips: arm feature peaks the --partial whole-body poses miss, with a knot of an arm pose within "
        f"{NEAR:g} s: {own_hit}/{own_missed} ({100.0 * own_hit / max(own_missed, 1):.0f} %); no arm knot within "
        f"{NEAR:g} s: {sum(r['bare'] for r in spliced_rows)} without --partial, "
        f"{sum(r['bare_parts'] for r in spliced_rows)} with"
    )
    print(f"most partial poses of one part in {WINDOW:g} s: {max(r['worst'] for r in rows)}")
    report(spliced_rows, "spliced clips")
    report(dev_rows, "dev BVH files")
    tw = sum(r["t_whole"] for r in rows)
    tp = sum(r["t_partial"] for r in rows)
    print(f"extract time, all clips: {tw:.2f} s without partial, {tp:.2f} s with ({100.0 * (tp / tw - 1):+.0f} %)")


if __name__ == "__main__":
    main(sys.argv[1:])
