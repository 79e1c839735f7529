"""Translation segments: cubic Béziers and their least-squares fit (paper 4.1.1).

Translations (``D`` components, file units) use a cubic Bézier with
endpoints ``p0``, ``p3`` and inner controls stored relative to them::

    P1 = p0 + a,   P2 = p3 + b.

The default ("uniform") controls, for segments whose samples cannot
determine their tangents, are the straight line at uniform speed; a
segment with a single inner sample bends them, by the least change, through
it (one sample cannot fix two controls, but a straight line ignores it).
"""

from __future__ import annotations

import numpy as np

from .segments import as_points, check_same_shape, check_samples

# A 2x2 normal matrix whose condition number exceeds this cannot pin down two
# Bézier controls from the samples: keep the defaults.
_MAX_CONDITION = 1e10


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
    p0, a, b, p3 = (as_points(n, x) for n, x in (("p0", p0), ("a", a), ("b", b), ("p3", p3)))
    check_same_shape(p0=p0, a=a, b=b, p3=p3)
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
    p0, a, b, p3 = (as_points(n, x) for n, x in (("p0", p0), ("a", a), ("b", b), ("p3", p3)))
    check_same_shape(p0=p0, a=a, b=b, p3=p3)
    seg, u = check_samples(seg, u, p0.shape[0])
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
    are used (the endpoints are interpolated anyway).  Segments with no such
    sample, or whose samples are too close together in ``u`` to separate the
    two controls, keep :func:`default_translation_tangents`; a segment with
    exactly one takes the least change of those that passes through it.

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
    p0 = as_points("p0", p0)
    p3 = as_points("p3", p3)
    if p0.shape != p3.shape or p0.shape[0] != n_segments:
        raise ValueError(f"p0 and p3 must both have shape ({n_segments}, D), got {p0.shape} and {p3.shape}")
    seg, u = check_samples(seg, u, n_segments)
    values = as_points("values", values)
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
    a, b = _through_one_sample(a, b, seg, wa, wb, y, count)
    return np.where(ok, fit_a, a), np.where(ok, fit_b, b)


def _through_one_sample(
    a: np.ndarray, b: np.ndarray, seg: np.ndarray, wa: np.ndarray, wb: np.ndarray, y: np.ndarray, count: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The default controls ``a, b`` (S, D) of the segments with one inner
    sample moved by the least change that makes the Bézier pass through it:
    ``(wa, wb) (y - wa a - wb b) / (wa² + wb²)`` (issue 34).  Two controls
    cannot be fitted to one sample, but the straight line ignores it: a knot
    put on an extreme two frames from its editing knot (a 30 Hz clip) made
    the spline miss the frame between them and the one after by the bend of
    the extreme, where the segment it split had fitted both."""
    one = count[seg] == 1
    if not one.any():
        return a, b
    s, u_a, u_b, target = seg[one], wa[one, None], wb[one, None], y[one]
    miss = (target - u_a * a[s] - u_b * b[s]) / (u_a * u_a + u_b * u_b)
    a, b = a.copy(), b.copy()
    a[s] += u_a * miss
    b[s] += u_b * miss
    return a, b
