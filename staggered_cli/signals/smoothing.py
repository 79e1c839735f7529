"""Smoothing of signals over frames, in seconds at every frame rate (paper 4.1, SPEC 4).

Amounts of filtering are durations in seconds, converted per frame rate:
iterated Laplacian smoothing is a diffusion, so the iteration count for a
given duration grows with the frame rate squared.  The tent filter is the
paper's final filter of the pose probability.
"""

from __future__ import annotations

import numpy as np

#: Default smoothing of the local evidence: standard deviation, seconds.
DEFAULT_SMOOTHING = 0.025
#: Default tent filter full base width, seconds (paper: 0.15 s).
DEFAULT_FILTER_WIDTH = 0.15

_LAMBDA = 0.25  # Laplacian step: kernel [1/4, 1/2, 1/4], variance 0.5 frame² per iteration


def smoothing_iterations(duration: float, rate: float) -> tuple[int, float]:
    """Iterations of Laplacian smoothing equivalent to a Gaussian of standard
    deviation ``duration`` seconds at ``rate`` Hz.

    Each iteration with step 1/4 adds a variance of 1/2 frame², so the count
    grows with ``rate²``.  Returns the number of full iterations and the step
    of one last partial iteration (0 if none) that makes the variance exact.
    """
    var = (max(duration, 0.0) * rate) ** 2
    full = int(np.floor(var / (2 * _LAMBDA) + 1e-9))
    rest = var - 2 * _LAMBDA * full
    return full, (rest / 2.0 if rest > 1e-9 else 0.0)


#: Up to this many iterations the smoothing runs them one by one (120 Hz at
#: the default 0.025 s takes 18); beyond, the same operator is applied in one
#: step in the cosine basis, so the cost does not grow with (σ · rate)².
MAX_EXPLICIT_ITERATIONS = 32


def laplacian_smooth(x: np.ndarray, duration: float, rate: float, breaks: np.ndarray | None = None) -> np.ndarray:
    """Iterated Laplacian smoothing along the first axis.

    Parameters
    ----------
    x : (T, ...) signals.
    duration : standard deviation of the equivalent Gaussian, seconds.
    rate : frames per second.
    breaks : (T-1,) bool or None; nothing diffuses across a break, nor past
        the ends of the clip.

    Returns
    -------
    (T, ...) a new array.

    Notes
    -----
    One iteration is ``x += λ L x`` with ``L`` the Laplacian of the chain of
    frames cut at the breaks (no flux through a break or an end).  Between
    two breaks ``L``'s eigenvectors are the DCT-II basis, with eigenvalues
    ``2 - 2 cos(π k / n)``, so ``n`` iterations are one multiplication by
    ``(1 - λ μ_k)^n`` there: the result of every iteration count in
    O(T log T).  Small counts run the iterations themselves (bit for bit the
    explicit scheme); both agree to about 1e-13.
    """
    # C order: the iterations update ``x.reshape(T, -1)`` in place, which is
    # a copy (and the result unsmoothed) for any other layout
    x = np.array(x, dtype=float, copy=True, order="C")
    T = x.shape[0]
    if T < 2:
        return x
    full, last = smoothing_iterations(duration, rate)
    cuts = np.zeros(T - 1, dtype=bool) if breaks is None else np.asarray(breaks, dtype=bool).reshape(T - 1)
    if full + (last > 0) > MAX_EXPLICIT_ITERATIONS:
        return _smooth_spectral(x, full, last, cuts)
    steps = [_LAMBDA] * full + ([last] if last > 0 else [])
    flat = x.reshape(T, -1)
    cond = (~cuts).astype(float)[:, None]
    # a few columns at a time where the signals are long (each column is its
    # own: the same numbers), so that the temporaries stay a few MB
    width = max(1, _SMOOTH_BLOCK // T)
    for c0 in range(0, flat.shape[1], width):
        xb = flat if width >= flat.shape[1] else np.ascontiguousarray(flat[:, c0 : c0 + width])
        for lam in steps:
            flux = cond * np.diff(xb, axis=0)  # (T-1, n)
            xb[:-1] += lam * flux
            xb[1:] -= lam * flux
        if xb is not flat:
            flat[:, c0 : c0 + width] = xb
    return x


#: Values :func:`laplacian_smooth` iterates on at once (8 MB).
_SMOOTH_BLOCK = 1 << 20


def _smooth_spectral(x: np.ndarray, full: int, last: float, cuts: np.ndarray) -> np.ndarray:
    """``full`` iterations of step λ and one of step ``last``, segment by
    segment between the ``cuts``, in the cosine basis (see
    :func:`laplacian_smooth`).  Segments of one length go through one FFT."""
    T = x.shape[0]
    starts = np.concatenate([[0], np.flatnonzero(cuts) + 1])
    lengths = np.diff(np.append(starts, T))
    out = x.copy()
    scale = np.abs(x).reshape(T, -1).max(axis=0).reshape(x.shape[1:])
    for n in np.unique(lengths[lengths > 1]):
        first = starts[lengths == n]
        idx = first[:, None] + np.arange(n)  # (S, n)
        seg = x[idx]  # (S, n, ...)
        # the even extension (x, reversed x): its DFT is the DCT-II of x
        spec = np.fft.rfft(np.concatenate([seg, seg[:, ::-1]], axis=1), axis=1)
        mu = 2.0 - 2.0 * np.cos(np.pi * np.arange(n + 1) / n)
        gain = np.power(np.clip(1.0 - _LAMBDA * mu, 0.0, None), full) * (1.0 - last * mu)
        spec *= gain.reshape((1, n + 1) + (1,) * (x.ndim - 1))
        out[idx] = np.fft.irfft(spec, n=2 * n, axis=1)[:, :n]
    # rounding leaves ~1e-16 of noise where the explicit scheme gives exact
    # zeros (or Gaussian tails below it): it would make spurious local maxima
    return np.where(np.abs(out) <= 1e-14 * scale, 0.0, out)


def tent_filter(x: np.ndarray, width: float, rate: float) -> np.ndarray:
    """Tent (triangle) low-pass filter along the first axis.

    ``width`` is the full base width in seconds.  Near the ends of the clip
    the kernel is renormalized over the samples that exist, so the ends are
    not pulled toward zero.
    """
    x = np.asarray(x, dtype=float)
    T = x.shape[0]
    half = 0.5 * width * rate  # frames
    r = int(np.ceil(half)) - 1 if half > 0 else 0
    r = min(r, T - 1)  # taps farther than the clip is long touch no sample
    if r < 1 or T < 2:
        return x.copy()
    k = np.arange(-r, r + 1)
    kernel = 1.0 - np.abs(k) / half
    flat = x.reshape(T, -1)
    pad = np.pad(flat, ((r, r), (0, 0)))
    ones = np.pad(np.ones(T), r)
    out = np.zeros_like(flat)
    norm = np.zeros(T)
    for kk, w in zip(k, kernel, strict=True):  # loop over kernel taps, not frames
        out += w * pad[r + kk : r + kk + T]
        norm += w * ones[r + kk : r + kk + T]
    return (out / norm[:, None]).reshape(x.shape)
