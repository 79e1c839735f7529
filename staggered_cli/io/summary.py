"""What a BVH, a C3D or a document holds, as one JSON-able dict (``info``):
the file's layout included (the frame time as written), which is io's to read.

Times in seconds, lengths in file units; derived floats are rounded to
six decimals so that golden files do not hang on the last bit.
"""

from __future__ import annotations

from typing import Any

_DIGITS = 6  # rounding of derived floats, so that golden files do not hang on the last bit


def _r(x: float) -> float:
    return round(float(x), _DIGITS)


def bvh_summary(motion) -> dict[str, Any]:
    """Summary of a :class:`~staggered_cli.motion.BvhMotion` (times in seconds,
    lengths in file units)."""
    sk = motion.skeleton
    orders: dict[str, int] = {}
    for j in range(sk.n_joints):
        order = sk.rotation_order(j)
        if order:
            orders[order] = orders.get(order, 0) + 1
    return {
        "kind": "bvh",
        "frames": motion.n_frames,
        "frame_time": motion.frame_time,
        "frame_time_text": motion.frame_time_text or repr(motion.frame_time),
        "rate": _r(motion.rate),
        "duration": _r(motion.n_frames * motion.frame_time),
        "joints": sk.n_joints,
        "joint_names": list(sk.names),
        "end_sites": len(sk.end_parents),
        "channels": int(motion.channels.shape[1]),
        "joints_with_position": sum(1 for j in range(sk.n_joints) if sk.has_position(j)),
        "euler_orders": dict(sorted(orders.items())),
        "figure_height": _r(motion.figure_height()),
    }


def c3d_summary(motion) -> dict[str, Any]:
    """Summary of a :class:`~staggered_cli.motion.MarkerMotion` (times in
    seconds, lengths in file units, ``gap_fraction`` of missing samples)."""
    import numpy as np

    pts = motion.points
    missing = ~np.all(np.isfinite(pts), axis=-1)  # (T, M): a marker sample is missing
    return {
        "kind": "c3d",
        "frames": motion.n_frames,
        "frame_time": _r(motion.frame_time),
        "rate": _r(motion.rate),
        "duration": _r(motion.n_frames * motion.frame_time),
        "markers": len(motion.labels),
        "marker_labels": list(motion.labels),
        "units": motion.units,
        "gap_fraction": _r(missing.mean()) if missing.size else 0.0,
        "markers_with_gaps": int(np.count_nonzero(missing.any(axis=0))),
        "figure_size": _r(motion.figure_height()),
    }


def document_info(doc) -> dict[str, Any]:
    """Summary of a :class:`~staggered_cli.model.document.Document` (JSON-able;
    includes ``frames`` and ``frame_time``)."""
    from ..model.document import document_summary

    return {"kind": "document", **document_summary(doc)}


def summarize(value, name: str | None = None) -> dict[str, Any]:
    """The summary dict of a BvhMotion, MarkerMotion or Document, as
    ``info --json`` prints it; ``file`` is ``name`` (default: the clip's own
    base name, or the document's source name)."""
    from ..errors import UsageError, arg
    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

    if isinstance(value, BvhMotion):
        summary = bvh_summary(value)
    elif isinstance(value, MarkerMotion):
        summary = c3d_summary(value)
    elif isinstance(value, Document):
        summary = document_info(value)
    else:
        what = type(value).__name__
        raise UsageError(f"{arg('value')} must be a Document, a BvhMotion or a MarkerMotion, got {what}")
    if name is None:
        name = getattr(value, "name", "") or getattr(value, "source_name", "")
    return {"file": name, **summary}
