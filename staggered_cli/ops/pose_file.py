"""Poses out to a DCC and back, and new motion from key poses (issue 15).

* :func:`export_poses`: the document's poses as a BVH clip, frame k = pose k,
  in the source's skeleton, channel layout, Euler orders (on the source's
  branch) and number format.
* :func:`apply_pose_file`: every frame k of such a file applied to pose k as
  a geometric edit, only where it differs from the document's pose.
* :func:`check_same_skeleton`: the file has the document's joints, in order,
  with the same offsets.
* :func:`new_document`: a document whose poses are the frames of a sparse
  BVH (key poses blocked in a DCC), joined by smooth cubic splines.
"""

from __future__ import annotations

import numpy as np

from .. import quat
from ..errors import DataError, UsageError, arg, warn
from ..model.document import Document, require_bvh, variable_layout
from ..model.evaluate import evaluate_at
from ..model.fit import knots_from_poses
from ..model.kinds import ROTATION, TRANSLATION, ops_for
from ..model.knots import Layer, Track, pose_arrays
from ..model.sampling import reference_channels
from ..motion import BvhMotion, channels_from_local, nominal_rate
from .edit_pose import joint_mask

#: What counts as a change when a pose file comes back (issue 15).
ROTATION_CHANGED = 0.01  # degrees
TRANSLATION_CHANGED = 1e-5  # of figure height
#: Offsets of a pose file must match the document's to this fraction of the
#: figure height: float32 round trips (Blender) pass, an axis conversion fails.
OFFSET_TOLERANCE = 1e-4



def _on(on: str) -> str:
    if on not in ("true", "extreme"):
        raise UsageError(f"{arg('on')} must be 'true' or 'extreme', got {on!r}")
    return on


def pose_locals(doc: Document, on: str = "true") -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (K, J, 4) and translations (K, J, 3) of every pose:
    the true pose at t_k (``on='true'``) or the non-staggered pose.  A
    partial pose holds the whole figure at its time: outside its part, the
    values the spline layer passes through there."""
    src = require_bvh(doc, "export-poses")
    sk = src.skeleton
    K = doc.n_poses
    rot = quat.identity((K, sk.n_joints))
    tra = np.broadcast_to(sk.offsets, (K, sk.n_joints, 3)).copy()
    for tr, owns in zip(doc.tracks, doc.track_owns(), strict=True):
        _, value, edit = pose_arrays(tr, K)
        vals = edit if _on(on) == "true" else value  # (K, V, D)
        kk, ii = np.nonzero(~owns)
        if len(kk):
            vals = vals.copy()
            vals[kk, ii] = evaluate_at(tr, ii, doc.pose_t[kk], depth=1)
        if tr.kind == ROTATION:
            rot[:, tr.targets] = vals
        else:
            tra[:, tr.targets] = vals
    return rot, tra


def export_poses(doc: Document, on: str = "true") -> BvhMotion:
    """The poses of ``doc`` as a BVH clip of ``n_poses`` frames (frame k is
    pose k), with the source's skeleton, channels, frame time and number
    format; Euler triples nearest the source's channels at t_k."""
    src = require_bvh(doc, "export-poses")
    _warn_layers(doc, "export-poses")
    rot, tra = pose_locals(doc, on)
    ref = reference_channels(doc, doc.pose_t)
    # a pose on a source frame takes that frame's own numbers as the
    # reference (its wraps and -0 included); between frames, the unwrapped blend
    f = np.rint(doc.pose_t / doc.frame_time).astype(int)
    on_frame = (np.abs(f * doc.frame_time - doc.pose_t) < 1e-9) & (f >= 0) & (f < doc.n_frames)
    ref = np.where(on_frame[:, None], src.channels[np.clip(f, 0, doc.n_frames - 1)], ref)
    channels = channels_from_local(src.skeleton, rot, tra, ref)
    # where a pose is the source's to rounding noise, write the source's own
    # numbers (its -0 and last digit included), as bake does
    channels = np.where(np.abs(channels - ref) < 1e-9, ref, channels)
    return src.with_channels(channels, same_text=False)


def _warn_layers(doc: Document, what: str) -> None:
    """One warning line when layers above the base change the motion: the
    poses ``what`` works on are the base layer's, not what ``bake`` gives."""
    if doc.n_layers > 1:
        n = doc.n_layers - 1
        above = "the layer above it stays" if n == 1 else f"the {n} layers above it stay"
        warn("%s works on the base layer's poses; %s as it is (see `layer --list`)", what, above)


def frame_note(doc: Document, name: str) -> str:
    """The stderr line of ``export-poses``: how frames map to poses."""
    t = doc.pose_t
    # to the frames' precision, as every message prints times (0.567 s at 120 Hz)
    times = ", ".join(doc.seconds(x)[:-2] for x in t[:3]) + (", ..." if len(t) > 3 else "")
    return (
        f"{name}: {len(t)} frames, frame k is pose k (t = {times} s; last {doc.seconds(t[-1])}); "
        "Blender shows frame k as frame k+1"
    )


def check_same_skeleton(doc: Document, motion: BvhMotion, name: str | None = None) -> None:
    """Refuse a pose file whose hierarchy or offsets differ from the document's.

    Joint names and parents must be the same, in order; every offset must be
    within :data:`OFFSET_TOLERANCE` of the figure height of the document's.
    Raises DataError naming the first joint that differs and by how much.
    """
    src = require_bvh(doc, arg("from_bvh"))
    if not isinstance(motion, BvhMotion):
        raise UsageError(f"{arg('from_bvh')} needs a BVH file", name)
    ours, theirs = src.skeleton, motion.skeleton
    if ours.names != theirs.names:
        diff = next((i for i, (a, b) in enumerate(zip(ours.names, theirs.names, strict=False)) if a != b), None)
        if diff is None:
            raise DataError(f"has {theirs.n_joints} joints, the document {ours.n_joints}: a different skeleton", name)
        raise DataError(
            f"joint {diff} is {theirs.names[diff]!r}, the document's is {ours.names[diff]!r}: a different skeleton",
            name,
        )
    if not np.array_equal(ours.parents, theirs.parents):
        j = int(np.flatnonzero(ours.parents != theirs.parents)[0])
        raise DataError(f"joint {ours.names[j]!r} has another parent than in the document", name)
    size = src.figure_height()
    off = np.linalg.norm(theirs.offsets - ours.offsets, axis=1)
    bad = np.flatnonzero(off > OFFSET_TOLERANCE * size)
    if len(bad):
        j = int(bad[0])
        raise DataError(
            f"the offset of joint {ours.names[j]!r} differs from the document's by {off[j]:.4g} "
            f"({off[j] / size:.2g} of the figure height): another skeleton, or an axis conversion on "
            "import or export (import with forward Y, up Z)",
            name,
        )


def apply_pose_file(
    doc: Document,
    motion: BvhMotion,
    *,
    on: str = "true",
    joints: list[str] | None = None,
    subtree: bool = False,
    name: str | None = None,
) -> tuple[Document, int, int]:
    """Apply frame k of ``motion`` to pose k of ``doc``, for every pose.

    A variable changes only where the file differs from the document's pose
    (``on='true'``: the pose at t_k; ``'extreme'``: the non-staggered pose)
    by more than :data:`ROTATION_CHANGED` degrees or
    :data:`TRANSLATION_CHANGED` of the figure height; its knots of that pose
    then receive the change (the mutually constrained pair, as in
    :func:`~staggered_cli.ops.edit_pose.edit_pose`).  Other poses keep
    their knots bit for bit.  The whole pose comes from the file, the root's
    translation included, within the ``joints``/``subtree`` mask; for a
    partial pose only its part's variables (the others have no knot of it),
    with a warning when the file changes others at its frame.

    Returns the document, the number of poses changed and the number of
    joints changed (over all poses, each joint counted once).

    Raises
    ------
    UsageError when the file's frame count is not the pose count, or when it
    moves a joint the document cannot move (no such channels); DataError
    when its skeleton differs (:func:`check_same_skeleton`).
    """
    _warn_layers(doc, f"edit-pose {arg('all')}")
    _on(on)
    check_same_skeleton(doc, motion, name)
    if motion.n_frames != doc.n_poses:
        raise UsageError(
            f"has {motion.n_frames} frames but the document has {doc.n_poses} poses: "
            f"{arg('all')} needs frame k for pose k",
            name,
        )
    sk = doc.source.skeleton
    size = doc.source.figure_height()
    file_rot, file_tra = motion.local_rotations(), motion.local_translations()
    doc_rot, doc_tra = pose_locals(doc, on)
    rot_changed = np.degrees(quat.angle_between(doc_rot, file_rot)) > ROTATION_CHANGED  # (K, J)
    tra_changed = np.linalg.norm(file_tra - doc_tra, axis=-1) > TRANSLATION_CHANGED * size
    mask = joint_mask(doc, joints, subtree)
    movable = {ROTATION: np.zeros(sk.n_joints, dtype=bool), TRANSLATION: np.zeros(sk.n_joints, dtype=bool)}
    allowed = np.zeros(sk.n_joints, dtype=bool)
    for tr, m in zip(doc.tracks, mask, strict=True):
        movable[tr.kind][tr.targets] = True
        allowed[tr.targets[m]] = True
    if not joints:
        allowed[:] = True
    for changed, kind, what in ((rot_changed, ROTATION, "rotates"), (tra_changed, TRANSLATION, "translates")):
        stuck = changed & ~movable[kind][None, :] & allowed[None, :]
        if stuck.any():
            k, j = (int(x[0]) for x in np.nonzero(stuck))
            channels = "rotation" if kind == ROTATION else "position"
            raise UsageError(
                f"frame {k} {what} joint {sk.names[j]!r}, which has no {channels} channels in the document: "
                "cannot apply it",
                name,
            )
    tracks, touched = [], np.zeros((doc.n_poses, sk.n_joints), dtype=bool)
    outside = np.zeros((doc.n_poses, sk.n_joints), dtype=bool)  # changes a partial pose has no knot for
    per_kind = {ROTATION: (rot_changed, doc_rot, file_rot), TRANSLATION: (tra_changed, doc_tra, file_tra)}
    for tr, m, owns in zip(doc.tracks, mask, doc.track_owns(), strict=True):
        t = tr.targets
        op = ops_for(tr.kind)
        changed, ours, theirs = per_kind[tr.kind]
        outside[:, t] |= changed[:, t] & m[None, :] & ~owns
        change = changed[:, t] & m[None, :] & owns
        delta = op.ominus(theirs[:, t], ours[:, t])  # (K, V, D): v_new ⊖ v
        if not change.any():
            tracks.append(tr)
            continue
        touched[:, t] |= change
        var = tr.knots.var
        hit = change[tr.knot_pose, var]
        knot_v = tr.knot_v.copy()
        d = delta[tr.knot_pose[hit], var[hit]]
        knot_v[hit] = op.normalize(op.oplus(tr.knot_v[hit], d))  # unit quaternions stay unit
        tracks.append(_with_knot_values(tr, knot_v))
    if outside.any():
        poses = np.flatnonzero(outside.any(axis=1))
        k = int(poses[0])
        warn(
            "%d frame%s of the file change%s joints outside %s partial pose's part (frame %d: %s, outside %s): "
            "left as they are (a partial pose owns only its part)",
            len(poses),
            "s" if len(poses) > 1 else "",
            "" if len(poses) > 1 else "s",
            "their" if len(poses) > 1 else "its",
            k,
            ", ".join(sk.names[j] for j in np.flatnonzero(outside[k])[:3]),
            doc.pose_part[k],
        )
    return doc.with_tracks(tuple(tracks)), int(touched.any(axis=1).sum()), int(touched.any(axis=0).sum())


def _with_knot_values(tr: Track, knot_v: np.ndarray) -> Track:
    return tr.with_knot_values(knot_v)


# --- new motion from key poses -------------------------------------------------


def check_key_times(times: np.ndarray, n_keys: int, frame_time: float) -> np.ndarray:
    """Key times (seconds) checked: one per key, from 0, strictly increasing,
    the last on a frame of ``frame_time`` (within a thousandth of a frame,
    so that times copied from ``info``'s six digits pass).  Raises
    UsageError.

    A written frame time is often a rounded reciprocal of the rate
    (``0.008333`` for 120 Hz).  Times typed on the nominal rate's clock
    (:func:`~staggered_cli.motion.nominal_rate`: 2.2 s is frame 264 at
    120 Hz) are then carried to the written frame time's clock, which frames
    and pose times use everywhere else (frame 264 is at 2.199912 s); times
    already on it stay.  The last time is returned exactly on its frame.
    """
    times = np.asarray(times, dtype=float)
    if times.shape != (n_keys,):
        raise UsageError(f"{arg('times')} gives {len(times)} times for the file's {n_keys} frames")
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise UsageError(f"{arg('times')} must increase strictly")
    if abs(times[0]) > 1e-9:
        raise UsageError(
            f"{arg('times')} must start at 0 (the first key is the motion's first frame), got {times[0]:g}"
        )
    rate = nominal_rate(frame_time)
    written, nominal = times[-1] / frame_time, times[-1] * rate
    on_nominal = abs(nominal - round(nominal)) < abs(written - round(written))
    frame = nominal if on_nominal else written
    if abs(frame - round(frame)) > 1e-3:
        raise UsageError(
            f"the last time {times[-1]:g} s is not on a frame at the file's frame time {frame_time:g} s "
            f"(nearest: {np.floor(nominal) / rate:.6g} or {np.ceil(nominal) / rate:.6g} s)"
        )
    out = times * (rate * frame_time) if on_nominal else times.copy()
    out[-1] = round(frame) * frame_time
    return out


def blocking_velocities(t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Velocities (K, ..., 3) at the keys for a blocking pass, per component,
    like Blender's Auto Clamped handles: the time-weighted average of the two
    neighbouring slopes, zero at a key that is a local extreme (the slopes
    change sign or one is zero) and at the first and last key, and at most
    three times the smaller slope, so that no segment overshoots its keys.

    ``values`` (K, ...) are positions (file units); rotations use the same
    rule on angular velocities (:func:`blocking_rotation_tangents`).
    """
    h = np.diff(t).reshape((-1,) + (1,) * (values.ndim - 1))
    slopes = np.diff(values, axis=0) / h  # (K-1, ...)
    return _clamped_average(t, slopes[:-1], slopes[1:])


def _clamped_average(t: np.ndarray, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Interior key velocities from the slopes left and right of each key
    (K-2, ...), with zero at both ends: (K, ...)."""
    h = np.diff(t)
    shape = (-1,) + (1,) * (left.ndim - 1)
    hl, hr = h[:-1].reshape(shape), h[1:].reshape(shape)
    m = (left * hr + right * hl) / (hl + hr)
    same = (np.sign(left) == np.sign(right)) & (left != 0) & (right != 0)
    limit = 3.0 * np.minimum(np.abs(left), np.abs(right))
    m = np.where(same, np.sign(m) * np.minimum(np.abs(m), limit), 0.0)
    z = np.zeros((1,) + left.shape[1:])
    return np.concatenate([z, m, z])


def blocking_translation_tangents(t: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Relative Bézier controls (K-1, V, 3) of the segments between keys
    ``p`` (K, V, 3) at times ``t`` (K,): ``P1 = p_k + a``, ``P2 = p_{k+1} + b``."""
    m = blocking_velocities(t, p)
    h = np.diff(t)[:, None, None]
    return h * m[:-1] / 3.0, -h * m[1:] / 3.0


def blocking_rotation_tangents(t: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation-vector tangents (K-1, V, 3) of the recursive-slerp cubic
    between keys ``q`` (K, V, 4) at times ``t``: the same rule as for
    translations on angular velocities in each key's local frame (the slope
    into a key, ``log(q_{k-1}^-1 q_k) / h``, is the same vector in both
    keys' frames).  With ``q1 = q0 exp(a)`` the cubic leaves ``q0`` at
    ``3a`` per unit of normalized time, so ``a = h ω_k / 3``, ``b = -h ω_{k+1} / 3``."""
    h = np.diff(t)
    step = quat.log(quat.mul(quat.conj(q[:-1]), q[1:]))  # (K-1, V, 3), radians
    slopes = step / h[:, None, None]
    w = _clamped_average(t, slopes[:-1], slopes[1:])
    return h[:, None, None] * w[:-1] / 3.0, -h[:, None, None] * w[1:] / 3.0


def _key_track(kind: str, names, targets, t: np.ndarray, keys: np.ndarray) -> Track:
    """A track with one unrefined knot per key, blocking tangents and empty
    displacement maps (keys (K, V, D))."""
    K, V = keys.shape[:2]
    knots = knots_from_poses(t, np.zeros((K, V)), keys, keys, names)
    if kind == TRANSLATION:
        a, b = blocking_translation_tangents(t, keys)
    else:
        a, b = blocking_rotation_tangents(t, keys)
    # segments are stored per variable: (V, K-1, 3) in CSR order
    a = np.transpose(a, (1, 0, 2)).reshape(-1, 3)
    b = np.transpose(b, (1, 0, 2)).reshape(-1, 3)
    d = keys.shape[-1]
    empty = np.zeros(V + 1, dtype=int)
    layer = Layer(knots, a, b, empty, np.zeros(0), np.zeros((0, d)))
    return Track(kind, tuple(names), np.asarray(targets, dtype=int), (layer,))


def new_document(
    keys: BvhMotion,
    times: np.ndarray | None = None,
    *,
    source_name: str = "",
    source_bytes: bytes | None = None,
) -> Document:
    """A document whose poses are the frames of ``keys`` at ``times``
    (seconds; default: the file's own frame times).

    Cubic splines pass through the keys with blocking tangents
    (:func:`blocking_velocities`), the displacement maps are empty.  The
    document's source, which baking and the other operations read, is that
    motion sampled at the file's frame time from 0 to the last key.
    """
    import hashlib

    from ..model.document import Document as Doc
    from ..model.evaluate import evaluate

    if keys.n_frames < 2:
        raise UsageError("new needs at least two key poses (frames)")
    ft = keys.frame_time
    t = check_key_times(np.arange(keys.n_frames) * ft if times is None else times, keys.n_frames, ft)
    rot = quat.unroll(keys.local_rotations(), axis=0)
    tra = keys.local_translations()
    tracks = []
    for kind, names, targets in variable_layout(keys):
        vals = rot[:, targets] if kind == ROTATION else tra[:, targets]
        tracks.append(_key_track(kind, names, targets, t, vals))
    n = int(round(t[-1] / ft)) + 1
    frame_t = np.minimum(np.arange(n) * ft, t[-1])
    sk = keys.skeleton
    drot = quat.identity((n, sk.n_joints))
    dtra = np.broadcast_to(sk.offsets, (n, sk.n_joints, 3)).copy()
    for tr in tracks:
        v = evaluate(tr, frame_t)
        if tr.kind == ROTATION:
            drot[:, tr.targets] = v
        else:
            dtra[:, tr.targets] = v
    # Euler branch: the keys' own channels, unwrapped and joined linearly
    from ..motion import rotation_columns

    ch = keys.channels.copy()
    cols = [c for _, cc, _ in rotation_columns(sk) for c in cc]
    ch[:, cols] = np.unwrap(ch[:, cols], period=360.0, axis=0)
    ref = np.stack([np.interp(frame_t, t, ch[:, c]) for c in range(ch.shape[1])], axis=1) if ch.shape[1] else ch
    dense = channels_from_local(sk, drot, dtra, ref)
    source = keys.with_channels(dense, same_text=False, decimals=6)
    priority = np.zeros(len(t))
    priority[[0, -1]] = np.inf
    return Doc(
        pose_t=t,
        priority=priority,
        tracks=tuple(tracks),
        source=source,
        source_name=source_name,
        source_sha256=hashlib.sha256(source_bytes).hexdigest() if source_bytes is not None else "",
        parameters={"new": {"keys": int(keys.n_frames), "times": [float(x) for x in t]}},
    )
