"""``preview``: a strip of stick figures in side and front views at the pose
times (or evenly spaced frames), optionally over a second clip; and the
drawing of a stick figure on an axes that the animated preview shares."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..errors import UsageError, arg
from .common import _figure
from .sticks import _Stick, _stick, _View, headings, turned, view_axes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

#: Most panels in a preview strip; more times are thinned evenly.
MAX_PANELS = 12
#: Frames shown by a PNG preview of a clip without poses.
DEFAULT_PREVIEW_FRAMES = 8
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
    parts = next((getattr(d, "pose_part", None) for d in (subject, compare) if hasattr(d, "pose_part")), None)
    times, labels = _times(
        sticks[0], pose_t, at, count, most=MAX_PANELS, default=DEFAULT_PREVIEW_FRAMES, parts=parts
    )
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
