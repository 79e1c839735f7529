"""``timing``: a dope sheet: poses as columns at ``t_k``, variables as rows,
each extreme knot drawn at its refined time ``t_k + r[k, i]`` so stagger
and succession show as slanted columns; editing knots as open diamonds;
contacts as bars in their rows; a partial pose as a dashed column with
square knots on its part's rows only."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .common import _CONTACT, _bands, _contact_rows, _crowded_window, _crowding, _figure, _label_rows, _rows, _title

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document

#: Extreme knots before, after and on their pose's time.
_EARLY, _LATE, _ON_POSE = "tab:blue", "tab:red", "0.45"
#: The line of a partial pose (one body part's poses, see Document.pose_part).
_PARTIAL = "tab:purple"


def timing_figure(
    doc: Document,
    *,
    name: str | None = None,
    joints: Sequence[str] | None = None,
    time: tuple[float, float] | None = None,
) -> Figure:
    """A dope sheet of the staggered poses.

    Columns: the poses (grey lines at ``t_k``, pose numbers on top).  Rows:
    the variables in hierarchy order, every other limb shaded.  Each extreme
    knot sits at its refined time ``t_k + r[k, i]``, joined to its pose line
    and coloured by the sign of the refinement (blue: before the pose, red:
    after, grey: on it); editing knots are open diamonds on the pose line.
    Contacts are green bars in their joint's or marker's row.  A partial
    pose (one that owns one body part) is a dashed purple line whose knots,
    squares, are on its part's rows only.  Without
    ``time``, a document of more than :data:`MAX_TIMING_POSES` poses shows
    its first ones (the title says which span).
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    lo, hi, span = _crowded_window(doc, time)
    rows = _rows(doc, joints)
    contacts = _contact_rows(doc, lo, hi)
    labels = [v.name for v in rows]
    row_of = {v.name: r for r, v in enumerate(rows)}
    if doc.kind == "bvh":  # a contact on a joint: its rotation row
        for v in reversed(rows):
            row_of.setdefault(doc.source.skeleton.names[v.target], row_of[v.name])
    if not joints:
        for c in contacts:
            if c not in row_of:
                row_of[c] = len(labels)
                labels.append(f"{c} (contact)")

    fig = _figure()
    ax = fig.add_subplot()
    fig.suptitle(_title("timing", doc, name) + span)
    _bands(ax, doc, rows)
    pose_t = doc.pose_t
    # every pose inside the axes (which reach two frames past the window),
    # so that a pose just outside it has its line and number with its knots
    margin = 2 * doc.frame_time
    in_win = np.flatnonzero((pose_t >= lo - margin - 1e-9) & (pose_t <= hi + margin + 1e-9))
    partial = np.array([p is not None for p in doc.pose_part], dtype=bool)
    whole_win, part_win = in_win[~partial[in_win]], in_win[partial[in_win]]
    ax.vlines(pose_t[whole_win], -0.5, len(labels) - 0.5, colors="0.75", lw=0.7, zorder=1)
    if len(part_win):  # a partial pose: a dashed line, its knots only on its part's rows
        ax.vlines(pose_t[part_win], -0.5, len(labels) - 0.5, colors=_PARTIAL, lw=0.7, linestyles="--", zorder=1)
    for c, spans in contacts.items():
        if c in row_of:
            ax.broken_barh(spans, (row_of[c] - 0.42, 0.84), facecolors=_CONTACT, alpha=0.28, zorder=1, lw=0)

    xs, ys, cs, ps, segs, seg_c, ex, ey = [], [], [], [], [], [], [], []
    for r, v in enumerate(rows):
        tr = doc.tracks[v.track]
        sl = tr.knot_slice(v.local)
        kt, kp, ke = tr.knot_t[sl], tr.knot_pose[sl], tr.knot_editing[sl]
        ext = ~ke
        te, tk = kt[ext], pose_t[kp[ext]]
        r_ = te - tk
        color = np.where(r_ < 0, _EARLY, np.where(r_ > 0, _LATE, _ON_POSE))
        xs.append(te)
        ys.append(np.full(len(te), r))
        cs.append(color)
        ps.append(partial[kp[ext]])
        moved = r_ != 0
        segs += [((a, r), (b, r)) for a, b in zip(tk[moved], te[moved], strict=True)]
        seg_c += list(color[moved])
        ex.append(kt[ke])
        ey.append(np.full(int(ke.sum()), r))
    if segs:
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(segs, colors=seg_c, lw=1.4, zorder=2))
    if rows:
        scale = _crowding(doc, lo, hi)
        x, y, c, p = np.concatenate(xs), np.concatenate(ys), np.concatenate(cs), np.concatenate(ps)
        ax.scatter(x[~p], y[~p], s=16 * scale, c=list(c[~p]), zorder=3, lw=0)
        if p.any():  # a partial pose's extreme knots: squares
            ax.scatter(x[p], y[p], s=20 * scale, c=list(c[p]), marker="s", zorder=3, lw=0)
        ax.scatter(
            np.concatenate(ex),
            np.concatenate(ey),
            s=22 * scale,
            marker="D",
            facecolors="white",
            edgecolors="black",
            lw=0.7 * math.sqrt(scale),
            zorder=4,
        )

    _label_rows(ax, labels)
    ax.set_ylim(len(labels) - 0.5, -0.5)
    ax.set_xlim(lo - margin, hi + margin)
    ax.set_xlabel("time (s)")
    top = ax.secondary_xaxis("top")
    step = max(1, math.ceil(len(in_win) / 40))
    top.set_xticks(pose_t[in_win][::step], [str(k) for k in in_win[::step]], fontsize=7)
    top.set_xlabel("pose", fontsize=8)
    handles = [
        Line2D([], [], color="0.75", lw=1, label="pose time t_k"),
        Line2D([], [], color=_EARLY, marker="o", lw=1.4, label="extreme knot before t_k (r < 0)"),
        Line2D([], [], color=_LATE, marker="o", lw=1.4, label="extreme knot after t_k (r > 0)"),
        Line2D([], [], color=_ON_POSE, marker="o", lw=0, label="extreme knot at t_k (r = 0)"),
        Line2D([], [], color="black", marker="D", markerfacecolor="white", lw=0, label="editing knot (at t_k)"),
        Patch(facecolor=_CONTACT, alpha=0.4, label="contact"),
    ]
    if len(part_win):
        handles.insert(
            1,
            Line2D(
                [],
                [],
                color=_PARTIAL,
                ls="--",
                marker="s",
                markerfacecolor=_ON_POSE,
                lw=1,
                label="partial pose (knots in its part's rows)",
            ),
        )
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 6), fontsize=8, frameon=False)
    return fig
