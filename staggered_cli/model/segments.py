"""A batch of cubic spline segments: the checks both kinds share (paper 4.1.1).

A *segment* joins two knot values on a normalized time ``u`` in [0, 1]
(SPEC section 3).  Every spline function works on a whole batch of segments
at once: ``S`` segments, ``N`` samples, ``seg[n]`` the segment of sample
``n``.  Translations use a cubic Bézier (:mod:`.bezier`), rotations
Shoemake's cubic by recursive slerp (:mod:`.rotation_spline`, fitted by
:mod:`.rotation_fit`).  Both store their inner controls relative to the
endpoints, so editing a knot value carries its tangent along.
"""

from __future__ import annotations

import numpy as np


def as_points(name: str, x: np.ndarray, ndim: int = 2) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-d array, got shape {x.shape}")
    return x


def check_same_shape(**arrays: np.ndarray) -> None:
    shapes = {k: v.shape for k, v in arrays.items()}
    if len(set(shapes.values())) > 1:
        detail = ", ".join(f"{k} {s}" for k, s in shapes.items())
        raise ValueError(f"segment arrays must have the same shape, got {detail}")


def check_samples(seg: np.ndarray, u: np.ndarray, n_segments: int) -> tuple[np.ndarray, np.ndarray]:
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
