"""Pictures of staggered-pose documents: signals, timing, curves and a
stick-figure preview.

Every picture is a pure function from values to a matplotlib ``Figure``
(drawn with the Agg canvas, no pyplot and no global state);
:func:`png_bytes` and :func:`preview_gif` turn them into file contents.
matplotlib is imported inside the functions so that importing this module
(and starting the command line) stays light.

Pictures
    ``signals``  the paper's Figures 4 and 5 for real data: a heat map of the
    per-variable local evidence ``p_i(t)`` (rows in hierarchy order, the
    weight ``w_i`` of each row beside it), the aggregate pose probability
    ``P(t)`` with the pose times (marker size: priority) and the contacts as
    bars.
    ``timing``  a dope sheet: poses as columns at ``t_k``, variables as rows,
    each extreme knot drawn at its refined time ``t_k + r[k, i]`` so stagger
    and succession show as slanted columns; editing knots as open diamonds;
    contacts as bars in their rows.
    ``curves``  a few joints' channels over time (the joint's own Euler
    channels in degrees, unwrapped, or coordinates in file units): the source, the
    spline layer alone and the baked result, with the knots.
    ``preview``  a stick figure in side and front views at the pose times
    (or evenly spaced frames), optionally overlaid on a second clip.

Rows "in hierarchy order": BVH variables by joint in file order (parents
before children), the translation of a joint before its rotation; C3D
markers from the highest to the lowest median height.  Variables that never
move (constant channels, a marker never seen) are left out unless asked for.

Up axis (preview, C3D row order): :func:`staggered_cli.contacts.up_direction`,
the world axis along which the figure's per-frame extent is largest (median
over frames: a standing, walking or dancing figure is taller than it is wide
or deep), pointing to the side where the figure lies (capture volumes put the
floor at zero).  Y for the BVH files and BTS C3D, Z for the other C3D files.
The preview strip turns each panel's camera with the figure's heading at
its time (:func:`headings`): the side view looks across the heading, the
front view along it (from the front).  The heading is the left-to-right
direction of the rigid left/right pairs at the figure's middle height (the
hips of a skeleton, the pelvis markers of a marker set) crossed with up;
without such pairs, the direction of travel; for a figure that stays in
place, the clip's own camera.  The clip's own camera (the animated
preview's) looks across the direction of travel from the first frame to
the last (or, for a figure that stays in place, across its narrowest
horizontal spread, which is its depth).
"""

from __future__ import annotations

import io
import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import quat
from ..errors import UsageError, arg

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

#: The kinds of ``staggered plot``.
KINDS = ("signals", "timing", "curves")
#: Figure size in inches (fits a laptop screen at 100 dpi).
FIGSIZE = (12.0, 7.0)
#: Default resolution of written pictures, dots per inch.
DPI = 100
#: Most panels in a preview strip; more times are thinned evenly.
MAX_PANELS = 12
#: Frames shown by a PNG preview of a clip without poses.
DEFAULT_PREVIEW_FRAMES = 8
#: Most points drawn per curve; longer clips are drawn every n-th frame.
MAX_DRAW_POINTS = 2000
#: Most poses in a dope sheet drawn without ``time``: a longer document
#: shows its first poses (the title says so; ``time`` shows the rest).
MAX_TIMING_POSES = 60
#: Joints drawn by ``curves`` when none are named, and the most allowed.
DEFAULT_CURVES = 4
MAX_CURVES = 8
#: Animated previews: frames per second (real time) and the most frames.
GIF_FPS = 15.0
MAX_GIF_FRAMES = 300

_AXIS_COLORS = {"X": "tab:red", "Y": "tab:green", "Z": "tab:blue"}
_EARLY, _LATE, _ON_POSE = "tab:blue", "tab:red", "0.45"
_CONTACT = "tab:green"
_PRIMARY, _PRIMARY_LIGHT = "#1f3f8a", "#4a8be0"
_SECOND, _SECOND_LIGHT = "#f08a3c", "#f08a3c"
_LEFT = re.compile(r"^(left|l(?=[A-Z_]))|(_l|\.l|left)$|^lhand$", re.IGNORECASE)


# --- output --------------------------------------------------------------------


def _figure(figsize: tuple[float, float] = FIGSIZE) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig: Figure, dpi: float = DPI) -> bytes:
    """The PNG file of ``fig`` at ``dpi`` dots per inch."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


# --- shared pieces ---------------------------------------------------------------


def _window(doc: Document, time: tuple[float, float] | None) -> tuple[float, float]:
    """The time window (seconds) to draw: ``time`` clipped to the clip."""
    end = doc.duration
    if time is None:
        return 0.0, end
    lo, hi = time
    if hi < 0 or lo > end or lo >= hi:
        a = "" if math.isinf(lo) else f"{lo:g}"
        b = "" if math.isinf(hi) else f"{hi:g}"
        raise UsageError(f"{arg('time')} {a}:{b} is outside the clip (0 to {end:.3f} s)")
    return max(lo, 0.0), min(hi, end)


def _crowded_window(doc: Document, time: tuple[float, float] | None) -> tuple[float, float, str]:
    """The window of a dope sheet or curves: ``time``, or without it the
    first :data:`MAX_TIMING_POSES` poses, with a note for the title."""
    lo, hi = _window(doc, time)
    if time is not None or doc.n_poses <= MAX_TIMING_POSES:
        return lo, hi, ""
    hi = float(doc.pose_t[MAX_TIMING_POSES - 1])
    return lo, hi, f" · {lo:.1f}-{hi:.1f} s of {doc.duration:.1f} s (others: --time A:B)"


def _crowding(doc: Document, lo: float, hi: float) -> float:
    """Marker area factor in (0.09, 1]: smaller when poses crowd the ~1100
    pixels of a wide axes at 100 dpi."""
    t = doc.pose_t[(doc.pose_t >= lo - 1e-9) & (doc.pose_t <= hi + 1e-9)]
    gap = float(np.median(np.diff(t))) if len(t) > 1 else hi - lo
    return float(np.clip(1100.0 * gap / max(hi - lo, 1e-9) / 20.0, 0.3, 1.0)) ** 2


def _frames_in(doc: Document, lo: float, hi: float, most: int = MAX_DRAW_POINTS) -> np.ndarray:
    """Frame indices within [lo, hi] seconds, every n-th so at most ``most``."""
    t = doc.frame_times
    f = np.flatnonzero((t >= lo - 1e-9) & (t <= hi + 1e-9))
    if len(f) == 0:  # a window narrower than a frame: the nearest frame
        f = np.array([int(np.clip(round(0.5 * (lo + hi) / doc.frame_time), 0, doc.n_frames - 1))])
    step = max(1, math.ceil(len(f) / most))
    return f[::step]


@dataclass(frozen=True)
class _Var:
    """One control variable of a document, for drawing."""

    index: int  # in doc.variable_names
    track: int
    local: int  # in its track
    name: str
    kind: str
    target: int  # joint or marker


def _variables(doc: Document) -> list[_Var]:
    out, n = [], 0
    for ti, tr in enumerate(doc.tracks):
        for i, name in enumerate(tr.names):
            out.append(_Var(n, ti, i, name, tr.kind, int(tr.targets[i])))
            n += 1
    return out


def _figure_points(motion: BvhMotion | MarkerMotion) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """World points ``(T, N, 3)`` (file units, NaN in gaps), bones ``(B, 2)``
    into them, and for each bone whether it is on the figure's left.  BVH:
    the joints of the body proper and their End Sites (a static placeholder
    root would draw a bone from the origin); C3D: the markers, no bones."""
    from ..motion import BvhMotion
    from ..skeleton import body_joints, end_site_positions

    if not isinstance(motion, BvhMotion):
        bones, left = marker_bones(motion.labels, motion.points)
        return motion.points, bones, left, tuple(motion.labels)
    sk = motion.skeleton
    wr, wp = motion.world()
    ends = end_site_positions(sk, wr, wp)
    body = body_joints(sk)
    ends_kept = np.flatnonzero(np.isin(sk.end_parents, body))
    pts = np.concatenate([wp[:, body], ends[:, ends_kept]], axis=1)
    where = {int(j): n for n, j in enumerate(body)}
    bones, left = [], []
    for j in body:
        p = int(sk.parents[j])
        if p in where:
            bones.append((where[p], where[int(j)]))
            left.append(bool(_LEFT.search(sk.names[j])))
    for n, e in enumerate(ends_kept):
        p = int(sk.end_parents[e])
        bones.append((where[p], len(body) + n))
        left.append(bool(_LEFT.search(sk.names[p])))
    names = tuple(sk.names[j] for j in body) + tuple(f"{sk.names[sk.end_parents[e]]}.end" for e in ends_kept)
    return pts, np.array(bones, dtype=int).reshape(-1, 2), np.array(left, dtype=bool), names


def marker_bones(labels: Sequence[str], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lines to draw between the markers of a set (B, 2), and whether each
    is on the figure's left (B,): the tree of the most rigid pairs
    (:func:`~staggered_cli.ops.marker_chain.rigid_tree`, the tree a
    randomize or retime of all markers moves them by), so that each body
    segment's markers are joined and the segments joined where they meet."""
    from ..ops.marker_chain import rigid_tree

    parents = rigid_tree(points)
    child = np.flatnonzero(parents >= 0)
    bones = np.column_stack([parents[child], child]).astype(int).reshape(-1, 2)
    if len(bones):  # the tree must join every marker: not with lines across the body
        from ..motion import MarkerMotion

        size = MarkerMotion(tuple(labels), points, 1.0).figure_height()
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a pair never seen together
            length = np.nanmedian(quat.norm(points[:, bones[:, 0]] - points[:, bones[:, 1]]), axis=0)
        bones = bones[~(length > LONGEST_LINE * size)]
    sides = _sides(labels)
    left = np.array([sides[a] == "left" and sides[b] == "left" for a, b in bones], dtype=bool)
    return bones, left


#: Lines between markers longer than this share of the figure height (median
#: over the clip) are not drawn: longer than any segment of the body (thigh
#: and shank are about 0.25), they join markers the rigid tree links only
#: because it must join them all (c7 to a knee on the BTS walk, 0.73; one
#: thigh to the other on the c3d.org walk, 0.52).
LONGEST_LINE = 0.45


def _sides(names: Sequence[str]) -> list[str]:
    """``'left'``, ``'right'`` or ``''`` for each name, as :func:`side_pairs` reads them."""
    out = [""] * len(names)
    for a, b in side_pairs(names):
        out[a], out[b] = "left", "right"
    return out


def _up(points: np.ndarray, size: float) -> np.ndarray:
    from ..contacts.detect import up_direction

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN frames of a C3D with gaps
        return up_direction(points, size)


def _moving(doc: Document, variables: list[_Var]) -> np.ndarray:
    """(V,) bool: the variable moves in the source or has a refinement."""
    from ..model.kinds import ROTATION
    from ..model.variables import dense_variables

    size = float(doc.source.figure_height())
    moving = []
    for kind, _, _, dense in dense_variables(doc.source):
        if kind == ROTATION:
            d = np.abs(np.sum(dense * dense[:1], axis=-1))  # |cos(angle / 2)| to the first frame
            moving.append(np.min(d, axis=0) < 1.0 - 1e-12)
        else:
            moving.append(np.max(np.ptp(dense, axis=0), axis=-1) > 1e-9 * size)
    out = np.concatenate(moving) if moving else np.zeros(0, dtype=bool)
    refined = np.any(doc.refinements() != 0.0, axis=0)
    return out | refined


def _order_key(doc: Document, variables: list[_Var]) -> np.ndarray:
    """Sort key of each variable: hierarchy order (BVH), or highest marker
    first (C3D)."""
    from ..model.kinds import TRANSLATION

    if doc.kind == "bvh":
        return np.array([2 * v.target + (0 if v.kind == TRANSLATION else 1) for v in variables], dtype=float)
    pts = doc.source.points
    up = _up(pts, float(doc.source.figure_height()))
    h = pts @ up  # (T, M)
    seen = np.isfinite(h)
    height = np.array(
        [np.median(h[seen[:, m], m]) if seen[:, m].any() else -np.inf for m in range(h.shape[1])], dtype=float
    )
    return np.array([-height[v.target] for v in variables])


def _rows(doc: Document, joints: Sequence[str] | None, *, rotation_only: bool = False) -> list[_Var]:
    """Variables to draw, in hierarchy order.

    ``joints`` names joints, markers or variables (``Hips.position``); a
    BVH joint name stands for its variables (its rotation alone with
    ``rotation_only`` when it has one).  Without ``joints``: every variable
    that moves.  Raises UsageError naming an unknown name.
    """
    from ..model.kinds import ROTATION

    variables = _variables(doc)
    if joints:
        chosen: set[int] = set()
        for name in joints:
            exact = [v.index for v in variables if v.name == name]
            if exact and name not in doc.target_names:  # a variable such as ``Hips.position``
                chosen.update(exact)
                continue
            j = doc.target_index(name)  # exact, without subject prefix, or @part; else suggestions
            mine = [v for v in variables if v.target == j]
            if rotation_only and any(v.kind == ROTATION for v in mine):
                mine = [v for v in mine if v.kind == ROTATION]
            if not mine:
                raise UsageError(f"joint {name!r} has no channels to draw")
            chosen.update(v.index for v in mine)
        picked = [v for v in variables if v.index in chosen]
    else:
        moving = _moving(doc, variables)
        picked = [v for v in variables if moving[v.index]] or variables
    key = _order_key(doc, variables)
    return sorted(picked, key=lambda v: (key[v.index], v.index))


def _signal(doc: Document, name: str, shape: tuple[int, ...]) -> np.ndarray | None:
    """A stored signal of the expected shape, or None."""
    val = doc.signals.get(name)
    if val is None:
        return None
    val = np.asarray(val, dtype=float)
    return val if val.shape == shape else None


def _title(kind: str, doc: Document, name: str | None) -> str:
    name = name or doc.source_name or "document"
    src = f" (from {doc.source_name})" if doc.source_name and doc.source_name != name else ""
    return f"{kind} · {name}{src}"


def _label_rows(ax, labels: list[str]) -> None:
    n = len(labels)
    step = max(1, math.ceil(n / 60))
    ax.set_yticks(np.arange(0, n, step))
    ax.set_yticklabels(labels[::step], fontsize=7 if n <= 30 else 6)


def _contact_rows(doc: Document, lo: float, hi: float) -> dict[str, list[tuple[float, float]]]:
    rows: dict[str, list[tuple[float, float]]] = {}
    for c in doc.constraints:
        if c.end >= lo and c.start <= hi:
            rows.setdefault(c.joint, []).append((c.start, max(c.end - c.start, doc.frame_time)))
    return rows


def _bands(ax, doc: Document, rows: list[_Var]) -> None:
    """Shade every other limb (a chain of joints below a joint with several
    children) so that a succession down one limb reads as one block."""
    if doc.kind != "bvh" or not rows:
        return
    sk = doc.source.skeleton
    n_children = np.bincount(sk.parents[sk.parents >= 0], minlength=sk.n_joints)
    limb = np.full(sk.n_joints, -1)
    for j in range(sk.n_joints):  # parents come before children
        p = int(sk.parents[j])
        if p >= 0:
            limb[j] = j if n_children[p] > 1 else limb[p]
    shade, prev = False, None
    for r, v in enumerate(rows):
        b = limb[v.target]
        if b != prev:
            shade, prev = (not shade) and b >= 0, b
        if shade:
            ax.axhspan(r - 0.5, r + 0.5, color="0.93", zorder=0, lw=0)


# --- signals -------------------------------------------------------------------


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


# --- timing --------------------------------------------------------------------


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
    Contacts are green bars in their joint's or marker's row.  Without
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
    ax.vlines(pose_t[in_win], -0.5, len(labels) - 0.5, colors="0.75", lw=0.7, zorder=1)
    for c, spans in contacts.items():
        if c in row_of:
            ax.broken_barh(spans, (row_of[c] - 0.42, 0.84), facecolors=_CONTACT, alpha=0.28, zorder=1, lw=0)

    xs, ys, cs, segs, seg_c, ex, ey = [], [], [], [], [], [], []
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
        x, y, c = np.concatenate(xs), np.concatenate(ys), np.concatenate(cs)
        ax.scatter(x, y, s=16 * scale, c=list(c), zorder=3, lw=0)
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
    fig.legend(handles=handles, loc="outside lower center", ncols=6, fontsize=8, frameon=False)
    return fig


# --- curves --------------------------------------------------------------------


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


def plot_figure(doc: Document, kind: str, **options) -> Figure:
    """The picture ``kind`` (one of :data:`KINDS`) of ``doc``."""
    makers = {"signals": signals_figure, "timing": timing_figure, "curves": curves_figure}
    if kind not in makers:
        raise UsageError(f"unknown kind of plot {kind!r} (one of {', '.join(KINDS)})")
    return makers[kind](doc, **options)


# --- preview -------------------------------------------------------------------


@dataclass(frozen=True)
class _Stick:
    """A clip ready to draw: world points (T, N, 3) in file units and bones."""

    name: str
    points: np.ndarray
    bones: np.ndarray
    left: np.ndarray
    frame_time: float
    pose_t: np.ndarray | None
    names: tuple[str, ...] = ()
    markers: bool = False  # a C3D marker set (drawn as dots, lines between them)

    def at(self, times: np.ndarray) -> np.ndarray:
        """Frame indices nearest ``times`` (seconds)."""
        f = np.rint(np.asarray(times) / self.frame_time).astype(int)
        return np.clip(f, 0, len(self.points) - 1)


def _stick(subject: Document | BvhMotion | MarkerMotion, name: str) -> _Stick:
    from ..model.document import Document
    from ..motion import BvhMotion
    from ..ops.bake import bake

    pose_t = None
    if isinstance(subject, Document):
        pose_t = subject.pose_t
        subject = bake(subject)
    pts, bones, left, names = _figure_points(subject)
    markers = not isinstance(subject, BvhMotion)
    return _Stick(name, pts, bones, left, float(subject.frame_time), pose_t, names, markers)


@dataclass(frozen=True)
class _View:
    """Projection of world points on the side and front views."""

    up: np.ndarray
    forward: np.ndarray
    lateral: np.ndarray
    size: float
    floor: float
    top: float

    def project(self, pts: np.ndarray, view: str) -> tuple[np.ndarray, np.ndarray]:
        across = self.forward if view == "side" else self.lateral
        return pts @ across, pts @ self.up


def view_axes(points: np.ndarray) -> _View:
    """Up, forward and lateral directions of a figure's points (T, N, 3)."""
    seen = np.all(np.isfinite(points), axis=2)
    good = seen.sum(axis=1) >= max(2, int(0.5 * seen.sum(axis=1).max()))
    pts = points[good] if good.any() else points[:1]
    ok = np.all(np.isfinite(pts), axis=2)
    with np.errstate(invalid="ignore"):
        ext = np.fmax.reduce(pts, axis=1) - np.fmin.reduce(pts, axis=1)
    ext_ok = np.all(np.isfinite(ext), axis=1)
    size = float(np.median(np.max(ext[ext_ok], axis=1))) if ext_ok.any() else 1.0
    size = size if size > 0 else 1.0
    up = _up(pts, size)
    count = np.maximum(ok.sum(axis=1), 1)
    center = np.where(ok[..., None], pts, 0.0).sum(axis=1) / count[:, None]  # (T', 3)
    flat = center - np.outer(center @ up, up)
    travel = flat[-1] - flat[0]
    if np.linalg.norm(travel) > 0.5 * size:
        forward = travel / np.linalg.norm(travel)
    else:  # standing in place: the narrowest horizontal spread of the body is its depth
        rel = np.where(ok[..., None], pts - center[:, None], np.nan).reshape(-1, 3)
        rel = rel[np.all(np.isfinite(rel), axis=1)]
        rel = rel - np.outer(rel @ up, up)
        if len(rel) >= 3:
            _, vecs = np.linalg.eigh(rel.T @ rel)
            forward = vecs[:, 1]  # middle eigenvalue: the smallest is the up axis (zero spread)
        else:
            forward = np.roll(np.abs(up), 1)
    forward = forward - (forward @ up) * up
    forward /= np.linalg.norm(forward)
    lateral = np.cross(up, forward)
    h = pts @ up
    h = h[np.isfinite(h)]
    floor, top = (float(h.min()), float(h.max())) if h.size else (0.0, size)  # no marker ever seen
    return _View(up, forward, lateral, size, floor, top)


#: Pairs of left and right points whose distance varies by less than this
#: share (standard deviation over median) are rigid across the body (hips,
#: pelvis markers): their left-to-right direction is the figure's.
RIGID_PAIR = 0.05
#: The heading at a time is measured over this many seconds around it
#: (against marker noise; a spinning dancer turns a quarter in 0.25 s:
#: on the dev dances and walks, the side panels show the hips at a median
#: 2-13 % of their width in the front panels with it, 15-25 % with 1 s);
#: the direction of travel (without sides) over the longer window, two
#: steps of a slow walk, so that the pelvis' sway from step to step cancels.
HEADING_WINDOW = 0.25
TRAVEL_WINDOW = 2.0


def side_pairs(names: Sequence[str]) -> list[tuple[int, int]]:
    """(left, right) index pairs of points whose names mirror each other:
    ``LeftUpLeg``/``RightUpLeg``, ``UpperLeg_L``/``UpperLeg_R``, ``l asis``/
    ``r asis``, ``Male:LFWT``/``Male:RFWT`` (a leading L or R before capitals,
    when the mirrored label exists)."""
    from ..names import base_name, side, tokens

    bases = [base_name(n) for n in names]
    have = set(bases)
    keys: dict[tuple[str, tuple[str, ...]], int] = {}
    for j, (n, b) in enumerate(zip(names, bases, strict=True)):
        where = side(n)
        if where:
            key = tuple(t for t in tokens(n) if t not in ("l", "r", "left", "right"))
        elif len(b) > 1 and b[0] in "LR" and b[1:].isupper() and ("RL"[b[0] == "R"] + b[1:]) in have:
            where, key = ("left" if b[0] == "L" else "right"), (b[1:],)
        else:
            continue
        keys.setdefault((where, key), j)
    return [(j, keys[("right", k)]) for (w, k), j in keys.items() if w == "left" and ("right", k) in keys]


def headings(stick: _Stick, frames: np.ndarray, view: _View) -> np.ndarray:
    """The figure's forward direction (F, 3), unit and level, at each of
    ``frames``: across the rigid left-right pairs nearest the figure's
    centre in height (the hips, the pelvis markers; :data:`RIGID_PAIR`), their
    left-to-right direction crossed with up, averaged over
    :data:`HEADING_WINDOW` around the frame; without such pairs (or where
    none is seen), the direction of travel over :data:`TRAVEL_WINDOW`; for a figure that stays
    in place, the clip's own view (:func:`view_axes`)."""
    frames = np.asarray(frames, dtype=int)
    pts, up, size = stick.points, view.up, view.size
    T = len(pts)
    half = max(1, round(0.5 * HEADING_WINDOW / stick.frame_time))
    lo, hi = np.clip(frames - half, 0, T - 1), np.clip(frames + half, 0, T - 1)
    lateral = np.full((len(frames), 3), np.nan)
    pairs = side_pairs(stick.names)
    if pairs:
        L, R = np.array([a for a, _ in pairs]), np.array([b for _, b in pairs])
        diff = pts[:, L] - pts[:, R]  # (T, P, 3)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # pairs never seen
            dist = quat.norm(diff)
            med = np.nanmedian(dist, axis=0)
            rigid = (med > 0.03 * size) & (np.nanstd(dist, axis=0) < RIGID_PAIR * med)
            height = np.nanmedian((pts[:, L] + pts[:, R]) @ up, axis=0) / 2
        if rigid.any():
            # the pairs nearest the figure's centre in height: the hips or pelvis
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                centre = np.nanmedian(pts @ up)
            off = np.where(rigid, np.abs(height - centre), np.inf)
            low = rigid & (off <= off.min() + 0.15 * size)
            flat = diff[:, low] - (diff[:, low] @ up)[..., None] * up  # (T, P', 3)
            summed = np.where(np.isfinite(flat), flat, 0.0).sum(axis=1)  # (T, 3)
            seen = np.isfinite(flat).all(axis=2).any(axis=1)
            csum = np.concatenate([np.zeros((1, 3)), np.cumsum(summed, axis=0)])
            cseen = np.concatenate([[0], np.cumsum(seen)])
            got = cseen[hi + 1] - cseen[lo] > 0
            lateral[got] = (csum[hi + 1] - csum[lo])[got]
    fwd = np.cross(lateral, up)
    # where no side is seen: the direction of travel over the window
    need = ~(quat.norm(fwd) > 1e-9 * size)
    if need.any():
        ok = np.isfinite(pts).all(axis=2)
        count = np.maximum(ok.sum(axis=1), 1)
        centre = np.where(ok[..., None], pts, 0.0).sum(axis=1) / count[:, None]
        centre[~ok.any(axis=1)] = np.nan
        wide = max(1, round(0.5 * TRAVEL_WINDOW / stick.frame_time))
        for k in np.flatnonzero(need):  # (a few panels)
            c = centre[max(frames[k] - wide, 0) : frames[k] + wide + 1]
            c = c[np.isfinite(c).all(axis=1)]
            if len(c) >= 2:
                move = c[-1] - c[0]
                move = move - (move @ up) * up
                if np.linalg.norm(move) > 0.05 * size:
                    fwd[k] = move
    bad = ~(quat.norm(fwd) > 1e-9 * size)
    fwd[bad] = view.forward
    fwd = fwd - np.outer(fwd @ up, up)
    return fwd / quat.norm(fwd)[:, None]


def turned(view: _View, forward: np.ndarray) -> _View:
    """``view`` looking across (side) and along (front) ``forward``."""
    from dataclasses import replace

    return replace(view, forward=forward, lateral=np.cross(view.up, forward))


def _parse_at(at: str, count: int | None, n_poses: int | None) -> tuple[str, int | None]:
    if at not in ("poses", "frames"):
        raise UsageError(f"{arg('at')} must be 'poses' or 'frames N', got {at!r}")
    if count is not None and count < 1:
        raise UsageError(f"{arg('at')} frames N needs N >= 1, got {count}")
    if at == "poses" and n_poses is None:
        at = "frames"  # a clip without poses
    return at, count


def _times(
    stick: _Stick, pose_t: np.ndarray | None, at: str, count: int | None, *, most: int | None, default: int | None
) -> tuple[np.ndarray, list[str]]:
    """Times (seconds) to show and their labels."""
    T = len(stick.points)
    if at == "poses" and pose_t is not None:
        k = np.arange(len(pose_t))
        if most is not None and len(k) > most:
            k = np.unique(np.rint(np.linspace(0, len(k) - 1, most)).astype(int))
        return pose_t[k], [f"pose {i}\n{pose_t[i]:.2f} s" for i in k]
    n = count if count is not None else default
    if n is None:  # every frame at about GIF_FPS, real time
        step = max(1, round(1.0 / (GIF_FPS * stick.frame_time)), math.ceil(T / MAX_GIF_FRAMES))
        f = np.arange(0, T, step)
    else:
        if most is not None:
            n = min(n, most)
        f = np.unique(np.rint(np.linspace(0, T - 1, min(n, T))).astype(int))
    t = f * stick.frame_time
    return t, [f"frame {i}\n{ti:.2f} s" for i, ti in zip(f, t, strict=True)]


def _draw_stick(
    ax, stick: _Stick, frame: int, view: _View, which: str, dark: str, light: str, ms: float, under: bool = False
):
    """Artists of one figure at one frame: a LineCollection of bones (or
    None) and a Line2D of joints or markers.  ``under``: the compared clip,
    wider and behind, so that where both agree the first one shows on top
    with a coloured edge."""
    lw, z = (4.0, 2) if under else (1.5, 3)
    if stick.markers:  # lines between markers: thinner, the dots are the data
        lw *= 0.5
    from matplotlib.collections import LineCollection

    x, y = view.project(stick.points[frame], which)
    bones = None
    if len(stick.bones):
        seg = np.stack(
            [
                np.column_stack([x[stick.bones[:, 0]], y[stick.bones[:, 0]]]),
                np.column_stack([x[stick.bones[:, 1]], y[stick.bones[:, 1]]]),
            ],
            axis=1,
        )
        colors = [light if lf else dark for lf in stick.left]
        bones = LineCollection(seg, colors=colors, lw=lw, capstyle="round", zorder=z, alpha=0.6 if under else 1.0)
        ax.add_collection(bones)
    size = (ms if stick.markers else 0.6 * ms) * (1.6 if under else 1.0)
    (dots,) = ax.plot(x, y, ls="none", marker="o", ms=size, color=dark, zorder=z + 0.5, alpha=0.6 if under else 1.0)
    return bones, dots


def _update_stick(bones, dots, stick: _Stick, frame: int, view: _View, which: str) -> np.ndarray:
    """Moves the artists of :func:`_draw_stick` to ``frame``; the drawn x."""
    x, y = view.project(stick.points[frame], which)
    if bones is not None:
        seg = np.stack(
            [
                np.column_stack([x[stick.bones[:, 0]], y[stick.bones[:, 0]]]),
                np.column_stack([x[stick.bones[:, 1]], y[stick.bones[:, 1]]]),
            ],
            axis=1,
        )
        bones.set_segments(seg)
    dots.set_data(x, y)
    return x


def _center(x: np.ndarray) -> float:
    ok = np.isfinite(x)
    return float(np.median(x[ok])) if ok.any() else 0.0


def _floor_marks(ax, view: _View, stick: _Stick, which: str) -> None:
    """Ticks on the floor every half figure height of world position, so
    that travel shows while the view follows the figure."""
    x = view.project(stick.points, which)[0]
    ok = np.isfinite(x)
    if not ok.any():
        return
    step = 0.5 * view.size
    lo = math.floor((x[ok].min() - view.size) / step)
    hi = math.ceil((x[ok].max() + view.size) / step)
    ax.vlines(np.arange(lo, hi + 1) * step, view.floor - 0.05 * view.size, view.floor, colors="0.6", lw=0.8, zorder=1)


def _frame_axes(ax, view: _View, cx: float, x: np.ndarray | None = None) -> None:
    """Limits of a panel centred on ``cx``, 1.2 figure heights wide; moved
    (or, for a figure lying wider than that, widened) so that every drawn
    point ``x`` is inside with a margin: a flip must not cut a foot off."""
    half = 0.6 * view.size
    if x is not None:
        x = np.asarray(x, dtype=float)
        x = x[np.isfinite(x)]
        if len(x):
            pad = 0.08 * view.size
            lo, hi = float(x.min()) - pad, float(x.max()) + pad
            if hi - lo <= 2 * half:
                cx = min(max(cx, hi - half), lo + half)
            else:
                cx, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    ax.set_xlim(cx - half, cx + half)
    pad = 0.06 * view.size
    ax.set_ylim(view.floor - pad, max(view.top, view.floor + view.size) + pad)
    ax.set_aspect("equal", adjustable="box")


def _subjects(subject, compare, name: str | None, compare_name: str | None) -> list[_Stick]:
    from ..model.document import Document

    def label(s, n, fallback):
        if n:
            return n
        if isinstance(s, Document):
            return f"{s.source_name or 'document'} (document)"
        return fallback

    out = [_stick(subject, label(subject, name, "clip"))]
    if compare is not None:
        out.append(_stick(compare, label(compare, compare_name, "compared clip")))
    return out


def skeleton_difference(a, b) -> str | None:
    """How the figure of ``b`` differs from that of ``a`` (documents or
    clips), in a few words, or None when they have the same joints (or
    markers) and sizes within 10 %: ``preview --compare`` warns, since
    the two drawings then do not line up joint for joint."""
    from ..model.document import Document
    from ..motion import BvhMotion

    clips = [x.source if isinstance(x, Document) else x for x in (a, b)]
    names = [tuple(c.skeleton.names) if isinstance(c, BvhMotion) else tuple(c.labels) for c in clips]
    kinds = ["skeleton" if isinstance(c, BvhMotion) else "marker set" for c in clips]
    if kinds[0] != kinds[1]:
        return f"a {kinds[1]}, not a {kinds[0]}"
    what = "joint" if kinds[0] == "skeleton" else "marker"
    if names[0] != names[1]:
        missing = [n for n in names[0] if n not in names[1]]
        extra = [n for n in names[1] if n not in names[0]]
        if missing or extra:
            first = f"no {what} {missing[0]}" if missing else f"an extra {what} {extra[0]}"
            return f"{len(names[1])} {what}s against {len(names[0])}, {first}"
        return f"the same {what}s in another order"
    h = [float(c.figure_height()) for c in clips]
    if abs(h[1] - h[0]) > 0.1 * max(h[0], 1e-12):
        return f"another size: {h[1]:.4g} file units tall against {h[0]:.4g}"
    return None


def _poses_of(sticks: list[_Stick]) -> np.ndarray | None:
    return next((s.pose_t for s in sticks if s.pose_t is not None), None)


def preview_figure(
    subject: Document | BvhMotion | MarkerMotion,
    *,
    compare: Document | BvhMotion | MarkerMotion | None = None,
    at: str = "poses",
    count: int | None = None,
    name: str | None = None,
    compare_name: str | None = None,
) -> Figure:
    """A strip of stick figures: side views above, front views below.

    A document is shown as it bakes.  ``at='poses'`` shows the pose times
    (of ``subject`` or, if it is a clip, of ``compare``; at most
    :data:`MAX_PANELS`, evenly chosen); a clip without poses, or
    ``at='frames'``, shows ``count`` (default
    :data:`DEFAULT_PREVIEW_FRAMES`) evenly spaced frames.  With ``compare``
    both are drawn at the same times, ``subject`` thin in blue (bones on the
    figure's left lighter) over ``compare`` wide in orange: where they agree
    the blue figure has an orange halo.  C3D markers are points.
    Each panel follows the figure: the horizontal axis is in file units
    along the view, so travel shows in the tick labels.
    """
    from matplotlib.lines import Line2D

    sticks = _subjects(subject, compare, name, compare_name)
    pose_t = _poses_of(sticks)
    at, count = _parse_at(at, count, None if pose_t is None else len(pose_t))
    times, labels = _times(sticks[0], pose_t, at, count, most=MAX_PANELS, default=DEFAULT_PREVIEW_FRAMES)
    view = view_axes(sticks[0].points)
    n = len(times)
    panel = min(11.6 / n, 2.4) - 0.1  # inches per panel, less the gaps
    aspect = (max(view.top, view.floor + view.size) - view.floor + 0.12 * view.size) / (1.2 * view.size)
    extra = 0.95 + (0.3 if len(sticks) > 1 else 0.0)  # title, panel titles, legend
    fig = _figure((min(12.0, n * (panel + 0.1) + 0.4), min(2 * panel * aspect + extra, 7.0)))
    axes = fig.subplots(2, n, squeeze=False)
    colors = [(_PRIMARY, _PRIMARY_LIGHT), (_SECOND, _SECOND_LIGHT)]
    ahead = headings(sticks[0], sticks[0].at(times), view)
    for col, (t, lab) in enumerate(zip(times, labels, strict=True)):
        panel_view = turned(view, ahead[col])
        for row, which in enumerate(("side", "front")):
            ax = axes[row, col]
            cx, drawn = None, []
            for i, (s, (dark, light)) in enumerate(zip(sticks, colors, strict=False)):
                frame = int(s.at([t])[0])
                _draw_stick(ax, s, frame, panel_view, which, dark, light, ms=2.5, under=i > 0)
                drawn.append(panel_view.project(s.points[frame], which)[0])
                if cx is None:
                    cx = _center(drawn[0])
            ax.axhline(view.floor, color="0.6", lw=0.8, zorder=1)
            _frame_axes(ax, panel_view, cx or 0.0, np.concatenate(drawn))
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(lab, fontsize=8)
            if col == 0:
                ax.set_ylabel(which, fontsize=9)
    what = "poses" if at == "poses" and pose_t is not None else "frames"
    fig.suptitle(f"preview · {' vs '.join(s.name for s in sticks)} · {n} {what}")
    if len(sticks) > 1:
        fig.legend(handles=_legend(sticks, Line2D), loc="outside lower center", ncols=2, fontsize=8, frameon=False)
    return fig


def _legend(sticks: list[_Stick], line) -> list:
    return [
        line([], [], color=_PRIMARY, lw=1.5, label=sticks[0].name),
        line([], [], color=_SECOND, lw=4.0, alpha=0.6, label=sticks[1].name),
    ]


def gif_durations(gaps: np.ndarray) -> list[int]:
    """Frame durations in milliseconds, whole centiseconds (GIF's unit), for
    frames that should last ``gaps`` (N,) seconds each.

    Rounding each frame on its own drifts (a 1/15 s frame becomes 0.06 s:
    10 % fast); rounding the running end time instead spreads the error, so
    the total is within half a centisecond of ``gaps.sum()`` (callers keep
    every gap at 0.05 s or more, above the 2 cs browsers honour).
    """
    ends = np.rint(100.0 * np.cumsum(np.asarray(gaps, dtype=float))).astype(int)
    return (10 * np.diff(ends, prepend=0)).tolist()


def preview_gif(
    subject: Document | BvhMotion | MarkerMotion,
    *,
    compare: Document | BvhMotion | MarkerMotion | None = None,
    at: str = "frames",
    count: int | None = None,
    name: str | None = None,
    compare_name: str | None = None,
    dpi: float = 80,
) -> bytes:
    """An animated GIF of the side and front views.

    ``at='frames'`` without ``count``: the whole clip in real time at about
    :data:`GIF_FPS` frames per second (at most :data:`MAX_GIF_FRAMES`
    frames, then coarser); with ``count``: that many evenly spaced frames;
    ``at='poses'``: one frame per pose, each held until the next pose's
    time (0.1 to 1 s).  Colours and views as :func:`preview_figure`.
    """
    from matplotlib.lines import Line2D
    from PIL import Image

    sticks = _subjects(subject, compare, name, compare_name)
    pose_t = _poses_of(sticks)
    at, count = _parse_at(at, count, None if pose_t is None else len(pose_t))
    times, labels = _times(sticks[0], pose_t, at, count, most=None if count is None else MAX_GIF_FRAMES, default=None)
    if len(times) > MAX_GIF_FRAMES:
        keep = np.unique(np.rint(np.linspace(0, len(times) - 1, MAX_GIF_FRAMES)).astype(int))
        times, labels = times[keep], [labels[i] for i in keep]
    view = view_axes(sticks[0].points)
    units = getattr(subject, "units", "") or getattr(getattr(subject, "source", None), "units", "") or "file units"
    fig = _figure((8.0, 4.6))
    fig.set_dpi(dpi)
    axes = fig.subplots(1, 2)
    colors = [(_PRIMARY, _PRIMARY_LIGHT), (_SECOND, _SECOND_LIGHT)]
    artists = []
    for ax, which in zip(axes, ("side", "front"), strict=True):
        for i, (s, (dark, light)) in enumerate(zip(sticks, colors, strict=False)):
            first = int(s.at(times[:1])[0])
            artists.append((ax, which, s, *_draw_stick(ax, s, first, view, which, dark, light, 3.0, under=i > 0)))
        ax.axhline(view.floor, color="0.6", lw=0.8, zorder=1)
        _floor_marks(ax, view, sticks[0], which)
        ax.set_title(f"{which} view", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_xticks([])  # travel shows on the floor marks; fixed ticks keep each frame cheap to draw
        ax.set_ylabel(f"height ({units})", fontsize=8)
        _frame_axes(ax, view, 0.0)
    title = fig.suptitle("")
    if len(sticks) > 1:
        fig.legend(handles=_legend(sticks, Line2D), loc="outside lower center", ncols=2, fontsize=8, frameon=False)
    names = " vs ".join(s.name for s in sticks)

    def render(t: float, lab: str):
        drawn: dict[int, list[np.ndarray]] = {}
        for ax, which, s, bones, dots in artists:
            drawn.setdefault(id(ax), []).append(_update_stick(bones, dots, s, int(s.at([t])[0]), view, which))
        for ax in axes:
            _frame_axes(ax, view, _center(drawn[id(ax)][0]), np.concatenate(drawn[id(ax)]))
        title.set_text(f"{names} · {lab.replace(chr(10), ' · ')}")
        fig.canvas.draw()
        rgb = Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3])
        return rgb.quantize(palette=palette) if palette is not None else rgb.quantize(colors=64)

    palette = None
    first = render(times[0], labels[0])
    palette = first
    fig.set_layout_engine("none")  # the layout of the first frame holds: no solve per frame
    rest = (render(t, lab) for t, lab in zip(times[1:], labels[1:], strict=True))
    if at == "poses" and pose_t is not None and len(times) > 1:
        gaps = np.clip(np.diff(times, append=times[-1] + 1.0), 0.1, 1.0)
    else:
        gap = float(np.median(np.diff(times))) if len(times) > 1 else 0.5
        gaps = np.clip(np.diff(times, append=times[-1] + gap), 0.05, 1.0)  # real time
    durations = gif_durations(gaps)
    buf = io.BytesIO()
    first.save(buf, format="GIF", save_all=True, append_images=rest, duration=durations, loop=0)
    return buf.getvalue()


# --- demo --------------------------------------------------------------------


def demo_pictures(
    doc: Document,
    out_dir: str | Path,
    *,
    name: str | None = None,
    joints: Sequence[str] | None = None,
    dpi: float = 72,
    force: bool = True,
) -> list[Path]:
    """Write ``signals.png``, ``timing.png``, ``curves.png`` (of ``joints``,
    default as :func:`curves_figure`) and ``preview.png`` (the document over
    its source clip) of ``doc`` into ``out_dir`` (created if needed) at a
    modest ``dpi``, small files for the README; returns the paths."""
    from ..io.files import write_atomic

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    source = f"{doc.source_name or 'source'} (source)"
    pictures = {
        "signals": signals_figure(doc, name=name),
        "timing": timing_figure(doc, name=name),
        "curves": curves_figure(doc, name=name, joints=joints),
        "preview": preview_figure(doc, compare=doc.source, name=name, compare_name=source),
    }
    paths = []
    for kind, fig in pictures.items():
        path = out / f"{kind}.png"
        write_atomic(str(path), png_bytes(fig, dpi), force)
        paths.append(path)
    return paths
