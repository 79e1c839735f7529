"""Partial poses in a document (issue 37): which were found, for which part.

The finding is :mod:`staggered_cli.signals.partial`; this module reads what
:func:`staggered_cli.ops.extract.extract` recorded.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import StaggeredWarning, UsageError
from ..model.document import Document
from ..model.sampling import local_pose
from ..motion import BvhMotion
from ..signals import partial as partial_signals
from ..skeleton import forward_kinematics
from . import cull

#: The document parameter the partial poses extract found are recorded in:
#: body part -> their times, seconds.
PARAMETER = "partial_poses"


def part_roots(motion: BvhMotion) -> dict[str, int]:
    """Body part -> its root joint, for the parts the skeleton has."""
    return partial_signals.part_roots(motion)


def partial_times(doc: Document) -> dict[str, np.ndarray]:
    """Body part (``left-arm``, ...) -> the times (seconds, sorted) of its partial poses."""
    found = doc.parameters.get(PARAMETER) or {}
    return {str(p): np.sort(np.asarray(t, dtype=float)) for p, t in found.items()}


#: A partial pose stays only where it lowers the spline layer's world error
#: by at least this share of what the knots of the whole-body pose a cull
#: would take first hold in place, per knot.
WORLD_VALUE = 1.0


def _world_error(doc: Document, rot: np.ndarray, tr: np.ndarray) -> float:
    """Summed over joints, the mean distance (file units) of the spline
    layer's joints from the source's (what ``bake --layers splines`` misses)."""
    pos = forward_kinematics(doc.source.skeleton, rot, tr)[1]
    return float(np.sum(np.mean(np.linalg.norm(pos - doc.source.world_positions(), axis=-1), axis=0)))


def _knots_of(doc: Document, joints: np.ndarray) -> int:
    """Knots of the variables that drive ``joints``."""
    n = 0
    for tr in doc.tracks:
        n += int(np.sum(np.diff(tr.knots.ptr)[np.isin(tr.targets, joints)]))
    return n


def confirmed(doc: Document, candidates: list[tuple[str, int]]) -> dict[str, np.ndarray]:
    """The partial poses of ``candidates`` ((part, frame), best first, from
    :func:`staggered_cli.signals.partial.find_partial`) that earn their knots
    in the real spline layer, judged in world space: each, added in turn, must
    lower the error of the spline layer alone (joint positions, summed over
    joints) by at least :data:`WORLD_VALUE` times, per knot, what the
    whole-body pose a cull would take first holds in place.  The proxy
    cannot see this: where a joint's spline error cancels its parent's
    (a walk's spine against its pelvis), a knot of the one alone makes the
    figure worse.  Body part -> times (seconds, sorted)."""
    if not candidates or doc.n_poses < 3:
        return {}
    times = doc.frame_times
    rot, tr = local_pose(doc, times, "splines")
    rot, tr = rot.copy(), tr.copy()
    error = _world_error(doc, rot, tr)
    fewer = cull.keep_poses(doc, cull.choose(doc, keep=str(doc.n_poses - 1), ignore_contacts=True))
    r1, t1 = local_pose(fewer, times, "splines")
    every = np.arange(doc.source.skeleton.n_joints)
    value = max(_world_error(doc, r1, t1) - error, 0.0) / max(_knots_of(doc, every) - _knots_of(fewer, every), 1)
    joints = partial_signals.part_joints(doc.source)
    per_part: dict[str, Document] = {}
    out: dict[str, list[float]] = {}
    for part, frame in candidates:
        t = float(frame) * doc.frame_time
        base = per_part.get(part, doc)
        js = joints[part]
        with warnings.catch_warnings():  # a refinement of another part that collapses does not count
            warnings.simplefilter("ignore", StaggeredWarning)
            try:
                trial = cull.add_pose(base, t)
            except UsageError:
                continue
        r2, t2 = local_pose(trial, times, "splines")
        rot_try, tr_try = rot.copy(), tr.copy()
        rot_try[:, js] = r2[:, js]
        tr_try[:, js] = t2[:, js]
        e = _world_error(doc, rot_try, tr_try)
        added = _knots_of(trial, js) - _knots_of(base, js)
        if error - e >= WORLD_VALUE * value * added:
            per_part[part] = trial
            rot, tr, error = rot_try, tr_try, e
            out.setdefault(part, []).append(t)
    return {p: np.sort(np.array(ts)) for p, ts in out.items()}
