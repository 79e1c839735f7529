"""``curves``: a few joints' channels over time (the joint's own Euler
channels in degrees, unwrapped, or coordinates in file units): the source,
the spline layer alone and the baked result, with the knots."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..errors import UsageError, arg
from .common import (
    _crowded_window,
    _crowding,
    _figure,
    _frames_in,
    _order_key,
    _rows,
    _signal,
    _title,
    _Var,
    _variables,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document

#: Joints drawn by ``curves`` when none are named, and the most allowed.
DEFAULT_CURVES = 4
MAX_CURVES = 8

_AXIS_COLORS = {"X": "tab:red", "Y": "tab:green", "Z": "tab:blue"}


def _default_curves(doc: Document) -> list[_Var]:
    """The few variables that move most (rotations for BVH), preferring
    those with refinements, in hierarchy order."""
    from ..model.kinds import ROTATION
    from ..model.variables import dense_variables

    variables = _variables(doc)
    w = _signal(doc, "weights", (len(variables),))
    if w is None:  # arc length of each variable's motion
        parts = []
        for kind, _, _, dense in dense_variables(doc.source):
            if kind == ROTATION:
                d = np.abs(np.sum(dense[1:] * dense[:-1], axis=-1))
                parts.append(np.sum(2 * np.arccos(np.clip(d, 0, 1)), axis=0))
            else:
                parts.append(np.sum(np.linalg.norm(np.diff(dense, axis=0), axis=-1), axis=0))
        w = np.concatenate(parts)
    pool = [v for v in variables if v.kind == ROTATION] or variables
    refined = np.any(doc.refinements() != 0.0, axis=0)
    if any(refined[v.index] for v in pool):
        pool = [v for v in pool if refined[v.index]]
    best = sorted(pool, key=lambda v: -w[v.index])[:DEFAULT_CURVES]
    key = _order_key(doc, variables)
    return sorted(best, key=lambda v: (key[v.index], v.index))


def _channels(doc: Document, v: _Var, motion) -> tuple[np.ndarray, list[str]]:
    """Values (T, C) of variable ``v`` in ``motion`` and channel labels: a
    BVH rotation as the joint's Euler channels (degrees, as written), a
    translation as its coordinates (file units)."""
    from ..model.kinds import ROTATION
    from ..motion import BvhMotion, position_columns, rotation_columns

    if isinstance(motion, BvhMotion):
        sk = motion.skeleton
        if v.kind == ROTATION:
            cols = next(c for j, c, _ in rotation_columns(sk) if j == v.target)
        else:
            cols = [c for c in next(c for j, c in position_columns(sk) if j == v.target) if c >= 0]
        slices = motion.channel_slices()[v.target]
        names = [sk.channels[v.target][c - slices[0]] for c in cols]
        return motion.channels[:, cols], [n[0] for n in names]
    return motion.points[:, v.target], ["X", "Y", "Z"]


def _unwrap(deg: np.ndarray, ref: np.ndarray | None = None) -> np.ndarray:
    """Angles (T, C) in degrees without jumps of 360; the first row brought
    within 180 of ``ref`` (C,) when given."""
    out = np.unwrap(deg, period=360.0, axis=0)
    if ref is not None and len(out):
        out = out + 360.0 * np.round((ref - out[0]) / 360.0)
    return out


def curves_figure(
    doc: Document,
    *,
    name: str | None = None,
    joints: Sequence[str] | None = None,
    time: tuple[float, float] | None = None,
) -> Figure:
    """Channels of a few joints over time, one panel each.

    A BVH joint's rotation as its own Euler channels in degrees (the
    numbers a curve editor shows, X red, Y green, Z blue, unwrapped: where
    the file jumps by 360° the curve goes on), a translation or
    a C3D marker as coordinates in file units relative to the clip's mean.
    Three layers: the source (thick, light), the spline layer alone (dashed:
    what the poses capture) and the baked result (thin); extreme knots
    (dots) and editing knots (open diamonds) on the spline layer.

    Parameters
    ----------
    joints : joints, markers or variables (default: the
        :data:`DEFAULT_CURVES` that move most among those with refinements).
    time : (start, end) seconds; without it a document of more than
        :data:`MAX_TIMING_POSES` poses shows its first ones.
    """
    from matplotlib.lines import Line2D

    from ..model.kinds import ROTATION
    from ..ops.bake import bake

    lo, hi, span = _crowded_window(doc, time)
    scale = _crowding(doc, lo, hi)
    rows = _rows(doc, joints, rotation_only=True) if joints else _default_curves(doc)
    if len(rows) > MAX_CURVES:
        raise UsageError(f"{arg('joints')}: at most {MAX_CURVES} curves in one picture, got {len(rows)}")
    baked = bake(doc)
    splines = bake(doc, layers="splines")
    t = doc.frame_times
    f = _frames_in(doc, lo, hi)
    units = getattr(doc.source, "units", "") or "file units"

    fig = _figure()
    fig.suptitle(_title("curves", doc, name) + span)
    axes = fig.subplots(len(rows), 1, sharex=True, squeeze=False)[:, 0]
    for ax, v in zip(axes, rows, strict=True):
        orig, labels = _channels(doc, v, doc.source)
        spl, _ = _channels(doc, v, splines)
        out, _ = _channels(doc, v, baked)
        rotation = doc.kind == "bvh" and v.kind == ROTATION
        if rotation:  # continuous curves: the file's ±180° wraps unwrapped, one branch for all layers
            orig = _unwrap(orig)
            spl, out = _unwrap(spl, orig[0]), _unwrap(out, orig[0])
        else:  # coordinates relative to the clip's mean
            seen = np.all(np.isfinite(orig), axis=1)
            mean = orig[seen].mean(axis=0) if seen.any() else np.zeros(orig.shape[1])
            orig, spl, out = orig - mean, spl - mean, out - mean
        tr = doc.tracks[v.track]
        sl = tr.knot_slice(v.local)
        kt, ke = tr.knot_t[sl], tr.knot_editing[sl]
        keep = (kt >= lo - 1e-9) & (kt <= hi + 1e-9)
        for c, axis in enumerate(labels):
            color = _AXIS_COLORS.get(axis, "0.3")
            ax.plot(t[f], orig[f, c], color=color, lw=3.2, alpha=0.28, solid_capstyle="butt")
            ax.plot(t[f], spl[f, c], color=color, lw=1.0, ls=(0, (4, 2)))
            ax.plot(t[f], out[f, c], color=color, lw=0.8)
            ok = np.isfinite(spl[:, c])
            if ok.sum() >= 2:
                kv = np.interp(kt, t[ok], spl[ok, c])
                ax.scatter(kt[keep & ~ke], kv[keep & ~ke], s=14 * scale, color=color, zorder=3, lw=0)
                ax.scatter(
                    kt[keep & ke],
                    kv[keep & ke],
                    s=20 * scale,
                    marker="D",
                    facecolors="white",
                    edgecolors=color,
                    lw=0.8 * math.sqrt(scale),
                    zorder=3,
                )
        what = "rotation" if rotation else ("marker" if doc.kind == "c3d" else "translation")
        ax.set_title(f"{v.name} ({what}, channels {''.join(labels)})", fontsize=9, loc="left")
        ax.set_ylabel("degrees" if rotation else f"{units} − mean", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(color="0.92", lw=0.5)
    axes[-1].set_xlabel("time (s)")
    axes[-1].set_xlim(lo, hi if hi > lo else lo + 1.0)  # a one-frame clip has no extent
    handles = [Line2D([], [], color=c, lw=2, label=f"{a} channel") for a, c in _AXIS_COLORS.items()] + [
        Line2D([], [], color="0.3", lw=3.2, alpha=0.28, label="source (original)"),
        Line2D([], [], color="0.3", lw=1.0, ls=(0, (4, 2)), label="spline layer alone"),
        Line2D([], [], color="0.3", lw=0.8, label="baked (splines ⊕ displacement ⊕ contacts)"),
        Line2D([], [], color="0.3", marker="o", lw=0, label="extreme knot"),
        Line2D([], [], color="0.3", marker="D", markerfacecolor="white", lw=0, label="editing knot"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=8, fontsize=8, frameon=False)
    return fig
