"""Fitting a track to motion: knots from staggered poses, splines and displacement maps (paper 4.1).

A layer is fitted to samples between given knots: each segment's spline
(:mod:`.bezier` for translations, :mod:`.rotation_fit` for rotations) and the
displacement map that carries the samples' detail on top of it, so the
motion at the samples stays exact.
"""

from __future__ import annotations

import numpy as np

from .. import quat
from . import bezier, kinds, rotation_fit, rotation_spline
from .kinds import TRANSLATION
from .knots import DIM, Fitted, Knots, Layer, Track, check_knot_order, locate_inside

#: Rotation tangents are fitted to at most this many evenly spread samples of
#: a segment, with at most this many Levenberg-Marquardt steps (the
#: displacement maps still keep every sample, so the motion stays exact): a
#: cubic has four controls, and at 120 Hz most segments hold 15-30 frames that
#: add fitting time, not information.  Against all samples and 30 steps, the
#: mean spline error of cmu_01_01 grows from 0.560 to 0.568 degrees and the
#: fit takes a third of the time.
FIT_SAMPLES = 8
FIT_ITERATIONS = 10


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
    owns: np.ndarray | None = None,
) -> Knots:
    """The knots of pose-level arrays.

    Parameters
    ----------
    pose_t : (K,) pose times, seconds.
    refine : (K, V) refinements, seconds.
    value : (K, V, D) extreme values.
    edit_value : (K, V, D) editing-knot values (used where ``refine != 0``).
    owns : (K, V) bool, which variables each pose has knots in (a partial
        pose owns one body part's, see :meth:`.document.Document.owns`);
        None: every pose owns every variable.  Where it is False the other
        arrays are not read.
    """
    K, V = refine.shape
    names = names or tuple(f"variable {i}" for i in range(V))
    d = value.shape[-1]
    own = np.ones((K, V), dtype=bool) if owns is None else np.asarray(owns, dtype=bool)
    # every variable's knots at once: its extreme knots (pose order), then
    # its editing knots (pose order), sorted by time within the variable,
    # stably (np.lexsort is), as one variable at a time would
    ex_var, ex_k = np.nonzero(own.T)  # variable-major, poses increasing
    ext_t = pose_t[ex_k] + refine[ex_k, ex_var]
    ed_var, ed_k = np.nonzero(((refine != 0.0) & own).T)  # variable-major, poses increasing
    var = np.concatenate([ex_var, ed_var])
    t = np.concatenate([ext_t, pose_t[ed_k]])
    order = np.lexsort((t, var))
    var, t = var[order], t[order]
    p = np.concatenate([ex_k, ed_k])[order]
    e = np.concatenate([np.zeros(len(ex_k), dtype=bool), np.ones(len(ed_k), dtype=bool)])[order]
    v = np.concatenate([value[ex_k, ex_var].reshape(-1, d), edit_value[ed_k, ed_var].reshape(-1, d)])[order]
    crossed = np.flatnonzero((np.diff(p) < 0) & (np.diff(var) == 0))
    if len(crossed):
        from ..errors import KnotOrderError

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
    owns: np.ndarray | None = None,
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
    owns : (K, V) bool, the variables each pose has knots in (partial
        poses, see :func:`knots_from_poses`); None: all.
    """
    K, V = refine.shape
    extreme_t = pose_t[:, None] + refine
    if isinstance(dense, np.ndarray):
        value = sample_dense(kind, frame_t, dense, extreme_t)
        edit_value = sample_dense(kind, frame_t, dense, pose_t)
        knots = knots_from_poses(pose_t, refine, value, edit_value, names, owns)
        columns = [dense[:, i] for i in range(V)]
    else:
        # a sequence of V (T, D) columns, each made when asked for: every
        # variable's knot values are sampled when the fit takes its column
        # (the same numbers as from all of them at once)
        d = DIM[kind]
        knots = knots_from_poses(pose_t, refine, np.zeros((K, V, d)), np.zeros((K, V, d)), names, owns)
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
    of about :data:`FIT_GROUP` samples each (every segment's fit is its own,
    so grouping does not change a bit), filling outputs allocated once: the
    temporaries stay bounded however long the clip.
    """
    V = knots.n_vars
    seg_ptr = knots.seg_ptr
    d = DIM[kind]
    # first the number of samples each variable keeps, so that the outputs
    # are allocated once and filled group by group
    counts = np.zeros(V, dtype=int)
    # each variable's samples located once where they are few (17 bytes a
    # sample kept); a long clip's are located again, group by group
    located: list = [None] * V
    held = 0
    for i in range(V):
        where = locate_inside(knots.t[knots.of(i)], np.asarray(samples_t[i], dtype=float))
        counts[i] = np.count_nonzero(where[2])
        held += len(where[2])
        if held <= FIT_GROUP:
            located[i] = where
    samp_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    first = knots.seg_first
    n_seg = len(first)
    a = np.zeros((n_seg, 3))
    b = np.zeros((n_seg, 3))
    s_a = np.zeros(int(samp_ptr[-1]))
    disp = np.zeros((int(samp_ptr[-1]), d))
    # the spline at the samples, kept for a bake in this process where it is small
    spline = np.zeros_like(disp) if disp.nbytes <= FITTED_BYTES else None
    for i0, i1 in variable_groups(counts, FIT_GROUP):
        g0, g1 = int(seg_ptr[i0]), int(seg_ptr[i1])
        gseg, us, vals = [], [], []
        for i in range(i0, i1):
            kt = knots.t[knots.of(i)]
            seg, u, keep = located[i] or locate_inside(kt, np.asarray(samples_t[i], dtype=float))
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
        ga, gb, gdisp = fit_segments(kind, knots.v[fs], knots.v[fs + 1], gseg_a, u_a, v_a, g1 - g0, out)
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
    return fitted_layer(knots, a, b, samp_ptr, s_a, disp, spline)


def fitted_layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d, spline: np.ndarray | None) -> Layer:
    """The layer of these arrays, holding ``spline`` (its fit's values at the
    samples, or None) with the very arrays it belongs to."""
    if spline is None:
        return Layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d)
    spline.flags.writeable = False
    return Layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d, Fitted(knots, tan_a, tan_b, samp_ptr, samp_s, spline))


#: The largest spline at the samples a fitted layer keeps (:class:`Fitted`):
#: a clip of a few minutes; a longer one's bake evaluates it again.
FITTED_BYTES = 1 << 26

#: Samples fitted in one batched call by :func:`fit_layer` (whole variables:
#: a group holds at least one): its temporaries are a few hundred bytes a
#: sample, so about 40 MB.
FIT_GROUP = 1 << 17


def variable_groups(counts: np.ndarray, most: int) -> list[tuple[int, int]]:
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


def fit_segments(kind, p0, p3, gseg, u, values, n_seg, spline_out=None):
    """Tangents (n_seg, 3) x 2 of segments with endpoints ``p0``, ``p3`` fitted
    to samples ``values`` at (``gseg``, ``u``), and the displacements
    ``values ⊖ spline`` there (the spline itself into ``spline_out``, if given)."""
    if kind == TRANSLATION:
        a, b = bezier.fit_translation_tangents(p0, p3, gseg, u, values, n_seg)
        s_val = bezier.bezier_eval_at(p0, a, b, p3, gseg, u)
        if spline_out is not None:
            spline_out[...] = s_val
        return a, b, values - s_val
    values = quat.normalize(values)
    pick = _evenly_within_segments(gseg, FIT_SAMPLES)
    a, b, at, fitted = rotation_fit.fit_rotation_tangents(
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
        s_val[rest] = rotation_spline.rotation_eval_at(p0, a, b, p3, gseg[rest], u[rest])
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
