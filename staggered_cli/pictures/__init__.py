"""Pictures of staggered-pose documents: signals, timing, curves and a
stick-figure preview, one module per kind.

Every picture is a pure function from values to a matplotlib ``Figure``
(drawn with the Agg canvas, no pyplot and no global state);
:func:`png_bytes` and :func:`preview_gif` turn them into file contents.
matplotlib is imported inside the functions so that importing this package
(and starting the command line) stays light.

Modules
    ``common``   the figure, PNG bytes, time windows, the variables drawn as
    rows (in hierarchy order), titles, contacts.
    ``signals``  the evidence for the poses (the paper's Figures 4 and 5).
    ``timing``   a dope sheet of the knots.
    ``curves``   a few joints' channels: source, spline layer, baked.
    ``sticks``   a clip as a stick figure: points, bones, views, headings.
    ``preview``  a strip of stick figures at the pose times.
    ``gif``      the animated preview.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import UsageError
from .common import DPI, FIGSIZE, MAX_TIMING_POSES, PREVIEW_COLORS, png_bytes
from .curves import curves_figure
from .gif import gif_durations, preview_gif
from .preview import MAX_PANELS, preview_figure
from .signals import signals_figure
from .sticks import marker_bones, skeleton_difference, view_axes
from .timing import timing_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document

__all__ = [
    "DPI",
    "FIGSIZE",
    "KINDS",
    "MAX_PANELS",
    "MAX_TIMING_POSES",
    "PREVIEW_COLORS",
    "curves_figure",
    "demo_pictures",
    "gif_durations",
    "marker_bones",
    "plot_figure",
    "png_bytes",
    "preview_figure",
    "preview_gif",
    "signals_figure",
    "skeleton_difference",
    "timing_figure",
    "view_axes",
]

#: The kinds of ``staggered plot``.
KINDS = ("signals", "timing", "curves")


def plot_figure(doc: Document, kind: str, **options) -> Figure:
    """The picture ``kind`` (one of :data:`KINDS`) of ``doc``."""
    makers = {"signals": signals_figure, "timing": timing_figure, "curves": curves_figure}
    if kind not in makers:
        raise UsageError(f"unknown kind of plot {kind!r} (one of {', '.join(KINDS)})")
    return makers[kind](doc, **options)


# --- demo --------------------------------------------------------------------


def demo_pictures(
    doc: Document,
    out_dir: str | Path,
    *,
    name: str | None = None,
    joints: Sequence[str] | None = None,
    dpi: float = DPI,
    force: bool = True,
) -> list[Path]:
    """Write ``signals.png``, ``timing.png``, ``curves.png`` (of ``joints``,
    default as :func:`curves_figure`) and ``preview.png`` (the document over
    its source clip) of ``doc`` into ``out_dir`` (created if needed) at
    ``dpi`` (the preview in a palette of :data:`PREVIEW_COLORS`); returns
    the paths."""
    from ..io.files import make_parent, write_atomic

    out = Path(out_dir)
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
        make_parent(str(path))
        write_atomic(str(path), png_bytes(fig, dpi, PREVIEW_COLORS if kind == "preview" else None), force)
        paths.append(path)
    return paths
