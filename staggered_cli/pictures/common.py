"""What every picture of a document shares: the figure and its PNG bytes,
the time window, the variables drawn as rows, titles, contacts and colours.

Rows "in hierarchy order": BVH variables by joint in file order (parents
before children), the translation of a joint before its rotation; C3D
markers from the highest to the lowest median height.  Variables that never
move (constant channels, a marker never seen) are left out unless asked for.
"""

from __future__ import annotations

import io
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import UsageError, arg

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..model.document import Document

#: Figure size in inches (fits a laptop screen at 100 dpi).
FIGSIZE = (12.0, 7.0)
#: Default resolution of written pictures, dots per inch.
DPI = 100
#: Most points drawn per curve; longer clips are drawn every n-th frame.
MAX_DRAW_POINTS = 2000
#: Most poses in a dope sheet drawn without ``time``: a longer document
#: shows its first poses (the title says so; ``time`` shows the rest).
MAX_TIMING_POSES = 60

#: Contacts, in every kind of picture.
_CONTACT = "tab:green"


# --- output --------------------------------------------------------------------


def _figure(figsize: tuple[float, float] = FIGSIZE) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


#: Colours of a preview PNG: an adaptive palette this large looks the same
#: as full colour on a line drawing, in a third of the bytes (the c3d.org
#: walk's 12 poses: 329 kB, 111 kB).
PREVIEW_COLORS = 64


def png_bytes(fig: Figure, dpi: float = DPI, colors: int | None = None) -> bytes:
    """The PNG file of ``fig`` at ``dpi`` dots per inch; with ``colors``, in
    an adaptive palette of that many colours (for line drawings such as the
    preview, not for the plots' colour maps)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    if colors is None:
        return buf.getvalue()
    from PIL import Image

    buf.seek(0)
    with Image.open(buf) as im:
        small = im.convert("RGB").quantize(colors=colors)
        out = io.BytesIO()
        small.save(out, format="PNG", optimize=True, dpi=(dpi, dpi))
    return out.getvalue()


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


def limb_shades(doc: Document, rows: list[_Var]) -> list[bool]:
    """Whether each row is shaded: every other limb (a chain of joints below
    a joint with several children), so that a succession down one limb
    reads as one block (the timing plot and the page's dope sheet)."""
    if doc.kind != "bvh" or not rows:
        return [False] * len(rows)
    sk = doc.source.skeleton
    n_children = np.bincount(sk.parents[sk.parents >= 0], minlength=sk.n_joints)
    limb = np.full(sk.n_joints, -1)
    for j in range(sk.n_joints):  # parents come before children
        p = int(sk.parents[j])
        if p >= 0:
            limb[j] = j if n_children[p] > 1 else limb[p]
    out, shade, prev = [], False, None
    for v in rows:
        b = limb[v.target]
        if b != prev:
            shade, prev = (not shade) and b >= 0, b
        out.append(bool(shade))
    return out


def _bands(ax, doc: Document, rows: list[_Var]) -> None:
    """Shade every other limb (:func:`limb_shades`)."""
    for r, shade in enumerate(limb_shades(doc, rows)):
        if shade:
            ax.axhspan(r - 0.5, r + 0.5, color="0.93", zorder=0, lw=0)
