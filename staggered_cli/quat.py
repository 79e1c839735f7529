"""Quaternion algebra on stacks of quaternions.

Every quaternion in this project is a float64 array whose last axis holds
``(w, x, y, z)`` (w first), combined with the Hamilton product.  All functions
broadcast over leading axes and never mutate their inputs.

The paper's operators (SPEC section 2) for rotations are

* ``a ⊕ b = a * b``  (b applied after a, in a's local frame),
* ``c ⊖ a = a⁻¹ * c`` so that ``a ⊕ (c ⊖ a) = c``,
* scaling by a weight ``w`` is ``exp(w · log(q))``.

``log`` and ``exp`` here map between unit quaternions and rotation vectors
(axis times angle, radians), so ``exp(log(q)) == q`` for ``q.w >= 0``.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def sin_cos(x: np.ndarray, out: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(sin x, cos x)`` of an array of angles (radians), from one tangent
    of the half angle: with ``t = tan(x / 2)``, ``sin x = 2t / (1 + t^2)``
    and ``cos x = (1 - t^2) / (1 + t^2)`` (into ``out``, if given).

    numpy vectorizes float64 ``tan`` with SIMD where the CPU has it (with
    AVX-512: 1.4 ns an element) but not ``sin`` and ``cos`` (9.3 ns each),
    so this is about six times faster than the two calls; elsewhere it is
    one libm call instead of two.  The error is a few units in the last
    place, as absolute error, at every angle: near the poles of the tangent
    (``x`` near an odd multiple of pi) ``t`` is huge and ``2t / (1 + t^2)``
    tends to ``2 / t``, which stays accurate (``t^2`` would overflow only
    within 1e-154 of a pole, which no float but a huge one comes near).
    ``x = 0`` gives exactly ``(0, 1)``.
    """
    t = np.tan(0.5 * np.asarray(x, dtype=float))
    s, c = (np.empty_like(t), np.empty_like(t)) if out is None else out
    t2 = t * t
    d = 1.0 + t2
    np.multiply(t, 2.0, out=s)
    s /= d
    np.subtract(1.0, t2, out=c)
    c /= d
    return s, c


def identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity quaternions of ``shape + (4,)``."""
    q = np.zeros(tuple(shape) + (4,))
    q[..., 0] = 1.0
    return q


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products over the last axis (of a few components: 3 or 4).

    Written out component by component, in the order ``np.sum`` adds them,
    so with its bits at a fifth of its time on such short axes.
    """
    out = a[..., 0] * b[..., 0]
    for i in range(1, a.shape[-1]):
        out = out + a[..., i] * b[..., i]
    return out


def norm(v: np.ndarray) -> np.ndarray:
    """Lengths over the last axis: ``np.linalg.norm(v, axis=-1)``, the same bits, faster."""
    v = np.asarray(v)
    return np.sqrt(dot(v, v))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (..., 3) vectors: ``np.cross``'s formula without its axis moves."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions, shape preserved."""
    q = np.asarray(q, dtype=float)
    return q / norm(q)[..., None]


def conj(q: np.ndarray) -> np.ndarray:
    """Conjugate, which is the inverse of a unit quaternion."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


inv = conj


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of ``(..., 4)`` arrays (broadcasting)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


# the Hamilton product, row by row: (a index, b index) of the first product,
# then (sign, a index, b index) of each further one, in mul's written order
MUL_TERMS = (
    ((0, 0), (-1, 1, 1), (-1, 2, 2), (-1, 3, 3)),
    ((0, 1), (1, 1, 0), (1, 2, 3), (-1, 3, 2)),
    ((0, 2), (-1, 1, 3), (1, 2, 0), (1, 3, 1)),
    ((0, 3), (1, 1, 2), (-1, 2, 1), (1, 3, 0)),
)
# the same for conj(a) b: every term of a's vector part changes sign
MUL_CONJ_TERMS = tuple((first, *((-sign, i, j) for sign, i, j in rest)) for first, *rest in MUL_TERMS)


def mul_rows(a: np.ndarray, b: np.ndarray, out: np.ndarray, terms: tuple = MUL_TERMS) -> None:
    """:func:`mul` of component-major quaternions (4, ...) into ``out``
    (4, ...), each component summed left to right in place through one
    scratch row: the same bits as :func:`mul` (or, with
    :data:`MUL_CONJ_TERMS`, as ``mul(conj(a), b)``), without its temporaries."""
    t = np.empty(out.shape[1:])
    for row, ((i, j), *rest) in zip(out, terms, strict=True):
        np.multiply(a[i], b[j], out=row)
        for sign, i, j in rest:
            np.multiply(a[i], b[j], out=t)
            if sign > 0:
                row += t
            else:
                row -= t


def mul_vec(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def log(q: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (radians) of unit quaternions.

    ``q`` and ``-q`` give the same rotation; the shorter one (w >= 0) is used.
    """
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., :1] < 0.0, -q, q)
    v = q[..., 1:]
    s = norm(v)
    half = np.arctan2(s, q[..., 0])
    # 2*half/s -> 2 as s -> 0 (use the series to stay accurate for tiny angles)
    small = s < 1e-8
    scale = np.where(small, 2.0 / np.maximum(q[..., 0], _EPS), 2.0 * half / np.where(small, 1.0, s))
    return v * scale[..., None]


def exp(r: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors ``r (..., 3)`` (radians)."""
    r = np.asarray(r, dtype=float)
    angle = norm(r)
    sin, cos = sin_cos(0.5 * angle)
    small = angle < 1e-8
    # sin(half)/angle -> 0.5 - angle**2/48 as angle -> 0
    k = np.where(small, 0.5 - angle**2 / 48.0, sin / np.where(small, 1.0, angle))
    return np.concatenate([cos[..., None], r * k[..., None]], axis=-1)


def angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, in [0, pi], of unit quaternions."""
    q = np.asarray(q, dtype=float)
    return 2.0 * np.arctan2(norm(q[..., 1:]), np.abs(q[..., 0]))


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in radians of the rotation that takes ``a`` to ``b`` (sign-blind)."""
    return angle(mul(conj(a), b))


def slerp(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc.

    ``u`` broadcasts against the leading axes of ``a`` and ``b``.
    """
    a = np.asarray(a, dtype=float)
    d = mul(conj(a), b)
    d = np.where(d[..., :1] < 0.0, -d, d)
    u = np.asarray(u, dtype=float)
    return mul(a, exp(log(d) * u[..., None]))


def pow(q: np.ndarray, w: np.ndarray | float) -> np.ndarray:  # noqa: A001 - the math name
    """Scale a rotation: ``exp(w · log(q))``."""
    w = np.asarray(w, dtype=float)
    return exp(log(q) * w[..., None] if w.ndim else log(q) * float(w))


def oplus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a ⊕ b = a * b`` for rotations."""
    return mul(a, b)


def ominus(c: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``c ⊖ a = a⁻¹ * c`` for rotations, so that ``a ⊕ (c ⊖ a) = c``."""
    return mul(conj(a), c)


def unroll(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """Flip signs along ``axis`` so that consecutive quaternions have dot >= 0."""
    q = np.moveaxis(np.array(q, dtype=float), axis, 0)  # the result: the one copy
    unroll_in_place(q)
    return np.moveaxis(q, 0, axis)


def unroll_in_place(q: np.ndarray) -> None:
    """:func:`unroll` along the first axis of the writable float array ``q``, in place."""
    T = q.shape[0]
    if T > 1:
        # a block of steps at a time, and the signs applied in place: no
        # temporaries the size of the input (unrolling a long clip's
        # rotations tripled their memory)
        rows = max(1, _UNROLL_BLOCK // max(q[0].size, 1))
        back = np.empty((T - 1,) + q.shape[1:-1], dtype=bool)
        for lo in range(0, T - 1, rows):
            hi = min(lo + rows, T - 1)
            back[lo:hi] = dot(q[lo + 1 : hi + 1], q[lo:hi]) < 0.0
        flips = np.logical_xor.accumulate(back, axis=0)  # the parity of the flips so far
        del back
        for lo in range(0, T - 1, rows):
            hi = min(lo + rows, T - 1)
            q[lo + 1 : hi + 1] *= (1.0 - 2.0 * flips[lo:hi])[..., None]


#: Quaternion components handled at once by :func:`unroll` (about 2 MB).
_UNROLL_BLOCK = 1 << 18


def hemisphere(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``q`` or ``-q``, whichever lies on the hemisphere of ``ref``."""
    q = np.asarray(q, dtype=float)
    return np.where(np.sum(q * ref, axis=-1, keepdims=True) < 0.0, -q, q)


_AXIS = {"X": 0, "Y": 1, "Z": 2}


def from_axis_angle(axis: str, angle_rad: np.ndarray) -> np.ndarray:
    """Rotations about a principal axis ``'X'``, ``'Y'`` or ``'Z'``."""
    angle_rad = np.asarray(angle_rad, dtype=float)
    q = np.zeros(angle_rad.shape + (4,))
    q[..., 1 + _AXIS[axis]], q[..., 0] = sin_cos(0.5 * angle_rad)
    return q


def from_euler(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Quaternions of intrinsic Euler angles (BVH convention).

    Parameters
    ----------
    angles_deg : (..., 3) array
        Angles in degrees, in the order the axes are listed in ``order``.
    order : str
        Three distinct axes, e.g. ``'ZXY'``: the first listed is the outermost
        rotation, ``q = q_Z(a0) * q_X(a1) * q_Y(a2)``.
    """
    a = np.radians(np.asarray(angles_deg, dtype=float))
    q = from_axis_angle(order[0], a[..., 0])
    q = mul(q, from_axis_angle(order[1], a[..., 1]))
    return mul(q, from_axis_angle(order[2], a[..., 2]))


#: Entry (row, column) of the rotation matrix of ``w, x, y, z``, each alone
#: (:func:`to_euler` computes only the entries it reads).
_ENTRY = (
    (
        lambda w, x, y, z: 1 - 2 * (y * y + z * z),
        lambda w, x, y, z: 2 * (x * y - w * z),
        lambda w, x, y, z: 2 * (x * z + w * y),
    ),
    (
        lambda w, x, y, z: 2 * (x * y + w * z),
        lambda w, x, y, z: 1 - 2 * (x * x + z * z),
        lambda w, x, y, z: 2 * (y * z - w * x),
    ),
    (
        lambda w, x, y, z: 2 * (x * z - w * y),
        lambda w, x, y, z: 2 * (y * z + w * x),
        lambda w, x, y, z: 1 - 2 * (x * x + y * y),
    ),
)


def _matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = (q[..., i] for i in range(4))
    return np.stack([np.stack([f(w, x, y, z) for f in row], -1) for row in _ENTRY], -2)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions."""
    return _matrix(normalize(q))


def to_euler(q: np.ndarray, order: str, reference_deg: np.ndarray | None = None) -> np.ndarray:
    """Intrinsic Euler angles in degrees, closest to a reference.

    Among the equivalent triples (whole turns, and the twin
    ``(a+180, 180-b, c+180)``) the one closest to ``reference_deg`` is
    returned; without a reference, the principal one (middle angle in
    [-90, 90]).  Near gimbal lock, where only the sum or difference of the
    outer angles is determined, the first angle is taken from the reference.

    Parameters
    ----------
    q : (..., 4) array, w first.
    order : str, three distinct axes, first listed outermost.
    reference_deg : (..., 3) array or None.
    """
    q = normalize(q)
    i, j, k = (_AXIS[c] for c in order)
    # the five entries of the rotation matrix that are needed (those of
    # _matrix, without the other four)
    w, x, y, z = (q[..., n] for n in range(4))
    m_ik, m_ii, m_ij, m_jk, m_kk = (_ENTRY[r][col](w, x, y, z) for r, col in ((i, k), (i, i), (i, j), (j, k), (k, k)))
    # R = R_i(a) R_j(b) R_k(c); parity sign of the axis permutation
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    sb = np.clip(sign * m_ik, -1.0, 1.0)
    # cos(b) from the other entries of the row keeps b accurate near +-90 deg
    # (entries of a rotation matrix: no overflow; np.hypot is 20x slower)
    cb = np.sqrt(m_ii * m_ii + m_ij * m_ij)
    b = np.arctan2(sb, cb)
    a = np.arctan2(-sign * m_jk, m_kk)
    c = np.arctan2(-sign * m_ij, m_ii)
    # cos(b) below ~1e-7 means the outer angles are numerically undetermined
    locked = cb < 1e-7
    # at lock, R_i(a) R_j(±90) R_k(c) depends on a ± c only: read it off the
    # remaining block and split it with the reference (or a = 0)
    if np.any(locked):
        # keep a from the reference (or 0) and solve c from what is left:
        # R_k(c) = R_j(b)^-1 R_i(a)^-1 R
        a_l = np.radians(reference_deg[..., 0]) if reference_deg is not None else np.zeros_like(a)
        rest = mul(conj(mul(from_axis_angle(order[0], a_l), from_axis_angle(order[1], b))), q)
        c_l = 2.0 * np.arctan2(rest[..., 1 + k], rest[..., 0])
        a = np.where(locked, a_l, a)
        c = np.where(locked, c_l, c)
    out = np.degrees(np.stack([a, b, c], axis=-1))
    if reference_deg is None:
        return out
    ref = np.asarray(reference_deg, dtype=float)
    twin = out + np.array([180.0, 0.0, 180.0])
    twin[..., 1] = 180.0 - out[..., 1]
    # each candidate by whole turns to the reference; the nearer one, the
    # first on a tie (and, like argmin, a NaN distance counts as the nearest)
    near = out + 360.0 * np.round((ref - out) / 360.0)
    twin += 360.0 * np.round((ref - twin) / 360.0)
    d_near = np.sum((near - ref) ** 2, axis=-1)
    d_twin = np.sum((twin - ref) ** 2, axis=-1)
    take_twin = (d_twin < d_near) | (np.isnan(d_twin) & ~np.isnan(d_near))
    return np.where(take_twin[..., None], twin, near)
