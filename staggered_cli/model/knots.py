"""Knots, layers and tracks: the staggered-pose representation in memory (paper section 3, SPEC section 3).

Motion is a sequence of staggered poses at times ``t_k``.  For every control
variable ``i`` the poses give knots: an *extreme knot* at ``t_k + r[k,i]``
with the extreme value ``v[k,i]`` and, where ``r[k,i] != 0``, an *editing
knot* at exactly ``t_k`` with the value the motion has at the pose time.
Between two consecutive knots of a variable lies a segment carrying a cubic
spline on normalized time ``u`` and a displacement map.

Storage is one :class:`Track` per kind of variable (translations, rotations),
ragged per variable in CSR layout:

* knots ``knot_t[knot_ptr[i]:knot_ptr[i+1]]`` (strictly increasing),
* segments ``seg_ptr[i] = knot_ptr[i] - i`` with relative tangents ``tan_a``,
  ``tan_b`` (see :mod:`.segments`),
* displacement samples at *knot coordinates* ``s = segment + u``.  The knot
  coordinate of a sample does not change when knots are retimed, so the
  detail is stretched with the segment, never lost.  Every displacement map
  is the identity at the knots (``s`` integer), which is what lets an edit of
  a knot value move the motion through the new value exactly.

Evaluation is ``v_i(t) = s_i(u) ⊕ d_i(u)`` (:mod:`.evaluate`); the splines
and displacement maps are fitted by :mod:`.fit` and refitted to new knots by
:mod:`.restructure`.  Operations never mutate a track; they return new ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import kinds
from .kinds import ROTATION, TRANSLATION

DIM = {TRANSLATION: 3, ROTATION: 4}
_AT_KNOT = 1e-9  # seconds: a sample this close to a knot is the knot


@dataclass(frozen=True)
class Knots:
    """The knots of every variable of a track, in CSR layout.

    Attributes
    ----------
    ptr : (V+1,) int, offsets: variable ``i`` owns knots ``ptr[i]:ptr[i+1]``.
    t : (NK,) knot times in seconds (strictly increasing per variable).
    v : (NK, D) knot values.
    pose : (NK,) int, the staggered pose (of the knots' layer) each knot belongs to.
    editing : (NK,) bool, True for editing knots (at ``t_k``).
    """

    ptr: np.ndarray
    t: np.ndarray
    v: np.ndarray
    pose: np.ndarray
    editing: np.ndarray

    @property
    def n_vars(self) -> int:
        return len(self.ptr) - 1

    @property
    def var(self) -> np.ndarray:
        """(NK,) the variable each knot belongs to."""
        return np.repeat(np.arange(self.n_vars), np.diff(self.ptr))

    @property
    def seg_ptr(self) -> np.ndarray:
        """(V+1,) offsets of the segments (one fewer than the knots per variable)."""
        return self.ptr - np.arange(self.n_vars + 1)

    @property
    def seg_var(self) -> np.ndarray:
        """(S,) the variable each segment belongs to."""
        return np.repeat(np.arange(self.n_vars), np.diff(self.seg_ptr))

    @property
    def seg_first(self) -> np.ndarray:
        """(S,) the index of each segment's first knot (its second is the next)."""
        seg_ptr, seg_var = self.seg_ptr, self.seg_var
        return self.ptr[seg_var] + (np.arange(int(seg_ptr[-1])) - seg_ptr[seg_var])

    def of(self, i: int) -> slice:
        return slice(int(self.ptr[i]), int(self.ptr[i + 1]))

    def subset(self, keep: np.ndarray, pose: np.ndarray | None = None) -> Knots:
        """The knots where ``keep`` (NK,) is True, with ``pose`` (NK,) as their
        new pose indices (default: unchanged)."""
        keep = np.asarray(keep, dtype=bool)
        ptr = np.concatenate([[0], np.cumsum(np.bincount(self.var[keep], minlength=self.n_vars))]).astype(int)
        new_pose = self.pose if pose is None else np.asarray(pose, dtype=int)
        return Knots(ptr, self.t[keep], self.v[keep], new_pose[keep], self.editing[keep])

    def with_values(self, v: np.ndarray) -> Knots:
        return replace(self, v=np.asarray(v, dtype=float))

    def with_times(self, t: np.ndarray) -> Knots:
        return replace(self, t=np.asarray(t, dtype=float))


@dataclass(frozen=True)
class Fitted:
    """The spline ``values`` (NS, D) of a layer at its samples, and the arrays
    of the layer they were computed from (the same objects: a layer made
    from it by ``replace`` with other knots, tangents or samples does not
    hold them, so its spline is evaluated; a layer's arrays are never
    changed in place)."""

    knots: Knots
    tan_a: np.ndarray
    tan_b: np.ndarray
    samp_ptr: np.ndarray
    samp_s: np.ndarray
    values: np.ndarray


@dataclass(frozen=True)
class Layer:
    """One layer of a track: a spline over its knots and a displacement map.

    Attributes
    ----------
    knots : the layer's knots.  The base layer (layer 0) holds the staggered
        poses of the document; a layer above it holds offsets at its own poses.
    tan_a, tan_b : (NK - V, 3) relative inner controls of each segment
        (see :mod:`.segments`).
    samp_ptr : (V+1,) int, CSR offsets into the sample arrays.
    samp_s : (NS,) knot coordinates (segment + u) of displacement samples.
    samp_d : (NS, D) displacement values (vectors, or unit quaternions).
    fitted : the spline at the samples as the fit computed it, for an
        evaluation in the same process (see :func:`fitted_spline`); in
        memory only, never written, and not part of the layer's value.
    """

    knots: Knots
    tan_a: np.ndarray
    tan_b: np.ndarray
    samp_ptr: np.ndarray
    samp_s: np.ndarray
    samp_d: np.ndarray
    fitted: Fitted | None = field(default=None, compare=False, repr=False)

    def samples(self, i: int) -> slice:
        return slice(int(self.samp_ptr[i]), int(self.samp_ptr[i + 1]))

    @property
    def samp_var(self) -> np.ndarray:
        """(NS,) the variable each displacement sample belongs to."""
        return np.repeat(np.arange(self.knots.n_vars), np.diff(self.samp_ptr))

    @property
    def has_detail(self) -> bool:
        return len(self.samp_s) > 0


@dataclass(frozen=True)
class Track:
    """All control variables of one kind, as a stack of layers.

    Attributes
    ----------
    kind : ``'translation'`` (values (..., 3), file units) or ``'rotation'``
        (values (..., 4), unit quaternions w first).
    names : (V,) variable names (``JOINT`` for rotations, ``JOINT.position``
        for BVH translations, the marker label for C3D).
    targets : (V,) int, the joint or marker each variable drives.
    layers : the stack, bottom first.  Layer 0 is fitted to the motion; the
        motion is ``layer_0 ⊕ layer_1 ⊕ ...`` (the order matters for
        rotations: each layer acts in the frame of the ones below).

    The ``knot_*``, ``tan_*`` and ``samp_*`` attributes are the base layer's.
    """

    kind: str
    names: tuple[str, ...]
    targets: np.ndarray
    layers: tuple[Layer, ...]

    @property
    def n_vars(self) -> int:
        return len(self.names)

    @property
    def dim(self) -> int:
        return DIM[self.kind]

    @property
    def ops(self) -> kinds.KindOps:
        return kinds.ops_for(self.kind)

    @property
    def base(self) -> Layer:
        return self.layers[0]

    @property
    def knots(self) -> Knots:
        """The base layer's knots (the document's staggered poses)."""
        return self.layers[0].knots

    # the base layer, by its old names
    knot_ptr = property(lambda self: self.layers[0].knots.ptr)
    knot_t = property(lambda self: self.layers[0].knots.t)
    knot_v = property(lambda self: self.layers[0].knots.v)
    knot_pose = property(lambda self: self.layers[0].knots.pose)
    knot_editing = property(lambda self: self.layers[0].knots.editing)
    tan_a = property(lambda self: self.layers[0].tan_a)
    tan_b = property(lambda self: self.layers[0].tan_b)
    samp_ptr = property(lambda self: self.layers[0].samp_ptr)
    samp_s = property(lambda self: self.layers[0].samp_s)
    samp_d = property(lambda self: self.layers[0].samp_d)

    @property
    def seg_ptr(self) -> np.ndarray:
        return self.knots.seg_ptr

    def knot_slice(self, i: int) -> slice:
        return self.knots.of(i)

    def samples(self, i: int) -> slice:
        return self.layers[0].samples(i)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def with_layer(self, n: int, layer: Layer) -> Track:
        """The track with layer ``n`` replaced (``n == len(layers)`` appends)."""
        if not 0 <= n <= len(self.layers):
            raise IndexError(f"layer {n} of {len(self.layers)}")
        return replace(self, layers=self.layers[:n] + (layer,) + self.layers[n + 1 :])

    def with_base(self, layer: Layer) -> Track:
        return self.with_layer(0, layer)

    def without_layer(self, n: int) -> Track:
        if not 1 <= n < len(self.layers):
            raise IndexError(f"layer {n} of {len(self.layers)} (the base layer stays)")
        return replace(self, layers=self.layers[:n] + self.layers[n + 1 :])

    def with_knot_values(self, v: np.ndarray, layer: int = 0) -> Track:
        """The same track with layer ``layer``'s knot values replaced: the
        relative tangents carry along, the displacement maps are untouched."""
        lay = self.layers[layer]
        return self.with_layer(layer, replace(lay, knots=lay.knots.with_values(v)))


# --- construction ----------------------------------------------------------


def empty_layer(kind: str, n_vars: int) -> Layer:
    d = DIM[kind]
    ptr = np.zeros(n_vars + 1, dtype=int)
    knots = Knots(ptr, np.zeros(0), np.zeros((0, d)), np.zeros(0, dtype=int), np.zeros(0, dtype=bool))
    return Layer(knots, np.zeros((0, 3)), np.zeros((0, 3)), ptr.copy(), np.zeros(0), np.zeros((0, d)))


def empty_track(kind: str, names: tuple[str, ...] = (), targets: np.ndarray | None = None) -> Track:
    targets = np.zeros(len(names), dtype=int) if targets is None else np.asarray(targets, dtype=int)
    return Track(kind, tuple(names), targets, (empty_layer(kind, len(names)),))


def offset_layer(kind: str, n_vars: int, pose_t: np.ndarray, owns: np.ndarray | None = None) -> Layer:
    """A layer of identity offsets at the poses ``pose_t`` (K,), for every
    variable (``owns`` (K, V): only where a pose owns the variable, see
    partial poses): it leaves the motion as it is.  Its tangents are flat (the
    inner controls sit on the knots), so an offset set at one pose rises from
    the identity at the previous pose and falls back at the next with zero
    velocity at all three: smooth, and confined between the neighbours."""
    ops = kinds.ops_for(kind)
    K = len(pose_t)
    own = np.ones((K, n_vars), dtype=bool) if owns is None else np.asarray(owns, dtype=bool)
    var, pose = np.nonzero(own.T)  # variable-major, poses increasing
    ptr = np.concatenate([[0], np.cumsum(own.sum(axis=0))]).astype(int)
    knots = Knots(
        ptr,
        np.asarray(pose_t, dtype=float)[pose],
        ops.identity((len(var),)),
        pose,
        np.zeros(len(var), dtype=bool),
    )
    n_seg = int(ptr[-1]) - n_vars if K else 0
    d = DIM[kind]
    return Layer(
        knots,
        np.zeros((n_seg, 3)),
        np.zeros((n_seg, 3)),
        np.zeros(n_vars + 1, dtype=int),
        np.zeros(0),
        np.zeros((0, d)),
    )


def locate_inside(kt: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment, normalized time and a mask of the times ``t`` that a fit
    between knots ``kt`` uses: strictly inside the knots' span and not at a
    knot (the knot itself is exact)."""
    if len(kt) < 2:
        return np.zeros(len(t), dtype=int), np.zeros(len(t)), np.zeros(len(t), dtype=bool)
    seg, u = locate(kt, t)
    # the knots nearest t are its segment's two (where t is a knot, the
    # segment it starts)
    near = np.minimum(np.abs(t - kt[seg]), np.abs(t - kt[seg + 1])) <= _AT_KNOT
    return seg, u, ~near & (t > kt[0]) & (t < kt[-1])


def locate(kt: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segment index and normalized time u in [0, 1] of times ``t`` between knots ``kt``."""
    n = len(kt)
    if n < 2:
        return np.zeros(len(t), dtype=int), np.zeros(len(t))
    seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, n - 2)
    u = np.clip((t - kt[seg]) / (kt[seg + 1] - kt[seg]), 0.0, 1.0)
    return seg, u


def check_knot_order(
    knot_ptr: np.ndarray, knot_t: np.ndarray, names: tuple[str, ...], frame_time: float | None = None
) -> None:
    """Raise KnotOrderError if the knots of a variable are not strictly
    increasing (the time it names to the precision of ``frame_time``, when given)."""
    from ..errors import KnotOrderError

    gaps = np.diff(knot_t)
    inside = np.ones(len(gaps), dtype=bool)
    inside[knot_ptr[1:-1] - 1] = False  # across variables
    bad = np.flatnonzero(inside & (gaps <= 0.0))
    if len(bad):
        var = int(np.searchsorted(knot_ptr, bad[0], side="right") - 1)
        if frame_time is None:
            at = f"{knot_t[bad[0]]:.4f} s"
        else:
            from .document import seconds

            at = seconds(knot_t[bad[0]], frame_time)
        raise KnotOrderError(f"knots of {names[var]!r} would cross at {at}")


def pose_arrays(track: Track, n_poses: int, layer: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose-level view of a layer: extreme knot times (K, V), extreme values
    (K, V, D), editing values (K, V, D) (equal to the extreme value where there
    is no editing knot)."""
    knots = track.layers[layer].knots
    V = track.n_vars
    var = knots.var
    ext = ~knots.editing
    ext_t = np.full((n_poses, V), np.nan)
    ext_t[knots.pose[ext], var[ext]] = knots.t[ext]
    value = np.zeros((n_poses, V, track.dim))
    value[knots.pose[ext], var[ext]] = knots.v[ext]
    edit = value.copy()
    ed = knots.editing
    edit[knots.pose[ed], var[ed]] = knots.v[ed]
    return ext_t, value, edit
