"""``staggered info FILE [--json]``: what a BVH, C3D or document holds."""

from __future__ import annotations

import json
import os
from typing import Any

import click

from ..errors import StaggeredError
from .options import input_argument, load_input

#: Keys shown first in the table, in this order; the rest follow sorted.
_FIRST = ("file", "kind", "frames", "frame_time", "rate", "duration")
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


def document_info(manifest: dict, arrays: dict) -> dict[str, Any]:
    """Summary of a document, from the representation's hook.

    Hook: ``model.document.document_summary(io.schema.from_parts(manifest, arrays)) -> dict``
    (JSON-able; includes ``frames`` and ``frame_time``).
    """
    from staggered_cli.io.schema import from_parts
    from staggered_cli.model.document import document_summary

    return {"kind": "document", **document_summary(from_parts(manifest, arrays))}


def summarize(obj, name: str, source: str | None = None) -> dict[str, Any]:
    """The summary dict of what :func:`~.options.load_input` returned.

    ``name`` is the ``file`` entry; errors name ``source`` (default ``name``),
    the path as given, like every other message about the file."""
    from ..motion import BvhMotion, MarkerMotion

    if isinstance(obj, BvhMotion):
        summary = bvh_summary(obj)
    elif isinstance(obj, MarkerMotion):
        summary = c3d_summary(obj)
    else:
        try:
            summary = document_info(*obj)
        except StaggeredError as err:
            err.with_source(source or name)
            raise
    return {"file": name, **summary}


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}" if abs(value) >= 1e-4 or value == 0 else repr(value)
    if isinstance(value, dict | list | tuple) and not value:
        return "none"
    if isinstance(value, dict):
        return ", ".join(f"{k} {_cell(v)}" for k, v in value.items())
    if isinstance(value, list | tuple):
        return ", ".join(_cell(v) for v in value)
    if value is None or value == "":
        return "-"
    return str(value)


def _layer_cell(n: int, poses: list[dict]) -> str:
    """``1: 6 poses at 0, 0.667, ... s`` (at most eight times shown)."""
    times = [_cell(float(p["time"])) for p in poses]
    shown = ", ".join(times[:7] + (["...", times[-1]] if len(times) > 8 else times[7:]))
    base = " (base)" if n == 0 else ""
    return f"{n}{base}: {len(poses)} poses at {shown} s"


def format_table(summary: dict[str, Any]) -> str:
    """Two aligned columns, key and value, the main keys first; a list of
    records (a document's poses, say) gets its count, then one line each."""
    keys = [k for k in _FIRST if k in summary] + sorted(k for k in summary if k not in _FIRST)
    if summary.get("kind") == "bvh" and "frame_time_text" in summary:
        summary = {**summary, "frame_time": summary["frame_time_text"]}
        keys.remove("frame_time_text")
    width = max(len(k) for k in keys)
    units = {"frame_time": " s", "duration": " s", "rate": " Hz"}
    lines = []
    for k in keys:
        value = summary[k]
        if k == "layers" and summary.get("kind") == "document":
            lines.append(f"{k.ljust(width)}  {len(value)}")
            lines.extend(f"{'':{width}}    {_layer_cell(n, v['poses'])}" for n, v in enumerate(value))
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            lines.append(f"{k.ljust(width)}  {len(value)}")
            lines.extend(f"{'':{width}}    {_cell(v)}" for v in value)
        else:
            lines.append(f"{k.ljust(width)}  {_cell(value)}{units.get(k, '')}")
    return "\n".join(lines)


def _json_safe(value: Any) -> Any:
    """``value`` with every infinite or NaN number replaced by null: JSON
    has no such numbers (``json.dumps`` would print ``Infinity``)."""
    import math

    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


@click.command("info")
@input_argument
@click.option("--json", "as_json", is_flag=True, help="Print JSON (sorted keys) instead of a table.")
def info(input_path: str, as_json: bool) -> None:
    """Summarize a BVH, C3D or staggered-poses document.

    Frames, frame time, rate, duration; joints or markers; figure size in
    file units; for a document its poses and constraints.
    """
    obj = load_input(input_path)
    name = "<stdin>" if input_path == "-" else os.path.basename(input_path)
    summary = summarize(obj, name, "<stdin>" if input_path == "-" else input_path)
    if as_json:
        text = json.dumps(_json_safe(summary), sort_keys=True, indent=1, ensure_ascii=False, allow_nan=False)
        click.echo(text)
    else:
        click.echo(format_table(summary))
