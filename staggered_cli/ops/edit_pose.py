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

import numpy as np

from .. import quat
from ..errors import DataError, UsageError, arg, warn
from ..model.document import Document, check_pose_index
from ..model.evaluate import evaluate, evaluate_at
from ..model.kinds import ROTATION, TRANSLATION, ops_for
from ..model.knots import Track, pose_arrays

#: Bounds of geometric edits: beyond them a value is a typo, not a pose.
MAX_TRANSLATE = 1000.0  # figure heights
MAX_EXAGGERATE = 100.0


def pose_values(doc: Document, k: int, on: str) -> list[np.ndarray]:
    """Per track, the (V, D) values of pose ``k``: the true pose at ``t_k``
    (``on='true'``) or the non-staggered pose of extreme values.  Where a
    partial pose has no knot (outside its part) both are the value the
    spline layer passes through at ``t_k``."""
    out = []
    for tr, owns in zip(doc.tracks, doc.track_owns(), strict=True):
        _, value, edit = pose_arrays(tr, doc.n_poses)
        vals = edit[k] if on == "true" else value[k]
        free = np.flatnonzero(~owns[k])
        if len(free):
            vals = vals.copy()
            vals[free] = evaluate_at(tr, free, np.full(len(free), float(doc.pose_t[k])), depth=1)
        out.append(vals)
    return out


def average_pose(doc: Document) -> list[np.ndarray]:
    """Per track, the mean over the source clip's frames (rotations: the
    normalized mean of hemisphere-aligned quaternions, the chordal L2 mean)."""
    from ..model.variables import dense_variables

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
        var = tr.knots.var
        mine = tr.knot_pose == k
        knot_v = tr.knot_v.copy()
        # only the pose's own knots change (the others to the bit: a partial
        # pose's edit leaves every other variable as it was)
        ops = ops_for(tr.kind)
        knot_v[mine] = ops.normalize(ops.oplus(tr.knot_v[mine], d[var[mine]]))
        tracks.append(tr.with_knot_values(knot_v))
    return doc.with_tracks(tuple(tracks))


def _identity_deltas(doc: Document) -> list[np.ndarray]:
    return [ops_for(tr.kind).identity((tr.n_vars,)) for tr in doc.tracks]


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
            raise UsageError(
                f"{arg('translate')} {name}: at most {MAX_TRANSLATE:g} figure heights ({MAX_TRANSLATE * size:g})"
            )
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
            raise UsageError(f"{arg('joints')}: {err.message}") from None
        chosen.extend(doc.source.skeleton.subtree(j).tolist() if subtree and doc.kind == "bvh" else [j])
    return [np.isin(tr.targets, chosen) for tr in doc.tracks]


def exaggeration_mask(doc: Document, joints: list[str] | None, subtree: bool, root: bool = False) -> list[np.ndarray]:
    """Per track, a (V,) mask of the variables ``--exaggerate`` scales.

    Exaggeration changes a pose's shape, not its place: in a BVH document
    only rotations are scaled (scaling the root translation's difference
    from the clip's mean would move the character across the room), unless
    ``root``, in which case every variable is, translations included
    (within ``joints`` when given).  The heading of the BVH's place joint is
    kept apart from this mask (see :func:`_heading_kept`).  In a C3D
    document every marker (a translation) is scaled, within ``joints`` when
    given.
    """
    mask = joint_mask(doc, joints, subtree)
    if doc.kind != "bvh" or root:
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
    root: bool = False,
    layer: int = 0,
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
        rotations are scaled unless ``root`` (see :func:`exaggeration_mask`).
        A rotation's scaled difference wraps past a half turn, so W then 1/W
        restores differences under 180°/max(W, 1).
        A BVH pose keeps its place and heading unless ``root`` (see
        :func:`_heading_kept`); a C3D pose keeps its limbs' lengths within
        the capture's own (see :func:`_segments_kept`).
    values : per track (V, D) target values (e.g. from another BVH), applied
        where ``joints`` allows.  The pose keeps its place and heading (see
        :func:`_keep_place`) unless ``root``.
    root : BVH: exaggerate (or take from ``values``) the place joint's
        translation and heading and the joints above it too.
    joints, subtree : restrict exaggeration and ``values`` to part of the body.
    layer : edit pose ``k`` of this layer (0: the base layer's staggered
        poses).  On a layer above the base the pose is what the whole stack
        gives at the layer's pose time, and the change goes into that
        layer's offsets (:func:`staggered_cli.ops.layers.apply_offset`).
    """
    from . import layers

    if on not in ("true", "extreme"):
        raise UsageError(f"{arg('on')} must be 'true' or 'extreme', got {on!r}")
    k = check_pose_index(doc, k, layer)
    times = doc.poses_of(layer)
    if layer:

        def values_at(d: Document, kk: int) -> list[np.ndarray]:
            return layers.pose_values(d, layer, kk)

        def apply(d: Document, deltas: list[np.ndarray | None]) -> Document:
            return layers.apply_offset(d, layer, k, deltas)

    else:

        def values_at(d: Document, kk: int) -> list[np.ndarray]:
            return pose_values(d, kk, on)

        def apply(d: Document, deltas: list[np.ndarray | None]) -> Document:
            return _apply_delta(d, k, deltas, on)

    rotate = rotate or {}
    translate = translate or {}
    part = doc.parts_of(layer)[k]
    owned = _split(doc, doc.part_mask(part))  # per track: the variables pose k has knots in
    if part is not None:
        _check_in_part(doc, k, part, owned, rotate, translate)
        if root:
            warn(
                f"{arg('root')}: %s owns only %s; the figure's place and heading change at whole-body poses",
                doc.pose_label(k, layer),
                part,
            )
    if rotate or translate:
        doc = apply(doc, offsets(doc, rotate, translate))
    if exaggerate is not None:
        check_exaggerate(exaggerate)
        if root and doc.kind != "bvh":
            raise UsageError(f"{arg('root')} is for a BVH's root; a C3D document's markers have none")
        r = _reference_pose(relative_to, k, len(times), doc.parts_of(layer))
        cur = values_at(doc, k)
        mask = [m & o for m, o in zip(exaggeration_mask(doc, joints, subtree, root), owned, strict=True)]
        if doc.kind == "c3d":  # the average of a marker set is its own (a mean shape)
            cur, ref = _marker_shapes(doc, times, k, r, cur, None if r is None else values_at(doc, r), mask[0])
        else:
            ref = average_pose(doc) if r is None else values_at(doc, r)
        deltas = []
        for tr, c, v, m in zip(doc.tracks, cur, ref, mask, strict=True):
            op = ops_for(tr.kind)
            target = op.oplus(v, op.scale(op.ominus(c, v), exaggerate))
            d = op.ominus(target, c)
            d[~m] = op.identity()
            deltas.append(d)
        if doc.kind == "bvh" and not root:
            deltas = _heading_kept(doc, cur, None if r is None else ref, exaggerate, deltas, mask)
        if doc.kind == "c3d" and not joints:
            deltas = [_planted_held(doc, times, k, deltas[0])]
        edited = apply(doc, deltas)
        if doc.kind == "c3d" and not layer:
            fixed = ~(mask[0] & _seen_at_pose(doc, times, k))
            planted = _planted(doc, times, k) if not joints else np.zeros_like(fixed)
            edited = _segments_kept(edited, doc, fixed, planted)
        doc = edited
    if values is not None:
        cur = values_at(doc, k)
        mask = [m & o for m, o in zip(joint_mask(doc, joints, subtree), owned, strict=True)]
        if not root and doc.kind == "bvh":
            values = _keep_place(doc, cur, values)
        deltas = []
        for tr, c, v, m in zip(doc.tracks, cur, values, mask, strict=True):
            op = ops_for(tr.kind)
            d = op.ominus(v, c)
            d[~m] = op.identity()
            deltas.append(d)
        doc = apply(doc, deltas)
    return doc


def _split(doc: Document, mask: np.ndarray) -> list[np.ndarray]:
    """A (V,) mask over all variables as one (V_track,) mask per track."""
    out, col = [], 0
    for tr in doc.tracks:
        out.append(mask[col : col + tr.n_vars])
        col += tr.n_vars
    return out


def _check_in_part(doc, k: int, part: str, owned: list[np.ndarray], rotate: dict, translate: dict) -> None:
    """Refuse ``--rotate``/``--translate`` of a joint outside partial pose
    ``k``'s part: the pose has no knot there to change."""
    for name, kind in [(n, ROTATION) for n in rotate] + [(n, TRANSLATION) for n in translate]:
        ti, i = _find(doc, name, kind)
        if not owned[ti][i]:
            raise UsageError(
                f"pose {k} is a partial pose of {part}: {doc.tracks[ti].names[i]!r} is not in it "
                "(edit a whole-body pose, or a partial pose of that part)"
            )


def check_exaggerate(w: float) -> None:
    """Refuse an ``--exaggerate`` weight that is not a number within :data:`MAX_EXAGGERATE`."""
    if not np.isfinite(w) or abs(w) > MAX_EXAGGERATE:
        raise UsageError(f"{arg('exaggerate')} must be a number between -{MAX_EXAGGERATE:g} and {MAX_EXAGGERATE:g}")


def check_values(exaggerate: float | None, ease: float | None) -> None:
    """Refuse an edit's ``exaggerate`` weight or ``ease`` out of range
    (:func:`check_exaggerate`, :func:`~staggered_cli.ops.layers.check_ease`),
    each where given, before any document is read."""
    from .layers import check_ease

    if exaggerate is not None:
        check_exaggerate(exaggerate)
    if ease is not None:
        check_ease(ease)


def check_request(
    *,
    pose: int | None,
    all_poses: bool,
    rotate: bool,
    translate: bool,
    exaggerate: float | None,
    ease: float | None,
    from_bvh: object | None,
    frame: int | None,
    root: bool,
    layer: int,
    time: float | None,
    shift: float | None,
    joints: bool,
    subtree: bool,
) -> None:
    """Refuse an edit whose options do not go together, before any document
    is read (``st.edit_pose`` and the CLI's ``edit-pose`` ask it; a batch
    checks its steps so).  ``rotate``, ``translate`` and ``joints`` say
    whether any were given; the values are checked apart (:func:`check_values`)."""
    if time is not None and shift is not None:
        raise UsageError(f"give {arg('time')} or {arg('shift')}, not both")
    if subtree and not joints:
        raise UsageError(f"{arg('subtree')} needs {arg('joints')}: it adds the descendants of the joints named there")
    moves = time is not None or shift is not None
    if all_poses:
        if from_bvh is None or pose is not None or frame is not None:
            raise UsageError(f"{arg('all')} needs {arg('from_bvh')}, and no {arg('pose')} or {arg('frame')}")
        if rotate or translate or exaggerate is not None or ease is not None or moves or root or layer:
            raise UsageError(
                f"{arg('all')} goes with {arg('from_bvh')}, {arg('on')}, {arg('joints')} and {arg('subtree')} only"
            )
        return
    if pose is None:
        raise UsageError(f"{arg('pose')} is missing (or give {arg('from_bvh')} with {arg('all')})")
    if (from_bvh is None) != (frame is None):
        raise UsageError(f"{arg('from_bvh')} and {arg('frame')} go together")
    if not (rotate or translate or exaggerate is not None or ease is not None or from_bvh is not None or moves):
        raise UsageError(
            f"nothing to do: give {arg('rotate')}, {arg('translate')}, {arg('exaggerate')}, {arg('from_bvh')}, "
            f"{arg('ease')}, {arg('time')} or {arg('shift')}"
        )
    if root and from_bvh is None and exaggerate is None:
        raise UsageError(f"{arg('root')} goes with {arg('from_bvh')} or {arg('exaggerate')}")
    if joints and exaggerate is None and from_bvh is None and ease is None:
        raise UsageError(
            f"{arg('joints')} restricts {arg('exaggerate')}, {arg('from_bvh')} and {arg('ease')} "
            f"({arg('rotate')} and {arg('translate')} name their own joints)"
        )


def place_joint(doc: Document) -> int:
    """The joint that carries the figure's place: the first joint, in
    hierarchy order, whose translation moves over the clip (CMU's root
    ``Hips``, Bandai's ``Hips`` below a still ``joint_Root``); the root when
    none does."""
    tra = doc.source.local_translations()
    moving = np.ptp(tra, axis=0).max(axis=1) > 1e-6 * doc.source.figure_height()
    return int(np.argmax(moving)) if moving.any() else 0


def up_axis(doc: Document) -> np.ndarray:
    """Unit up vector (3,) of a BVH document's figure, from the body's
    joints as contact detection finds it (see :mod:`..contacts`): a still
    joint above the body (Bandai's ``joint_Root`` at the origin) widens
    every frame of a walk along its path (the Bandai walk's up came out -Z)."""
    from ..contacts.detect import up_direction
    from ..skeleton import body_joints

    src = doc.source
    return up_direction(src.world_positions(), src.figure_height(), body_joints(src.skeleton))


def heading_split(q: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``q = heading ⊗ rest``: the rotation about ``up`` (the twist of a
    swing-twist split) and what remains, which turns nothing about ``up``."""
    v = np.sum(q[..., 1:] * up, axis=-1, keepdims=True) * up
    twist = np.concatenate([q[..., :1], v], axis=-1)
    n = np.linalg.norm(twist, axis=-1, keepdims=True)
    twist = np.where(n > 1e-12, twist / np.maximum(n, 1e-300), quat.identity(q.shape[:-1]))
    return twist, quat.mul(quat.conj(twist), q)


def _place_chain(doc: Document) -> list[int]:
    """The :func:`place_joint` and its ancestors, up to the root."""
    parents = doc.source.skeleton.parents
    chain = [place_joint(doc)]
    while parents[chain[-1]] >= 0:
        chain.append(int(parents[chain[-1]]))
    return chain


def _rotation_of(doc: Document, j: int) -> tuple[int, int] | None:
    """(track, variable) of joint ``j``'s rotation, None when it has none."""
    for ti, tr in enumerate(doc.tracks):
        if tr.kind == ROTATION and j in tr.targets:
            return ti, int(np.flatnonzero(tr.targets == j)[0])
    return None


def _tilted_up(q: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3): where the rest of :func:`heading_split` of
    ``q`` (its tilt, a turn about a horizontal axis) takes ``up``.  The tilt
    is the shortest turn from ``up`` to that vector, so the vector alone
    says it, with no heading in it."""
    return quat.mul_vec(heading_split(q, up)[1], np.broadcast_to(up, np.shape(q)[:-1] + (3,)))


def _tilt_towards(up: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The shortest turn (4,) that takes ``up`` to the unit vector ``d``."""
    q = np.concatenate([[1.0 + float(up @ d)], np.cross(up, d)])
    n = float(np.linalg.norm(q))
    if n < 1e-9:  # upside down: half a turn about a horizontal axis
        side = np.cross(up, np.eye(3)[int(np.argmin(np.abs(up)))])
        return np.concatenate([[0.0], side / np.linalg.norm(side)])
    return q / n


def _scaled_direction(ref: np.ndarray, cur: np.ndarray, w: float) -> np.ndarray:
    """The unit vector on the great circle from ``ref`` through ``cur`` at
    ``w`` times their angle from ``ref`` (``w = 1``: ``cur``)."""
    axis = np.cross(ref, cur)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return cur
    angle = float(np.arctan2(s, float(ref @ cur)))
    return quat.mul_vec(quat.exp(axis / s * (w * angle)), ref)


def _heading_kept(
    doc: Document,
    cur: list[np.ndarray],
    ref: list[np.ndarray] | None,
    w: float,
    deltas: list[np.ndarray],
    mask: list[np.ndarray],
) -> list[np.ndarray]:
    """BVH: the changes of an exaggeration by ``w`` of pose values ``cur``
    against ``ref`` (a pose's values; None: the source clip's average) that
    keep the figure's place and heading, as ``--from-bvh`` does.

    The joints above the :func:`place_joint` keep their values and the
    chain's translations stay.  The place joint's world rotation is split
    into heading (about the up axis) and tilt (:func:`heading_split`); the
    tilt alone is exaggerated, in the figure's own facing frame: the
    direction the tilt takes the up axis to turns away from the reference's
    (the average: the mean of those directions over the source's frames,
    each without its own heading, since the mean of opposite headings means
    nothing) by ``w`` times their angle, and the pose's heading is put back.
    """
    chain = _place_chain(doc)
    place, above = chain[0], chain[1:]
    out = [d.copy() for d in deltas]
    for ti, tr in enumerate(doc.tracks):  # translations and the joints above: kept
        keep = np.isin(tr.targets, above) | ((tr.kind == TRANSLATION) & np.isin(tr.targets, chain))
        out[ti][keep] = ops_for(tr.kind).identity()
    at = _rotation_of(doc, place)
    if at is None or not mask[at[0]][at[1]]:
        return out
    ti, i = at
    up = up_axis(doc)

    def world(vals: list[np.ndarray]) -> np.ndarray:
        g = quat.identity()
        for j in reversed(chain):
            where = _rotation_of(doc, j)
            if where is not None:
                g = quat.mul(g, vals[where[0]][where[1]])
        return g

    g_cur = world(cur)
    if ref is None:
        rot = doc.source.local_rotations()
        g = quat.identity((rot.shape[0],))
        for j in reversed(chain):
            g = quat.mul(g, rot[:, j])
        mean = _tilted_up(g, up).mean(axis=0)
        d_ref = mean / max(float(np.linalg.norm(mean)), 1e-12)
    else:
        d_ref = _tilted_up(world(ref), up)
    heading, _ = heading_split(g_cur, up)
    tilt = _tilt_towards(up, _scaled_direction(d_ref, _tilted_up(g_cur, up), w))
    parent = quat.mul(g_cur, quat.conj(cur[ti][i]))  # the joints above, as they are
    local = quat.mul(quat.conj(parent), quat.mul(heading, tilt))
    out[ti][i] = quat.normalize(quat.ominus(quat.hemisphere(local, cur[ti][i]), cur[ti][i]))
    return out


def _keep_place(doc: Document, cur: list[np.ndarray], values: list[np.ndarray]) -> list[np.ndarray]:
    """``values`` of a whole-body pose with the document's place and heading.

    The joints from the root down to the :func:`place_joint` keep the
    document's translations, the joints above it its rotations too, and the
    place joint's world rotation is the document's heading (about the up
    axis) times the rest of the file's world rotation: the pose lands where
    the figure is, facing where it faces.
    """
    sk = doc.source.skeleton
    place = place_joint(doc)
    chain = [place]
    while sk.parents[chain[-1]] >= 0:
        chain.append(int(sk.parents[chain[-1]]))
    out = [v.copy() for v in values]

    def world_rotation(vals: list[np.ndarray]) -> np.ndarray:
        g = quat.identity()
        for j in reversed(chain):
            for tr, v in zip(doc.tracks, vals, strict=True):
                if tr.kind == ROTATION and j in tr.targets:
                    g = quat.mul(g, v[list(tr.targets).index(j)])
        return g

    up = up_axis(doc)
    heading, _ = heading_split(world_rotation(cur), up)
    _, rest = heading_split(world_rotation(values), up)
    above = quat.identity()
    for j in reversed(chain[1:]):
        for tr, c in zip(doc.tracks, cur, strict=True):
            if tr.kind == ROTATION and j in tr.targets:
                above = quat.mul(above, c[list(tr.targets).index(j)])
    for tr, c, o in zip(doc.tracks, cur, out, strict=True):
        for j in chain:
            if j not in tr.targets:
                continue
            i = list(tr.targets).index(j)
            if tr.kind == TRANSLATION or j != place:
                o[i] = c[i]
            else:
                o[i] = quat.hemisphere(quat.mul(quat.conj(above), quat.mul(heading, rest)), c[i])
    return out


def _marker_shapes(
    doc: Document, times: np.ndarray, k: int, r: int | None, cur: list[np.ndarray], ref, selected
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """C3D: pose ``k`` and its reference (pose ``r`` of values ``ref``, or
    None for both: the average) as
    shapes, each relative to its own body centre, so that exaggerating scales
    the shape and not the place: the changes the edit makes sum to zero.

    Only the ``selected`` markers captured at pose ``k``'s frame take part;
    the others keep their places (the reference is the pose itself there).
    The average is the mean shape over the frames that capture every one of
    them, each centred on their centroid: a marker's mean over the frames
    it happens to be seen in (a walkway's start for one, its end for
    another) is no shape at all.  A reference pose must capture them all.
    """
    pts = doc.source.points
    seen = np.all(np.isfinite(pts), axis=2)  # (T, M)
    frame = _frame_of(doc, times[k])
    use = seen[frame] & np.asarray(selected, dtype=bool)
    if not use.any():
        raise UsageError(f"pose {k} (frame {frame}) captures none of the markers to exaggerate: all are in a gap there")
    if r is None:
        full = np.flatnonzero(np.all(seen[:, use], axis=1))  # pose k's own frame among them
        shapes = pts[full][:, use]
        shape_ref = np.mean(shapes - shapes.mean(axis=1, keepdims=True), axis=0)
    else:
        at = _frame_of(doc, times[r])
        missing = np.flatnonzero(use & ~seen[at])
        if len(missing):
            first = doc.target_names[int(missing[0])]
            raise UsageError(
                f"pose {r} (frame {at}) does not capture {len(missing)} of the markers pose {k} shows "
                f"({first!r} among them): exaggerate relative to a pose that captures them, or to the average"
            )
        shape_ref = ref[0][use] - ref[0][use].mean(axis=0)
    out_cur = cur[0] - cur[0][use].mean(axis=0)
    out_ref = out_cur.copy()
    out_ref[use] = shape_ref
    return [out_cur], [out_ref]


def _frame_of(doc: Document, t: float) -> int:
    return int(np.clip(np.rint(t / doc.frame_time), 0, doc.n_frames - 1))


def _planted_held(doc: Document, times: np.ndarray, k: int, delta: np.ndarray) -> np.ndarray:
    """C3D: the changes (M, 3) of a whole-body exaggeration with the markers
    planted while the edit acts (a contact constraint overlapping the span
    between the neighbouring poses) held where they are, and the others
    shifted alike so that the changes still sum to zero over the markers
    seen at the pose: the contact layer of ``bake`` would hold the planted
    ones anyway, and the body's centre would then move."""
    planted = _planted(doc, times, k)
    if not planted.any() or planted.all():
        return delta
    seen = _seen_at_pose(doc, times, k)
    free = seen & ~planted
    if not free.any():
        return delta
    out = delta.copy()
    out[free] += delta[seen & planted].sum(axis=0) / free.sum()  # a marker in a gap at the pose stays
    out[planted] = 0.0
    return out


def _planted(doc: Document, times: np.ndarray, k: int) -> np.ndarray:
    """C3D: mask (M,) of the markers planted while an edit of pose ``k``
    acts (a contact constraint overlapping the span between its neighbours)."""
    labels = list(doc.target_names)
    lo = times[max(k - 1, 0)]
    hi = times[min(k + 1, len(times) - 1)]
    planted = np.zeros(len(labels), dtype=bool)
    for c in doc.constraints:
        if c.joint in labels and c.start < hi and c.end > lo:
            planted[labels.index(c.joint)] = True
    return planted


def _seen_at_pose(doc: Document, times: np.ndarray, k: int) -> np.ndarray:
    """C3D: mask (M,) of the markers captured at pose ``k``'s frame."""
    return np.all(np.isfinite(doc.source.points[_frame_of(doc, times[k])]), axis=1)


def _segments_kept(doc: Document, before: Document, fixed: np.ndarray, planted: np.ndarray) -> Document:
    """C3D: the edited document ``doc`` with every segment of its marker
    tree (see :func:`.marker_chain.document_tree`) within the lengths the
    source gives it, at every source frame and knot.

    An exaggeration scales the markers' shape as points, which stretches
    limbs (elbow to wrist 267-290 mm became 222-367 mm on a sprint), and the
    splines between the edited pose and its neighbours blend the change in
    along straight lines, which shortens a turning segment.  So the edited
    motion is walked along the tree (see :func:`.marker_chain.keep_segments`)
    from the ``fixed`` markers (outside the edit, or in a gap at the pose)
    and from the body held as it was (``before``) between each ``planted``
    marker and the body's centre (:func:`.marker_chain.centre_marker`), the
    stance that carries the body as the contact layer would: each other
    marker is put at the one it hangs from plus its own exaggerated
    direction times its length clamped into the source's [shortest,
    longest] for that segment.  The markers that moved are refitted on the
    same knots; the rest keep their values.
    """
    from . import marker_chain

    track = doc.tracks[0]
    parents = marker_chain.document_tree(doc)
    if not (parents >= 0).any():
        return doc
    pts = doc.source.points
    lo, hi = marker_chain.segment_ranges(pts, parents)
    frame_t = doc.frame_times
    t = np.unique(np.concatenate([frame_t, track.knot_t]))
    V = track.n_vars

    def sampled(tr: Track, depth: int | None = None) -> np.ndarray:
        v = evaluate_at(tr, np.repeat(np.arange(V), len(t)), np.tile(t, V), depth=depth)
        return v.reshape(V, len(t), 3).transpose(1, 0, 2)

    values = sampled(track)  # what bake gives: every layer (the base refitted below carries the change)
    hold = np.zeros(V, dtype=bool)
    if planted.any():
        centre = marker_chain.centre_marker(pts)
        for m in np.flatnonzero(planted):
            hold[marker_chain.tree_path(parents, int(m), centre)] = True
        hold &= ~fixed | planted
    if hold.any():
        values[:, hold] = sampled(before.tracks[0])[:, hold]
    seen = marker_chain.seen_at(np.all(np.isfinite(pts), axis=2), frame_t, t)
    out = marker_chain.keep_segments(values, parents, fixed | hold, lo, hi, seen)
    start = sampled(track)
    changed = np.any(out != start, axis=(0, 2))
    if changed.any():  # markers are sums of their layers: the base takes the difference
        base = sampled(track, depth=1)
        track = marker_chain.refit_markers(track, frame_t, t, base + (out - start), changed)
    return doc.with_tracks((track,) + tuple(doc.tracks[1:]))


def reference_values(doc: Document, k: int, relative_to: str, on: str) -> list[np.ndarray]:
    """Per track (V, D) values of the reference pose for exaggeration."""
    r = _reference_pose(relative_to, k, doc.n_poses, doc.pose_part)
    return average_pose(doc) if r is None else pose_values(doc, r, on)


def _reference_pose(relative_to: str, k: int, n_poses: int, parts: tuple | None = None) -> int | None:
    """The index of pose ``k``'s reference pose, or None for the average.

    ``prev`` and ``next`` are the nearest poses as whole as pose ``k`` with
    knots in its variables (``parts``, see
    :attr:`~staggered_cli.model.document.Document.pose_part`): for a
    whole-body pose the whole-body poses, for a partial pose those and the
    partial poses of its part."""
    key = str(relative_to).strip().lower()
    if key == "average":
        return None
    parts = (None,) * n_poses if parts is None else parts

    def near(j: int) -> bool:
        return parts[j] is None or parts[j] == parts[k]

    if key == "prev":
        if k == 0:
            raise UsageError("pose 0 has no previous pose to exaggerate against")
        return next(j for j in range(k - 1, -1, -1) if near(j))
    if key == "next":
        if k == n_poses - 1:
            raise UsageError(f"pose {k} is the last; it has no next pose to exaggerate against")
        return next(j for j in range(k + 1, n_poses) if near(j))
    try:
        r = int(key)
    except ValueError:
        raise UsageError(
            f"{arg('relative_to')} takes prev, next, average or a pose index, got {relative_to!r}"
        ) from None
    if not -n_poses <= r < n_poses:
        raise UsageError(f"pose {r} is out of range (the document has poses 0 to {n_poses - 1})")
    r %= n_poses
    if r == k:
        raise UsageError("a pose cannot be exaggerated relative to itself")
    return r


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
        raise UsageError(f"{arg('from_bvh')} needs a BVH document and a BVH file")
    if not -motion.n_frames <= frame < motion.n_frames:
        raise UsageError(f"{arg('frame')} {frame} is out of range (the file has frames 0 to {motion.n_frames - 1})")
    mask = joint_mask(doc, joints, subtree)
    ours = doc.source.skeleton.names
    theirs = {n: j for j, n in enumerate(motion.skeleton.names)}
    rot = motion.local_rotations()[frame]
    tra = motion.local_translations()[frame]
    out = []
    missing: list[str] = []
    for tr, m in zip(doc.tracks, mask, strict=True):
        vals = ops_for(tr.kind).identity((tr.n_vars,))
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
    check_same_bones(doc, motion, frame)
    return out


#: A bone of the pose file may differ from the document's by this fraction
#: of the figure height: the same rig on another actor differs by up to
#: 3.5 % (CMU subjects 02, 05 and 115), a file with other axes (a Blender
#: export turns Y-up offsets to Z-up) by 20 % and more on every long bone.
BONE_TOLERANCE = 0.05


def check_same_bones(doc: Document, motion, frame: int) -> None:
    """Refuse a pose file whose bones differ from the document's.

    Every joint of the document that the file has (matched by name) is
    compared, in hierarchy order, by its parent's name and by its
    translation from its parent: the file's at ``frame`` against the
    document's source at its first frame.  Joints whose translation moves
    in either clip (the root, Bandai's ``Hips``) carry the motion's place,
    not a bone, and are not compared by translation.  The first joint that
    differs (another parent, or a translation more than
    :data:`BONE_TOLERANCE` of the figure height away) raises a DataError
    naming it and by how much.
    """
    src = doc.source
    ours, theirs = src.skeleton, motion.skeleton
    size = float(src.figure_height())
    here, there = src.local_translations(), motion.local_translations()
    still = 1e-6 * size
    index = {n: j for j, n in enumerate(theirs.names)}
    for j, name in enumerate(ours.names):
        i = index.get(name)
        if i is None or ours.parents[j] < 0 or theirs.parents[i] < 0:
            continue
        mine, its = ours.names[ours.parents[j]], theirs.names[theirs.parents[i]]
        if mine != its:
            raise DataError(
                f"the BVH's skeleton differs from the document's at joint {name!r}: its parent is {its!r}, not {mine!r}"
            )
        if np.ptp(here[:, j], axis=0).max() > still or np.ptp(there[:, i], axis=0).max() > still:
            continue
        off = float(np.linalg.norm(there[frame, i] - here[0, j]))
        if off > BONE_TOLERANCE * size:
            raise DataError(
                f"the BVH's skeleton differs from the document's at joint {name!r}: its offset is "
                f"{off:.4g} file units ({100 * off / size:.0f} % of the figure height) from the document's "
                f"(other axes or another rig?); at most {100 * BONE_TOLERANCE:g} % is accepted"
            )


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
