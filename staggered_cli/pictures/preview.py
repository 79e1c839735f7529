"""``preview``: a strip of stick figures in side and front views at the pose
times (or evenly spaced frames), optionally over a second clip; and the
drawing of a stick figure on an axes that the animated preview shares."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..errors import UsageError, arg
from .common import _figure
from .sticks import LONGEST_LINE, _Stick, _stick, _View, headings, turned, view_axes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

#: Most panels in a preview strip; more times are thinned evenly.
MAX_PANELS = 12
#: Frames shown by a PNG preview of a clip without poses.
DEFAULT_PREVIEW_FRAMES = 8
#: Height of each panel of a PNG preview, inches (350 pixels at the default
#: 100 dpi), and the widest strip: more panels wrap onto further rows.
PANEL_HEIGHT = 3.5
MAX_WIDTH = 18.0
#: Width of a preview panel in figure heights (a stride, arms out); a
#: figure lying wider widens its panel's limits.
PANEL_WIDTH = 0.9
#: Animated previews: frames per second (real time) and the most frames.
GIF_FPS = 15.0
MAX_GIF_FRAMES = 300

#: The subject (dark, its left lighter) and the compared clip.
_PRIMARY, _PRIMARY_LIGHT = "#1f3f8a", "#4a8be0"
_SECOND, _SECOND_LIGHT = "#f08a3c", "#f08a3c"


def _parse_at(at: str, count: int | None, n_poses: int | None) -> tuple[str, int | None]:
    if at not in ("poses", "frames"):
        raise UsageError(f"{arg('at')} must be 'poses' or 'frames N', got {at!r}")
    if count is not None and count < 1:
        raise UsageError(f"{arg('at')} frames N needs N >= 1, got {count}")
    if at == "poses" and n_poses is None:
        at = "frames"  # a clip without poses
    return at, count


def _times(
    stick: _Stick,
    pose_t: np.ndarray | None,
    at: str,
    count: int | None,
    *,
    most: int | None,
    default: int | None,
    parts: tuple | None = None,
) -> tuple[np.ndarray, list[str]]:
    """Times (seconds) to show and their labels (``parts``: the poses' body
    parts, a partial pose labelled ``pose 5 (@left-arm)``)."""
    T = len(stick.points)
    if at == "poses" and pose_t is not None:
        k = np.arange(len(pose_t))
        if most is not None and len(k) > most:
            k = np.unique(np.rint(np.linspace(0, len(k) - 1, most)).astype(int))
        part = [None] * len(pose_t) if parts is None or len(parts) != len(pose_t) else parts
        return pose_t[k], [
            f"pose {i}{'' if part[i] is None else f' ({part[i]})'}\n{pose_t[i]:.2f} s" for i in k
        ]
    n = count if count is not None else default
    if n is None:  # every frame at about GIF_FPS, real time
        step = max(1, round(1.0 / (GIF_FPS * stick.frame_time)), math.ceil(T / MAX_GIF_FRAMES))
        f = np.arange(0, T, step)
    else:
        if most is not None:
            n = min(n, most)
        seen = _seen_frames(stick.points)
        f = seen[np.unique(np.rint(np.linspace(0, len(seen) - 1, min(n, len(seen)))).astype(int))]
    t = f * stick.frame_time
    return t, [f"frame {i}\n{ti:.2f} s" for i, ti in zip(f, t, strict=True)]


def _seen_frames(points: np.ndarray) -> np.ndarray:
    """Frames (indices) where at least half as many points are seen as in
    the best-seen frame: every frame of a skeleton; a marker set's frames
    without its long gaps (the BTS walk sees no marker in its first 239);
    every frame when no marker is ever seen (each panel says so)."""
    count = np.all(np.isfinite(points), axis=2).sum(axis=1)
    if not count.any():
        return np.arange(len(points))
    return np.flatnonzero(count >= 0.5 * count.max())


def _segments(stick: _Stick, frame: int, x: np.ndarray, y: np.ndarray, size: float) -> np.ndarray:
    """The bones at ``frame`` as drawn (B, 2, 2), NaN where one is not.  A
    marker whose parent is in a gap is joined to its nearest ancestor seen
    (a knee to the pelvis while the thigh's marker is missing; the parts
    hanging from a root in a gap to the first of them), unless that is
    longer than :data:`~staggered_cli.pictures.sticks.LONGEST_LINE`."""
    a, b = stick.bones[:, 0], stick.bones[:, 1]
    if stick.markers:
        pts = stick.points[frame]
        seen = np.all(np.isfinite(pts), axis=1)
        up = np.full(len(pts), -1)
        up[b] = a
        a = a.copy()
        for _ in range(len(pts)):
            gap = ~seen[a] & (up[a] >= 0)
            if not gap.any():
                break
            a[gap] = up[a[gap]]
        for r in np.unique(a[~seen[a]]):  # a root in a gap: what hangs from it joins its first part seen
            mine = np.flatnonzero((a == r) & seen[b])
            if len(mine) > 1:
                a[mine[1:]] = b[mine[0]]
        with np.errstate(invalid="ignore"):
            far = ~(np.linalg.norm(pts[a] - pts[b], axis=1) <= LONGEST_LINE * size)
        a = np.where(far & (a != stick.bones[:, 0]), stick.bones[:, 0], a)  # left out: drawn as the gap it is
    return np.stack([np.column_stack([x[a], y[a]]), np.column_stack([x[b], y[b]])], axis=1)


def _draw_stick(
    ax,
    stick: _Stick,
    frame: int,
    view: _View,
    which: str,
    dark: str,
    light: str,
    ms: float,
    under: bool = False,
    lw: float = 1.5,
):
    """Artists of one figure at one frame: a LineCollection of bones (or
    None) and a Line2D of joints or markers.  ``under``: the compared clip,
    wider and behind, so that where both agree the first one shows on top
    with a coloured edge."""
    lw, z = (lw * 8 / 3, 2) if under else (lw, 3)
    if stick.markers:  # lines between markers: thinner, the dots are the data
        lw *= 0.5
    from matplotlib.collections import LineCollection

    x, y = view.project(stick.points[frame], which)
    bones = None
    if len(stick.bones):
        seg = _segments(stick, frame, x, y, view.size)
        colors = [light if lf else dark for lf in stick.left]
        bones = LineCollection(seg, colors=colors, lw=lw, capstyle="round", zorder=z, alpha=0.6 if under else 1.0)
        ax.add_collection(bones)
    size = (ms if stick.markers else 0.6 * ms) * (1.6 if under else 1.0)
    (dots,) = ax.plot(x, y, ls="none", marker="o", ms=size, color=dark, zorder=z + 0.5, alpha=0.6 if under else 1.0)
    return bones, dots


def _update_stick(bones, dots, stick: _Stick, frame: int, view: _View, which: str) -> tuple[np.ndarray, np.ndarray]:
    """Moves the artists of :func:`_draw_stick` to ``frame``; the drawn x and y."""
    x, y = view.project(stick.points[frame], which)
    if bones is not None:
        seg = _segments(stick, frame, x, y, view.size)
        bones.set_segments(seg)
    dots.set_data(x, y)
    return x, y


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


def _frame_axes(
    ax,
    view: _View,
    cx: float,
    x: np.ndarray | None = None,
    y: np.ndarray | None = None,
    aspect: float | None = None,
    width: float = 1.2,
) -> None:
    """Limits of a panel centred on ``cx``, ``width`` figure heights wide, from
    the floor to the figure's top; moved (or, for a figure lying wider than
    that, widened) so that every drawn point ``x``, ``y`` is inside with a
    margin: a flip must not cut a foot off.  ``aspect`` (height over width
    of the panel): the limits are widened to it, so that the panel keeps its
    size; without it the panel shrinks to the limits."""
    half = 0.5 * width * view.size
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
    pad = 0.06 * view.size
    bottom, top = view.floor - pad, max(view.top, view.floor + view.size) + pad
    if y is not None:  # a marker seen only outside the frames the view was measured on
        y = np.asarray(y, dtype=float)
        y = y[np.isfinite(y)]
        if len(y):
            bottom, top = min(bottom, float(y.min()) - pad), max(top, float(y.max()) + pad)
    if aspect is not None:
        if top - bottom < aspect * 2 * half:
            top = bottom + aspect * 2 * half  # room above a figure lying wide
        else:
            half = 0.5 * (top - bottom) / aspect
    ax.set_xlim(cx - half, cx + half)
    ax.set_ylim(bottom, top)
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
    :data:`DEFAULT_PREVIEW_FRAMES`) evenly spaced frames (of a marker set,
    among the frames where at least half as many markers are seen as at
    best: not in a capture's empty lead-in).  With ``compare``
    both are drawn at the same times, ``subject`` thin in blue (bones on the
    figure's left lighter) over ``compare`` wide in orange: where they agree
    the blue figure has an orange halo.  C3D markers are dots joined by
    lines along the body (:func:`~staggered_cli.pictures.sticks.marker_bones`;
    a document's own marker tree where it has one).
    Each time is a column of a side panel over a front panel,
    :data:`PANEL_HEIGHT` inches tall and :data:`PANEL_WIDTH` figure heights
    wide, in rows at most :data:`MAX_WIDTH` inches wide (``fig.axes``: the
    side panels, then the front panels, in time order).  Each panel follows
    the figure and holds every point drawn in it.
    """
    from matplotlib.lines import Line2D

    sticks = _subjects(subject, compare, name, compare_name)
    pose_t = _poses_of(sticks)
    at, count = _parse_at(at, count, None if pose_t is None else len(pose_t))
    parts = next((getattr(d, "pose_part", None) for d in (subject, compare) if hasattr(d, "pose_part")), None)
    times, labels = _times(
        sticks[0], pose_t, at, count, most=MAX_PANELS, default=DEFAULT_PREVIEW_FRAMES, parts=parts
    )
    view = view_axes(sticks[0].points)
    n = len(times)
    aspect = (max(view.top, view.floor + view.size) - view.floor + 0.12 * view.size) / (PANEL_WIDTH * view.size)
    rows, cols, width = _grid(n, aspect)
    gap = 0.15
    extra = 0.6 + (0.35 if len(sticks) > 1 else 0.0)  # title, legend
    fig = _figure((cols * (width + gap) + 0.45, rows * (2 * PANEL_HEIGHT + 0.6) + extra))
    grid = fig.add_gridspec(2 * rows, cols)
    # side panels first, then front panels: fig.axes as a (2, n) strip's
    axes = np.array([[fig.add_subplot(grid[2 * (k // cols) + r, k % cols]) for k in range(n)] for r in (0, 1)])
    colors = [(_PRIMARY, _PRIMARY_LIGHT), (_SECOND, _SECOND_LIGHT)]
    ahead = headings(sticks[0], sticks[0].at(times), view)
    for col, (t, lab) in enumerate(zip(times, labels, strict=True)):
        panel_view = turned(view, ahead[col])
        for row, which in enumerate(("side", "front")):
            ax = axes[row, col]
            cx, xs, ys = None, [], []
            for i, (s, (dark, light)) in enumerate(zip(sticks, colors, strict=False)):
                frame = int(s.at([t])[0])
                _draw_stick(ax, s, frame, panel_view, which, dark, light, ms=4.0, under=i > 0, lw=2.0)
                x, y = panel_view.project(s.points[frame], which)
                xs.append(x)
                ys.append(y)
                if cx is None:
                    cx = _center(x)
            ax.axhline(view.floor, color="0.6", lw=0.8, zorder=1)
            _frame_axes(ax, panel_view, cx or 0.0, np.concatenate(xs), np.concatenate(ys), aspect, PANEL_WIDTH)
            if not np.isfinite(np.concatenate(xs)).any():
                ax.text(0.5, 0.5, "no marker seen", ha="center", va="center", color="0.5", transform=ax.transAxes)
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(lab, fontsize=10)
            if col % cols == 0:
                ax.set_ylabel(which, fontsize=11)
    what = "poses" if at == "poses" and pose_t is not None else "frames"
    fig.suptitle(f"preview · {' vs '.join(s.name for s in sticks)} · {n} {what}")
    if len(sticks) > 1:
        fig.legend(handles=_legend(sticks, Line2D), loc="outside lower center", ncols=2, fontsize=10, frameon=False)
    return fig


def _grid(n: int, aspect: float) -> tuple[int, int, float]:
    """Rows and columns of ``n`` panels of :data:`PANEL_HEIGHT` and
    ``aspect`` (height over width), at most :data:`MAX_WIDTH` wide, rows as
    even as they can be (8 panels: two rows of 4), and a panel's width."""
    width = min(max(PANEL_HEIGHT / aspect, 1.5), MAX_WIDTH)
    cols = max(1, min(n, int(MAX_WIDTH // (width + 0.15))))
    rows = math.ceil(n / cols)
    return rows, math.ceil(n / rows), width


def _legend(sticks: list[_Stick], line) -> list:
    return [
        line([], [], color=_PRIMARY, lw=1.5, label=sticks[0].name),
        line([], [], color=_SECOND, lw=4.0, alpha=0.6, label=sticks[1].name),
    ]
