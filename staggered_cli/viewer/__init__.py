"""``staggered view``: what the self-contained HTML page plays, as data.

:func:`page_data` turns a clip or a document (and the motions compared
with it) into what the page needs: for each figure its world points per
frame in metres with Y up (float32, packed), the lines between them, the
names of its points; the floor; and for a document the staggered timing of
its poses as ``plot --kind timing`` draws it (pose times, each variable's
extreme knots about its pose, editing knots, contacts, the poses of the
layers above the base).  :func:`staggered_cli.io.page.page_pieces` lays it
in the page (``page.html``, ``page.css``, ``page.js`` and the vendored
three.js beside this module).

Points: a BVH's joints of the body proper and its End Sites (forward
kinematics in numpy, so the page draws line segments only); a C3D's
markers (NaN in gaps: the page hides them), joined by the document's
marker tree where it has one, else the tree of the most rigid pairs;
a document's motion as it bakes (:func:`staggered_cli.ops.bake.bake`).
Units: metres per file unit as the glTF writer infers them
(:func:`staggered_cli.io.gltf.unit_scale_for`: a C3D's POINT:UNITS, else
the unit that makes the figure a person's height).  Up: the detected up
axis (:func:`staggered_cli.contacts.detect.up_direction`) turned to +Y.
Floor: the height of the figure's lowest point in most frames (the 2nd
percentile over frames of the lowest point's height).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

#: Share of the frames below which the lowest point may go and still stand
#: on the floor (a jump's landing, a marker's glitch).
FLOOR_PERCENTILE = 2.0


@dataclass(frozen=True)
class Figure:
    """One motion ready for the page: points (T, N, 3) float32, metres, Y up."""

    name: str
    kind: str  # "skeleton" or "markers"
    frame_time: float
    points: np.ndarray
    bones: np.ndarray  # (B, 2) indices into the points
    left: np.ndarray  # (B,) bool: a bone of the figure's left side
    labels: tuple[str, ...]
    floor: float  # metres, in the page's Y


def _turn_and_scale(motion: BvhMotion | MarkerMotion, pts: np.ndarray) -> np.ndarray:
    """``pts`` (file units, the file's up) in metres with Y up, float32."""
    from ..io.gltf import unit_scale_for, up_turn
    from ..pictures.common import _up  # contacts.detect.up_direction, quiet on all-NaN frames

    scale = unit_scale_for(motion)[0]
    turn = up_turn(_up(pts, float(motion.figure_height())))
    out = np.empty(pts.shape, dtype=np.float32)
    step = 1 << 16
    for lo in range(0, len(pts), step):  # blocks: a long clip's float64 copy would be large
        out[lo : lo + step] = (pts[lo : lo + step] @ (turn.T * scale)).astype(np.float32)
    return out


def _floor(points: np.ndarray) -> float:
    with np.errstate(invalid="ignore"):
        low = np.fmin.reduce(points[..., 1], axis=1)
    low = low[np.isfinite(low)]
    return float(np.percentile(low, FLOOR_PERCENTILE)) if low.size else 0.0


def figure(subject: Document | BvhMotion | MarkerMotion, name: str) -> Figure:
    """The figure of a clip, or of a document as it bakes."""
    from ..model.document import Document
    from ..motion import BvhMotion
    from ..ops.bake import bake
    from ..pictures.sticks import _figure_points

    tree = None
    if isinstance(subject, Document):
        if subject.kind != "bvh":  # its marker tree (succession, randomize), as preview draws it
            from ..ops.marker_chain import document_tree

            tree = (document_tree(subject), subject.source.points)
        subject = bake(subject)
    pts, bones, left, labels = _figure_points(subject, tree)
    page_pts = _turn_and_scale(subject, pts)
    kind = "skeleton" if isinstance(subject, BvhMotion) else "markers"
    return Figure(
        name,
        kind,
        float(subject.frame_time),
        page_pts,
        np.asarray(bones, dtype=int).reshape(-1, 2),
        np.asarray(left, dtype=bool),
        tuple(str(x) for x in labels),
        _floor(page_pts),
    )


def timing(doc: Document) -> dict[str, Any]:
    """The staggered timing of ``doc`` as ``plot --kind timing`` draws it:
    pose times, rows (variables in hierarchy order, every other limb
    shaded) with their extreme knots ``[t_k, t]`` and editing knot times,
    contacts as ``[start, end]`` bars in their rows, and the pose times of
    each layer above the base."""
    from ..pictures.common import _contact_rows, _rows, limb_shades

    rows = _rows(doc, None)
    labels = [v.name for v in rows]
    row_of = {v.name: r for r, v in enumerate(rows)}
    shade = limb_shades(doc, rows)
    if doc.kind == "bvh":  # a contact on a joint: its rotation row
        for v in reversed(rows):
            row_of.setdefault(doc.source.skeleton.names[v.target], row_of[v.name])
    out_rows = []
    for r, v in enumerate(rows):
        tr = doc.tracks[v.track]
        sl = tr.knot_slice(v.local)
        kt, kp, ke = tr.knot_t[sl], tr.knot_pose[sl], tr.knot_editing[sl]
        ext = ~ke
        pairs = np.column_stack([doc.pose_t[kp[ext]], kt[ext]])
        out_rows.append({"name": labels[r], "shade": bool(shade[r]), "ext": _round(pairs), "edit": _round(kt[ke])})
    contacts = []
    for joint, spans in _contact_rows(doc, 0.0, doc.duration).items():
        if joint not in row_of:
            row_of[joint] = len(out_rows)
            out_rows.append({"name": f"{joint} (contact)", "shade": False, "ext": [], "edit": []})
        contacts.append({"row": row_of[joint], "spans": _round([(s, s + d) for s, d in spans])})
    return {
        "pose_t": _round(doc.pose_t),
        "pose_part": list(doc.pose_part),  # null: a whole-body pose; else the body part it owns
        "rows": out_rows,
        "contacts": contacts,
        "layers": [_round(t) for t in doc.layer_pose_t],
    }


def _round(a) -> list:
    """Seconds as JSON numbers (a microsecond is finer than any frame)."""
    return np.round(np.asarray(a, dtype=float), 6).tolist()


def page_data(
    subject: Document | BvhMotion | MarkerMotion,
    *,
    compare: tuple[Document | BvhMotion | MarkerMotion, ...] = (),
    names: tuple[str, ...] = (),
) -> tuple[dict[str, Any], list[bytes]]:
    """What the page shows: its description (JSON-able) and one float32
    array of points (little-endian bytes, frame after frame) per figure.

    ``names``: of ``subject`` and then of each of ``compare`` (default:
    the clip's or document's own name).  The poses of ``subject`` (a
    document) drive the timeline.
    """
    from ..model.document import Document

    subjects = (subject, *compare)
    names = tuple(names) + tuple("" for _ in range(len(subjects) - len(names)))
    named = enumerate(zip(subjects, names, strict=True))
    figures = [figure(s, n or _own_name(s) or f"motion {i + 1}") for i, (s, n) in named]
    meta: dict[str, Any] = {
        "title": figures[0].name,
        "floor": figures[0].floor,
        "duration": max((len(f.points) - 1) * f.frame_time for f in figures),
        "figures": [
            {
                "name": f.name,
                "kind": f.kind,
                "frame_time": f.frame_time,
                "frames": int(f.points.shape[0]),
                "points": int(f.points.shape[1]),
                "labels": list(f.labels),
                "bones": f.bones.ravel().tolist(),
                "left": f.left.astype(int).tolist(),
            }
            for f in figures
        ],
        "timing": timing(subject) if isinstance(subject, Document) else None,
    }
    blobs = [np.ascontiguousarray(f.points, dtype="<f4").tobytes() for f in figures]
    return meta, blobs


def _own_name(value) -> str:
    return str(getattr(value, "name", "") or getattr(value, "source_name", "") or "")
