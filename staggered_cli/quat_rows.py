"""Quaternion and SO(3) kernels on component-major rows, w first.

The spline kernels of :mod:`staggered_cli.model.rotation_spline` and
:mod:`staggered_cli.model.rotation_fit` work on component-major arrays,
shape (k, n): one contiguous row of n samples per quaternion / vector /
matrix component.  Numpy handles (n, 3, 3) stacks of tiny matrices one by
one, which is several times slower than arithmetic on whole rows.  This
module is :mod:`staggered_cli.quat`'s algebra in that layout (``mul``,
``mul_conj``, ``log``, ``exp`` of (4, n) rows) and the coefficient
functions of SO(3)'s right Jacobians that the Levenberg-Marquardt fit of
rotation tangents needs.
"""

from __future__ import annotations

import numpy as np

from . import quat

# Rows at least this long are computed in place, row by row (the same
# operations in the same order, so the same bits): below it the extra numpy
# calls cost more than the temporaries they save.
_ROWS_IN_PLACE = 2048
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])[:, None]
# Below this argument the closed forms of the SO(3) coefficient functions lose
# digits to cancellation; their Taylor series (error < 1e-13) take over.
_SERIES = 0.05


def mul_conj(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``conj(a) b`` of (4, n) quaternions: ``mul(a * _CONJ, b)`` with the
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
    return _mul_rows(a, b, quat.MUL_CONJ_TERMS)


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
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
    return _mul_rows(a, b, quat.MUL_TERMS)


def _mul_rows(a: np.ndarray, b: np.ndarray, terms: tuple) -> np.ndarray:
    # long rows: each summed left to right in place (quat.mul_rows), the
    # same rounding without the temporaries
    out = np.empty((4, *np.broadcast_shapes(a.shape[1:], b.shape[1:])))
    quat.mul_rows(a, b, out, terms)
    return out


def log(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def exp(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
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
    "g": (1.0 / 12.0, 1.0 / 720.0, 1.0 / 30240.0),  # see jr_inv_k2
}


def coefficients(x: np.ndarray, *names: str) -> tuple[np.ndarray, ...]:
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


def jr_inv_k2(x: np.ndarray) -> np.ndarray:
    """(1 - (x/2) cot(x/2)) / x**2, the K^2 coefficient of the inverse right Jacobian.

    Finite on [0, pi] (1/pi**2 at pi), which is all ``log`` returns.
    """
    return coefficients(x, "g")[0]


# Every operator met in the Jacobian of a slerp is a function of one rotation
# vector w: exp(s K), J_r(s w), J_r^-1(w) with K = [w]x.  Since K^3 = -|w|^2 K
# each is p0 I + p1 K + p2 K^2, and products stay in that form; a triple
# (p0, p1, p2) of (n,) rows holds one.


def pmul(a: tuple, b: tuple, t2: np.ndarray) -> tuple:
    """Product of two polynomials in the same K with |w|^2 = ``t2``."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return (
        a0 * b0,
        a0 * b1 + a1 * b0 - t2 * (a1 * b2 + a2 * b1),
        a0 * b2 + a1 * b1 + a2 * b0 - t2 * a2 * b2,
    )


def pmatrix(p: tuple, w: np.ndarray, t2: np.ndarray) -> np.ndarray:
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


def mm(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
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


def jr(s: np.ndarray | float, angle: np.ndarray, f: tuple | None = None) -> tuple:
    """s * J_r(s w) as a polynomial in [w]x, for |w| = ``angle`` and s >= 0
    (``f``: ``_f1`` and ``_f2`` of ``s * angle``, when the caller has them
    already).  Its constant term is ``s`` itself (a float or a row)."""
    f1, f2 = coefficients(s * angle, "f1", "f2") if f is None else f
    return (s, -s * s * f1, s * s * s * f2)
