"""Layers of offsets and transition controls (paper sections 3, 4.1.1 and 5).

The motion is a stack ``v = l_0 ⊕ l_1 ⊕ ...``: the base layer ``l_0`` holds
the staggered poses fitted to the capture (splines and displacement maps),
and every layer above it holds offsets at poses of its own, identity when
it is added (so the motion is unchanged).  Editing a pose of a sparse top
layer changes the motion smoothly between that layer's neighbouring poses,
over all the detail below; removing the layer gives the motion back.

Transition controls act on the splines and displacement maps themselves:

* :func:`ease` scales the inner controls of the segments on both sides of a
  pose, about the linear (uniform-speed) ones;
* :func:`detail` scales the displacement maps.

Both change the stored controls, so later culls and retimes keep them: a
cull refits only the segments next to the poses it removes, from the motion
as it is (see :func:`staggered_cli.model.restructure.restructure`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import quat
from ..errors import UsageError, arg
from ..model.document import MAX_LAYERS, Document, check_pose_index, check_pose_move, check_time_range
from ..model.evaluate import evaluate_at
from ..model.kinds import ROTATION
from ..model.knots import Track, offset_layer
from ..model.restructure import sample_times

#: ``--ease`` beyond this is no longer a transition (the controls overshoot).
MAX_EASE = 10.0
#: ``detail --gain`` beyond this amplifies noise into motion of its own.
MAX_GAIN = 10.0
#: ``detail --time A:B`` eases its gain in and out over this long inside the
#: range, so that the motion does not jump at A and B.
DETAIL_RAMP = 0.1


# --- the stack ----------------------------------------------------------------


def layer_times(doc: Document, times: list[float]) -> np.ndarray:
    """Pose times of a new layer: ``times`` (seconds within the clip, half a
    frame of slack), plus the first and last frame, sorted and distinct."""
    half = 0.5 * doc.frame_time
    out = [0.0, doc.duration]
    for t in times:
        if not np.isfinite(t) or not -half <= t <= doc.duration + half:
            raise UsageError(f"{arg('times')}: {t:g} s lies outside the clip (0 to {doc.seconds(doc.duration)})")
        out.append(float(min(max(t, 0.0), doc.duration)))
    t = np.unique(np.array(out))
    keep = np.concatenate([[True], np.diff(t) > 1e-9])
    return t[keep]


def add_layer(doc: Document, pose_t: np.ndarray, parts: tuple[str | None, ...] | None = None) -> Document:
    """The document with a layer of identity offsets at ``pose_t`` on top:
    the motion is unchanged.  ``parts`` (one per pose, None: all whole-body)
    makes some of the layer's poses partial: offsets only in their body
    part's variables (e.g. the parts of the base poses a ``keep`` chose)."""
    pose_t = np.asarray(pose_t, dtype=float)
    if len(pose_t) < 2 or pose_t[0] != 0.0 or abs(pose_t[-1] - doc.duration) > 1e-9 or np.any(np.diff(pose_t) <= 0):
        raise ValueError("a layer's poses run from the first frame to the last, strictly increasing")
    if doc.n_layers >= MAX_LAYERS:
        raise UsageError(f"the document already has {doc.n_layers} layers (at most {MAX_LAYERS})")
    parts = (None,) * len(pose_t) if parts is None else tuple(parts)
    if len(parts) != len(pose_t) or parts[0] is not None or parts[-1] is not None:
        raise ValueError("a layer's parts: one per pose, the first and last whole-body")
    owns = np.ones((len(pose_t), len(doc.variable_names)), dtype=bool)
    for k, p in enumerate(parts):
        if p is not None:
            owns[k] = doc.part_mask(p)
    tracks, col = [], 0
    for tr in doc.tracks:
        mine = owns[:, col : col + tr.n_vars]
        col += tr.n_vars
        tracks.append(tr.with_layer(len(tr.layers), offset_layer(tr.kind, tr.n_vars, pose_t, mine)))
    return replace(
        doc,
        tracks=tuple(tracks),
        layer_pose_t=doc.layer_pose_t + (pose_t,),
        layer_pose_part=doc.layer_pose_part + (parts,),
    )


def remove_layer(doc: Document, layer: int) -> Document:
    """The document without layer ``layer`` (>= 1): the motion the layers
    below and above it give, exactly."""
    if not 1 <= layer < doc.n_layers:
        if doc.n_layers == 1:
            raise UsageError(
                f"{arg('layer', '--remove')} {layer}: the document has only its base layer (0), which stays"
            )
        raise UsageError(
            f"{arg('layer', '--remove')} takes a layer from 1 to {doc.n_layers - 1} (the base layer 0 stays), "
            f"got {layer}"
        )
    tracks = tuple(tr.without_layer(layer) for tr in doc.tracks)
    poses = doc.layer_pose_t[: layer - 1] + doc.layer_pose_t[layer:]
    parts = doc.layer_pose_part[: layer - 1] + doc.layer_pose_part[layer:]
    return replace(doc, tracks=tracks, layer_pose_t=poses, layer_pose_part=parts)


def layer_rows(doc: Document) -> list[dict]:
    """One entry per layer: its index, pose times, and how far its offsets
    reach (largest rotation in degrees, largest translation in file units)."""
    rows = []
    for n in range(doc.n_layers):
        row = {"layer": n, "poses": [round(float(t), 9) for t in doc.poses_of(n)]}
        if n > 0:
            rot = trans = 0.0
            for tr in doc.tracks:
                v = tr.layers[n].knots.v
                if not len(v):
                    continue
                if tr.kind == ROTATION:
                    rot = max(rot, float(np.degrees(quat.angle(v)).max()))
                else:
                    trans = max(trans, float(np.linalg.norm(v, axis=1).max()))
            row["largest_rotation"] = round(rot, 6)
            row["largest_translation"] = round(trans, 6)
        rows.append(row)
    return rows


def stack_values(track: Track, t: float, lo: int = 0, hi: int | None = None) -> np.ndarray:
    """(V, D) the layers ``lo:hi`` of ``track`` folded at time ``t``
    (identity for an empty range)."""
    hi = len(track.layers) if hi is None else hi
    if hi <= lo:
        return track.ops.identity((track.n_vars,))
    sub = replace(track, layers=track.layers[lo:hi])
    return evaluate_at(sub, np.arange(track.n_vars), np.full(track.n_vars, float(t)))


def pose_values(doc: Document, layer: int, k: int) -> list[np.ndarray]:
    """Per track, the (V, D) values the whole stack gives at pose ``k`` of ``layer``."""
    t = doc.poses_of(layer)[k]
    return [stack_values(tr, t) for tr in doc.tracks]


def apply_offset(doc: Document, layer: int, k: int, deltas: list[np.ndarray | None]) -> Document:
    """Change pose ``k`` of ``layer`` (>= 1) so that the motion there becomes
    ``v ⊕ Δ`` (``deltas``: per track (V, D) or None), exactly.

    With ``v = below ⊕ o ⊕ above`` the layer's offset becomes
    ``o ⊕ above ⊕ Δ ⊕ above⁻¹`` (for translations simply ``o + Δ``): the
    change is the same in the frame of the whole stack whichever layer takes
    it.
    """
    t = doc.poses_of(layer)[k]
    tracks = []
    for tr, d in zip(doc.tracks, deltas, strict=True):
        if d is None:
            tracks.append(tr)
            continue
        ops = tr.ops
        lay = tr.layers[layer]
        mine = np.flatnonzero(lay.knots.pose == k)  # one knot per variable it owns, in variable order
        var = lay.knots.var[mine]
        above = stack_values(tr, t, layer + 1)
        change = ops.oplus(ops.oplus(above, d), ops.ominus(ops.identity((tr.n_vars,)), above))
        v = lay.knots.v.copy()
        v[mine] = ops.normalize(ops.oplus(v[mine], change[var]))
        tracks.append(tr.with_knot_values(v, layer))
    return doc.with_tracks(tuple(tracks))


def retime_layer_pose(doc: Document, layer: int, k: int, new_time: float) -> Document:
    """Move pose ``k`` of ``layer`` (>= 1) to ``new_time`` seconds, between its
    neighbours: its offsets move with it."""
    check_pose_move(doc, k, new_time, layer)
    new_times = doc.poses_of(layer).copy()
    new_times[k] = new_time
    tracks = []
    for tr in doc.tracks:
        lay = tr.layers[layer]
        knots = lay.knots.with_times(new_times[lay.knots.pose])
        tracks.append(tr.with_layer(layer, replace(lay, knots=knots)))
    poses = list(doc.layer_pose_t)
    poses[layer - 1] = new_times
    return replace(doc, tracks=tuple(tracks), layer_pose_t=tuple(poses))


# --- transition controls ------------------------------------------------------


def ease(doc: Document, k: int, x: float, *, layer: int = 0, masks: list[np.ndarray] | None = None) -> Document:
    """Scale the inner spline controls of the segments on both sides of pose
    ``k`` of ``layer`` about the linear ones: ``c = c_lin + x (c - c_lin)``.

    ``x = 1`` leaves them, ``0`` makes the transitions uniform-speed (a
    straight line, a slerp), above 1 holds longer at the pose.  Every segment
    with a knot of pose ``k`` is scaled (a staggered pose's segment between
    its editing and extreme knots too), for the variables in ``masks`` (per
    track (V,) bool, None: all).  The displacement maps keep the detail.
    """
    check_ease(x)
    k = check_pose_index(doc, k, layer)
    tracks = []
    for n, tr in enumerate(doc.tracks):
        lay = tr.layers[layer]
        knots = lay.knots
        seg_var, first = knots.seg_var, knots.seg_first
        hit = (knots.pose[first] == k) | (knots.pose[first + 1] == k)
        if masks is not None:
            hit &= masks[n][seg_var]
        if not hit.any():
            tracks.append(tr)
            continue
        f = first[hit]
        a_lin, b_lin = tr.ops.linear_controls(knots.v[f], knots.v[f + 1])
        tan_a, tan_b = lay.tan_a.copy(), lay.tan_b.copy()
        tan_a[hit] = a_lin + x * (lay.tan_a[hit] - a_lin)
        tan_b[hit] = b_lin + x * (lay.tan_b[hit] - b_lin)
        tracks.append(tr.with_layer(layer, replace(lay, tan_a=tan_a, tan_b=tan_b)))
    return doc.with_tracks(tuple(tracks))


def check_gain(gain: float) -> None:
    """Refuse a ``detail --gain`` outside 0 to :data:`MAX_GAIN`."""
    if not np.isfinite(gain) or not 0.0 <= gain <= MAX_GAIN:
        raise UsageError(f"{arg('gain')} must be a number from 0 to {MAX_GAIN:g}, got {gain:g}")


def check_ease(x: float) -> None:
    """Refuse an ``--ease`` outside 0 to :data:`MAX_EASE`."""
    if not np.isfinite(x) or not 0.0 <= x <= MAX_EASE:
        raise UsageError(f"{arg('ease')} must be a number from 0 to {MAX_EASE:g}, got {x:g}")


def detail_gain(t: np.ndarray, gain: float, time_range: tuple[float, float] | None, duration: float) -> np.ndarray:
    """The gain at times ``t``: ``gain`` inside ``time_range`` (all the clip
    when None), 1 outside, eased over :data:`DETAIL_RAMP` inside the range's
    ends that are not the clip's."""
    t = np.asarray(t, dtype=float)
    if time_range is None:
        return np.full(len(t), float(gain))
    a, b = time_range
    ramp = min(DETAIL_RAMP, 0.25 * (b - a)) if b > a else 0.0
    w = np.ones(len(t))
    if a > 0.0 and ramp > 0:
        w = np.minimum(w, np.clip((t - a) / ramp, 0.0, 1.0))
    if b < duration and ramp > 0:
        w = np.minimum(w, np.clip((b - t) / ramp, 0.0, 1.0))
    w = np.where((t < a - 1e-9) | (t > b + 1e-9), 0.0, w)
    w = w * w * (3.0 - 2.0 * w)  # smoothstep: no kink where the ramp starts
    return 1.0 + (float(gain) - 1.0) * w


def detail(
    doc: Document,
    gain: float,
    *,
    masks: list[np.ndarray] | None = None,
    time_range: tuple[float, float] | None = None,
) -> Document:
    """Scale the displacement maps of every layer by ``gain``: 0 leaves the
    splines alone, 1 changes nothing, 0.5 softens the capture's jitter, 1.5
    accentuates it.  ``masks`` (per track (V,) bool) limits it to some
    variables, ``time_range`` (A, B) seconds to part of the clip (see
    :func:`detail_gain`)."""
    check_gain(gain)
    if time_range is not None:
        check_time_range(doc, time_range)
    tracks = []
    for n, tr in enumerate(doc.tracks):
        for li, lay in enumerate(tr.layers):
            if not lay.has_detail:
                continue
            owner = lay.samp_var
            times = np.concatenate([sample_times(tr, i, li) for i in range(tr.n_vars)])
            g = detail_gain(times, gain, time_range, doc.duration)
            if masks is not None:
                g = np.where(masks[n][owner], g, 1.0)
            if np.all(g == 1.0):
                continue
            d = tr.ops.normalize(tr.ops.scale(lay.samp_d, g))
            d = np.where((g == 1.0)[:, None], lay.samp_d, d)  # exactly as they were outside
            tr = tr.with_layer(li, replace(lay, samp_d=d))
        tracks.append(tr)
    return doc.with_tracks(tuple(tracks))
