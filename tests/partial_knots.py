"""The spline layer with partial poses, at the same total number of knots (issue 37).

A partial pose of a body part is a knot of each of the part's variables
(and none of the others').  Each variable's spline is fitted to its own
knots alone, so the spline layer of a document with partial poses is, part
by part, that of the whole-body document with the part's partial poses
added as poses (:func:`staggered_cli.ops.cull.add_pose`), read for the
part's variables only.  That is how it is measured here.
"""

from __future__ import annotations

import warnings

import numpy as np

from staggered_cli.errors import StaggeredWarning
from staggered_cli.model.sampling import local_pose
from staggered_cli.ops import cull
from staggered_cli.signals import partial as partial_signals
from staggered_cli.skeleton import forward_kinematics


def knot_count(doc) -> int:
    """Knots of every variable of the base layer."""
    return int(sum(len(t.knots.t) for t in doc.tracks))


def with_partial(doc, found: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, int]:
    """The spline layer's local rotations (T, J, 4) and translations (T, J, 3)
    of ``doc`` with the partial poses ``found`` (body part -> times), and its
    total number of knots."""
    rot, tr = local_pose(doc, doc.frame_times, "splines")
    rot, tr = rot.copy(), tr.copy()
    n = knot_count(doc)
    joints = partial_signals.part_joints(doc.source)
    for part, times in found.items():
        if len(times) == 0:
            continue
        d = doc
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", StaggeredWarning)
            for t in times:
                d = cull.add_pose(d, float(t))
        r2, t2 = local_pose(d, doc.frame_times, "splines")
        js = joints[part]
        rot[:, js] = r2[:, js]
        tr[:, js] = t2[:, js]
        for a, b in zip(doc.tracks, d.tracks, strict=True):
            for name in a.names:
                if a.targets[a.index(name)] in js:
                    i = a.index(name)
                    n += (b.knots.ptr[i + 1] - b.knots.ptr[i]) - (a.knots.ptr[i + 1] - a.knots.ptr[i])
    return rot, tr, int(n)


def spline_error(doc, rot: np.ndarray, tr: np.ndarray) -> float:
    """Mean world joint position error of a spline layer against the source, % of figure height."""
    src = doc.source
    pos = forward_kinematics(src.skeleton, rot, tr)[1]
    return float(np.mean(np.linalg.norm(pos - src.world_positions(), axis=-1)) / src.figure_height() * 100.0)


def equal_knots_ratio(whole, found: dict[str, np.ndarray]) -> tuple[float, tuple[int, int]]:
    """The spline layer's error with the partial poses ``found`` over that of
    the whole-body document ``whole`` alone, at the same total number of
    knots: ``whole`` is culled (by error) by the fewest poses that bring the
    knots of its poses left plus the partial poses to at most its own, and
    the error is read at exactly its knot count, linearly between that cull
    and the one with a pose more (a pose is some 30 knots, a partial pose
    4 to 8); and the two knot counts (without, with at that cull)."""
    rot, tr = local_pose(whole, whole.frame_times, "splines")
    base = spline_error(whole, rot, tr)
    n_whole = knot_count(whole)
    if not any(len(t) for t in found.values()):
        return 1.0, (n_whole, n_whole)
    K = whole.n_poses
    above = (n_whole, base)  # (knots, error) of the last trial with more knots than ``whole``
    for keep in range(K, 1, -1):
        d = whole if keep == K else cull.keep_poses(whole, cull.choose(whole, keep=str(keep)))
        # partial poses where a pose left stands are not needed there
        left = {
            p: np.array([t for t in ts if np.min(np.abs(d.pose_t - t)) > 0.5 * d.frame_time]) for p, ts in found.items()
        }
        rot, tr, n = with_partial(d, left)
        err = spline_error(whole, rot, tr)
        if n <= n_whole:
            # the error at exactly ``n_whole`` knots, linear between this trial and the one above
            (n1, e1) = above
            e = err if n1 <= n else err + (e1 - err) * (n_whole - n) / (n1 - n)
            return e / base, (n_whole, n)
        above = (n, err)
    return float("inf"), (n_whole, n_whole)
