"""Bake a document back to dense motion: splines ⊕ displacement maps ⊕ the
contact layer (:mod:`staggered_cli.contact_layer`), in the source's skeleton
and channel layout (or markers), at the source's rate or another.
"""

from __future__ import annotations

import numpy as np

from .. import quat
from ..contacts import layer as contact_layer
from ..errors import UsageError, arg
from ..model.document import Document
from ..model.sampling import at_times, local_pose, marker_points, reference_channels
from ..motion import (
    BvhMotion,
    MarkerMotion,
    channels_from_local,
    rate_problem,
)

_SAME_VALUE = 1e-9  # channel units (degrees, file units)

#: Bounds of a resampled bake: no motion is captured finer than this.
MAX_FPS_FACTOR = 100
MAX_OUTPUT_FRAMES = 10_000_000


def bake(
    doc: Document,
    *,
    fps: float | None = None,
    layers: str = "all",
    ik: bool = True,
    ik_blend: float = 0.1,
    move_plants: bool = False,
) -> BvhMotion | MarkerMotion:
    """Dense motion of ``doc`` at the source rate (or ``fps``).

    Parameters
    ----------
    layers : ``'all'`` or ``'splines'`` (the splines alone, without
        displacement maps or the contact layer: what the poses capture).
    ik : apply the contact layer to disturbed constraints.
    ik_blend : seconds over which the layer fades in and out.
    move_plants : the edits moved the figure as a whole: planted contacts
        move with them, horizontally (by default they stay on their captured
        path; see :mod:`staggered_cli.contact_layer`).

    At another rate the contact layer is solved at the source's frames and
    its correction resampled to the output's (slerp of each joint's local
    correction, linear for markers), so that every rate repairs the same
    contacts the same way.
    """
    if layers not in ("all", "splines"):
        raise UsageError(f"{arg('layers')} must be 'all' or 'splines', got {layers!r}")
    if not np.isfinite(ik_blend) or ik_blend < 0:
        raise UsageError(f"{arg('ik_blend')} must be a non-negative number of seconds, got {ik_blend}")
    t = output_times(doc, fps)
    same_rate = is_same_rate(doc, fps)
    frame_time = doc.frame_time if same_rate else 1.0 / fps
    if doc.kind == "bvh":
        src = doc.source
        use_layer = ik and layers == "all" and bool(doc.constraints)
        if not use_layer or (same_rate and not contact_layer.repairs_unseen(doc)):
            channels = _channels_by_blocks(doc, t, layers, same_rate, ik_blend if use_layer else None)
            if channels is not None:
                return src.with_channels(channels, None if same_rate else frame_time)
        rot, tr = local_pose(doc, t, layers)
        if use_layer and same_rate:
            rot = contact_layer.joint_layer(doc, rot, tr, t, ik_blend, True, move_plants)
        elif use_layer:
            rot = _resampled_layer(doc, rot, t, ik_blend, move_plants)
        ref = reference_channels(doc, t)
        channels = channels_from_local(src.skeleton, rot, tr, ref)
        del rot, tr
        if same_rate:
            # where the motion is the source's to rounding noise, write the
            # source's own numbers (its -0 and its last digit included);
            # in place, since channels is this function's own
            near = channels - ref
            np.abs(near, out=near)
            np.copyto(channels, ref, where=near < _SAME_VALUE)
            del near
        return src.with_channels(channels, None if same_rate else frame_time)
    src = doc.source
    pts = marker_points(doc, t, layers)
    if ik and layers == "all" and doc.constraints:
        if same_rate:
            pts = contact_layer.marker_layer(doc, pts, t, ik_blend, True, move_plants)
        else:  # solved at the source's frames, the correction resampled
            native = marker_points(doc, doc.frame_times, layers)
            corr = contact_layer.marker_layer(doc, native, doc.frame_times, ik_blend, True, move_plants) - native
            del native
            pts = pts + at_times(np.nan_to_num(corr), doc.frame_time, t)
    return src.with_points(pts, 1.0 / frame_time)


def _resampled_layer(doc: Document, rot: np.ndarray, t: np.ndarray, blend: float, move_plants: bool) -> np.ndarray:
    """Local rotations ``rot`` (N, J, 4) at output times ``t`` (another rate)
    with the contact layer: solved at the source's frames, where it is
    defined, and each joint's local correction there slerped to ``t``."""
    ft = doc.frame_time
    native, tr = local_pose(doc, doc.frame_times, "all")
    solved = contact_layer.joint_layer(doc, native, tr, doc.frame_times, blend, True, move_plants)
    if solved is native:
        return rot
    joints = np.flatnonzero(np.any(solved != native, axis=(0, 2)))
    corr = quat.mul(quat.conj(native[:, joints]), solved[:, joints])  # (T, n, 4)
    del native, solved, tr
    corr = np.where(corr[..., :1] < 0.0, -corr, corr)  # corrections are under a half turn
    f = np.clip(t / ft, 0, len(corr) - 1)
    lo = np.floor(f).astype(int)
    hi = np.minimum(lo + 1, len(corr) - 1)
    out = rot.copy()
    out[:, joints] = quat.mul(rot[:, joints], quat.slerp(corr[lo], corr[hi], (f - lo)[:, None]))
    return out


def _channels_by_blocks(
    doc: Document, t: np.ndarray, layers: str, same_rate: bool, blend: float | None
) -> np.ndarray | None:
    """The baked channel values (N, C) of a BVH document at times ``t``, a
    block of frames at a time (each frame is its own: the same numbers as
    all at once), so that the pose of the whole clip never exists.

    With a ``blend`` (same-rate, contact layer on), each block is also
    compared with the source: where a constraint's chain changed, the
    contact layer has work, which needs the whole pose: None is returned
    (at the first such block) and the caller bakes all at once.
    """
    src = doc.source
    sk = src.skeleton
    chains = None
    if blend is not None:
        contact_layer.check_joints(doc)
        chains = contact_layer.chain_joints(doc)  # the joints the test of a block looks at
    ref = reference_channels(doc, t)
    channels = np.empty(ref.shape)
    for lo in range(0, len(t), _BAKE_BLOCK):
        hi = min(lo + _BAKE_BLOCK, len(t))
        rot, tr = local_pose(doc, t[lo:hi], layers)
        if blend is not None and contact_layer.disturbed_in(
            doc, contact_layer.source_changed(src, rot, tr, lo, chains), t[lo:hi], blend
        ):
            return None
        block = channels_from_local(sk, rot, tr, ref[lo:hi])
        if same_rate:
            # where the motion is the source's to rounding noise, write the
            # source's own numbers (its -0 and its last digit included)
            block = np.where(np.abs(block - ref[lo:hi]) < _SAME_VALUE, ref[lo:hi], block)
        channels[lo:hi] = block
    return channels


#: Frames baked at once by :func:`_channels_by_blocks` (a multiple of the
#: evaluation's own block, so that it evaluates in the same batches).
_BAKE_BLOCK = 8192


def is_same_rate(doc: Document, fps: float | None) -> bool:
    """Whether ``fps`` is the source's own rate (its nominal rate, e.g. 120
    for a written frame time of .0083333, or exactly its frame time)."""
    if fps is None:
        return True
    return abs(fps - doc.source.rate) <= 1e-6 * fps or abs(fps * doc.frame_time - 1.0) < 1e-9


def output_times(doc: Document, fps: float | None = None) -> np.ndarray:
    """Frame times (seconds) to bake at: the source's, or a new rate over the same span."""
    if fps is not None and (not np.isfinite(fps) or fps <= 0):
        raise UsageError(f"{arg('fps')} must be a positive number, got {fps}")
    if fps is not None and rate_problem(fps) is not None:
        raise UsageError(f"{arg('fps')} {fps:g} {rate_problem(fps)}")
    if is_same_rate(doc, fps):
        return doc.frame_times
    n = int(np.floor(doc.duration * fps + 1e-3)) + 1  # a frame within 1/1000 of the end counts
    if fps > MAX_FPS_FACTOR * doc.source.rate or n > MAX_OUTPUT_FRAMES:
        raise UsageError(
            f"{arg('fps')} {fps:g} is out of range: at most {MAX_FPS_FACTOR}x the source's {doc.source.rate:g} Hz "
            f"and {MAX_OUTPUT_FRAMES} frames"
        )
    return np.minimum(np.arange(n) / fps, doc.duration)
