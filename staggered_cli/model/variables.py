"""Dense motion as control variables, and a document built from it.

A clip's variables are its joints' local rotations and translations (BVH,
in the order of :func:`staggered_cli.model.document.variable_layout`) or its
markers' positions (C3D, gaps filled); :func:`from_motion` fits splines and
displacement maps to them at chosen pose times and refinements.
"""

from __future__ import annotations

import hashlib

import numpy as np

from ..contacts.constraint import Constraint
from ..errors import UsageError
from ..motion import BvhMotion, MarkerMotion
from .document import Document, canonical_part, part_of_targets, seconds, variable_layout
from .fit import build_track
from .kinds import ROTATION


def dense_variables(
    motion: BvhMotion | MarkerMotion, by_column: bool = False
) -> list[tuple[str, tuple[str, ...], np.ndarray, np.ndarray]]:
    """The control variables of a clip as (kind, names, targets, dense values (T, V, D)).

    With ``by_column`` (BVH), the rotations are instead a sequence of each
    variable's (T, 4), made when it is asked for unless the clip's are
    cached (:meth:`BvhMotion.local_rotation_columns`).
    """
    layout = variable_layout(motion)
    if isinstance(motion, BvhMotion):
        # the rotations are cached per clip; the translations are made for
        # the joints that have position channels only (all joints' would be
        # a transient copy of 24 bytes per joint and frame)
        out = []
        for kind, names, targets in layout:
            if kind != ROTATION:
                out.append((kind, names, targets, motion.local_translations(targets)))
            elif by_column:
                out.append((kind, names, targets, motion.local_rotation_columns(targets)))
            else:
                out.append((kind, names, targets, _columns(motion.local_rotations(), targets)))
        return out
    return [(*layout[0], fill_gaps(motion.points))]


#: Bytes of a clip's local rotations (32 a joint and frame) above which
#: :func:`from_motion` fits them a joint at a time, each made as the fit
#: takes it, rather than all at once: an hour at 120 Hz (428 MB) then never
#: holds them all during its fit, for the cost of making them once more.
BY_COLUMN_BYTES = 1 << 28


def fits_by_column(motion: BvhMotion | MarkerMotion) -> bool:
    """Whether :func:`from_motion` fits the clip's rotations a joint at a
    time when they are not cached (see :data:`BY_COLUMN_BYTES`)."""
    return isinstance(motion, BvhMotion) and 32 * motion.n_frames * motion.skeleton.n_joints > BY_COLUMN_BYTES


def _columns(values: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """``values[:, targets]`` (T, V, D): the cached array itself (read-only,
    not a copy of 2.3 times the channel bytes) when the targets are all its
    joints in order, the common case."""
    if np.array_equal(targets, np.arange(values.shape[1])):
        return values
    return values[:, targets]


def fill_gaps(points: np.ndarray) -> np.ndarray:
    """Markers with NaN gaps filled by linear interpolation (held at the ends;
    a marker never seen is zero).  The gaps are put back when baking."""
    T, M, _ = points.shape
    out = np.array(points, dtype=float, copy=True)
    frames = np.arange(T)
    seen = np.all(np.isfinite(out), axis=2)
    for m in range(M):
        ok = seen[:, m]
        if ok.all():
            continue
        if not ok.any():
            out[:, m] = 0.0
            continue
        for ax in range(3):
            out[:, m, ax] = np.interp(frames, frames[ok], out[ok, m, ax])
    return out


def from_motion(
    motion: BvhMotion | MarkerMotion,
    pose_t: np.ndarray,
    refine: np.ndarray | None = None,
    *,
    priority: np.ndarray | None = None,
    source_name: str = "",
    source_bytes: bytes | None = None,
    constraints: tuple[Constraint, ...] = (),
    signals: dict | None = None,
    parameters: dict | None = None,
    pose_part: tuple[str | None, ...] | None = None,
) -> Document:
    """Build a document with poses at chosen times and refinements.

    Parameters
    ----------
    motion : the dense clip.
    pose_t : (K,) pose times in seconds; the first and last frame are added
        when missing.  Times are used as given (they need not be on frames).
    refine : (K, V) refinements in seconds over all variables (translations
        first, then rotations); zero by default.  The first and last poses
        are kept unrefined.
    pose_part : (K,) each pose's body part (``'@left-arm'``) for partial
        poses, which get knots in that part's variables only (their
        refinements elsewhere are ignored), None for whole-body poses;
        default all whole-body.  The first and last pose (added when
        missing) are whole-body.

    Raises
    ------
    UsageError if poses lie outside the clip or knots would cross.
    """
    T = motion.n_frames
    ft = float(motion.frame_time)
    frame_t = np.arange(T) * ft
    pose_t = np.asarray(pose_t, dtype=float)
    end = frame_t[-1]
    if np.any(pose_t < -1e-9) or np.any(pose_t > end + 1e-9):
        raise UsageError(f"pose times must lie within the clip (0 to {seconds(end, ft)})")
    variables = dense_variables(motion, by_column=fits_by_column(motion))
    V = sum(len(names) for _, names, _, _ in variables)
    if refine is None:
        refine = np.zeros((len(pose_t), V))
    refine = np.asarray(refine, dtype=float)
    if refine.shape != (len(pose_t), V):
        raise UsageError(f"refinements must have shape ({len(pose_t)}, {V}), got {refine.shape}")
    parts = [None] * len(pose_t) if pose_part is None else [None if p is None else canonical_part(p) for p in pose_part]
    if len(parts) != len(pose_t):
        raise UsageError(f"pose_part gives {len(parts)} parts for {len(pose_t)} poses")
    # first and last frame always carry an unrefined pose
    extra = [t for t in (0.0, end) if not np.any(np.abs(pose_t - t) < 1e-9)]
    if extra:
        pose_t = np.concatenate([pose_t, extra])
        parts += [None] * len(extra)
        refine = np.concatenate([refine, np.zeros((len(extra), V))])
        if priority is not None:
            priority = np.concatenate([priority, np.full(len(extra), np.inf)])
    order = np.argsort(pose_t, kind="stable")
    pose_t, refine = pose_t[order], refine[order]
    parts = tuple(parts[i] for i in order)
    if np.any(np.diff(pose_t) <= 0):
        raise UsageError("pose times must be distinct")
    if parts[0] is not None or parts[-1] is not None:
        raise UsageError("the first and last pose (the clip's ends) must be whole-body")
    owns = np.ones((len(pose_t), V), dtype=bool)
    if any(p is not None for p in parts):
        targets = np.concatenate([t for _, _, t, _ in variables])
        masks = {p: part_of_targets(motion, targets, p) for p in set(parts) if p is not None}
        for k, p in enumerate(parts):
            if p is not None:
                owns[k] = masks[p]
    refine[0] = 0.0
    refine[-1] = 0.0
    if priority is None:
        priority = np.zeros(len(pose_t))
        priority[[0, -1]] = np.inf
    else:
        priority = np.asarray(priority, dtype=float)[order]
    tracks, col = [], 0
    for kind, names, targets, dense in variables:
        n = len(names)
        own = None if owns.all() else owns[:, col : col + n]
        tracks.append(build_track(kind, names, targets, frame_t, dense, pose_t, refine[:, col : col + n], own))
        col += n
    sha = hashlib.sha256(source_bytes).hexdigest() if source_bytes is not None else ""
    return Document(
        pose_t=pose_t,
        priority=priority,
        tracks=tuple(tracks),
        source=motion,
        source_name=source_name,
        source_sha256=sha,
        constraints=tuple(constraints),
        signals=dict(signals or {}),
        parameters=dict(parameters or {}),
        pose_part=parts,
    )
