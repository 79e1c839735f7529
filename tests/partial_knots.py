"""The spline layer with partial poses, at the same total number of knots (issue 37).

The whole-body extract of a clip is compared with its ``--partial``
extract: the latter is the former with partial poses added (the whole-body
poses are the same), so at equal knots it is the whole-body document culled
by error by as many poses as the partial poses' knots make up, with the
partial poses added (:func:`staggered_cli.ops.cull.add_poses`), against the
whole-body document.
"""

from __future__ import annotations

import warnings

import numpy as np

from staggered_cli.errors import StaggeredWarning
from staggered_cli.model.sampling import local_pose
from staggered_cli.ops import cull
from staggered_cli.skeleton import forward_kinematics


def knot_count(doc) -> int:
    """Knots of every variable of the base layer."""
    return int(sum(len(t.knots.t) for t in doc.tracks))


def spline_error(doc) -> float:
    """Mean world joint position error of the spline layer alone against the
    source (``bake --layers splines``), % of figure height."""
    src = doc.source
    rot, tr = local_pose(doc, doc.frame_times, "splines")
    pos = forward_kinematics(src.skeleton, rot, tr)[1]
    return float(np.mean(np.linalg.norm(pos - src.world_positions(), axis=-1)) / src.figure_height() * 100.0)


def partial_poses(doc) -> tuple[list[float], list[str]]:
    """The times and parts of ``doc``'s partial poses."""
    keep = [(float(t), p) for t, p in zip(doc.pose_t, doc.pose_part, strict=True) if p is not None]
    return [t for t, _ in keep], [p for _, p in keep]


def equal_knots_ratio(whole, with_parts) -> tuple[float, tuple[int, int]]:
    """The spline layer's error with the partial poses of ``with_parts`` over
    that of the whole-body document ``whole`` alone, at the same total number
    of knots, and the two knot counts (without, with at the cull that
    reaches them).

    ``whole`` is culled (by error) by the fewest poses that bring the knots
    of its poses left plus the partial poses to at most its own; the error
    is read at exactly its knot count, linearly between that cull and the
    one with a pose more (a pose is 20 to 50 knots, a partial pose 3 to 8).
    """
    base = spline_error(whole)
    n_whole = knot_count(whole)
    times, parts = partial_poses(with_parts)
    if not times:
        return 1.0, (n_whole, n_whole)
    K = whole.n_poses
    above = (n_whole, base)
    for keep in range(K, 1, -1):
        d = whole if keep == K else cull.keep_poses(whole, cull.choose(whole, keep=str(keep)))
        left = [i for i, t in enumerate(times) if np.min(np.abs(d.pose_t - t)) > 0.5 * d.frame_time]
        with warnings.catch_warnings():  # a culled pose's refinement in the way collapses: so be it
            warnings.simplefilter("ignore", StaggeredWarning)
            d = cull.add_poses(d, [times[i] for i in left], [parts[i] for i in left])
        n, err = knot_count(d), spline_error(d)
        if n <= n_whole:
            n1, e1 = above
            e = err if n1 <= n else err + (e1 - err) * (n_whole - n) / (n1 - n)
            return e / base, (n_whole, n)
        above = (n, err)
    return float("inf"), (n_whole, n_whole)
