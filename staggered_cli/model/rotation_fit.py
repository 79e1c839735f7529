"""The batched fit of rotation tangents (paper Appendix A, SPEC section 4 step 8).

Rotation tangents are fitted by a batched Levenberg–Marquardt on the sum of
squared rotation angles between spline and samples, with an analytic
Jacobian built from the right Jacobians of SO(3).  It replaces the paper's
per-segment Nelder–Mead with a unit-length penalty: the tangents are exactly
unit by construction and all segments are solved together.
"""

from __future__ import annotations

import numpy as np

from .. import quat, quat_rows
from . import rotation_spline
from .bezier import fit_translation_tangents
from .rotation_spline import (
    check_rotation_segments,
    curve_rows,
    default_rotation_tangents,
    rotation_eval_at,
    wrap_rotation_vector,
)
from .segments import as_points, check_samples

#: Up to this many samples, a trial step's error and Jacobian are one call
_TAIL_SAMPLES = 1024
#: At the end of a fit, on at most this many samples, the next steps of a
#: segment (if the ones before fail) are tried in the same call, at most
#: _TRIES of them: the calls are still about their fixed cost (on 1024
#: samples, the steps pipeline of the 10 dev files was 4 % slower)
_TRIAL_SAMPLES = 256
_TRIES = 8
# An RMS angle (radians, about 6e-7 degrees) below which a fit has converged:
# far below the digits of any mocap file.
_NEGLIGIBLE = 1e-8


def _residuals_t(
    q0: np.ndarray,
    x: np.ndarray,
    q3: np.ndarray,
    u: np.ndarray,
    values: np.ndarray,
    jacobian: bool,
    idx: np.ndarray | None = None,
    curve: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals ``log(values^-1 s(u))`` (3, n) and their Jacobian (3, 6, n)
    (and the curve ``s(u)`` itself written into ``curve`` (4, n), if given).

    ``x`` (6, n) holds (a, b) per sample, angles <= pi (or, with ``idx``,
    ``q0``, ``x``, ``q3`` are per segment, as in :func:`curve_rows`).
    ``|residual|`` is the angle between spline and sample.
    """
    s, js = curve_rows(q0, x[:3], x[3:], q3, u, jacobian, idx)
    if curve is not None:
        curve[...] = s
    r, th = quat_rows.log(quat_rows.mul_conj(values, s))
    if not jacobian:
        return r, None
    t2 = th * th
    jinv = quat_rows.pmatrix((1.0, 0.5, quat_rows.jr_inv_k2(th)), r, t2)
    j = np.empty((3, 6, th.shape[-1]))
    quat_rows.mm(jinv, js[0], out=j[:, :3])
    quat_rows.mm(jinv, js[1], out=j[:, 3:])
    return r, j


def _rotation_residuals(
    q0: np.ndarray, x: np.ndarray, q3: np.ndarray, u: np.ndarray, values: np.ndarray, jacobian: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """Sample-major wrapper of the residual kernel (for tests).

    q0, q3, values (N, 4); x (N, 6) with angles <= pi; u (N,).
    Returns residuals (N, 3) and, if asked, d residual / d x (N, 3, 6).
    """
    r, j = _residuals_t(q0.T, x.T, q3.T, u, values.T, jacobian)
    return r.T, None if j is None else np.moveaxis(j, -1, 0)


def _check_rotation_values(values: np.ndarray, n: int) -> np.ndarray:
    values = as_points("values", values)
    if values.shape != (n, 4):
        raise ValueError(f"values must have shape ({n}, 4), got {values.shape}")
    return quat.normalize(values)


def rotation_fit_errors(
    q0: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    q3: np.ndarray,
    seg: np.ndarray,
    u: np.ndarray,
    values: np.ndarray,
    n_segments: int,
) -> np.ndarray:
    """RMS angle (radians) between each segment's spline and its samples.

    Parameters
    ----------
    q0, a, b, q3 : segments as in :func:`rotation_eval_at`, S = ``n_segments``.
    seg, u : (N,) arrays, samples as in :func:`rotation_eval_at`.
    values : (N, 4) array, sample rotations (unit, w first, either sign).
    n_segments : int

    Returns
    -------
    (S,) array, NaN for segments without samples.
    """
    q0, a, b, q3 = check_rotation_segments(q0, a, b, q3)
    seg, u = check_samples(seg, u, n_segments)
    if q0.shape[0] != n_segments:
        raise ValueError(f"q0 must have {n_segments} rows, got {q0.shape[0]}")
    values = _check_rotation_values(values, u.shape[0])
    ang = quat.angle_between(rotation_eval_at(q0, a, b, q3, seg, u), values)
    count = np.bincount(seg, minlength=n_segments)
    total = np.bincount(seg, weights=ang * ang, minlength=n_segments)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(total / count)


class _NormalEquations:
    """Per-segment Gauss–Newton sums over samples grouped by segment.

    Holds the usable samples sorted by segment in component-major form, and
    evaluates, for any subset of segments, the squared error, J^T J and
    J^T r in chunks that never split a segment.
    """

    def __init__(self, q0, q3, seg, u, values, n_segments):
        order = np.argsort(seg, kind="stable")
        self.order = order
        self.seg = seg[order]
        self.u = u[order]
        self.q0 = q0.T.copy()  # per segment: curve_rows gathers them
        self.q3 = q3.T.copy()
        self.values = values[order].T.copy()
        self.count = np.bincount(seg, minlength=n_segments)
        self.first = np.concatenate([[0], np.cumsum(self.count)[:-1]])

    def samples(self, rows: np.ndarray) -> np.ndarray:
        """Indices (in this object's sorted order) of the samples of segments ``rows``."""
        return self._spans(rows)[2]

    def _spans(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample counts (R,) and offsets (R+1,) of segments ``rows``, and
        their samples' indices, in segment order."""
        counts = self.count[rows]
        offsets = np.concatenate([[0], np.cumsum(counts)])
        return counts, offsets, np.repeat(self.first[rows] - offsets[:-1], counts) + np.arange(offsets[-1])

    def __call__(
        self,
        rows: np.ndarray,
        x: np.ndarray,
        jacobian: bool = True,
        curve: np.ndarray | None = None,
        in_call_order: bool = False,
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Squared error (R,), J^T J (R, 6, 6) and J^T r (R, 6) of segments
        ``rows`` at ``x`` (R, 6); without ``jacobian``, the error alone (and
        None, None).  With ``curve`` (4, N), the spline at the samples is
        written there, each at its sorted index (``in_call_order``: one
        segment after the other as ``rows`` lists them, which may repeat)."""
        counts, offsets, idx = self._spans(rows)
        local = np.repeat(np.arange(rows.size), counts)
        # chunk boundaries at segment starts
        group = offsets[:-1] // rotation_spline.CHUNK
        cuts = np.concatenate([[0], np.flatnonzero(np.diff(group)) + 1, [rows.size]])
        cost = np.empty(rows.size)
        jtj = np.empty((rows.size, 6, 6)) if jacobian else None
        jtr = np.empty((rows.size, 6)) if jacobian else None
        for s0, s1 in zip(cuts[:-1], cuts[1:], strict=True):
            lo, hi = offsets[s0], offsets[s1]
            sl = idx[lo:hi]
            if not in_call_order and hi > lo and sl[-1] - sl[0] == hi - lo - 1:
                # consecutive samples (rows increase, so idx does): a view;
                # rows that repeat may span as many samples and not be them
                sl = slice(int(sl[0]), int(sl[-1]) + 1)
            segs = rows[s0:s1]
            q0, q3 = self.q0[:, segs], self.q3[:, segs]
            s_out = None if curve is None else np.empty((4, hi - lo))
            r, j = _residuals_t(q0, x[s0:s1].T, q3, self.u[sl], self.values[:, sl], jacobian, local[lo:hi] - s0, s_out)
            if curve is not None:
                curve[:, slice(lo, hi) if in_call_order else sl] = s_out
            starts = offsets[s0:s1] - lo
            cost[s0:s1] = np.add.reduceat(np.sum(r * r, axis=0), starts)
            if not jacobian:
                continue
            jtj[s0:s1] = _gram_sums(j, starts)
            jr = j[0] * r[0]
            jr += np.multiply(j[1], r[1], out=j[0])  # (j's rows are not needed again)
            jr += np.multiply(j[2], r[2], out=j[0])
            jtr[s0:s1] = np.add.reduceat(jr, starts, axis=-1).T
        return cost, jtj, jtr


# the entries (p, q), p <= q, of a symmetric 6x6 matrix, row by row
_UPPER = np.triu_indices(6)


def _gram_sums(j: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Sums ``sum_n j[:, :, n]^T j[:, :, n]`` (S, 6, 6) over the runs of
    samples beginning at ``starts`` of Jacobians ``j`` (3, 6, n).

    Each entry is ``j0p j0q + j1p j1q + j2p j2q`` summed left to right, as
    the whole product of broadcast rows gives it; only the upper triangle
    is computed (``x * y == y * x`` exactly) and mirrored.
    """
    n = j.shape[-1]
    upper = np.empty((21, n))
    t = np.empty((6, n))
    r = 0
    for p in range(6):
        k = 6 - p
        o = upper[r : r + k]
        np.multiply(j[0, p], j[0, p:], out=o)
        o += np.multiply(j[1, p], j[1, p:], out=t[:k])
        o += np.multiply(j[2, p], j[2, p:], out=t[:k])
        r += k
    sums = np.add.reduceat(upper, starts, axis=-1)  # (21, S)
    out = np.empty((len(starts), 6, 6))
    out[:, _UPPER[0], _UPPER[1]] = sums.T
    out[:, _UPPER[1], _UPPER[0]] = sums.T
    return out


def _tangent_space_start(
    q0: np.ndarray, q3: np.ndarray, seg: np.ndarray, u: np.ndarray, values: np.ndarray, n_segments: int
) -> np.ndarray:
    """Tangents (S, 6) from a linear Bezier fit of log(q0^-1 q) over each segment."""
    r = quat.log(quat.mul(quat.conj(q0[seg]), values))
    r3 = quat.log(quat.mul(quat.conj(q0), q3))
    p1_rel, p2_rel = fit_translation_tangents(np.zeros_like(r3), r3, seg, u, r, n_segments)
    p1, p2 = p1_rel, r3 + p2_rel  # the inner controls in the tangent space at q0
    a = wrap_rotation_vector(p1)
    b = wrap_rotation_vector(quat.log(quat.mul(quat.conj(q3), quat.mul(q0, quat.exp(p2)))))
    return np.concatenate([a, b], axis=-1)


def _damped_steps(jtj: np.ndarray, jtr: np.ndarray, lam: np.ndarray, eye: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt steps (R, 6) of segments with normal equations
    ``jtj`` (R, 6, 6), ``jtr`` (R, 6) and damping ``lam`` (R,), and the
    decrease of the squared error the Gauss-Newton model promises (R,)."""
    diag = np.diagonal(jtj, axis1=-2, axis2=-1)
    # Marquardt scaling, floored so that a direction the samples barely
    # see still gets a bounded step
    scale = np.maximum(diag, 1e-9 * np.max(diag, axis=-1, keepdims=True) + 1e-300)
    h = jtj + (lam[:, None] * scale)[:, :, None] * eye
    step = -np.linalg.solve(h, jtr[..., None])[..., 0]
    # decrease promised by the Gauss-Newton model: when even that is
    # negligible the segment has converged, and evaluating is wasted work
    predicted = -(2.0 * np.sum(step * jtr, axis=-1) + np.einsum("si,sij,sj->s", step, jtj, step))
    return step, predicted


def _trial_tangents(params: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangents (R, 6) after ``step``, each angle wrapped to at most pi (the
    tangents as they were where a step is not finite), and which are finite."""
    trial = params + step
    trial = np.concatenate([wrap_rotation_vector(trial[:, :3]), wrap_rotation_vector(trial[:, 3:])], -1)
    finite = np.all(np.isfinite(trial), axis=-1)
    return np.where(finite[:, None], trial, params), finite


def fit_rotation_tangents(
    q0: np.ndarray,
    q3: np.ndarray,
    seg: np.ndarray,
    u: np.ndarray,
    values: np.ndarray,
    n_segments: int,
    iterations: int = 30,
    rtol: float = 1e-4,
    damping: float = 1e-3,
    return_curve: bool = False,
) -> tuple[np.ndarray, ...]:
    """Fit the tangents of every rotation segment at once (batched Levenberg–Marquardt).

    Minimizes, per segment, the sum over its samples with ``0 < u < 1`` of
    the squared angle between the spline and the sample: the objective of
    the paper's Appendix A without its unit-length penalty, since the
    tangents ``q0 exp(a)``, ``q3 exp(b)`` are unit by construction.  Starts
    from the uniform tangents (exactly slerp) and accepts a step only when it
    lowers that segment's error, so no segment ends worse than slerp.  Each
    segment has its own damping and stops on its own once converged.
    Segments with no usable sample keep the uniform tangents; one with a
    single sample starts from the tangent-space fit that bends the uniform
    controls through it (:func:`.bezier.fit_translation_tangents`) and
    meets it (issue 34: a knot on an extreme a frame or two from its editing
    knot left the slerp to miss the bend between them).

    Parameters
    ----------
    q0, q3 : (S, 4) arrays
        Knot rotations, unit quaternions, w first (either sign).
    seg : (N,) int array
        Segment index of each sample, in ``range(n_segments)``.
    u : (N,) array
        Normalized time of each sample.
    values : (N, 4) array
        Sample rotations, unit quaternions, w first (either sign).
    n_segments : int
        ``S``.
    iterations : int
        At most this many Levenberg–Marquardt steps per segment.
    rtol : float
        A segment stops once an accepted step lowers its squared error by
        less than this fraction, or the Gauss-Newton model promises less.
        The default 1e-4 ends every segment of the real clips within 0.02 %
        of the fully converged error (1e-8; the spline RMS of whole clips
        within 0.001 %), with a fifth fewer Jacobian evaluations.
    damping : float
        Initial Marquardt damping, relative to the diagonal of J^T J.

    Returns
    -------
    a, b : (S, 3) arrays
        Tangent rotation vectors (radians, angle at most pi): q1 = q0 exp(a),
        q2 = q3 exp(b).  Always finite.
    at, curve : (M,) int and (M, 4) arrays, with ``return_curve`` only
        The spline at samples ``at`` (of those given), as the fit last
        evaluated it there: ``rotation_eval_at(q0, a, b, q3, seg[at],
        u[at])`` bit for bit, without evaluating it again.
    """
    q0 = as_points("q0", q0)
    q3 = as_points("q3", q3)
    if q0.shape != (n_segments, 4) or q3.shape != q0.shape:
        raise ValueError(f"q0 and q3 must both have shape ({n_segments}, 4), got {q0.shape} and {q3.shape}")
    seg, u = check_samples(seg, u, n_segments)
    values = _check_rotation_values(values, u.shape[0])
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")
    q0, q3 = quat.normalize(q0), quat.normalize(q3)
    a0, b0 = default_rotation_tangents(q0, q3)
    params = np.concatenate([a0, b0], axis=-1)

    use = (u > 0.0) & (u < 1.0) & np.all(np.isfinite(values), axis=-1)
    active = np.bincount(seg[use], minlength=n_segments) >= 1
    use &= active[seg]
    if iterations == 0 or not np.any(active):
        return (a0, b0, np.zeros(0, dtype=np.intp), np.zeros((0, 4))) if return_curve else (a0, b0)
    normal = _NormalEquations(q0, q3, seg[use], u[use], values[use], n_segments)
    # the spline at each sample at its segment's accepted tangents, and at the last trial
    kept_curve = np.empty((4, normal.u.size)) if return_curve else None
    trial_curve = np.empty((4, normal.u.size)) if return_curve else None

    def accept(segments: np.ndarray) -> None:
        if return_curve and segments.size:
            at = normal.samples(segments)
            kept_curve[:, at] = trial_curve[:, at]

    rows = np.flatnonzero(active)
    cost = np.zeros(n_segments)
    jtj = np.zeros((n_segments, 6, 6))
    jtr = np.zeros((n_segments, 6))
    # a second start: the Bezier fitted linearly in the tangent space at q0,
    # which is close to the optimum for the small turns of most segments;
    # each segment starts from whichever of the two fits better.  The second
    # wins for most segments (about 7 in 8 of the samples): the Jacobian is
    # built with its error, and again at the first only where that one wins
    cost[rows] = normal(rows, params[rows], jacobian=False, curve=kept_curve)[0]
    guess = _tangent_space_start(q0, q3, seg[use], u[use], values[use], n_segments)[rows]
    g_cost, g_jtj, g_jtr = normal(rows, guess, curve=trial_curve)
    take = np.isfinite(g_cost) & (g_cost < cost[rows])
    won = rows[take]
    accept(won)
    params[won], cost[won], jtj[won], jtr[won] = guess[take], g_cost[take], g_jtj[take], g_jtr[take]
    del g_jtj, g_jtr
    kept = rows[~take]
    if kept.size:
        _, jtj[kept], jtr[kept] = normal(kept, params[kept])
    lam = np.full(n_segments, float(damping))
    eye = np.eye(6)
    # a segment whose samples the curve meets to within _NEGLIGIBLE radians
    # has converged (a segment of two samples is fitted exactly and would
    # otherwise chase rounding towards zero for every iteration)
    floor = _NEGLIGIBLE**2 * normal.count

    def tail(start: int) -> None:
        # the last segments still moving, on a few samples: each call costs
        # its fixed ~1 ms more than its samples, and a segment whose steps
        # fail takes one call per failure.  The steps the next failures
        # would take (the same Jacobian, the damping times 4, 16, ...) are
        # tried in the same call, and the sequence replayed segment by
        # segment: the same steps, numbers and decisions as one at a time,
        # each segment counting its own iterations
        count = np.full(n_segments, start)
        while True:
            rows = np.flatnonzero(active)
            if rows.size == 0:
                return
            R = rows.size
            k = max(1, min(_TRIES, _TRIAL_SAMPLES // max(int(normal.count[rows].sum()), 1)))
            lams = [lam[rows]]
            for _ in range(k - 1):
                lams.append(lams[-1] * 4.0)
            lam_k = np.concatenate(lams)
            rows_k = np.tile(rows, k)
            step, predicted = _damped_steps(jtj[rows_k], jtr[rows_k], lam_k, eye)
            trial, finite = _trial_tangents(params[rows_k], step)
            sizes = normal.count[rows_k]
            call_curve = np.empty((4, int(sizes.sum()))) if return_curve else None
            c_new, t_jtj, t_jtr = normal(rows_k, trial, curve=call_curve, in_call_order=True)
            starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            pending = np.ones(R, dtype=bool)  # the segments whose next step this call holds
            for j in range(k):
                at = j * R + np.arange(R)
                it = count[rows]
                spent = pending & (it >= iterations)
                done = pending & ~spent & ((predicted[at] <= rtol * cost[rows]) | (cost[rows] <= floor[rows]))
                active[rows[spent | done]] = False
                pending &= ~(spent | done)
                better = pending & finite[at] & np.isfinite(c_new[at]) & (c_new[at] < cost[rows])
                ok, p = rows[better], at[better]
                if return_curve and ok.size:
                    n = normal.count[ok]
                    src = np.repeat(starts[p] - np.concatenate([[0], np.cumsum(n)[:-1]]), n) + np.arange(int(n.sum()))
                    kept_curve[:, normal.samples(ok)] = call_curve[:, src]
                converged = (cost[ok] - c_new[p] <= rtol * cost[ok]) | (c_new[p] <= floor[ok])
                params[ok], cost[ok] = trial[p], c_new[p]
                lam[ok] = np.maximum(lam_k[p] / 3.0, 1e-12)
                active[ok[converged]] = False
                again = ~converged & (it[better] + 1 < iterations)
                jtj[ok[again]], jtr[ok[again]] = t_jtj[p[again]], t_jtr[p[again]]
                count[ok] = it[better] + 1
                pending &= ~better
                bad = rows[pending]
                lam[bad] = lam_k[at[pending]] * 4.0
                count[bad] += 1
                # a segment whose steps keep failing sits at a minimum, to rounding
                stuck = pending & (lam[rows] > 1e8)
                active[rows[stuck]] = False
                pending &= ~stuck
            active[rows[count[rows] >= iterations]] = False

    for it in range(iterations):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        if 2 * int(normal.count[rows].sum()) <= _TRIAL_SAMPLES:
            tail(it)
            break
        step, predicted = _damped_steps(jtj[rows], jtr[rows], lam[rows], eye)
        done = (predicted <= rtol * cost[rows]) | (cost[rows] <= floor[rows])
        active[rows[done]] = False
        rows, step = rows[~done], step[~done]
        if rows.size == 0:
            break
        trial, finite = _trial_tangents(params[rows], step)

        # the error first: the Jacobian is needed only where a step is
        # accepted and another will be taken from there.  On a few samples
        # (the last segments still moving) a call costs its fixed ~0.4 ms
        # more than its samples: the Jacobian comes with the error in one
        # call, the same numbers at the same tangents, kept where needed
        last = it + 1 == iterations
        both = not last and int(normal.count[rows].sum()) <= _TAIL_SAMPLES
        c_new, t_jtj, t_jtr = normal(rows, trial, jacobian=both, curve=trial_curve)
        better = finite & np.isfinite(c_new) & (c_new < cost[rows])
        ok = rows[better]
        accept(ok)
        converged = (cost[ok] - c_new[better] <= rtol * cost[ok]) | (c_new[better] <= floor[ok])
        params[ok], cost[ok] = trial[better], c_new[better]
        lam[ok] = np.maximum(lam[ok] / 3.0, 1e-12)
        bad = rows[~better]
        lam[bad] *= 4.0
        active[ok[converged]] = False
        # a segment whose steps keep failing sits at a minimum, to rounding
        active[bad[lam[bad] > 1e8]] = False
        again = ok[~converged]
        if again.size and not last:
            if both:
                at = np.flatnonzero(better)[~converged]
                jtj[again], jtr[again] = t_jtj[at], t_jtr[at]
            else:
                _, jtj[again], jtr[again] = normal(again, params[again])

    a, b = params[:, :3].copy(), params[:, 3:].copy()
    if not return_curve:
        return a, b
    # rotation_eval_at wraps the tangents again: a segment whose tangents
    # that would change (an angle within rounding of pi) keeps none of its samples
    same = np.all(wrap_rotation_vector(a) == a, axis=-1) & np.all(wrap_rotation_vector(b) == b, axis=-1)
    sure = same[normal.seg]
    at = np.flatnonzero(use)[normal.order[sure]]
    return a, b, at, quat.normalize(np.ascontiguousarray(kept_curve[:, sure].T))
