"""Geometric pose editing (paper section 5.1).

An edit changes knot values only.  Spline tangents are stored relative to
their knots and the displacement maps are untouched, so the change is
confined to the segments next to the pose's knots and the motion detail
rides along.

* ``on='true'`` edits the pose at ``t_k`` (the editing knots); the extreme
  knots receive the same change ``Δ = vo_new ⊖ vo`` so no short, large
  acceleration appears.
* ``on='extreme'`` edits the non-staggered pose (the extreme values); the
  editing knots receive the same change ``Δ = v_new ⊖ v``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import quat
from ..document import Document, check_pose_index
from ..errors import UsageError
from ..representation import ROTATION, TRANSLATION, Track, evaluate, pose_arrays

#: Bounds of geometric edits: beyond them a value is a typo, not a pose.
MAX_TRANSLATE = 1000.0  # figure heights
MAX_EXAGGERATE = 100.0


def _oplus(kind: str, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a + b if kind == TRANSLATION else quat.mul(a, b)


def _ominus(kind: str, c: np.ndarray, a: np.ndarray) -> np.ndarray:
    return c - a if kind == TRANSLATION else quat.mul(quat.conj(a), c)


def _scale(kind: str, d: np.ndarray, w: float) -> np.ndarray:
    return d * w if kind == TRANSLATION else quat.exp(quat.log(d) * w)


def pose_values(doc: Document, k: int, on: str) -> list[np.ndarray]:
    """Per track, the (V, D) values of pose ``k``: the true pose at ``t_k``
    (``on='true'``) or the non-staggered pose of extreme values."""
    out = []
    for tr in doc.tracks:
        _, value, edit = pose_arrays(tr, doc.n_poses)
        out.append(edit[k] if on == "true" else value[k])
    return out


def average_pose(doc: Document) -> list[np.ndarray]:
    """Per track, the mean over the source clip's frames (rotations: the
    normalized mean of hemisphere-aligned quaternions, the chordal L2 mean)."""
    from ..document import dense_variables

    out = []
    for kind, _, _, dense in dense_variables(doc.source):
        if kind == TRANSLATION:
            out.append(dense.mean(axis=0))
        else:
            aligned = quat.hemisphere(dense, dense[:1])
            out.append(quat.normalize(aligned.sum(axis=0)))
    return out


def _apply_delta(doc: Document, k: int, deltas: list[np.ndarray | None], on: str) -> Document:
    """Apply per-variable changes Δ (list per track of (V, D), None = none) to pose k:
    the edited knot and its mutually constrained partner get the same Δ."""
    del on  # both knots of a variable receive the same change either way
    tracks = []
    for tr, d in zip(doc.tracks, deltas, strict=True):
        if d is None:
            tracks.append(tr)
            continue
        var = np.repeat(np.arange(tr.n_vars), np.diff(tr.knot_ptr))
        mine = tr.knot_pose == k
        knot_v = tr.knot_v.copy()
        knot_v[mine] = _oplus(tr.kind, tr.knot_v[mine], d[var[mine]])
        if tr.kind == ROTATION:
            knot_v = quat.normalize(knot_v)
        tracks.append(replace(tr, knot_v=knot_v))
    return doc.with_tracks(tuple(tracks))


def _identity_deltas(doc: Document) -> list[np.ndarray]:
    return [np.zeros((tr.n_vars, 3)) if tr.kind == TRANSLATION else quat.identity((tr.n_vars,)) for tr in doc.tracks]


def offsets(
    doc: Document, rotate: dict[str, tuple[float, float, float]], translate: dict[str, tuple[float, float, float]]
) -> list[np.ndarray | None]:
    """Per-track deltas from ``--rotate JOINT=rx,ry,rz`` (degrees about the
    joint's local axes, one rotation built in XYZ order) and ``--translate
    JOINT=x,y,z`` (file units)."""
    deltas = _identity_deltas(doc)
    touched = [False] * len(doc.tracks)
    for name, xyz in rotate.items():
        ti, i = _find(doc, name, ROTATION)
        deltas[ti][i] = quat.from_euler(np.asarray(xyz, dtype=float), "XYZ")
        touched[ti] = True
    size = doc.source.figure_height()
    for name, xyz in translate.items():
        ti, i = _find(doc, name, TRANSLATION)
        xyz = np.asarray(xyz, dtype=float)
        if not np.all(np.isfinite(xyz)) or np.abs(xyz).max() > MAX_TRANSLATE * size:
            raise UsageError(f"--translate {name}: at most {MAX_TRANSLATE:g} figure heights ({MAX_TRANSLATE * size:g})")
        deltas[ti][i] = xyz
        touched[ti] = True
    return [d if t else None for d, t in zip(deltas, touched, strict=True)]


def _find(doc: Document, name: str, kind: str) -> tuple[int, int]:
    j = doc.target_index(name)  # unknown name: UsageError with suggestions
    for ti, tr in enumerate(doc.tracks):
        if tr.kind == kind and j in tr.targets:
            return ti, int(np.flatnonzero(tr.targets == j)[0])
    what = "rotation channels" if kind == ROTATION else "position channels"
    raise UsageError(f"{doc.target_names[j]!r} has no {what} to edit")


def joint_mask(doc: Document, joints: list[str] | None, subtree: bool) -> list[np.ndarray]:
    """Per track, a (V,) mask of the variables an edit may touch (partial poses)."""
    if not joints:
        return [np.ones(tr.n_vars, dtype=bool) for tr in doc.tracks]
    chosen: list[int] = []
    for name in joints:
        try:
            j = doc.target_index(name)
        except UsageError as err:
            raise UsageError(f"--joints: {err.message}") from None
        chosen.extend(doc.source.skeleton.subtree(j).tolist() if subtree and doc.kind == "bvh" else [j])
    return [np.isin(tr.targets, chosen) for tr in doc.tracks]


def exaggeration_mask(doc: Document, joints: list[str] | None, subtree: bool) -> list[np.ndarray]:
    """Per track, a (V,) mask of the variables ``--exaggerate`` scales.

    Exaggeration changes a pose's shape, not its place: in a BVH document
    only rotations are scaled (scaling the root translation's difference
    from the clip's mean would move the character across the room), unless
    ``joints`` names joints explicitly, in which case every variable of the
    chosen joints is, translations included.  In a C3D document every marker
    (a translation) is scaled, within ``joints`` when given.
    """
    mask = joint_mask(doc, joints, subtree)
    if doc.kind != "bvh" or joints:
        return mask
    return [m & (tr.kind == ROTATION) for tr, m in zip(doc.tracks, mask, strict=True)]


def edit_pose(
    doc: Document,
    k: int,
    *,
    on: str = "true",
    rotate: dict[str, tuple[float, float, float]] | None = None,
    translate: dict[str, tuple[float, float, float]] | None = None,
    exaggerate: float | None = None,
    relative_to: str = "average",
    joints: list[str] | None = None,
    subtree: bool = False,
    values: list[np.ndarray] | None = None,
) -> Document:
    """Geometric edit of pose ``k``.

    Parameters
    ----------
    on : ``'true'`` (the pose at t_k) or ``'extreme'`` (the non-staggered pose).
    rotate, translate : per-joint offsets (see :func:`offsets`).
    exaggerate : weight W: each value becomes ``v_ref ⊕ W·(v ⊖ v_ref)``
        (W = 1 is the identity, 2 doubles the difference, 0.5 halves it; the
        paper's ``v ⊕ w_r(v ⊖ v_ref)`` with ``w_r = W - 1``), relative to
        ``relative_to``: ``'prev'``, ``'next'``, ``'average'`` (the mean pose
        of the source clip) or a pose index.  In a BVH document only the
        rotations are scaled unless ``joints`` is given (see
        :func:`exaggeration_mask`).  A rotation's scaled difference wraps
        past a half turn, so W then 1/W restores differences under 180°/max(W, 1).
    values : per track (V, D) target values (e.g. from another BVH), applied
        where ``joints`` allows.
    joints, subtree : restrict exaggeration and ``values`` to part of the body.
    """
    if on not in ("true", "extreme"):
        raise UsageError(f"--on must be 'true' or 'extreme', got {on!r}")
    k = check_pose_index(doc, k)
    rotate = rotate or {}
    translate = translate or {}
    if rotate or translate:
        doc = _apply_delta(doc, k, offsets(doc, rotate, translate), on)
    if exaggerate is not None:
        if not np.isfinite(exaggerate) or abs(exaggerate) > MAX_EXAGGERATE:
            raise UsageError(f"--exaggerate must be a number between -{MAX_EXAGGERATE:g} and {MAX_EXAGGERATE:g}")
        ref = reference_values(doc, k, relative_to, on)
        cur = pose_values(doc, k, on)
        mask = exaggeration_mask(doc, joints, subtree)
        deltas = []
        for tr, c, r, m in zip(doc.tracks, cur, ref, mask, strict=True):
            target = _oplus(tr.kind, r, _scale(tr.kind, _ominus(tr.kind, c, r), exaggerate))
            d = _ominus(tr.kind, target, c)
            d[~m] = 0.0 if tr.kind == TRANSLATION else quat.identity()
            deltas.append(d)
        doc = _apply_delta(doc, k, deltas, on)
    if values is not None:
        cur = pose_values(doc, k, on)
        mask = joint_mask(doc, joints, subtree)
        deltas = []
        for tr, c, v, m in zip(doc.tracks, cur, values, mask, strict=True):
            d = _ominus(tr.kind, v, c)
            d[~m] = 0.0 if tr.kind == TRANSLATION else quat.identity()
            deltas.append(d)
        doc = _apply_delta(doc, k, deltas, on)
    return doc


def reference_values(doc: Document, k: int, relative_to: str, on: str) -> list[np.ndarray]:
    """Per track (V, D) values of the reference pose for exaggeration."""
    key = str(relative_to).strip().lower()
    if key == "average":
        return average_pose(doc)
    if key == "prev":
        if k == 0:
            raise UsageError("pose 0 has no previous pose to exaggerate against")
        return pose_values(doc, k - 1, on)
    if key == "next":
        if k == doc.n_poses - 1:
            raise UsageError(f"pose {k} is the last; it has no next pose to exaggerate against")
        return pose_values(doc, k + 1, on)
    try:
        r = int(key)
    except ValueError:
        raise UsageError(f"--relative-to takes prev, next, average or a pose index, got {relative_to!r}") from None
    r = check_pose_index(doc, r)
    if r == k:
        raise UsageError("a pose cannot be exaggerated relative to itself")
    return pose_values(doc, r, on)


def values_from_motion(
    doc: Document, motion, frame: int, joints: list[str] | None = None, subtree: bool = False
) -> list[np.ndarray]:
    """Per track (V, D) values of frame ``frame`` of another BVH, matched by
    joint name.

    Values come from the file's local rotations and translations of the
    joint of the same name, so a joint without position channels in the file
    (e.g. a typical Blender export, with positions on the root only) gives
    its offset as its translation.  Only the variables inside the
    ``joints``/``subtree`` mask (all when ``joints`` is empty) must find
    their joint in the file; the others, which the edit leaves alone, are
    given as the identity (zero translation, unit quaternion).
    """
    from ..motion import BvhMotion

    if doc.kind != "bvh" or not isinstance(motion, BvhMotion):
        raise UsageError("--from-bvh needs a BVH document and a BVH file")
    if not -motion.n_frames <= frame < motion.n_frames:
        raise UsageError(f"--frame {frame} is out of range (the file has frames 0 to {motion.n_frames - 1})")
    mask = joint_mask(doc, joints, subtree)
    ours = doc.source.skeleton.names
    theirs = {n: j for j, n in enumerate(motion.skeleton.names)}
    rot = motion.local_rotations()[frame]
    tra = motion.local_translations()[frame]
    out = []
    missing: list[str] = []
    for tr, m in zip(doc.tracks, mask, strict=True):
        vals = np.zeros((tr.n_vars, 3)) if tr.kind == TRANSLATION else quat.identity((tr.n_vars,))
        for i, target in enumerate(tr.targets):
            if not m[i]:
                continue
            name = ours[int(target)]
            j = theirs.get(name)
            if j is None:
                if name not in missing:
                    missing.append(name)
                continue
            vals[i] = tra[j] if tr.kind == TRANSLATION else rot[j]
        out.append(vals)
    if missing:
        raise UsageError(
            "the BVH has a different skeleton: it lacks joint"
            f"{'s' if len(missing) > 1 else ''} {', '.join(missing[:5])}{'...' if len(missing) > 5 else ''}"
        )
    return out


def true_pose(doc: Document, k: int) -> list[np.ndarray]:
    """Per track (V, D) values the motion has at t_k (for tests and info)."""
    return [evaluate(tr, np.array([doc.pose_t[k]]))[0] for tr in doc.tracks]


__all__ = [
    "edit_pose",
    "exaggeration_mask",
    "values_from_motion",
    "reference_values",
    "pose_values",
    "true_pose",
    "Track",
]
