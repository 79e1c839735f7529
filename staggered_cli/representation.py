"""The staggered-pose representation in memory (paper section 3, SPEC section 3).

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
  ``tan_b`` (see :mod:`splines`),
* displacement samples at *knot coordinates* ``s = segment + u``.  The knot
  coordinate of a sample does not change when knots are retimed, so the
  detail is stretched with the segment, never lost.  Every displacement map
  is the identity at the knots (``s`` integer), which is what lets an edit of
  a knot value move the motion through the new value exactly.

Evaluation is ``v_i(t) = s_i(u) ⊕ d_i(u)``.  Operations never mutate a track;
they return new ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import kinds, quat, splines

TRANSLATION = kinds.TRANSLATION
ROTATION = kinds.ROTATION
_DIM = {TRANSLATION: 3, ROTATION: 4}
_AT_KNOT = 1e-9  # seconds: a sample this close to a knot is the knot
#: Rotation tangents are fitted to at most this many evenly spread samples of
#: a segment, with at most this many Levenberg-Marquardt steps (the
#: displacement maps still keep every sample, so the motion stays exact): a
#: cubic has four controls, and at 120 Hz most segments hold 15-30 frames that
#: add fitting time, not information.  Against all samples and 30 steps, the
#: mean spline error of cmu_01_01 grows from 0.560 to 0.568 degrees and the
#: fit takes a third of the time.
FIT_SAMPLES = 8
FIT_ITERATIONS = 10


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
class _Fitted:
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
        (see :mod:`splines`).
    samp_ptr : (V+1,) int, CSR offsets into the sample arrays.
    samp_s : (NS,) knot coordinates (segment + u) of displacement samples.
    samp_d : (NS, D) displacement values (vectors, or unit quaternions).
    fitted : the spline at the samples as the fit computed it, for an
        evaluation in the same process (see :func:`_fitted_spline`); in
        memory only, never written, and not part of the layer's value.
    """

    knots: Knots
    tan_a: np.ndarray
    tan_b: np.ndarray
    samp_ptr: np.ndarray
    samp_s: np.ndarray
    samp_d: np.ndarray
    fitted: _Fitted | None = field(default=None, compare=False, repr=False)

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
        return _DIM[self.kind]

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
    d = _DIM[kind]
    ptr = np.zeros(n_vars + 1, dtype=int)
    knots = Knots(ptr, np.zeros(0), np.zeros((0, d)), np.zeros(0, dtype=int), np.zeros(0, dtype=bool))
    return Layer(knots, np.zeros((0, 3)), np.zeros((0, 3)), ptr.copy(), np.zeros(0), np.zeros((0, d)))


def empty_track(kind: str, names: tuple[str, ...] = (), targets: np.ndarray | None = None) -> Track:
    targets = np.zeros(len(names), dtype=int) if targets is None else np.asarray(targets, dtype=int)
    return Track(kind, tuple(names), targets, (empty_layer(kind, len(names)),))


def offset_layer(kind: str, n_vars: int, pose_t: np.ndarray) -> Layer:
    """A layer of identity offsets at the poses ``pose_t`` (K,), for every
    variable: it leaves the motion as it is.  Its tangents are flat (the
    inner controls sit on the knots), so an offset set at one pose rises from
    the identity at the previous pose and falls back at the next with zero
    velocity at all three: smooth, and confined between the neighbours."""
    ops = kinds.ops_for(kind)
    K = len(pose_t)
    ptr = np.arange(n_vars + 1) * K
    knots = Knots(
        ptr,
        np.tile(np.asarray(pose_t, dtype=float), n_vars),
        ops.identity((n_vars * K,)),
        np.tile(np.arange(K), n_vars),
        np.zeros(n_vars * K, dtype=bool),
    )
    n_seg = n_vars * max(K - 1, 0)
    d = _DIM[kind]
    return Layer(
        knots,
        np.zeros((n_seg, 3)),
        np.zeros((n_seg, 3)),
        np.zeros(n_vars + 1, dtype=int),
        np.zeros(0),
        np.zeros((0, d)),
    )


def sample_dense(kind: str, frame_t: np.ndarray, dense: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Values of dense samples at arbitrary times (linear / slerp between frames).

    Parameters
    ----------
    frame_t : (T,) increasing sample times, seconds.
    dense : (T, V, D) values.
    t : (N,) or (N, V) times.

    Returns
    -------
    (N, V, D)
    """
    t = np.asarray(t, dtype=float)
    T, V = dense.shape[:2]
    tt = np.broadcast_to(t.reshape(len(t), -1), (len(t), V)) if t.ndim == 1 or t.shape[1] == 1 else t
    if T == 1:
        return np.broadcast_to(dense[0], (len(t),) + dense.shape[1:]).copy()
    hi = np.clip(np.searchsorted(frame_t, tt, side="right"), 1, T - 1)
    lo = hi - 1
    w = np.clip((tt - frame_t[lo]) / (frame_t[hi] - frame_t[lo]), 0.0, 1.0)
    cols = np.arange(V)[None, :]
    return kinds.ops_for(kind).interpolate(dense[lo, cols], dense[hi, cols], w)


def knots_from_poses(
    pose_t: np.ndarray,
    refine: np.ndarray,
    value: np.ndarray,
    edit_value: np.ndarray,
    names: tuple[str, ...] | None = None,
) -> Knots:
    """The knots of pose-level arrays.

    Parameters
    ----------
    pose_t : (K,) pose times, seconds.
    refine : (K, V) refinements, seconds.
    value : (K, V, D) extreme values.
    edit_value : (K, V, D) editing-knot values (used where ``refine != 0``).
    """
    K, V = refine.shape
    names = names or tuple(f"variable {i}" for i in range(V))
    d = value.shape[-1]
    # every variable's knots at once: its extreme knots (pose order), then
    # its editing knots (pose order), sorted by time within the variable,
    # stably (np.lexsort is), as one variable at a time would
    ext_t = (pose_t[:, None] + refine).T.ravel()  # variable-major
    ed_var, ed_k = np.nonzero((refine != 0.0).T)  # variable-major, poses increasing
    var = np.concatenate([np.repeat(np.arange(V), K), ed_var])
    t = np.concatenate([ext_t, pose_t[ed_k]])
    order = np.lexsort((t, var))
    var, t = var[order], t[order]
    p = np.concatenate([np.tile(np.arange(K), V), ed_k])[order]
    e = np.concatenate([np.zeros(K * V, dtype=bool), np.ones(len(ed_k), dtype=bool)])[order]
    v = np.concatenate([value.transpose(1, 0, 2).reshape(K * V, d), edit_value[ed_k, ed_var]])[order]
    crossed = np.flatnonzero((np.diff(p) < 0) & (np.diff(var) == 0))
    if len(crossed):
        from .errors import KnotOrderError

        i, k = int(var[crossed[0]]), int(p[crossed[0]])
        raise KnotOrderError(f"the knots of {names[i]!r} around pose {k} would cross a neighbouring pose's knots")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(var, minlength=V))]).astype(int)
    return Knots(ptr, t, v, p, e)


def build_track(
    kind: str,
    names: tuple[str, ...],
    targets: np.ndarray,
    frame_t: np.ndarray,
    dense: np.ndarray,
    pose_t: np.ndarray,
    refine: np.ndarray,
) -> Track:
    """Fit a one-layer track to dense motion for given poses and refinements.

    Parameters
    ----------
    frame_t : (T,) source frame times, seconds.
    dense : (T, V, D) motion values (rotations unrolled per variable), or a
        sequence of the V variables' (T, D), each taken once, in order (a
        long clip's rotations, made a joint at a time).
    pose_t : (K,) strictly increasing pose times within the clip.
    refine : (K, V) refinements in seconds (0 on the first and last pose).
    """
    K, V = refine.shape
    extreme_t = pose_t[:, None] + refine
    if isinstance(dense, np.ndarray):
        value = sample_dense(kind, frame_t, dense, extreme_t)
        edit_value = sample_dense(kind, frame_t, dense, pose_t)
        knots = knots_from_poses(pose_t, refine, value, edit_value, names)
        columns = [dense[:, i] for i in range(V)]
    else:
        # a sequence of V (T, D) columns, each made when asked for: every
        # variable's knot values are sampled when the fit takes its column
        # (the same numbers as from all of them at once)
        d = _DIM[kind]
        knots = knots_from_poses(pose_t, refine, np.zeros((K, V, d)), np.zeros((K, V, d)), names)
        columns = _SampledColumns(kind, frame_t, dense, pose_t, extreme_t, knots)
    check_knot_order(knots.ptr, knots.t, names)
    layer = fit_layer(kind, knots, [frame_t] * V, columns)
    return Track(kind, tuple(names), np.asarray(targets, dtype=int), (layer,))


class _SampledColumns:
    """The columns of :func:`build_track`'s ``dense`` as :func:`fit_layer`
    takes them, one by one: taking variable ``i``'s fills its knot values
    (``knots.v``, which the fit reads only after) from it."""

    def __init__(self, kind, frame_t, columns, pose_t, extreme_t, knots: Knots):
        self.kind, self.frame_t, self.columns = kind, frame_t, columns
        self.pose_t, self.extreme_t, self.knots = pose_t, extreme_t, knots

    def __len__(self) -> int:
        return len(self.columns)

    def __getitem__(self, i: int) -> np.ndarray:
        col = np.asarray(self.columns[i])
        kn = self.knots
        rows = kn.of(i)
        value = sample_dense(self.kind, self.frame_t, col[:, None], self.extreme_t[:, i : i + 1])[:, 0]
        edit = sample_dense(self.kind, self.frame_t, col[:, None], self.pose_t)[:, 0]
        p = kn.pose[rows]
        kn.v[rows] = np.where(kn.editing[rows][:, None], edit[p], value[p])
        return col


def fit_track(
    kind: str,
    names: tuple[str, ...],
    targets: np.ndarray,
    knots: Knots,
    samples_t: list[np.ndarray],
    samples_v: list[np.ndarray],
) -> Track:
    """A one-layer track fitted to samples (see :func:`fit_layer`)."""
    return Track(kind, tuple(names), np.asarray(targets, dtype=int), (fit_layer(kind, knots, samples_t, samples_v),))


def fit_layer(kind: str, knots: Knots, samples_t: list[np.ndarray], samples_v: list[np.ndarray]) -> Layer:
    """Fit splines to samples between given knots and measure displacement maps.

    ``samples_t[i]`` (Ni,) and ``samples_v[i]`` (Ni, D) are the motion of
    variable ``i``; samples at a knot time are dropped (the knot is exact).
    The segments are fitted in batched calls over groups of whole variables
    of about :data:`_FIT_GROUP` samples each (every segment's fit is its own,
    so grouping does not change a bit), filling outputs allocated once: the
    temporaries stay bounded however long the clip.
    """
    V = knots.n_vars
    seg_ptr = knots.seg_ptr
    d = _DIM[kind]
    # first the number of samples each variable keeps, so that the outputs
    # are allocated once and filled group by group
    counts = np.zeros(V, dtype=int)
    # each variable's samples located once where they are few (17 bytes a
    # sample kept); a long clip's are located again, group by group
    located: list = [None] * V
    held = 0
    for i in range(V):
        where = _inside(knots.t[knots.of(i)], np.asarray(samples_t[i], dtype=float))
        counts[i] = np.count_nonzero(where[2])
        held += len(where[2])
        if held <= _FIT_GROUP:
            located[i] = where
    samp_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    first = knots.seg_first
    n_seg = len(first)
    a = np.zeros((n_seg, 3))
    b = np.zeros((n_seg, 3))
    s_a = np.zeros(int(samp_ptr[-1]))
    disp = np.zeros((int(samp_ptr[-1]), d))
    # the spline at the samples, kept for a bake in this process where it is small
    spline = np.zeros_like(disp) if disp.nbytes <= _FITTED_BYTES else None
    for i0, i1 in _variable_groups(counts, _FIT_GROUP):
        g0, g1 = int(seg_ptr[i0]), int(seg_ptr[i1])
        gseg, us, vals = [], [], []
        for i in range(i0, i1):
            kt = knots.t[knots.of(i)]
            seg, u, keep = located[i] or _inside(kt, np.asarray(samples_t[i], dtype=float))
            located[i] = None
            seg, u = seg[keep], u[keep]
            gseg.append(seg + (seg_ptr[i] - g0))
            us.append(u)
            vals.append(np.asarray(samples_v[i])[keep])
            s_a[samp_ptr[i] : samp_ptr[i + 1]] = seg + u
        gseg_a = np.concatenate(gseg) if gseg else np.zeros(0, dtype=int)
        u_a = np.concatenate(us) if us else np.zeros(0)
        v_a = np.concatenate(vals) if vals else np.zeros((0, d))
        del gseg, us, vals
        fs = first[g0:g1]
        out = None if spline is None else spline[samp_ptr[i0] : samp_ptr[i1]]
        ga, gb, gdisp = _fit_segments(kind, knots.v[fs], knots.v[fs + 1], gseg_a, u_a, v_a, g1 - g0, out)
        a[g0:g1], b[g0:g1] = ga, gb
        disp[samp_ptr[i0] : samp_ptr[i1]] = gdisp
        del gseg_a, u_a, v_a, ga, gb, gdisp
    knots = Knots(
        np.asarray(knots.ptr, dtype=int),
        np.asarray(knots.t, dtype=float),
        np.asarray(knots.v, dtype=float),
        np.asarray(knots.pose, dtype=int),
        np.asarray(knots.editing, dtype=bool),
    )
    return _fitted_layer(knots, a, b, samp_ptr, s_a, disp, spline)


def _fitted_layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d, spline: np.ndarray | None) -> Layer:
    """The layer of these arrays, holding ``spline`` (its fit's values at the
    samples, or None) with the very arrays it belongs to."""
    if spline is None:
        return Layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d)
    spline.flags.writeable = False
    return Layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d, _Fitted(knots, tan_a, tan_b, samp_ptr, samp_s, spline))


#: The largest spline at the samples a fitted layer keeps (:class:`_Fitted`):
#: a clip of a few minutes; a longer one's bake evaluates it again.
_FITTED_BYTES = 1 << 26

#: Samples fitted in one batched call by :func:`fit_layer` (whole variables:
#: a group holds at least one): its temporaries are a few hundred bytes a
#: sample, so about 40 MB.
_FIT_GROUP = 1 << 17


def _variable_groups(counts: np.ndarray, most: int) -> list[tuple[int, int]]:
    """Consecutive ranges ``[i0, i1)`` of variables whose ``counts`` add up
    to at most ``most`` (a variable with more stands alone); none if there
    are no variables."""
    out, i0, n = [], 0, 0
    for i, c in enumerate(counts):
        if i > i0 and n + c > most:
            out.append((i0, i))
            i0, n = i, 0
        n += int(c)
    if len(counts):
        out.append((i0, len(counts)))
    return out


def _fit_segments(kind, p0, p3, gseg, u, values, n_seg, spline_out=None):
    """Tangents (n_seg, 3) x 2 of segments with endpoints ``p0``, ``p3`` fitted
    to samples ``values`` at (``gseg``, ``u``), and the displacements
    ``values ⊖ spline`` there (the spline itself into ``spline_out``, if given)."""
    if kind == TRANSLATION:
        a, b = splines.fit_translation_tangents(p0, p3, gseg, u, values, n_seg)
        s_val = splines.bezier_eval_at(p0, a, b, p3, gseg, u)
        if spline_out is not None:
            spline_out[...] = s_val
        return a, b, values - s_val
    values = quat.normalize(values)
    pick = _evenly_within_segments(gseg, FIT_SAMPLES)
    a, b, at, fitted = splines.fit_rotation_tangents(
        p0, p3, gseg[pick], u[pick], values[pick], n_seg, iterations=FIT_ITERATIONS, return_curve=True
    )
    # the spline where the fit last evaluated it is taken from the fit (the
    # same bits), and evaluated at the other samples only
    s_val = np.empty((len(u), 4))
    done = pick[at]
    s_val[done] = fitted
    rest = np.ones(len(u), dtype=bool)
    rest[done] = False
    rest = np.flatnonzero(rest)
    if rest.size:
        s_val[rest] = splines.rotation_eval_at(p0, a, b, p3, gseg[rest], u[rest])
    if spline_out is not None:
        spline_out[...] = s_val
    return a, b, quat.hemisphere(quat.mul(quat.conj(s_val), values), quat.identity((1,)))


def _evenly_within_segments(seg: np.ndarray, most: int) -> np.ndarray:
    """Indices of at most ``most`` evenly spread samples of each segment
    (``seg`` sorted, so each segment's samples are contiguous)."""
    if len(seg) == 0:
        return np.zeros(0, dtype=int)
    starts = np.flatnonzero(np.concatenate([[True], seg[1:] != seg[:-1]]))
    counts = np.diff(np.concatenate([starts, [len(seg)]]))
    n = np.repeat(counts, counts)
    rank = np.arange(len(seg)) - np.repeat(starts, counts)
    # sample r is kept when the grid of `most` slots steps at it
    keep = (n <= most) | (rank * most // n != (rank - 1) * most // n) | (rank == 0)
    return np.flatnonzero(keep)


def _inside(kt: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment, normalized time and a mask of the times ``t`` that a fit
    between knots ``kt`` uses: strictly inside the knots' span and not at a
    knot (the knot itself is exact)."""
    if len(kt) < 2:
        return np.zeros(len(t), dtype=int), np.zeros(len(t)), np.zeros(len(t), dtype=bool)
    seg, u = _locate(kt, t)
    # the knots nearest t are its segment's two (where t is a knot, the
    # segment it starts)
    near = np.minimum(np.abs(t - kt[seg]), np.abs(t - kt[seg + 1])) <= _AT_KNOT
    return seg, u, ~near & (t > kt[0]) & (t < kt[-1])


def _locate(kt: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    from .errors import KnotOrderError

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


# --- evaluation --------------------------------------------------------------


def evaluate(track: Track, t: np.ndarray, layers: str = "all", depth: int | None = None) -> np.ndarray:
    """Values of every variable at times ``t``.

    Parameters
    ----------
    t : (N,) seconds.
    layers : ``'all'`` (spline ⊕ displacement, every layer) or ``'splines'``
        (the splines of every layer, without their displacement maps).
    depth : fold only the bottom ``depth`` layers (None: all; 1: the base).

    Returns
    -------
    (N, V, D) values (unit quaternions w first for rotations).
    """
    if layers not in ("all", "splines"):
        raise ValueError(f"layers must be 'all' or 'splines', got {layers!r}")
    t = np.asarray(t, dtype=float)
    V, N = track.n_vars, len(t)
    stack = track.layers if depth is None else track.layers[:depth]
    out = np.empty((N, V, track.dim))
    # in blocks of frames, so that the temporaries stay small whatever the length
    rows = max(1, _BLOCK // max(V, 1))
    for lo in range(0, N, rows):
        tb = t[lo : lo + rows]
        n = len(tb)
        var = np.broadcast_to(np.arange(V)[None, :], (n, V)).ravel()
        # the queries grouped by variable without sorting: variable i's are i, i + V, ...
        order = np.arange(n * V).reshape(n, V).T.ravel()
        bounds = np.arange(V + 1) * n
        out[lo : lo + n] = _fold(track, stack, layers == "all", var, np.repeat(tb, V), order, bounds).reshape(
            n, V, track.dim
        )
    return out


def evaluate_at(
    track: Track,
    var: np.ndarray,
    t: np.ndarray,
    layers: str = "all",
    depth: int | None = None,
) -> np.ndarray:
    """Values of variable ``var[n]`` at time ``t[n]``: (N, D), the layers
    folded bottom up (``v = l_0 ⊕ l_1 ⊕ ...``)."""
    if layers not in ("all", "splines"):
        raise ValueError(f"layers must be 'all' or 'splines', got {layers!r}")
    var = np.asarray(var, dtype=int)
    t = np.asarray(t, dtype=float)
    order = np.argsort(var, kind="stable")
    bounds = np.searchsorted(var[order], np.arange(track.n_vars + 1))
    stack = track.layers if depth is None else track.layers[:depth]
    return _fold(track, stack, layers == "all", var, t, order, bounds)


#: Queries evaluated at once by :func:`evaluate` (its temporaries: a few
#: arrays of this many values and their (N, 4) companions, about 10 MB).
_BLOCK = 1 << 16


def _fold(track: Track, stack, detail: bool, var, t, order, bounds) -> np.ndarray:
    """``l_0 ⊕ l_1 ⊕ ...`` over ``stack`` (with their displacement maps, or
    the splines alone)."""
    out = None
    for layer in stack:
        val = layer_at(track.kind, layer, var, t, order, bounds, detail=detail)
        out = val if out is None else track.ops.oplus(out, val)
    return track.ops.normalize(out) if len(stack) > 1 else out


def layer_at(
    kind: str,
    layer: Layer,
    var: np.ndarray,
    t: np.ndarray,
    order: np.ndarray | None = None,
    bounds: np.ndarray | None = None,
    detail: bool = True,
) -> np.ndarray:
    """Values (N, D) of one layer (spline ⊕ displacement, or the spline alone
    without ``detail``) of variable ``var[n]`` at time ``t[n]``.  ``order``
    and ``bounds`` group the queries by variable (computed when not given)."""
    knots = layer.knots
    V = knots.n_vars
    if order is None:
        order = np.argsort(var, kind="stable")
        bounds = np.searchsorted(var[order], np.arange(V + 1))
    N = len(t)
    gseg = np.zeros(N, dtype=int)
    u = np.zeros(N)
    s = np.zeros(N)
    seg_ptr = knots.seg_ptr
    for i in range(V):
        idx = order[bounds[i] : bounds[i + 1]]
        if len(idx) == 0:
            continue
        seg, uu = _locate(knots.t[knots.of(i)], t[idx])
        gseg[idx] = seg + seg_ptr[i]
        u[idx] = uu
        s[idx] = seg + uu
    if int(seg_ptr[-1]) == 0:  # single-knot variables (a 1-frame clip): the knot itself
        return knots.v[knots.ptr[var]]
    # only the segments the queries meet are gathered (and the spline's
    # per-segment work done for them): a block of frames meets a few of a
    # long clip's segments, and all of them at every block would make a
    # bake quadratic in the clip's length.  Each segment's numbers are its
    # own, so they are the same bits as with every segment.
    ops = kinds.ops_for(kind)
    fitted = _fitted_spline(layer) if detail and layer.has_detail else None
    if fitted is None:
        val = _spline_at(ops, layer, gseg, u)
    else:
        # at a sample the spline is the fit's (the same numbers); elsewhere
        # (at the knots, between frames) it is evaluated
        disp, hit_q, hit_sample = _displacement_at(kind, layer, s, order, bounds, hits=True)
        val = np.empty((N, ops.dim))
        val[hit_q] = fitted[hit_sample]
        miss = np.ones(N, dtype=bool)
        miss[hit_q] = False
        miss = np.flatnonzero(miss)
        if miss.size:
            val[miss] = _spline_at(ops, layer, gseg[miss], u[miss])
    single = np.diff(knots.ptr)[var] < 2
    if np.any(single):
        val[single] = knots.v[knots.ptr[var[single]]]
    if not detail or not layer.has_detail:
        return val
    return ops.oplus(val, disp if fitted is not None else _displacement_at(kind, layer, s, order, bounds))


def _spline_at(ops, layer: Layer, gseg: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The layer's spline on its segments ``gseg`` at times ``u`` (N, D)."""
    seg_ptr, v = layer.knots.seg_ptr, layer.knots.v
    used, at = splines.compact_segments(gseg)
    # the first knot of segment g of variable i is g + i (seg_ptr = ptr - i)
    first = used + (np.searchsorted(seg_ptr, used, side="right") - 1)
    return ops.spline_at(v[first], layer.tan_a[used], layer.tan_b[used], v[first + 1], at, u)


def _fitted_spline(layer: Layer) -> np.ndarray | None:
    """The spline at ``layer``'s samples as its fit computed it (NS, D), or
    None: when the layer was not fitted in this process, or was made from a
    fitted one with other knots, tangents or sample coordinates."""
    f = layer.fitted
    if f is None:
        return None
    mine = (f.knots, f.tan_a, f.tan_b, f.samp_ptr, f.samp_s)
    theirs = (layer.knots, layer.tan_a, layer.tan_b, layer.samp_ptr, layer.samp_s)
    return f.values if all(x is y for x, y in zip(mine, theirs, strict=True)) else None


def _displacement_at(kind: str, layer: Layer, s: np.ndarray, order: np.ndarray, bounds: np.ndarray, hits: bool = False):
    """Displacement (N, D) at knot coordinates ``s``, identity at integers.

    Each variable's samples are sorted by knot coordinate (the fit makes
    them so and reading checks it); the identity at the knots is not stored
    but met where the nearest sample lies in another segment, so nothing
    is copied.  With ``hits``, also the queries that lie on a sample (at its
    very knot coordinate, in its segment) and those samples: (out, queries,
    samples).
    """
    ops = kinds.ops_for(kind)
    N = len(s)
    D = ops.dim
    ident = ops.identity()
    # per variable only the search among its own samples; the rest is done
    # for all queries at once (the same numbers, one query at a time)
    q = order[: bounds[-1]]  # the queries, grouped by variable
    k = np.zeros(len(q), dtype=np.intp)  # the first sample of the variable after s
    first = np.zeros(len(q), dtype=np.intp)  # the variable's first sample
    stop = np.zeros(len(q), dtype=np.intp)  # one past its last
    ptr = layer.samp_ptr
    xs_all = layer.samp_s
    for i in range(layer.knots.n_vars):
        a, b = int(bounds[i]), int(bounds[i + 1])
        if a == b:
            continue
        lo, hi = int(ptr[i]), int(ptr[i + 1])
        if hi > lo:
            k[a:b] = np.searchsorted(xs_all[lo:hi], s[order[a:b]], side="right") + lo
        else:
            k[a:b] = lo
        first[a:b] = lo
        stop[a:b] = hi
    si = s[q]
    j = np.floor(si)
    below = k > first
    has = stop > first
    kb = np.where(below, k - 1, first)
    ka = np.minimum(k, stop - 1)
    if len(layer.samp_s):
        np.copyto(kb, 0, where=~has)  # no sample at all: any index (masked below)
        np.copyto(ka, 0, where=~has)
        xb, xa = xs_all[kb], xs_all[ka]
        left = has & below & (xb > j)  # a sample of this segment at or before s
        right = has & (k < stop) & (xa < j + 1.0)  # a sample of this segment after s
        del k, first, stop, below, has  # (a query's temporaries go as soon as they are used)
        if hits:
            on = left & (xb == si)
            hit_q, hit_sample = q[on], kb[on]
            del on
        x_lo = np.where(left, xb, j)  # the knots around each query, identity there
        x_hi = np.where(right, xa, j + 1.0)
        del xb, xa
        lo_g = layer.samp_d[kb]
        del kb
        lo_g[~left] = ident
        hi_g = layer.samp_d[ka]
        del ka
        hi_g[~right] = ident
        del left, right
    else:
        x_lo, x_hi = j, j + 1.0
        lo_g = np.broadcast_to(ident, (len(q), D)).copy()
        hi_g = lo_g.copy()
        hit_q = hit_sample = np.zeros(0, dtype=np.intp)
    # computed in the queries' grouped order, then put in place
    w_g = np.clip((si - x_lo) / (x_hi - x_lo), 0.0, 1.0)
    del si, j, x_lo, x_hi
    out_g = ops.interpolate(lo_g, hi_g, w_g)
    del lo_g, hi_g, w_g
    if len(q) == N:
        out = np.empty((N, D))
    else:  # queries of no variable: the identity
        out = np.broadcast_to(ident, (N, D)).copy()
    out[q] = out_g
    return (out, hit_q, hit_sample) if hits else out


# --- structure ----------------------------------------------------------------


def sample_times(track: Track, i: int, layer: int = 0) -> np.ndarray:
    """Current times (seconds) of variable ``i``'s displacement samples in ``layer``."""
    lay = track.layers[layer]
    kt = lay.knots.t[lay.knots.of(i)]
    s = lay.samp_s[lay.samples(i)]
    if len(kt) < 2:
        return np.full(len(s), kt[0] if len(kt) else 0.0)
    seg = np.clip(np.floor(s).astype(int), 0, len(kt) - 2)
    return kt[seg] + (s - seg) * (kt[seg + 1] - kt[seg])


def with_knot_times(track: Track, knot_t: np.ndarray, layer: int = 0, frame_time: float | None = None) -> Track:
    """The same track with a layer's knots moved in time (same structure):
    the motion between them is warped, its detail carried along in
    normalized time.  ``frame_time``: the clip's, for the precision of the
    time a KnotOrderError names."""
    lay = track.layers[layer]
    check_knot_order(lay.knots.ptr, knot_t, track.names, frame_time)
    return track.with_layer(layer, replace(lay, knots=lay.knots.with_times(knot_t)))


def restructure(
    track: Track, knots: Knots, *, frame_t: np.ndarray | None = None, dense: np.ndarray | None = None
) -> Track:
    """Refit the base layer of ``track`` to new knots, keeping the motion it has now.

    Only segments that changed are refitted: a new segment whose two knots
    (times and values) are two consecutive knots of the old base layer keeps
    its tangents and displacement samples as they are, so what a user set
    there (``--ease``, ``detail``) stays exactly.  The other segments are
    fitted again and their displacement maps measured from the base layer's
    motion as it was (SPEC invariant 2), sampled at the source frame times
    ``frame_t`` (increasing; where the motion is baked, so it stays exact
    there even after a retiming moved the old samples between frames) plus
    the old knot times inside them; without ``frame_t``, at the current
    sample times.  ``dense`` (T, V, D), when given with ``frame_t``, is that
    motion at ``frame_t`` (``evaluate(track, frame_t, depth=1)``, which a
    caller may already have): it is read instead of evaluated again, and only
    the knot times between frames are evaluated.  Only the variables with a
    refitted segment are sampled at all.  The layers above the base are kept
    as they are.
    """
    check_knot_order(
        knots.ptr, knots.t, track.names, None if frame_t is None or len(frame_t) < 2 else frame_t[1] - frame_t[0]
    )
    old = track.base
    V = track.n_vars
    kept_old = _unchanged_segments(old.knots, knots)  # (S_new,) old segment index or -1
    new_first = knots.seg_first
    seg_var = knots.seg_var
    refit = np.flatnonzero(kept_old < 0)
    is_refit = kept_old < 0
    ft = None if frame_t is None else np.asarray(frame_t, dtype=float)
    if dense is not None and (ft is None or dense.shape[:2] != (len(ft), V)):
        raise ValueError(f"dense must be (T, V, D) values at frame_t, got {np.shape(dense)}")
    D = track.dim
    # the changed segments are numbered 0..len(refit)-1 and fitted over groups
    # of whole variables of about _FIT_GROUP samples (every segment's fit is
    # its own, so grouping does not change a bit): the temporaries stay
    # bounded however long the clip
    local = np.full(len(new_first), -1)
    local[refit] = np.arange(len(refit))
    a_new = np.zeros((len(refit), 3))
    b_new = np.zeros((len(refit), 3))
    # (not np.unique, which imports numpy.ma: 15 ms at a command's first call)
    todo = np.flatnonzero(np.bincount(seg_var[refit], minlength=V))
    n_old = np.diff(old.knots.ptr)
    if ft is None:
        size = np.diff(old.samp_ptr)[todo] + n_old[todo]
    else:
        size = len(ft) + n_old[todo]
    # the new samples are written in their final order (by variable, then
    # knot coordinate) into arrays allocated once, range of variables by
    # range: each fit group's variables with their carried samples, and the
    # variables in between (nothing refitted) in groups of _FIT_GROUP old
    # samples.  The bound (old samples + the refitted variables' candidate
    # times) is allocated but the pages past the end are never touched.
    old_to_new = np.full(int(old.knots.seg_ptr[-1]), -1)
    kept = np.flatnonzero(kept_old >= 0)
    old_to_new[kept_old[kept]] = kept
    bound = int(old.samp_ptr[-1]) + int(np.sum(size))
    out_s = np.empty(bound)
    out_d = np.empty((bound, D))
    # the fit's spline at the samples, where the old layer has it: carried
    # with the kept segments' samples, computed at the refitted ones
    old_fit = _fitted_spline(old)
    out_f = np.empty((bound, D)) if old_fit is not None and bound * D * 8 <= _FITTED_BYTES else None
    counts = np.zeros(V, dtype=int)
    w = 0

    def emit(i0: int, i1: int, g_var, g_seg, g_s, g_d, g_f) -> None:
        # the old samples of variables i0..i1-1 whose segment is kept, and
        # the fresh ones, in order of (new) segment: each segment's samples
        # are already in order, and all carried or all fresh, so ordering by
        # segment (stably) is enough
        nonlocal w
        o0, o1 = int(old.samp_ptr[i0]), int(old.samp_ptr[i1])
        ss = old.samp_s[o0:o1]
        owner = np.repeat(np.arange(i0, i1), np.diff(old.samp_ptr[i0 : i1 + 1]))
        old_local = np.floor(ss).astype(int)
        old_local = np.minimum(old_local, np.maximum(n_old[owner] - 2, 0))
        new_of_sample = old_to_new[old_local + old.knots.seg_ptr[owner]] if len(ss) else np.zeros(0, dtype=int)
        carry = new_of_sample >= 0
        carried_seg = new_of_sample[carry]
        carried_s = ss[carry] - old_local[carry] + (carried_seg - knots.seg_ptr[seg_var[carried_seg]])
        del old_local, new_of_sample
        o = np.argsort(np.concatenate([carried_seg, g_seg]), kind="stable")
        n = len(o)
        out_s[w : w + n] = np.concatenate([carried_s, g_s])[o]
        out_d[w : w + n] = np.concatenate([old.samp_d[o0:o1][carry], g_d])[o]
        if out_f is not None:
            out_f[w : w + n] = np.concatenate([old_fit[o0:o1][carry], g_f])[o]
        counts[i0:i1] = np.bincount(np.concatenate([owner[carry], g_var]) - i0, minlength=i1 - i0)
        w += n

    none_i, none_f, none_d = np.zeros(0, dtype=int), np.zeros(0), np.zeros((0, D))
    old_counts = np.diff(old.samp_ptr)

    def emit_carried(i0: int, i1: int) -> None:
        for c0, c1 in _variable_groups(old_counts[i0:i1], _FIT_GROUP):
            emit(i0 + c0, i0 + c1, none_i, none_i, none_f, none_d, none_d)

    done = 0  # variables emitted so far
    groups = _variable_groups(size, _FIT_GROUP)
    for j0, j1 in groups:
        # samples of the group's segments to refit: (time, frame index or -1)
        samples_t, samples_frame, samples_var, samples_seg, samples_u = [], [], [], [], []
        for i in todo[j0:j1]:
            kt = knots.t[knots.of(i)]
            old_kt = old.knots.t[old.knots.of(i)]
            if ft is None:
                st = np.unique(np.concatenate([sample_times(track, i), old_kt]))
                frame = np.full(len(st), -1)
            else:
                st, frame = _with_knot_times(ft, old_kt)
            seg, u, inside = _inside(kt, st)
            gseg = seg + knots.seg_ptr[i]
            take = inside & is_refit[gseg]
            samples_t.append(st[take])
            samples_frame.append(frame[take])
            samples_var.append(np.full(int(take.sum()), i))
            samples_seg.append(gseg[take])
            samples_u.append(u[take])
            del st, frame, seg, u, inside, gseg, take
        g_t = np.concatenate(samples_t)
        g_frame = np.concatenate(samples_frame)
        g_var = np.concatenate(samples_var)
        g_seg = np.concatenate(samples_seg)
        g_u = np.concatenate(samples_u)
        del samples_t, samples_frame, samples_var, samples_seg, samples_u
        if dense is None:
            values = evaluate_at(track, g_var, g_t, depth=1) if len(g_t) else np.zeros((0, D))
        else:
            # the same numbers: evaluate and evaluate_at compute each value alike
            # rows of the (T * V, D) view (a knot time between frames takes row 0, then its own value)
            on_frame = g_frame >= 0
            rows = np.where(on_frame, g_frame * V + g_var, 0)
            values = np.take(dense.reshape(-1, D), rows, axis=0)
            del rows
            off = np.flatnonzero(~on_frame)
            if len(off):
                values[off] = evaluate_at(track, g_var[off], g_t[off], depth=1)
        del g_t, g_frame
        r0 = int(np.searchsorted(refit, knots.seg_ptr[todo[j0]]))
        r1 = int(np.searchsorted(refit, knots.seg_ptr[todo[j1 - 1] + 1]))
        fs = new_first[refit[r0:r1]]
        gf = None if out_f is None else np.empty((len(g_u), D))
        ga, gb, gd = _fit_segments(
            track.kind, knots.v[fs], knots.v[fs + 1], local[g_seg] - r0, g_u, values, r1 - r0, gf
        )
        del values
        a_new[r0:r1], b_new[r0:r1] = ga, gb
        i0, i1 = int(todo[j0]), int(todo[j1 - 1]) + 1
        emit_carried(done, i0)
        emit(i0, i1, g_var, g_seg, (g_seg - knots.seg_ptr[g_var]) + g_u, gd, gf)
        done = i1
        del g_var, g_seg, g_u, ga, gb, gd, gf
    emit_carried(done, V)
    tan_a = np.zeros((len(new_first), 3))
    tan_b = np.zeros((len(new_first), 3))
    tan_a[kept], tan_b[kept] = old.tan_a[kept_old[kept]], old.tan_b[kept_old[kept]]
    tan_a[refit], tan_b[refit] = a_new, b_new
    samp_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    layer = _fitted_layer(knots, tan_a, tan_b, samp_ptr, out_s[:w], out_d[:w], None if out_f is None else out_f[:w])
    return track.with_base(layer)


def _with_knot_times(frame_t: np.ndarray, knot_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The increasing times ``frame_t`` (T,) and ``knot_t`` (n,) together, in
    order and each once (``np.unique`` of both), and the frame index (-1 for
    a knot time between frames) of each."""
    pos = np.searchsorted(frame_t, knot_t)
    at = np.minimum(pos, len(frame_t) - 1)
    new = (pos >= len(frame_t)) | (frame_t[at] != knot_t) if len(frame_t) else np.ones(len(knot_t), dtype=bool)
    st = np.insert(frame_t, pos[new], knot_t[new])
    frame = np.insert(np.arange(len(frame_t)), pos[new], -1)
    return st, frame


def _unchanged_segments(old: Knots, new: Knots) -> np.ndarray:
    """For each segment of ``new``, the index of the segment of ``old`` that
    has the same two knots (variable, times and values exactly), else -1."""
    new_first = new.seg_first
    out = np.full(len(new_first), -1)
    old_first = old.seg_first
    if len(new_first) == 0 or len(old_first) == 0:
        return out
    for i in range(new.n_vars):
        ns = slice(int(new.seg_ptr[i]), int(new.seg_ptr[i + 1]))
        os_ = slice(int(old.seg_ptr[i]), int(old.seg_ptr[i + 1]))
        if ns.stop == ns.start or os_.stop == os_.start:
            continue
        o0 = old.t[old_first[os_]]
        n0 = new.t[new_first[ns]]
        j = np.clip(np.searchsorted(o0, n0), 0, len(o0) - 1)
        cand = old_first[os_][j]
        nf = new_first[ns]
        same = (
            (old.t[cand] == new.t[nf])
            & (old.t[cand + 1] == new.t[nf + 1])
            & np.all(old.v[cand] == new.v[nf], axis=1)
            & np.all(old.v[cand + 1] == new.v[nf + 1], axis=1)
        )
        out[np.arange(ns.start, ns.stop)[same]] = (os_.start + j)[same]
    return out


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
