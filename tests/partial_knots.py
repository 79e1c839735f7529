"""The spline layer with partial poses, at the same total number of knots (issue 37).

The whole-body extract of a clip is compared with its ``--partial``
extract: the latter keeps the former's whole-body poses but makes some of
them partial poses and adds partial poses, within the former's knots; at
equal knots it is compared with the whole-body document culled by error to
its own number of knots (:func:`equal_knots_ratio`).
"""

from __future__ import annotations

import numpy as np

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
    """The spline layer's error of ``with_parts`` (the ``--partial``
    extract) at its own total number of knots over that of the whole-body
    extract ``whole`` culled (by error, ``cull --keep``) to the same number
    of knots, and the two knot counts (``whole``'s, ``with_parts``').

    ``whole``'s error at exactly ``with_parts``' knot count is read linearly
    between the cull at or below it and the one with a pose more (a pose is
    20 to 50 knots); at ``whole``'s own count it is ``whole``'s error.  The
    ``--partial`` extract spends at most the knots of the whole-body one
    (its whole-body poses are some of ``whole``'s, a few made partial, and
    its partial poses); one with more has no fair comparison (ValueError).
    """
    base = spline_error(whole)
    n_whole, n_parts = knot_count(whole), knot_count(with_parts)
    if n_parts > n_whole:
        raise ValueError(f"the partial document has {n_parts} knots, more than the whole-body one's {n_whole}")
    err = spline_error(with_parts)
    K = whole.n_poses
    above = (n_whole, base)
    for keep in range(K - 1, 1, -1):
        if above[0] == n_parts:
            break
        d = cull.keep_poses(whole, cull.choose(whole, keep=str(keep)))
        n, e = knot_count(d), spline_error(d)
        if n <= n_parts:
            n1, e1 = above
            return err / (e + (e1 - e) * (n_parts - n) / (n1 - n)), (n_whole, n_parts)
        above = (n, e)
    return err / above[1], (n_whole, n_parts)
