"""Cubic spline segments and their batched fitting (paper 4.1.1, Appendix A).

A *segment* joins two knot values on a normalized time ``u`` in [0, 1]
(SPEC section 3).  Every function here works on a whole batch of segments at
once: ``S`` segments, ``N`` samples, ``seg[n]`` the segment of sample ``n``.

Translations (``D`` components, file units) use a cubic Bézier with
endpoints ``p0``, ``p3`` and inner controls stored relative to them::

    P1 = p0 + a,   P2 = p3 + b.

Rotations (unit quaternions, **w first**) use Shoemake's cubic built by
recursive slerp (de Casteljau with slerp) with endpoints ``q0``, ``q3`` and
tangent quaternions stored relative to them as rotation vectors (radians)::

    q1 = q0 * exp(a),   q2 = q3 * exp(b).

Storing the inner controls relative to the endpoints means that editing a
knot value carries its tangent along.  Every slerp takes the shorter arc, so
the curve depends on the rotations only: ``q`` and ``-q`` endpoints give the
same rotations.

Defaults ("uniform" controls, for segments whose samples cannot determine
their tangents) are the straight line at uniform speed for translations and
exactly ``slerp(q0, q3, u)`` for rotations.

Rotation tangents are fitted by a batched Levenberg–Marquardt on the sum of
squared rotation angles between spline and samples, with an analytic
Jacobian built from the right Jacobians of SO(3).  It replaces the paper's
per-segment Nelder–Mead with a unit-length penalty (SPEC section 4, step 8):
the tangents are exactly unit by construction and all segments are solved
together.
"""

from __future__ import annotations

import numpy as np

from . import quat

__all__ = [
    "bezier_eval",
    "bezier_eval_at",
    "rotation_eval",
    "rotation_eval_at",
    "default_translation_tangents",
    "default_rotation_tangents",
    "fit_translation_tangents",
    "fit_rotation_tangents",
    "rotation_fit_errors",
]

# A 2x2 normal matrix whose condition number exceeds this cannot pin down two
# Bézier controls from the samples: keep the defaults.
_MAX_CONDITION = 1e10


# ---------------------------------------------------------------------------
# validation helpers


def _as_points(name: str, x: np.ndarray, ndim: int = 2) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-d array, got shape {x.shape}")
    return x


def _check_same_shape(**arrays: np.ndarray) -> None:
    shapes = {k: v.shape for k, v in arrays.items()}
    if len(set(shapes.values())) > 1:
        detail = ", ".join(f"{k} {s}" for k, s in shapes.items())
        raise ValueError(f"segment arrays must have the same shape, got {detail}")


def _check_samples(seg: np.ndarray, u: np.ndarray, n_segments: int) -> tuple[np.ndarray, np.ndarray]:
    seg = np.asarray(seg)
    u = np.asarray(u, dtype=float)
    if seg.ndim != 1 or u.ndim != 1 or seg.shape != u.shape:
        raise ValueError(f"seg and u must be 1-d arrays of one length, got shapes {seg.shape} and {u.shape}")
    if seg.size and not np.issubdtype(seg.dtype, np.integer):
        raise ValueError(f"seg must hold integer segment indices, got dtype {seg.dtype}")
    seg = seg.astype(np.intp, copy=False)
    if seg.size and (seg.min() < 0 or seg.max() >= n_segments):
        raise ValueError(f"seg must index segments 0..{n_segments - 1}, got values in [{seg.min()}, {seg.max()}]")
    return seg, u


def _check_rotation_segments(q0, a, b, q3) -> tuple[np.ndarray, ...]:
    q0 = _as_points("q0", q0)
    q3 = _as_points("q3", q3)
    a = _as_points("a", a)
    b = _as_points("b", b)
    if q0.shape[-1] != 4 or q3.shape != q0.shape:
        raise ValueError(f"q0 and q3 must both have shape (S, 4), got {q0.shape} and {q3.shape}")
    if a.shape != (q0.shape[0], 3) or b.shape != a.shape:
        raise ValueError(f"a and b must both have shape ({q0.shape[0]}, 3), got {a.shape} and {b.shape}")
    return quat.normalize(q0), a, b, quat.normalize(q3)


# ---------------------------------------------------------------------------
# translations: cubic Bézier


def _bezier_weights(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weights of (p0, a, b, p3) in B(u) with P1 = p0 + a, P2 = p3 + b."""
    v = 1.0 - u
    wa = 3.0 * v * v * u
    wb = 3.0 * v * u * u
    # P0 and P3 also receive the weights of the controls stored relative to them
    return v * v * v + wa, wa, wb, u * u * u + wb


def bezier_eval(p0: np.ndarray, a: np.ndarray, b: np.ndarray, p3: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Evaluate every segment at the same normalized times.

    Parameters
    ----------
    p0, p3 : (S, D) arrays
        Knot values at u = 0 and u = 1 (file units).
    a, b : (S, D) arrays
        Inner controls relative to the endpoints: P1 = p0 + a, P2 = p3 + b.
    u : (N,) array
        Normalized times, normally in [0, 1].

    Returns
    -------
    (S, N, D) array
    """
    p0, a, b, p3 = (_as_points(n, x) for n, x in (("p0", p0), ("a", a), ("b", b), ("p3", p3)))
    _check_same_shape(p0=p0, a=a, b=b, p3=p3)
    u = np.asarray(u, dtype=float)
    if u.ndim != 1:
        raise ValueError(f"u must be a 1-d array, got shape {u.shape}")
    w0, wa, wb, w3 = (w[None, :, None] for w in _bezier_weights(u))
    return w0 * p0[:, None] + wa * a[:, None] + wb * b[:, None] + w3 * p3[:, None]


def bezier_eval_at(
    p0: np.ndarray, a: np.ndarray, b: np.ndarray, p3: np.ndarray, seg: np.ndarray, u: np.ndarray
) -> np.ndarray:
    """Evaluate sample ``n`` on segment ``seg[n]`` at time ``u[n]``.

    Parameters
    ----------
    p0, a, b, p3 : (S, D) arrays
        Segments as in :func:`bezier_eval`.
    seg : (N,) int array
        Segment index of each sample.
    u : (N,) array
        Normalized time of each sample.

    Returns
    -------
    (N, D) array
    """
    p0, a, b, p3 = (_as_points(n, x) for n, x in (("p0", p0), ("a", a), ("b", b), ("p3", p3)))
    _check_same_shape(p0=p0, a=a, b=b, p3=p3)
    seg, u = _check_samples(seg, u, p0.shape[0])
    w0, wa, wb, w3 = (w[:, None] for w in _bezier_weights(u))
    return w0 * p0[seg] + wa * a[seg] + wb * b[seg] + w3 * p3[seg]


def default_translation_tangents(p0: np.ndarray, p3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform controls: the straight line from ``p0`` to ``p3`` at constant speed.

    Parameters
    ----------
    p0, p3 : (S, D) arrays

    Returns
    -------
    a, b : (S, D) arrays, ``(p3 - p0) / 3`` and ``(p0 - p3) / 3``.
    """
    p0 = np.asarray(p0, dtype=float)
    p3 = np.asarray(p3, dtype=float)
    if p0.shape != p3.shape:
        raise ValueError(f"p0 and p3 must have the same shape, got {p0.shape} and {p3.shape}")
    d = (p3 - p0) / 3.0
    return d, -d


def fit_translation_tangents(
    p0: np.ndarray,
    p3: np.ndarray,
    seg: np.ndarray,
    u: np.ndarray,
    values: np.ndarray,
    n_segments: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares inner controls of every Bézier segment at once.

    The Bézier is linear in ``(a, b)``, so each segment solves a 2x2 normal
    system shared by all ``D`` components.  Only samples with ``0 < u < 1``
    are used (the endpoints are interpolated anyway).  Segments with fewer
    than 2 such samples, or whose samples are too close together in ``u`` to
    separate the two controls, keep :func:`default_translation_tangents`.

    Parameters
    ----------
    p0, p3 : (S, D) arrays
        Knot values (file units).
    seg : (N,) int array
        Segment index of each sample, in ``range(n_segments)``.
    u : (N,) array
        Normalized time of each sample.
    values : (N, D) array
        Sample values (file units).
    n_segments : int
        ``S``.

    Returns
    -------
    a, b : (S, D) arrays
        P1 = p0 + a, P2 = p3 + b.
    """
    p0 = _as_points("p0", p0)
    p3 = _as_points("p3", p3)
    if p0.shape != p3.shape or p0.shape[0] != n_segments:
        raise ValueError(f"p0 and p3 must both have shape ({n_segments}, D), got {p0.shape} and {p3.shape}")
    seg, u = _check_samples(seg, u, n_segments)
    values = _as_points("values", values)
    if values.shape != (u.shape[0], p0.shape[1]):
        raise ValueError(f"values must have shape ({u.shape[0]}, {p0.shape[1]}), got {values.shape}")

    a, b = default_translation_tangents(p0, p3)
    use = (u > 0.0) & (u < 1.0)
    seg, u, values = seg[use], u[use], values[use]
    w0, wa, wb, w3 = _bezier_weights(u)
    # what the controls must explain once the endpoint terms are removed
    y = values - w0[:, None] * p0[seg] - w3[:, None] * p3[seg]

    def per_segment(w: np.ndarray) -> np.ndarray:
        return np.bincount(seg, weights=w, minlength=n_segments)

    count = np.bincount(seg, minlength=n_segments)
    m11, m12, m22 = per_segment(wa * wa), per_segment(wa * wb), per_segment(wb * wb)
    r1 = np.stack([per_segment(wa * y[:, d]) for d in range(y.shape[1])], axis=-1)
    r2 = np.stack([per_segment(wb * y[:, d]) for d in range(y.shape[1])], axis=-1)

    det = m11 * m22 - m12 * m12
    # eigenvalues of the symmetric 2x2 give its condition number
    half_trace = 0.5 * (m11 + m22)
    spread = np.sqrt(np.maximum(half_trace**2 - det, 0.0))
    lam_max, lam_min = half_trace + spread, half_trace - spread
    ok = (count >= 2) & (lam_min > 0.0) & (lam_max < _MAX_CONDITION * np.maximum(lam_min, 1e-300))
    det_safe = np.where(ok, det, 1.0)[:, None]
    fit_a = (m22[:, None] * r1 - m12[:, None] * r2) / det_safe
    fit_b = (m11[:, None] * r2 - m12[:, None] * r1) / det_safe
    ok = ok[:, None] & np.isfinite(fit_a) & np.isfinite(fit_b)
    return np.where(ok, fit_a, a), np.where(ok, fit_b, b)


# ---------------------------------------------------------------------------
# rotations: recursive slerp
#
# The kernels below work on component-major arrays, shape (k, n): one
# contiguous row of n samples per quaternion / vector / matrix component.
# Numpy handles (n, 3, 3) stacks of tiny matrices one by one, which is
# several times slower than arithmetic on whole rows.  Samples are processed
# in chunks of about _CHUNK so that the rows stay in cache.

_CHUNK = 8192
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
# Rows at least this long are computed in place, row by row (the same
# operations in the same order, so the same bits): below it the extra numpy
# calls cost more than the temporaries they save.
_ROWS_IN_PLACE = 2048
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])[:, None]
# Below this argument the closed forms of the SO(3) coefficient functions lose
# digits to cancellation; their Taylor series (error < 1e-13) take over.
_SERIES = 0.05


def _qmul_conj_t(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``conj(a) b`` of (4, n) quaternions: ``_qmul_t(a * _CONJ, b)`` with the
    signs of a's vector part folded into the sums (``p - (-x) y`` is
    ``p + x y`` exactly), without the negated copy of ``a``."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    if a.shape[-1] < _ROWS_IN_PLACE:
        return np.stack(
            [
                aw * bw + ax * bx + ay * by + az * bz,
                aw * bx - ax * bw - ay * bz + az * by,
                aw * by + ax * bz - ay * bw - az * bx,
                aw * bz - ax * by + ay * bx - az * bw,
            ]
        )
    return _qmul_rows(a, b, quat.MUL_CONJ_TERMS)


def _qmul_t(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (4, n) quaternions, w first."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    if a.shape[-1] < _ROWS_IN_PLACE:
        return np.stack(
            [
                aw * bw - ax * bx - ay * by - az * bz,
                aw * bx + ax * bw + ay * bz - az * by,
                aw * by - ax * bz + ay * bw + az * bx,
                aw * bz + ax * by - ay * bx + az * bw,
            ]
        )
    return _qmul_rows(a, b, quat.MUL_TERMS)


def _qmul_rows(a: np.ndarray, b: np.ndarray, terms: tuple) -> np.ndarray:
    # long rows: each summed left to right in place (quat.mul_rows), the
    # same rounding without the temporaries
    out = np.empty((4, *np.broadcast_shapes(a.shape[1:], b.shape[1:])))
    quat.mul_rows(a, b, out, terms)
    return out


def _qlog_t(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation vectors (3, n) and their angles (n,) of unit quaternions (4, n).

    Sign-blind: ``q`` and ``-q`` give the same (shorter-arc) vector, angle <= pi.
    """
    sign = np.where(q[0] < 0.0, -1.0, 1.0)
    w = q[0] * sign
    s = np.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-8
    if small.any():  # the few small ones fixed afterwards: the same numbers as np.where
        idx = np.flatnonzero(small)
        safe = s.copy()
        safe[idx] = 1.0
        scale = angle / safe
        scale[idx] = 2.0 / np.maximum(w[idx], 1e-12)
    else:  # the same numbers without the masks
        scale = angle / s
    scale *= sign
    return q[1:] * scale, angle


def _qexp_t(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Unit quaternions (4, n) of rotation vectors (3, n) with norms ``angle`` (n,)."""
    small = angle < 1e-8
    out = np.empty((4, *v.shape[1:]))
    sin = np.empty(angle.shape)
    quat.sin_cos(0.5 * angle, out=(sin, out[0]))
    if small.any():  # the few small ones fixed afterwards: the same numbers as np.where
        idx = np.flatnonzero(small)
        safe = angle.copy()
        safe[idx] = 1.0
        k = np.divide(sin, safe, out=sin)
        tiny = angle[idx]
        k[idx] = 0.5 - tiny * tiny / 48.0
    else:  # the same numbers without the masks
        k = sin
        k /= angle
    np.multiply(v, k, out=out[1:])
    return out


# Taylor coefficients (c0, c2, c4) of the SO(3) coefficient functions
_SERIES_TERMS = {
    "f1": (0.5, -1.0 / 24.0, 1.0 / 720.0),  # (1 - cos x) / x**2
    "f2": (1.0 / 6.0, -1.0 / 120.0, 1.0 / 5040.0),  # (x - sin x) / x**3
    "sinc": (1.0, -1.0 / 6.0, 1.0 / 120.0),  # sin x / x
    "g": (1.0 / 12.0, 1.0 / 720.0, 1.0 / 30240.0),  # see _g
}


def _coefficients(x: np.ndarray, *names: str) -> tuple[np.ndarray, ...]:
    """The functions ``names`` (of ``f1``, ``f2``, ``sinc``, ``g``) of one
    argument ``x`` (n,) >= 0: closed forms, or their Taylor series below
    ``_SERIES``.  What they share (the masked argument, its square, the
    tangent of its half) is computed once; where no argument (or every one)
    is small, the masks and the unused branch are skipped: the same numbers
    as each function on its own."""
    x2 = x * x
    small = x < _SERIES
    n_small = int(np.count_nonzero(small))
    closed = {}
    if n_small < small.size:
        t = np.where(small, 1.0, x) if n_small else x
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = t * t
            # every function from one tangent of the half angle, u = tan(t/2):
            # sin t = 2u / (1 + u^2), 1 - cos t = 2u^2 / (1 + u^2) (no
            # cancellation) and cot(t/2) = 1/u; numpy vectorizes tan, not
            # float64 sin and cos (see quat.sin_cos)
            h = 0.5 * t
            u = np.tan(h)
            d = 1.0 + u * u
            sin = 2.0 * u / d if "f2" in names or "sinc" in names else None
            for name in names:
                if name == "f1":
                    closed[name] = 2.0 * (u * u) / d / tt
                elif name == "f2":
                    closed[name] = (t - sin) / (tt * t)
                elif name == "sinc":
                    closed[name] = sin / t
                else:
                    closed[name] = (1.0 - h / u) / tt
    out = []
    for name in names:
        if n_small == 0:
            out.append(closed[name])
            continue
        c0, c2, c4 = _SERIES_TERMS[name]
        series = c0 + x2 * (c2 + x2 * c4)
        out.append(series if n_small == small.size else np.where(small, series, closed[name]))
    return tuple(out)


def _g(x: np.ndarray) -> np.ndarray:
    """(1 - (x/2) cot(x/2)) / x**2, the K^2 coefficient of the inverse right Jacobian.

    Finite on [0, pi] (1/pi**2 at pi), which is all ``_qlog_t`` returns.
    """
    return _coefficients(x, "g")[0]


# Every operator met in the Jacobian of a slerp is a function of one rotation
# vector w: exp(s K), J_r(s w), J_r^-1(w) with K = [w]x.  Since K^3 = -|w|^2 K
# each is p0 I + p1 K + p2 K^2, and products stay in that form; a triple
# (p0, p1, p2) of (n,) rows holds one.


def _pmul(a: tuple, b: tuple, t2: np.ndarray) -> tuple:
    """Product of two polynomials in the same K with |w|^2 = ``t2``."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return (
        a0 * b0,
        a0 * b1 + a1 * b0 - t2 * (a1 * b2 + a2 * b1),
        a0 * b2 + a1 * b1 + a2 * b0 - t2 * a2 * b2,
    )


def _pmatrix(p: tuple, w: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """The (3, 3, n) matrix p0 I + p1 [w]x + p2 [w]x^2 (with [w]x^2 = w w^T - |w|^2 I)."""
    p0, p1, p2 = p
    pw = p2 * w
    d = p0 - p2 * t2
    k = p1 * w  # kx, ky, kz
    # every entry's product in one call, the diagonal's sums in one (the
    # same operations on every entry as one entry at a time)
    m = np.multiply(pw[:, None], w[None])
    m9 = m.reshape(9, -1)
    m9[::4] += d
    m[0, 1] -= k[2]
    m[1, 0] += k[2]
    m[0, 2] += k[1]
    m[2, 0] -= k[1]
    m[1, 2] -= k[0]
    m[2, 1] += k[0]
    return m


def _mm(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Per-sample matrix product of (3, 3, n) and (3, k, n) -> (3, k, n) (into ``out``).

    Each entry summed over the inner index left to right (einsum's order,
    so with its rounding), a row of k entries at once: faster than einsum,
    or than the entries one by one, on rows of any length.
    """
    if out is None:
        out = np.empty((3, *b.shape[1:]))
    t = np.empty(b.shape[1:])
    for i in range(3):
        o = out[i]
        np.multiply(a[i, 0], b[0], out=o)
        o += np.multiply(a[i, 1], b[1], out=t)
        o += np.multiply(a[i, 2], b[2], out=t)
    return out


def _jr(s: np.ndarray | float, angle: np.ndarray, f: tuple | None = None) -> tuple:
    """s * J_r(s w) as a polynomial in [w]x, for |w| = ``angle`` and s >= 0
    (``f``: ``_f1`` and ``_f2`` of ``s * angle``, when the caller has them
    already).  Its constant term is ``s`` itself (a float or a row)."""
    f1, f2 = _coefficients(s * angle, "f1", "f2") if f is None else f
    return (s, -s * s * f1, s * s * s * f2)


# A Jacobian is a pair of (3, 3, n) blocks (d/da, d/db), None for a zero block.
_Jac = tuple


def _add_terms(*terms: np.ndarray | None) -> np.ndarray | None:
    out = None
    for t in terms:
        if t is not None:
            if out is None:
                out = t
            else:  # the terms are fresh products (of _mm): add in place
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
    ``(_g, _sinc, _f1)`` (the last two needed with ``jx`` only).

    Polynomials of the constant 1 (or 1/2) hold the float itself: the same
    numbers as rows of ones, without the rows.
    """
    w, th = _qlog_t(_qmul_conj_t(x, z)) if log is None else log
    ut = u * th
    y = _qmul_t(x, _qexp_t(u * w, ut))
    if jx is None and jz is None:
        return y, None
    t2 = th * th
    # each function of an angle computed once for its every use
    if jx is None:
        f1_ut, f2_ut = _coefficients(ut, "f1", "f2")
        g_th = _coefficients(th, "g")[0] if th_terms is None else th_terms[0]
    else:
        f1_ut, f2_ut, sinc_ut = _coefficients(ut, "f1", "f2", "sinc")
        g_th, sinc_th, f1_th = _coefficients(th, "g", "sinc", "f1") if th_terms is None else th_terms
    c = _pmul(_jr(u, th, (f1_ut, f2_ut)), (1.0, 0.5, g_th), t2)
    cm = _pmatrix(c, w, t2) if jz is not None else None
    am = None
    if jx is not None:
        exp_mu = (1.0, -u * sinc_ut, u * u * f1_ut)
        exp_m1 = (1.0, -sinc_th, f1_th)
        c_e = _pmul(c, exp_m1, t2)
        am = _pmatrix(tuple(p - q for p, q in zip(exp_mu, c_e, strict=True)), w, t2)
    jy = []
    for i in range(2):
        bx = None if jx is None or jx[i] is None else _mm(am, jx[i])
        bz = None if jz is None or jz[i] is None else _mm(cm, jz[i])
        jy.append(_add_terms(bx, bz))
    return y, (jy[0], jy[1])


def _curve_t(
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
    q1 = _qmul_t(q0, _qexp_t(a, ta))
    q2 = _qmul_t(q3, _qexp_t(b, tb))
    log12 = _qlog_t(_qmul_conj_t(q1, q2))
    if jacobian:
        j1 = (_pmatrix(_jr(1.0, ta), a, ta * ta), None)
        j2 = (None, _pmatrix(_jr(1.0, tb), b, tb * tb))
        # the middle slerp's functions of its angle, once per segment
        th12 = _coefficients(log12[1], "g", "sinc", "f1")
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
    q01 = _qmul_t(q0, _qexp_t(u * a, u * ta))
    q23 = _qmul_t(q3, _qexp_t(v * b, v * tb))
    if jacobian:
        ta2, tb2 = ta * ta, tb * tb
        j01 = (_pmatrix(_jr(u, ta), a, ta2), None)
        j23 = (None, _pmatrix(_jr(v, tb), b, tb2))
    else:
        j01 = j23 = None
    q12, j12 = _slerp_t(q1, j1, q2, j2, u, log12, th12)
    q012, j012 = _slerp_t(q01, j01, q12, j12, u)
    q123, j123 = _slerp_t(q12, j12, q23, j23, u)
    return _slerp_t(q012, j012, q123, j123, u)


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
    ``q0``, ``x``, ``q3`` are per segment, as in :func:`_curve_t`).
    ``|residual|`` is the angle between spline and sample.
    """
    s, js = _curve_t(q0, x[:3], x[3:], q3, u, jacobian, idx)
    if curve is not None:
        curve[...] = s
    r, th = _qlog_t(_qmul_conj_t(values, s))
    if not jacobian:
        return r, None
    t2 = th * th
    jinv = _pmatrix((1.0, 0.5, _g(th)), r, t2)
    j = np.empty((3, 6, th.shape[-1]))
    _mm(jinv, js[0], out=j[:, :3])
    _mm(jinv, js[1], out=j[:, 3:])
    return r, j


def _wrap_rotation_vector(v: np.ndarray) -> np.ndarray:
    """The same rotation (..., 3) with angle at most pi, as ``quat.log`` gives it."""
    t = quat.norm(v)[..., None]
    over = t > np.pi
    return np.where(over, v * (1.0 - 2.0 * np.pi / np.where(over, t, 1.0)), v)


def _rotation_residuals(
    q0: np.ndarray, x: np.ndarray, q3: np.ndarray, u: np.ndarray, values: np.ndarray, jacobian: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """Sample-major wrapper of the residual kernel (for tests).

    q0, q3, values (N, 4); x (N, 6) with angles <= pi; u (N,).
    Returns residuals (N, 3) and, if asked, d residual / d x (N, 3, 6).
    """
    r, j = _residuals_t(q0.T, x.T, q3.T, u, values.T, jacobian)
    return r.T, None if j is None else np.moveaxis(j, -1, 0)


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
    q0, a, b, q3 = _check_rotation_segments(q0, a, b, q3)
    seg, u = _check_samples(seg, u, q0.shape[0])
    a, b = _wrap_rotation_vector(a), _wrap_rotation_vector(b)
    out = np.empty((u.shape[0], 4))
    for lo in range(0, u.shape[0], _CHUNK):
        sg = seg[lo : lo + _CHUNK]
        used, idx = compact_segments(sg)
        q, _ = _curve_t(q0[used].T, a[used].T, b[used].T, q3[used].T, u[lo : lo + _CHUNK], False, idx)
        out[lo : lo + _CHUNK] = q.T
    return quat.normalize(out)


def compact_segments(seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The segments ``used`` that ``seg`` meets (increasing) and each
    sample's place among them, ``used[idx] == seg`` (np.unique's answer
    without its import of numpy.ma, about 18 ms a process)."""
    if seg.size == 0:
        return seg, seg
    lo = int(seg.min())
    mark = np.zeros(int(seg.max()) - lo + 1, dtype=bool)
    mark[seg - lo] = True
    return np.flatnonzero(mark) + lo, (np.cumsum(mark) - 1)[seg - lo]


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


def _check_rotation_values(values: np.ndarray, n: int) -> np.ndarray:
    values = _as_points("values", values)
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
    q0, a, b, q3 = _check_rotation_segments(q0, a, b, q3)
    seg, u = _check_samples(seg, u, n_segments)
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
        self.q0 = q0.T.copy()  # per segment: _curve_t gathers them
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
        group = offsets[:-1] // _CHUNK
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
    a = _wrap_rotation_vector(p1)
    b = _wrap_rotation_vector(quat.log(quat.mul(quat.conj(q3), quat.mul(q0, quat.exp(p2)))))
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
    trial = np.concatenate([_wrap_rotation_vector(trial[:, :3]), _wrap_rotation_vector(trial[:, 3:])], -1)
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
    Segments with fewer than 2 usable samples keep the uniform tangents.

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
    q0 = _as_points("q0", q0)
    q3 = _as_points("q3", q3)
    if q0.shape != (n_segments, 4) or q3.shape != q0.shape:
        raise ValueError(f"q0 and q3 must both have shape ({n_segments}, 4), got {q0.shape} and {q3.shape}")
    seg, u = _check_samples(seg, u, n_segments)
    values = _check_rotation_values(values, u.shape[0])
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")
    q0, q3 = quat.normalize(q0), quat.normalize(q3)
    a0, b0 = default_rotation_tangents(q0, q3)
    params = np.concatenate([a0, b0], axis=-1)

    use = (u > 0.0) & (u < 1.0) & np.all(np.isfinite(values), axis=-1)
    active = np.bincount(seg[use], minlength=n_segments) >= 2
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
    same = np.all(_wrap_rotation_vector(a) == a, axis=-1) & np.all(_wrap_rotation_vector(b) == b, axis=-1)
    sure = same[normal.seg]
    at = np.flatnonzero(use)[normal.order[sure]]
    return a, b, at, quat.normalize(np.ascontiguousarray(kept_curve[:, sure].T))
