"""A document's motion sampled at any times: local poses, marker points and
the source's channel values (the reference for choosing Euler triples).

What baking and pose files read; pure functions of a :class:`Document`.
"""

from __future__ import annotations

import numpy as np

from .. import quat
from ..motion import BvhMotion, MarkerMotion, rotation_columns
from .document import Document
from .evaluate import evaluate
from .kinds import ROTATION


def local_pose(doc: Document, t: np.ndarray, layers: str = "all") -> tuple[np.ndarray, np.ndarray]:
    """BVH documents: local rotations (N, J, 4) and translations (N, J, 3) at times ``t``."""
    src = doc.source
    assert isinstance(src, BvhMotion)
    sk = src.skeleton
    N = len(t)
    rot = quat.identity((N, sk.n_joints))
    tr = np.broadcast_to(sk.offsets, (N, sk.n_joints, 3)).copy()
    t = np.asarray(t, dtype=float)
    step = _FRAMES_AT_ONCE
    for track in doc.tracks:
        into = rot if track.kind == ROTATION else tr
        for lo in range(0, N, step):  # a block at a time: no second copy of the whole clip
            into[lo : lo + step, track.targets] = evaluate(track, t[lo : lo + step], layers)
    return rot, tr


#: Frames evaluated at once by :func:`local_pose`.
_FRAMES_AT_ONCE = 2048


def marker_points(doc: Document, t: np.ndarray, layers: str = "all") -> np.ndarray:
    """C3D documents: marker positions (N, M, 3) at times ``t``, NaN where the
    source had a gap at the nearest source frame."""
    src = doc.source
    assert isinstance(src, MarkerMotion)
    pts = evaluate(doc.tracks[0], t, layers)
    nearest = np.clip(np.rint(np.asarray(t) / doc.frame_time).astype(int), 0, doc.n_frames - 1)
    gap = ~np.all(np.isfinite(src.points), axis=2)[nearest]
    return np.where(gap[..., None], np.nan, pts)


def reference_channels(doc: Document, t: np.ndarray) -> np.ndarray:
    """BVH channel values of the source at times ``t`` (exact on source frames,
    linear between them, rotation channels unwrapped first so that a wrap
    from 179 to -179 degrees does not interpolate through 0): the reference
    for choosing Euler triples."""
    src = doc.source
    assert isinstance(src, BvhMotion)
    ch = src.channels
    if len(t) == src.n_frames and np.allclose(t, doc.frame_times, atol=1e-9, rtol=0):
        return ch
    rot_cols = [c for _, cols, _ in rotation_columns(src.skeleton) for c in cols]
    ch = ch.copy()
    ch[:, rot_cols] = np.unwrap(ch[:, rot_cols], period=360.0, axis=0)
    return at_times(ch, doc.frame_time, t)


def at_times(values: np.ndarray, frame_time: float, t: np.ndarray) -> np.ndarray:
    """Frame values ``(T, ...)`` (frame k at ``k · frame_time`` seconds) at
    times ``t`` (N,): linear between frames, held at the ends; NaN where a
    neighbouring frame is NaN.  Returns (N, ...)."""
    f = np.clip(np.asarray(t, dtype=float) / frame_time, 0, len(values) - 1)
    lo = np.floor(f).astype(int)
    hi = np.minimum(lo + 1, len(values) - 1)
    w = (f - lo).reshape((-1,) + (1,) * (values.ndim - 1))
    return values[lo] * (1.0 - w) + values[hi] * w
