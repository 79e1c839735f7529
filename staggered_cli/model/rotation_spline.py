"""Rotation segments: Shoemake's cubic by recursive slerp (paper 4.1.1).

Rotations (unit quaternions, **w first**) use Shoemake's cubic built by
recursive slerp (de Casteljau with slerp) with endpoints ``q0``, ``q3`` and
tangent quaternions stored relative to them as rotation vectors (radians)::

    q1 = q0 * exp(a),   q2 = q3 * exp(b).

Every slerp takes the shorter arc, so the curve depends on the rotations
only: ``q`` and ``-q`` endpoints give the same rotations.  The default
("uniform") tangents give exactly ``slerp(q0, q3, u)``.

The curve and its Jacobian are computed on component-major rows
(:mod:`staggered_cli.quat_rows`), samples in chunks of about ``CHUNK`` so
that the rows stay in cache.
"""

from __future__ import annotations

import numpy as np

from .. import quat, quat_rows
from .segments import as_points, check_samples, compact_segments


def check_rotation_segments(q0, a, b, q3) -> tuple[np.ndarray, ...]:
    q0 = as_points("q0", q0)
    q3 = as_points("q3", q3)
    a = as_points("a", a)
    b = as_points("b", b)
    if q0.shape[-1] != 4 or q3.shape != q0.shape:
        raise ValueError(f"q0 and q3 must both have shape (S, 4), got {q0.shape} and {q3.shape}")
    if a.shape != (q0.shape[0], 3) or b.shape != a.shape:
        raise ValueError(f"a and b must both have shape ({q0.shape[0]}, 3), got {a.shape} and {b.shape}")
    return quat.normalize(q0), a, b, quat.normalize(q3)


#: Samples are evaluated (and fitted, see :mod:`.rotation_fit`) in chunks of
#: about this many, so that the component rows stay in cache.
CHUNK = 8192


# A Jacobian is a pair of (3, 3, n) blocks (d/da, d/db), None for a zero block.
_Jac = tuple


def _add_terms(*terms: np.ndarray | None) -> np.ndarray | None:
    out = None
    for t in terms:
        if t is not None:
            if out is None:
                out = t
            else:  # the terms are fresh products (of quat_rows.mm): add in place
                out += t
    return out


def _slerp_t(
    x: np.ndarray,
    jx: _Jac | None,
    z: np.ndarray,
    jz: _Jac | None,
    u: np.ndarray,
    log: tuple | None = None,
    th_terms: tuple | None = None,
) -> tuple[np.ndarray, _Jac | None]:
    """Shorter-arc slerp ``y = x exp(u log(x^-1 z))`` on (4, n) rows, with its Jacobian.

    Jacobians are of right perturbations: ``x exp(jx @ dp)``.  Perturbing x
    by dx and z by dz moves y by
    ``(exp(-uK) - C exp(-K)) dx + C dz`` with ``C = u J_r(u w) J_r^-1(w)``,
    ``w = log(x^-1 z)`` and ``K = [w]x``; ``log``, when given, is that
    ``(w, |w|)`` computed beforehand, and ``th_terms`` its angle's
    ``(quat_rows.jr_inv_k2, _sinc, _f1)`` (the last two needed with ``jx`` only).

    Polynomials of the constant 1 (or 1/2) hold the float itself: the same
    numbers as rows of ones, without the rows.
    """
    w, th = quat_rows.log(quat_rows.mul_conj(x, z)) if log is None else log
    ut = u * th
    y = quat_rows.mul(x, quat_rows.exp(u * w, ut))
    if jx is None and jz is None:
        return y, None
    t2 = th * th
    # each function of an angle computed once for its every use
    if jx is None:
        f1_ut, f2_ut = quat_rows.coefficients(ut, "f1", "f2")
        g_th = quat_rows.coefficients(th, "g")[0] if th_terms is None else th_terms[0]
    else:
        f1_ut, f2_ut, sinc_ut = quat_rows.coefficients(ut, "f1", "f2", "sinc")
        g_th, sinc_th, f1_th = quat_rows.coefficients(th, "g", "sinc", "f1") if th_terms is None else th_terms
    c = quat_rows.pmul(quat_rows.jr(u, th, (f1_ut, f2_ut)), (1.0, 0.5, g_th), t2)
    cm = quat_rows.pmatrix(c, w, t2) if jz is not None else None
    am = None
    if jx is not None:
        exp_mu = (1.0, -u * sinc_ut, u * u * f1_ut)
        exp_m1 = (1.0, -sinc_th, f1_th)
        c_e = quat_rows.pmul(c, exp_m1, t2)
        am = quat_rows.pmatrix(tuple(p - q for p, q in zip(exp_mu, c_e, strict=True)), w, t2)
    jy = []
    for i in range(2):
        bx = None if jx is None or jx[i] is None else quat_rows.mm(am, jx[i])
        bz = None if jz is None or jz[i] is None else quat_rows.mm(cm, jz[i])
        jy.append(_add_terms(bx, bz))
    return y, (jy[0], jy[1])


def curve_rows(
    q0: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    q3: np.ndarray,
    u: np.ndarray,
    jacobian: bool,
    idx: np.ndarray | None = None,
) -> tuple[np.ndarray, _Jac | None]:
    """The recursive-slerp cubic on (k, n) rows; ``a``, ``b`` have angles <= pi.

    With ``idx`` (n,), ``q0``, ``a``, ``b``, ``q3`` are (k, S) rows of S
    segments and sample ``i`` lies on segment ``idx[i]``: what depends on
    the segment alone (the inner controls, their Jacobians and the log of
    the middle slerp) is computed once per segment and then gathered, which
    gives the same numbers as gathering first.

    The outer slerps are written in closed form: with |a| <= pi,
    ``slerp(q0, q0 exp(a), u) = q0 exp(u a)`` and
    ``slerp(q3 exp(b), q3, u) = q3 exp((1 - u) b)``.
    """
    ta = np.sqrt(np.sum(a * a, axis=0))
    tb = np.sqrt(np.sum(b * b, axis=0))
    q1 = quat_rows.mul(q0, quat_rows.exp(a, ta))
    q2 = quat_rows.mul(q3, quat_rows.exp(b, tb))
    log12 = quat_rows.log(quat_rows.mul_conj(q1, q2))
    if jacobian:
        j1 = (quat_rows.pmatrix(quat_rows.jr(1.0, ta), a, ta * ta), None)
        j2 = (None, quat_rows.pmatrix(quat_rows.jr(1.0, tb), b, tb * tb))
        # the middle slerp's functions of its angle, once per segment
        th12 = quat_rows.coefficients(log12[1], "g", "sinc", "f1")
    else:
        j1 = j2 = th12 = None
    if idx is not None:
        # np.take keeps the rows contiguous (fancy indexing of the last axis
        # would give sample-major strides, which einsum handles slowly)
        q0, a, b, q3, ta, tb, q1, q2 = (np.take(x, idx, axis=-1) for x in (q0, a, b, q3, ta, tb, q1, q2))
        log12 = (np.take(log12[0], idx, axis=-1), log12[1][idx])
        if jacobian:
            j1, j2 = (np.take(j1[0], idx, axis=-1), None), (None, np.take(j2[1], idx, axis=-1))
            th12 = tuple(f[idx] for f in th12)
    v = 1.0 - u
    q01 = quat_rows.mul(q0, quat_rows.exp(u * a, u * ta))
    q23 = quat_rows.mul(q3, quat_rows.exp(v * b, v * tb))
    if jacobian:
        ta2, tb2 = ta * ta, tb * tb
        j01 = (quat_rows.pmatrix(quat_rows.jr(u, ta), a, ta2), None)
        j23 = (None, quat_rows.pmatrix(quat_rows.jr(v, tb), b, tb2))
    else:
        j01 = j23 = None
    q12, j12 = _slerp_t(q1, j1, q2, j2, u, log12, th12)
    q012, j012 = _slerp_t(q01, j01, q12, j12, u)
    q123, j123 = _slerp_t(q12, j12, q23, j23, u)
    return _slerp_t(q012, j012, q123, j123, u)


def wrap_rotation_vector(v: np.ndarray) -> np.ndarray:
    """The same rotation (..., 3) with angle at most pi, as ``quat.log`` gives it."""
    t = quat.norm(v)[..., None]
    over = t > np.pi
    return np.where(over, v * (1.0 - 2.0 * np.pi / np.where(over, t, 1.0)), v)


def rotation_eval(q0: np.ndarray, a: np.ndarray, b: np.ndarray, q3: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Evaluate every rotation segment at the same normalized times.

    Parameters
    ----------
    q0, q3 : (S, 4) arrays
        Knot rotations, unit quaternions, w first.
    a, b : (S, 3) arrays
        Tangents as rotation vectors (radians): q1 = q0 exp(a), q2 = q3 exp(b).
    u : (N,) array
        Normalized times.

    Returns
    -------
    (S, N, 4) array of unit quaternions, w first (sign as in :func:`rotation_eval_at`).
    """
    u = np.asarray(u, dtype=float)
    if u.ndim != 1:
        raise ValueError(f"u must be a 1-d array, got shape {u.shape}")
    s = np.asarray(q0).shape[0] if np.ndim(q0) == 2 else 0
    seg = np.repeat(np.arange(s), u.shape[0])
    return rotation_eval_at(q0, a, b, q3, seg, np.tile(u, s)).reshape(s, u.shape[0], 4)


def rotation_eval_at(
    q0: np.ndarray, a: np.ndarray, b: np.ndarray, q3: np.ndarray, seg: np.ndarray, u: np.ndarray
) -> np.ndarray:
    """Evaluate sample ``n`` on rotation segment ``seg[n]`` at time ``u[n]``.

    Shoemake's cubic: de Casteljau's construction with slerp along the
    shorter arc on the controls q0, q1 = q0 exp(a), q2 = q3 exp(b), q3.

    Parameters
    ----------
    q0, q3 : (S, 4) arrays
        Knot rotations, unit quaternions, w first (either sign).
    a, b : (S, 3) arrays
        Tangents as rotation vectors (radians); angles above pi are the
        same rotations as their wrapped vectors.
    seg : (N,) int array
        Segment index of each sample.
    u : (N,) array
        Normalized time of each sample.

    Returns
    -------
    (N, 4) array
        Unit quaternions, w first.  The sign varies continuously with ``u``
        starting from exactly ``q0`` at u = 0, so at u = 1 the value is ``q3``
        or ``-q3`` (``q3`` on tracks kept on one hemisphere, unless the curve
        swings more than half a turn away from it).
    """
    q0, a, b, q3 = check_rotation_segments(q0, a, b, q3)
    seg, u = check_samples(seg, u, q0.shape[0])
    a, b = wrap_rotation_vector(a), wrap_rotation_vector(b)
    out = np.empty((u.shape[0], 4))
    for lo in range(0, u.shape[0], CHUNK):
        sg = seg[lo : lo + CHUNK]
        used, idx = compact_segments(sg)
        q, _ = curve_rows(q0[used].T, a[used].T, b[used].T, q3[used].T, u[lo : lo + CHUNK], False, idx)
        out[lo : lo + CHUNK] = q.T
    return quat.normalize(out)


def default_rotation_tangents(q0: np.ndarray, q3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform tangents: the cubic is exactly ``slerp(q0, q3, u)``.

    Parameters
    ----------
    q0, q3 : (S, 4) arrays
        Unit quaternions, w first.

    Returns
    -------
    a, b : (S, 3) arrays (radians)
        ``log(q0^-1 q3) / 3`` and ``log(q3^-1 q0) / 3`` (shorter arc).
    """
    q0 = np.asarray(q0, dtype=float)
    q3 = np.asarray(q3, dtype=float)
    if q0.shape != q3.shape or q0.shape[-1:] != (4,):
        raise ValueError(f"q0 and q3 must both have shape (..., 4), got {q0.shape} and {q3.shape}")
    q0, q3 = quat.normalize(q0), quat.normalize(q3)
    return quat.log(quat.mul(quat.conj(q0), q3)) / 3.0, quat.log(quat.mul(quat.conj(q3), q0)) / 3.0
