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

from dataclasses import dataclass, replace

import numpy as np

from . import quat, splines

TRANSLATION = "translation"
ROTATION = "rotation"
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
class Track:
    """All control variables of one kind.

    Attributes
    ----------
    kind : ``'translation'`` (values (..., 3), file units) or ``'rotation'``
        (values (..., 4), unit quaternions w first).
    names : (V,) variable names (``JOINT`` for rotations, ``JOINT.position``
        for BVH translations, the marker label for C3D).
    targets : (V,) int, the joint or marker each variable drives.
    knot_ptr : (V+1,) int, CSR offsets into the knot arrays.
    knot_t : (NK,) knot times in seconds.
    knot_v : (NK, D) knot values.
    knot_pose : (NK,) int, the staggered pose each knot belongs to.
    knot_editing : (NK,) bool, True for editing knots (at ``t_k``).
    tan_a, tan_b : (NK - V, 3) relative inner controls of each segment.
    samp_ptr : (V+1,) int, CSR offsets into the sample arrays.
    samp_s : (NS,) knot coordinates (segment + u) of displacement samples.
    samp_d : (NS, D) displacement values (vectors, or unit quaternions).
    """

    kind: str
    names: tuple[str, ...]
    targets: np.ndarray
    knot_ptr: np.ndarray
    knot_t: np.ndarray
    knot_v: np.ndarray
    knot_pose: np.ndarray
    knot_editing: np.ndarray
    tan_a: np.ndarray
    tan_b: np.ndarray
    samp_ptr: np.ndarray
    samp_s: np.ndarray
    samp_d: np.ndarray

    @property
    def n_vars(self) -> int:
        return len(self.names)

    @property
    def dim(self) -> int:
        return _DIM[self.kind]

    @property
    def seg_ptr(self) -> np.ndarray:
        return self.knot_ptr - np.arange(self.n_vars + 1)

    def knots(self, i: int) -> slice:
        return slice(int(self.knot_ptr[i]), int(self.knot_ptr[i + 1]))

    def samples(self, i: int) -> slice:
        return slice(int(self.samp_ptr[i]), int(self.samp_ptr[i + 1]))

    def index(self, name: str) -> int:
        return self.names.index(name)


# --- construction ----------------------------------------------------------


def empty_track(kind: str, names: tuple[str, ...] = (), targets: np.ndarray | None = None) -> Track:
    d = _DIM[kind]
    z = np.zeros(0)
    zi = np.zeros(0, dtype=int)
    return Track(
        kind,
        tuple(names),
        np.zeros(len(names), dtype=int) if targets is None else np.asarray(targets, dtype=int),
        np.zeros(len(names) + 1, dtype=int),
        z,
        np.zeros((0, d)),
        zi,
        np.zeros(0, dtype=bool),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros(len(names) + 1, dtype=int),
        z,
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
    a, b = dense[lo, cols], dense[hi, cols]
    if kind == TRANSLATION:
        return a + (b - a) * w[..., None]
    exact = w == 0.0
    out = quat.slerp(a, b, w)
    return np.where(exact[..., None], a, out)


def knots_from_poses(
    pose_t: np.ndarray,
    refine: np.ndarray,
    value: np.ndarray,
    edit_value: np.ndarray,
    names: tuple[str, ...] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """CSR knot arrays from pose-level arrays.

    Parameters
    ----------
    pose_t : (K,) pose times, seconds.
    refine : (K, V) refinements, seconds.
    value : (K, V, D) extreme values.
    edit_value : (K, V, D) editing-knot values (used where ``refine != 0``).

    Returns
    -------
    knot_ptr, knot_t, knot_v, knot_pose, knot_editing
    """
    K, V = refine.shape
    names = names or tuple(f"variable {i}" for i in range(V))
    ptr = [0]
    ts, vs, ps, es = [], [], [], []
    for i in range(V):
        nz = refine[:, i] != 0.0
        k_ed = np.flatnonzero(nz)
        t = np.concatenate([pose_t + refine[:, i], pose_t[k_ed]])
        v = np.concatenate([value[:, i], edit_value[k_ed, i]])
        p = np.concatenate([np.arange(K), k_ed])
        e = np.concatenate([np.zeros(K, dtype=bool), np.ones(len(k_ed), dtype=bool)])
        order = np.argsort(t, kind="stable")
        if np.any(np.diff(p[order]) < 0):
            from .errors import KnotOrderError

            k = int(p[order][np.flatnonzero(np.diff(p[order]) < 0)[0]])
            raise KnotOrderError(f"the knots of {names[i]!r} around pose {k} would cross a neighbouring pose's knots")
        ts.append(t[order])
        vs.append(v[order])
        ps.append(p[order])
        es.append(e[order])
        ptr.append(ptr[-1] + len(t))
    d = value.shape[-1]
    return (
        np.array(ptr, dtype=int),
        np.concatenate(ts) if ts else np.zeros(0),
        np.concatenate(vs) if vs else np.zeros((0, d)),
        np.concatenate(ps) if ps else np.zeros(0, dtype=int),
        np.concatenate(es) if es else np.zeros(0, dtype=bool),
    )


def build_track(
    kind: str,
    names: tuple[str, ...],
    targets: np.ndarray,
    frame_t: np.ndarray,
    dense: np.ndarray,
    pose_t: np.ndarray,
    refine: np.ndarray,
) -> Track:
    """Fit a track to dense motion for given poses and refinements.

    Parameters
    ----------
    frame_t : (T,) source frame times, seconds.
    dense : (T, V, D) motion values (rotations unrolled per variable).
    pose_t : (K,) strictly increasing pose times within the clip.
    refine : (K, V) refinements in seconds (0 on the first and last pose).
    """
    K, V = refine.shape
    extreme_t = pose_t[:, None] + refine
    value = sample_dense(kind, frame_t, dense, extreme_t)
    edit_value = sample_dense(kind, frame_t, dense, pose_t)
    knots = knots_from_poses(pose_t, refine, value, edit_value, names)
    check_knot_order(knots[0], knots[1], names)
    samples_t = [frame_t] * V
    samples_v = [dense[:, i] for i in range(V)]
    return fit_track(kind, names, targets, *knots, samples_t, samples_v)


def fit_track(
    kind: str,
    names: tuple[str, ...],
    targets: np.ndarray,
    knot_ptr: np.ndarray,
    knot_t: np.ndarray,
    knot_v: np.ndarray,
    knot_pose: np.ndarray,
    knot_editing: np.ndarray,
    samples_t: list[np.ndarray],
    samples_v: list[np.ndarray],
) -> Track:
    """Fit splines to samples between given knots and measure displacement maps.

    ``samples_t[i]`` (Ni,) and ``samples_v[i]`` (Ni, D) are the motion of
    variable ``i``; samples at a knot time are dropped (the knot is exact).
    Every segment of every variable is fitted in one batched call.
    """
    V = len(names)
    seg_ptr = knot_ptr - np.arange(V + 1)
    n_seg = int(seg_ptr[-1])
    gseg, us, vals, owner, scoord = [], [], [], [], []
    for i in range(V):
        kt = knot_t[knot_ptr[i] : knot_ptr[i + 1]]
        t = np.asarray(samples_t[i], dtype=float)
        seg, u = _locate(kt, t)
        near = _near_knot(kt, t)
        keep = ~near & (t > kt[0]) & (t < kt[-1])
        gseg.append(seg[keep] + seg_ptr[i])
        us.append(u[keep])
        vals.append(np.asarray(samples_v[i])[keep])
        owner.append(np.full(int(keep.sum()), i))
        scoord.append(seg[keep] + u[keep])
    d = _DIM[kind]
    gseg_a = np.concatenate(gseg) if gseg else np.zeros(0, dtype=int)
    u_a = np.concatenate(us) if us else np.zeros(0)
    v_a = np.concatenate(vals) if vals else np.zeros((0, d))
    s_a = np.concatenate(scoord) if scoord else np.zeros(0)
    owner_a = np.concatenate(owner) if owner else np.zeros(0, dtype=int)
    # segment endpoints: knot j and j+1 of the same variable
    seg_var = np.repeat(np.arange(V), np.diff(seg_ptr))
    first = knot_ptr[seg_var] + (np.arange(n_seg) - seg_ptr[seg_var])
    p0, p3 = knot_v[first], knot_v[first + 1]
    if kind == TRANSLATION:
        a, b = splines.fit_translation_tangents(p0, p3, gseg_a, u_a, v_a, n_seg)
        s_val = splines.bezier_eval_at(p0, a, b, p3, gseg_a, u_a)
        disp = v_a - s_val
    else:
        v_a = quat.normalize(v_a)
        pick = _evenly_within_segments(gseg_a, FIT_SAMPLES)
        a, b = splines.fit_rotation_tangents(
            p0, p3, gseg_a[pick], u_a[pick], v_a[pick], n_seg, iterations=FIT_ITERATIONS
        )
        s_val = splines.rotation_eval_at(p0, a, b, p3, gseg_a, u_a)
        disp = quat.hemisphere(quat.mul(quat.conj(s_val), v_a), quat.identity((1,)))
    samp_ptr = np.concatenate([[0], np.cumsum(np.bincount(owner_a, minlength=V))]).astype(int)
    return Track(
        kind,
        tuple(names),
        np.asarray(targets, dtype=int),
        np.asarray(knot_ptr, dtype=int),
        np.asarray(knot_t, dtype=float),
        np.asarray(knot_v, dtype=float),
        np.asarray(knot_pose, dtype=int),
        np.asarray(knot_editing, dtype=bool),
        a,
        b,
        samp_ptr,
        s_a,
        disp,
    )


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


def _near_knot(kt: np.ndarray, t: np.ndarray) -> np.ndarray:
    if len(kt) < 2:
        return np.ones(len(t), dtype=bool)
    j = np.clip(np.searchsorted(kt, t), 1, len(kt) - 1)
    return np.minimum(np.abs(t - kt[j - 1]), np.abs(t - kt[j])) <= _AT_KNOT


def _locate(kt: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segment index and normalized time u in [0, 1] of times ``t`` between knots ``kt``."""
    n = len(kt)
    if n < 2:
        return np.zeros(len(t), dtype=int), np.zeros(len(t))
    seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, n - 2)
    u = np.clip((t - kt[seg]) / (kt[seg + 1] - kt[seg]), 0.0, 1.0)
    return seg, u


def check_knot_order(knot_ptr: np.ndarray, knot_t: np.ndarray, names: tuple[str, ...]) -> None:
    """Raise KnotOrderError if the knots of a variable are not strictly increasing."""
    from .errors import KnotOrderError

    gaps = np.diff(knot_t)
    inside = np.ones(len(gaps), dtype=bool)
    inside[knot_ptr[1:-1] - 1] = False  # across variables
    bad = np.flatnonzero(inside & (gaps <= 0.0))
    if len(bad):
        var = int(np.searchsorted(knot_ptr, bad[0], side="right") - 1)
        raise KnotOrderError(f"knots of {names[var]!r} would cross at {knot_t[bad[0]]:.4f} s")


# --- evaluation --------------------------------------------------------------


def evaluate(track: Track, t: np.ndarray, layers: str = "all") -> np.ndarray:
    """Values of every variable at times ``t``.

    Parameters
    ----------
    t : (N,) seconds.
    layers : ``'all'`` (spline ⊕ displacement) or ``'splines'``.

    Returns
    -------
    (N, V, D) values (unit quaternions w first for rotations).
    """
    t = np.asarray(t, dtype=float)
    V = track.n_vars
    var = np.repeat(np.arange(V)[None, :], len(t), axis=0).ravel()
    tt = np.repeat(t, V)
    out = evaluate_at(track, var, tt, layers)
    return out.reshape(len(t), V, track.dim)


def evaluate_at(track: Track, var: np.ndarray, t: np.ndarray, layers: str = "all") -> np.ndarray:
    """Values of variable ``var[n]`` at time ``t[n]``: (N, D)."""
    var = np.asarray(var, dtype=int)
    t = np.asarray(t, dtype=float)
    N = len(t)
    gseg = np.zeros(N, dtype=int)
    u = np.zeros(N)
    s = np.zeros(N)
    seg_ptr = track.seg_ptr
    order = np.argsort(var, kind="stable")
    bounds = np.searchsorted(var[order], np.arange(track.n_vars + 1))
    for i in range(track.n_vars):
        idx = order[bounds[i] : bounds[i + 1]]
        if len(idx) == 0:
            continue
        seg, uu = _locate(track.knot_t[track.knots(i)], t[idx])
        gseg[idx] = seg + seg_ptr[i]
        u[idx] = uu
        s[idx] = seg + uu
    seg_var = np.repeat(np.arange(track.n_vars), np.diff(seg_ptr))
    first = track.knot_ptr[seg_var] + (np.arange(int(seg_ptr[-1])) - seg_ptr[seg_var])
    p0, p3 = track.knot_v[first], track.knot_v[first + 1]
    if int(seg_ptr[-1]) == 0:  # single-knot variables (a 1-frame clip): the knot itself
        return track.knot_v[track.knot_ptr[var]]
    if track.kind == TRANSLATION:
        val = splines.bezier_eval_at(p0, track.tan_a, track.tan_b, p3, gseg, u)
    else:
        val = splines.rotation_eval_at(p0, track.tan_a, track.tan_b, p3, gseg, u)
    single = np.diff(track.knot_ptr)[var] < 2
    if np.any(single):
        val[single] = track.knot_v[track.knot_ptr[var[single]]]
    if layers == "splines":
        return val
    d = _displacement_at(track, var, s, order, bounds)
    if track.kind == TRANSLATION:
        return val + d
    return quat.mul(val, d)


def _displacement_at(track: Track, var: np.ndarray, s: np.ndarray, order: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Displacement (N, D) at knot coordinates ``s``, identity at integers."""
    N = len(s)
    D = track.dim
    lo_val = np.zeros((N, D))
    hi_val = np.zeros((N, D))
    w = np.zeros(N)
    ident = np.zeros(D)
    if track.kind == ROTATION:
        ident[0] = 1.0
    for i in range(track.n_vars):
        idx = order[bounds[i] : bounds[i + 1]]
        if len(idx) == 0:
            continue
        n_knots = int(track.knot_ptr[i + 1] - track.knot_ptr[i])
        sl = track.samples(i)
        xs = np.concatenate([track.samp_s[sl], np.arange(n_knots, dtype=float)])
        ys = np.concatenate([track.samp_d[sl], np.broadcast_to(ident, (n_knots, D))])
        o = np.argsort(xs, kind="stable")
        xs, ys = xs[o], ys[o]
        si = s[idx]
        hi = (
            np.clip(np.searchsorted(xs, si, side="right"), 1, len(xs) - 1)
            if len(xs) > 1
            else np.zeros(len(si), dtype=int)
        )
        lo = np.maximum(hi - 1, 0)
        span = xs[hi] - xs[lo]
        ww = np.where(span > 0, (si - xs[lo]) / np.where(span > 0, span, 1.0), 0.0)
        lo_val[idx] = ys[lo]
        hi_val[idx] = ys[hi]
        w[idx] = np.clip(ww, 0.0, 1.0)
    if track.kind == TRANSLATION:
        return lo_val + (hi_val - lo_val) * w[:, None]
    out = quat.slerp(lo_val, hi_val, w)
    return np.where((w == 0.0)[:, None], lo_val, out)


# --- structure ----------------------------------------------------------------


def sample_times(track: Track, i: int) -> np.ndarray:
    """Current times (seconds) of variable ``i``'s displacement samples."""
    kt = track.knot_t[track.knots(i)]
    s = track.samp_s[track.samples(i)]
    if len(kt) < 2:
        return np.full(len(s), kt[0] if len(kt) else 0.0)
    seg = np.clip(np.floor(s).astype(int), 0, len(kt) - 2)
    return kt[seg] + (s - seg) * (kt[seg + 1] - kt[seg])


def with_knot_times(track: Track, knot_t: np.ndarray) -> Track:
    """The same track with knots moved in time (same structure): the motion
    between them is warped, its detail carried along in normalized time."""
    check_knot_order(track.knot_ptr, knot_t, track.names)
    return replace(track, knot_t=np.asarray(knot_t, dtype=float))


def restructure(
    track: Track,
    knot_ptr: np.ndarray,
    knot_t: np.ndarray,
    knot_v: np.ndarray,
    knot_pose: np.ndarray,
    knot_editing: np.ndarray,
    *,
    frame_t: np.ndarray | None = None,
) -> Track:
    """Refit ``track`` to new knots, keeping the motion it has now.

    The displacement maps are measured again from the motion as it was
    (SPEC invariant 2), sampled at the source frame times ``frame_t`` (where
    the motion is baked, so it stays exact there even after a retiming moved
    the old samples between frames) plus the old knot times; without
    ``frame_t``, at the current sample times.
    """
    check_knot_order(knot_ptr, knot_t, track.names)
    samples_t, var_idx = [], []
    for i in range(track.n_vars):
        base = sample_times(track, i) if frame_t is None else np.asarray(frame_t, dtype=float)
        st = np.unique(np.concatenate([base, track.knot_t[track.knots(i)]]))
        samples_t.append(st)
        var_idx.append(np.full(len(st), i))
    flat_t = np.concatenate(samples_t) if samples_t else np.zeros(0)
    flat_var = np.concatenate(var_idx) if var_idx else np.zeros(0, dtype=int)
    values = evaluate_at(track, flat_var, flat_t)
    bounds = np.concatenate([[0], np.cumsum([len(x) for x in samples_t])])
    samples_v = [values[bounds[i] : bounds[i + 1]] for i in range(track.n_vars)]
    return fit_track(
        track.kind,
        track.names,
        track.targets,
        knot_ptr,
        knot_t,
        knot_v,
        knot_pose,
        knot_editing,
        samples_t,
        samples_v,
    )


def pose_arrays(track: Track, n_poses: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose-level view: extreme knot times (K, V), extreme values (K, V, D),
    editing values (K, V, D) (equal to the extreme value where there is no
    editing knot)."""
    V = track.n_vars
    var = np.repeat(np.arange(V), np.diff(track.knot_ptr))
    ext = ~track.knot_editing
    ext_t = np.full((n_poses, V), np.nan)
    ext_t[track.knot_pose[ext], var[ext]] = track.knot_t[ext]
    value = np.zeros((n_poses, V, track.dim))
    value[track.knot_pose[ext], var[ext]] = track.knot_v[ext]
    edit = value.copy()
    ed = track.knot_editing
    edit[track.knot_pose[ed], var[ed]] = track.knot_v[ed]
    return ext_t, value, edit
