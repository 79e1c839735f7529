"""The animated preview: side and front views of a clip in real time, or of
its poses, as a GIF."""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

import numpy as np

from .common import _figure
from .preview import (
    _PRIMARY,
    _PRIMARY_LIGHT,
    _SECOND,
    _SECOND_LIGHT,
    MAX_GIF_FRAMES,
    _center,
    _draw_stick,
    _floor_marks,
    _frame_axes,
    _legend,
    _parse_at,
    _poses_of,
    _subjects,
    _times,
    _update_stick,
)
from .sticks import view_axes

if TYPE_CHECKING:
    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion


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
        drawn: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        for ax, which, s, bones, dots in artists:
            drawn.setdefault(id(ax), []).append(_update_stick(bones, dots, s, int(s.at([t])[0]), view, which))
        for ax in axes:
            xs, ys = zip(*drawn[id(ax)], strict=True)
            _frame_axes(ax, view, _center(xs[0]), np.concatenate(xs), np.concatenate(ys))
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
