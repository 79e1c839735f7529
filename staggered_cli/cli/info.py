"""``staggered info FILE [--json]``: what a BVH, C3D or document holds."""

from __future__ import annotations

import json
import os
from typing import Any

import click

from .options import input_argument, load_input

#: Keys shown first in the table, in this order; the rest follow sorted.
_FIRST = ("file", "kind", "frames", "frame_time", "rate", "duration")


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
            # a whole-body pose's part (null) is not worth a column of dashes
            lines.extend(
                f"{'':{width}}    {_cell({kk: vv for kk, vv in v.items() if kk != 'part' or vv is not None})}"
                for v in value
            )
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
    from ..api import info as summarize

    value = load_input(input_path)
    name = "<stdin>" if input_path == "-" else os.path.basename(input_path)
    summary = {**summarize(value), "file": name}
    if as_json:
        text = json.dumps(_json_safe(summary), sort_keys=True, indent=1, ensure_ascii=False, allow_nan=False)
        click.echo(text)
    else:
        click.echo(format_table(summary))
