"""Bake a document back to dense motion: splines ⊕ displacement maps ⊕ the
contact layer, in the source's skeleton and channel layout (or markers).

The contact (IK) layer repairs what edits disturbed: a constraint whose
effector is where the source had it (to 1e-6 of the figure's size) over the
constraint and its blend windows gets no layer, so an unedited round trip
stays lossless and an edit stays local.  During a disturbed constraint the
effector follows its own captured path, shifted by the mean offset the edit
gave it over the constraint: the edit adds no sliding, the capture's own
heel-to-toe roll is kept, and an edit that moves the whole figure moves its
plants along.
"""

from __future__ import annotations

import numpy as np

from ..document import Document, at_times, local_pose, marker_points, output_times, reference_channels
from ..document import same_rate as is_same_rate
from ..errors import UsageError
from ..motion import (
    BvhMotion,
    MarkerMotion,
    channels_from_local,
)
from ..skeleton import forward_kinematics

_UNDISTURBED = 1e-6  # of figure height
_SAME_VALUE = 1e-9  # channel units (degrees, file units)
_RESAMPLED = 1e-3  # of figure height, when baking at another rate


def bake(
    doc: Document, *, fps: float | None = None, layers: str = "all", ik: bool = True, ik_blend: float = 0.1
) -> BvhMotion | MarkerMotion:
    """Dense motion of ``doc`` at the source rate (or ``fps``).

    Parameters
    ----------
    layers : ``'all'`` or ``'splines'`` (the splines alone, without
        displacement maps or the contact layer: what the poses capture).
    ik : apply the contact layer to disturbed constraints.
    ik_blend : seconds over which the layer fades in and out.
    """
    if layers not in ("all", "splines"):
        raise UsageError(f"--layers must be 'all' or 'splines', got {layers!r}")
    if not np.isfinite(ik_blend) or ik_blend < 0:
        raise UsageError(f"--ik-blend must be a non-negative number of seconds, got {ik_blend}")
    t = output_times(doc, fps)
    same_rate = is_same_rate(doc, fps)
    frame_time = doc.frame_time if same_rate else 1.0 / fps
    if doc.kind == "bvh":
        src = doc.source
        rot, tr = local_pose(doc, t, layers)
        if ik and layers == "all" and doc.constraints:
            rot = _contact_layer(doc, rot, tr, t, ik_blend, same_rate)
        ref = reference_channels(doc, t)
        channels = channels_from_local(src.skeleton, rot, tr, ref)
        if same_rate:
            # where the motion is the source's to rounding noise, write the
            # source's own numbers (its -0 and its last digit included)
            channels = np.where(np.abs(channels - ref) < _SAME_VALUE, ref, channels)
        text = src.frame_time_text if same_rate else _frame_time_text(frame_time)
        return BvhMotion(src.skeleton, channels, frame_time, text, src.number_format, source=src.source)
    src = doc.source
    pts = marker_points(doc, t, layers)
    if ik and layers == "all" and doc.constraints:
        pts = _pin_markers(doc, pts, t, ik_blend, same_rate)
    return MarkerMotion(src.labels, pts, 1.0 / frame_time, src.units, src.source)


def _frame_time_text(ft: float) -> str:
    return f"{ft:.7f}".rstrip("0")


def _source_path(points: np.ndarray, frame_time: float, c, t: np.ndarray) -> np.ndarray:
    """Where a constrained point was in the source (T', 3) at output times ``t``.

    Inside the constraint, its source span is stretched onto its current
    span (timing edits move constraints); before and after, the source is
    shifted by the same amount as the nearer end.  Linear between source
    frames (NaN where a neighbouring frame is a gap).
    """
    s0, s1 = c.source_span
    span = c.end - c.start
    inside = s0 + (t - c.start) * ((s1 - s0) / span if span > 0 else 0.0)
    s = np.where(t < c.start, t + (s0 - c.start), np.where(t > c.end, t + (s1 - c.end), inside))
    return at_times(points, frame_time, s)


def _disturbed(pos: np.ndarray, path: np.ndarray, t: np.ndarray, c, blend: float, tolerance: float) -> bool:
    """Whether the edits moved a constrained point off its source path over
    the constraint and its blend windows."""
    window = (t >= c.start - blend - 1e-9) & (t <= c.end + blend + 1e-9)
    if not window.any():
        return False
    with np.errstate(invalid="ignore"):
        d = np.linalg.norm(pos[window] - path[window], axis=-1)
    return bool(np.nanmax(d) > tolerance) if np.isfinite(d).any() else False


def _check_blend(blend: float, same_rate: bool) -> float:
    # resampled frames differ from the source by interpolation, which is large
    # where a lifting foot moves fast: judge a resampled bake inside the
    # constraint only, where a planted point is still
    return blend if same_rate else 0.0


def _tolerance(size: float, same_rate: bool) -> float:
    # resampled output differs from the source by interpolation alone, which a
    # planted point (nearly still) keeps far below a thousandth of the figure
    return (_UNDISTURBED if same_rate else _RESAMPLED) * size


def _chain_changed(sk, changed: np.ndarray, t: np.ndarray, c, blend: float) -> bool:
    """Whether any joint from the root down to ``c.joint`` differs from the
    source over the constraint's window (``changed`` (T, J) bool), or the
    constraint was moved by a timing edit."""
    if c.source_span != (float(c.start), float(c.end)):
        return True
    window = (t >= c.start - blend - 1e-9) & (t <= c.end + blend + 1e-9)
    j = sk.names.index(c.joint)
    chain = []
    while j >= 0:
        chain.append(j)
        j = int(sk.parents[j])
    return bool(changed[np.ix_(window, chain)].any())


def _linked(sk, a: str, b: str) -> bool:
    """Whether one joint is the other's parent (a foot and its toe)."""
    ia, ib = sk.names.index(a), sk.names.index(b)
    return ia != ib and (sk.parents[ia] == ib or sk.parents[ib] == ia)


def _overlap(c, d, blend: float) -> bool:
    return c.start - blend <= d.end + blend and d.start - blend <= c.end + blend


def _contact_layer(
    doc: Document, rot: np.ndarray, tr: np.ndarray, t: np.ndarray, blend: float, same_rate: bool
) -> np.ndarray:
    """Repair the constraints the edits disturbed (see the module docstring)."""
    src = doc.source
    sk = src.skeleton
    for c in doc.constraints:
        if c.joint not in sk.names:
            raise UsageError(f"constraint on unknown joint {c.joint!r}")
    candidates = list(doc.constraints)
    if same_rate:
        # cheap first pass without forward kinematics: a constraint whose
        # chain keeps the source's local values over its window is untouched
        changed = (1.0 - np.abs(np.sum(rot * src.local_rotations(), axis=-1)) > 1e-12) | np.any(
            np.abs(tr - src.local_translations()) > 1e-9, axis=-1
        )
        candidates = [c for c in candidates if c.pin or _chain_changed(sk, changed, t, c, blend)]
    if not candidates:
        return rot
    _, wp = forward_kinematics(sk, rot, tr)
    src_wp = src.world()[1]
    size = src.figure_height()  # cached with the clip's world positions

    def target(c):
        j = sk.names.index(c.joint)
        path = _source_path(src_wp[:, j], doc.frame_time, c, t)
        inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
        offset = (wp[inside, j] - path[inside]).mean(axis=0) if inside.any() else np.zeros(3)
        return path, path + offset

    todo = [
        c
        for c in candidates
        if c.pin
        or _disturbed(
            wp[:, sk.names.index(c.joint)],
            target(c)[0],
            t,
            c,
            _check_blend(blend, same_rate),
            _tolerance(size, same_rate),
        )
    ]
    # a foot and its toe share a chain: solving one moves the other, so a
    # planted neighbour overlapping a repaired constraint is held on its path too
    for c in [c for c in todo if not c.pin]:  # a pinned joint is the user's word: its neighbours follow it
        for d in doc.constraints:
            if d not in todo and _linked(sk, c.joint, d.joint) and _overlap(c, d, blend):
                todo.append(d)
    if not todo:
        return rot
    targets = [None if c.pin else target(c)[1] for c in todo]  # None: held at its mean position
    from ..ik import ik_layer

    return ik_layer(sk, rot, tr, t, tuple(todo), blend=blend, targets=targets)


def _smooth_weight(t: np.ndarray, start: float, end: float, blend: float) -> np.ndarray:
    """1 inside [start, end], a C1 smoothstep ramp to 0 over ``blend`` seconds outside."""
    w = ((t >= start) & (t <= end)).astype(float)
    if blend > 0:
        for edge, side in ((start, -1.0), (end, 1.0)):
            x = side * (t - edge) / blend
            ramp = (x > 0) & (x < 1)
            s = 1.0 - x[ramp]
            w[ramp] = np.maximum(w[ramp], s * s * (3.0 - 2.0 * s))
    return w


def _pin_markers(doc: Document, pts: np.ndarray, t: np.ndarray, blend: float, same_rate: bool) -> np.ndarray:
    """C3D: a disturbed constrained marker follows its captured path shifted by
    the edit's mean offset over the constraint, blended in and out (markers
    have no chain to solve)."""
    src = doc.source
    tolerance = _tolerance(src.figure_height(), same_rate)
    out = pts.copy()
    for c in doc.constraints:
        if c.joint not in src.labels:
            raise UsageError(f"constraint on unknown marker {c.joint!r}")
        m = src.labels.index(c.joint)
        path = _source_path(src.points[:, m], doc.frame_time, c, t)
        if c.pin:  # planted by the user: held at its mean position over the constraint
            inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
            seen = pts[inside, m][np.all(np.isfinite(pts[inside, m]), axis=1)]
            if not len(seen):
                continue
            path = np.broadcast_to(seen.mean(axis=0), path.shape)
        elif not _disturbed(pts[:, m], path, t, c, _check_blend(blend, same_rate), tolerance):
            continue
        inside = (t >= c.start - 1e-9) & (t <= c.end + 1e-9)
        seen = inside & np.all(np.isfinite(pts[:, m]), axis=1) & np.all(np.isfinite(path), axis=1)
        if not seen.any():
            continue
        target = path + (pts[seen, m] - path[seen]).mean(axis=0)
        w = _smooth_weight(t, c.start, c.end, blend)[:, None]
        # in the blend windows the correction fades from its value at the boundary
        i0, i1 = np.flatnonzero(seen)[[0, -1]]
        corr = np.where((t < c.start)[:, None], target[i0] - pts[i0, m], target[i1] - pts[i1, m])
        corr[inside] = (target - pts[:, m])[inside]
        out[:, m] = np.where(w > 0, pts[:, m] + w * np.nan_to_num(corr), out[:, m])
    return out
