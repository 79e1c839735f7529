"""``signals``: the paper's Figures 4 and 5 for real data: a heat map of the
per-variable local evidence ``p_i(t)`` (rows in hierarchy order, the weight
``w_i`` of each row beside it), the aggregate pose probability ``P(t)`` with
the pose times (marker size: priority) and the contacts as bars."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .common import _CONTACT, _contact_rows, _figure, _label_rows, _rows, _signal, _title, _window

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document


def signals_figure(
    doc: Document,
    *,
    name: str | None = None,
    joints: Sequence[str] | None = None,
    time: tuple[float, float] | None = None,
) -> Figure:
    """The evidence for the poses (paper Figures 4 and 5).

    Top: the local evidence ``p_i(t)`` of each variable as a heat map (rows
    in hierarchy order, ``w_i`` beside), pose times as thin lines.  Middle:
    ``P(t)`` (black), the weighted mean of the local evidence before the tent
    filter (grey), contact changes (green), and each pose as a stem at
    ``t_k`` with a marker sized by its priority (squares: the first and last
    pose, always kept).  Bottom: contacts as bars.  A document without
    stored signals (not made by ``extract``) says so and shows the poses and
    contacts alone, stems then as high as the priority.

    Parameters
    ----------
    joints : joint, marker or variable names for the heat map rows
        (default: every variable that moves).
    time : (start, end) seconds to show (default: the whole clip).
    """
    lo, hi = _window(doc, time)
    rows = _rows(doc, joints)
    T, V = doc.n_frames, len(doc.variable_names)
    p = _signal(doc, "p", (T, V))
    P = _signal(doc, "P", (T,))
    w = _signal(doc, "weights", (V,))
    contact = _signal(doc, "contact", (T,))
    t = doc.frame_times
    f = np.flatnonzero((t >= lo - 1e-9) & (t <= hi + 1e-9))
    ft = doc.frame_time
    in_win = (doc.pose_t >= lo - 1e-9) & (doc.pose_t <= hi + 1e-9)
    contacts = _contact_rows(doc, lo, hi)

    fig = _figure()
    n_c = max(len(contacts), 1)
    gs = fig.add_gridspec(3, 3, height_ratios=[5.0, 2.4, 0.35 + 0.22 * min(n_c, 8)], width_ratios=[40, 3, 1])
    ax_p = fig.add_subplot(gs[0, 0])
    ax_P = fig.add_subplot(gs[1, 0], sharex=ax_p)
    ax_c = fig.add_subplot(gs[2, 0], sharex=ax_p)
    ax_w = fig.add_subplot(gs[0, 1], sharey=ax_p)
    cax = fig.add_subplot(gs[0, 2])
    fig.suptitle(_title("signals", doc, name))

    labels = [v.name for v in rows]
    if p is not None:
        img = p[np.ix_(f, [v.index for v in rows])].T if len(f) else np.zeros((len(rows), 1))
        t0, t1 = (t[f[0]], t[f[-1]]) if len(f) else (lo, hi)
        im = ax_p.imshow(
            img,
            aspect="auto",
            origin="upper",
            cmap="viridis",
            vmin=0.0,
            vmax=1.0,
            extent=(t0 - 0.5 * ft, t1 + 0.5 * ft, len(rows) - 0.5, -0.5),
            interpolation="antialiased",
        )
        fig.colorbar(im, cax=cax, label="local evidence p (scaled curvature)")
        ax_p.vlines(doc.pose_t[in_win], -0.5, len(rows) - 0.5, colors="white", lw=0.5, alpha=0.45)
        order = "in hierarchy order" if doc.kind == "bvh" else "highest marker first"
        ax_p.set_title(f"local evidence p_i(t) per variable (rows {order}); lines: pose times", fontsize=9)
    else:
        ax_p.set_ylim(len(rows) - 0.5, -0.5)
        ax_p.text(
            0.5,
            0.5,
            "no signals stored in this document\n(only `staggered extract` stores the evidence for its poses)",
            transform=ax_p.transAxes,
            ha="center",
            va="center",
            color="0.35",
        )
        cax.set_axis_off()
    _label_rows(ax_p, labels)
    ax_p.tick_params(axis="x", labelbottom=False)

    if w is not None:
        ww = w[[v.index for v in rows]]
        top = float(np.max(w)) if np.max(w) > 0 else 1.0
        ax_w.barh(np.arange(len(rows)), ww / top, color="0.5", height=0.7)
        ax_w.set_xlim(0, 1.05)
        ax_w.set_xticks([0, 1])
        ax_w.set_title("weight w_i", fontsize=8)
    else:
        ax_w.set_xticks([])
    ax_w.tick_params(axis="y", labelleft=False, left=False)
    ax_w.tick_params(axis="x", labelsize=7)

    _draw_probability(ax_P, doc, f, p, P, w, contact, in_win)
    _draw_contacts(ax_c, contacts)
    ax_c.set_xlabel("time (s)")
    ax_p.set_xlim(lo - 0.5 * ft, hi + 0.5 * ft)
    return fig


def _draw_probability(ax, doc, f, p, P, w, contact, in_win) -> None:
    t = doc.frame_times
    pose_t = doc.pose_t[in_win]
    pri = doc.priority[in_win]
    finite = np.isfinite(doc.priority)
    top_pri = float(np.max(doc.priority[finite])) if finite.any() and np.max(doc.priority[finite]) > 0 else 1.0
    biggest = float(np.clip(140.0 * 25.0 / max(len(pose_t), 1), 30.0, 140.0))  # crowded poses: smaller
    size = np.where(np.isfinite(pri), 6.0 + biggest * np.clip(pri / top_pri, 0, 1), 0.4 * biggest)
    ends = ~np.isfinite(pri)
    if P is not None:
        if p is not None and w is not None and np.sum(w) > 0:
            ax.plot(t[f], (p[f] @ w) / np.sum(w), color="0.6", lw=0.8, label="Σ w_i p_i / Σ w_i (before filter)")
        ax.plot(t[f], P[f], color="black", lw=1.3, label="P(t), pose probability")
        height = np.interp(pose_t, t, P)
        ax.set_ylabel("probability")
        stem_label = "poses at t_k (size: priority)"
    else:
        height = np.where(np.isfinite(pri), np.clip(pri / top_pri, 0, 1), 1.0)
        ax.set_ylabel("priority (of max)")
        stem_label = "poses at t_k (height: priority)"
    ymax = max(float(np.max(height)) if len(height) else 0.0, float(np.max(P[f])) if P is not None and len(f) else 0.0)
    ymax = ymax if ymax > 0 else 1.0
    if contact is not None and np.any(contact[f] > 0):
        ax.fill_between(t[f], 0, 0.12 * ymax * contact[f], color=_CONTACT, alpha=0.5, lw=0, label="contact change")
    ax.vlines(pose_t, 0, height, colors="tab:red", lw=0.8, alpha=0.7)
    ax.scatter(pose_t[~ends], height[~ends], s=size[~ends], color="tab:red", zorder=3, label=stem_label)
    if ends.any():
        ax.scatter(
            pose_t[ends],
            height[ends],
            s=size[ends],
            marker="s",
            color="tab:red",
            zorder=3,
            label="first / last pose (always kept)",
        )
    ax.set_ylim(0, 1.12 * ymax)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=7, ncols=5, frameon=False, borderaxespad=0.2)
    ax.tick_params(axis="x", labelbottom=False)
    ax.grid(axis="y", color="0.9", lw=0.5)


def _draw_contacts(ax, contacts: dict[str, list[tuple[float, float]]]) -> None:
    names = list(contacts)
    for r, n in enumerate(names):
        ax.broken_barh(contacts[n], (r - 0.35, 0.7), facecolors=_CONTACT, alpha=0.7)
    if names:
        ax.set_yticks(np.arange(len(names)))
        ax.set_yticklabels(names, fontsize=7)
        ax.set_ylim(len(names) - 0.5, -0.5)
        ax.set_ylabel("contacts", fontsize=8)
    else:
        ax.set_yticks([])
        ax.text(0.5, 0.5, "no contacts", transform=ax.transAxes, ha="center", va="center", color="0.4", fontsize=8)
