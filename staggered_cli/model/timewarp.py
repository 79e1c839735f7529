"""Piecewise-linear time warps: the one way timing edits move times.

A warp is given by matching times ``old_t -> new_t`` (both increasing, same
length): a time between two of ``old_t`` goes to the same fraction of the
way between the matching ``new_t``; a time outside is held at the end
(SPEC section 2, paper section 5.2).  Timing edits warp knot times with it,
and contact constraints move by the same map as the motion that carries
them.  Pure functions over arrays.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def warp(t, old_t: np.ndarray, new_t: np.ndarray) -> np.ndarray:
    """Times ``t`` moved by the warp ``old_t -> new_t``: float array of ``t``'s shape."""
    return np.interp(t, old_t, new_t)


def warp_span(start: float, end: float, old_t: np.ndarray, new_t: np.ndarray) -> tuple[float, float]:
    """The span ``start..end`` (seconds) moved by the warp ``old_t -> new_t``."""
    a, b = warp([start, end], old_t, new_t)
    return float(a), float(b)


def from_pairs(pairs: Iterable[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """The warp through the points ``(old, new)``, given in any order: (old_t, new_t)."""
    old_t, new_t = (np.array(x) for x in zip(*sorted(pairs), strict=True))
    return old_t, new_t
