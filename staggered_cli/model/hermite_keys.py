"""The staggered poses as cubic Hermite keys (glTF's CUBICSPLINE, issue 36).

Each variable is keyed at its own knots of the base layer (extreme and
editing knots): the value there is the spline's, and each segment's out- and
in-tangents are fitted, by least squares on samples inside the segment, so
that the cubic Hermite on the components (then normalized, for rotations)
follows the document's spline.  glTF keeps a separate in- and out-tangent
per key, so every segment is fitted on its own: a tangent may break at a
knot as the spline's does.  Quaternions stay w first here; the file format
turns them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UsageError, arg
from .document import Document
from .evaluate import evaluate_at
from .kinds import ROTATION

#: Samples per segment the tangents are fitted to (inside it: its ends are the keys).
SAMPLES = 16


@dataclass(frozen=True)
class Keys:
    """One variable's keys: ``times`` (K,), ``values`` (K, D), ``tangent_in``
    and ``tangent_out`` (K, D), per second (glTF's: multiplied by the
    segment's duration when evaluated)."""

    kind: str
    target: int
    times: np.ndarray
    values: np.ndarray
    tangent_in: np.ndarray
    tangent_out: np.ndarray


def _basis(u: np.ndarray) -> np.ndarray:
    """Cubic Hermite basis (N, 4): h00, h10, h01, h11."""
    u2, u3 = u * u, u * u * u
    return np.stack([2 * u3 - 3 * u2 + 1, u3 - 2 * u2 + u, -2 * u3 + 3 * u2, u3 - u2], axis=1)


def pose_keys(doc: Document) -> list[Keys]:
    """Every variable's keys, rotation and translation tracks, for a
    document of one layer (``UsageError`` for stacked layers: their keys
    would be the base layer's, not the motion's)."""
    if doc.n_layers > 1:
        raise UsageError(
            f"the document has {doc.n_layers} layers: glTF pose keys are the base layer's; "
            f"remove the layers above it (layer --remove L), or write {arg('keys')} dense"
        )
    u = np.arange(1, SAMPLES) / SAMPLES
    H = _basis(u)
    pinv = np.linalg.pinv(H[:, [1, 3]])  # (2, N): the tangents' least squares
    out: list[Keys] = []
    for track in doc.tracks:
        k = track.knots
        for i in range(track.n_vars):
            t = k.t[k.of(i)]
            n = len(t)
            var = np.full(n, i)
            values = evaluate_at(track, var, t, "splines")
            if track.kind == ROTATION:
                values = _unrolled(values / np.linalg.norm(values, axis=1, keepdims=True))
            if n < 2:
                zero = np.zeros_like(values)
                out.append(Keys(track.kind, int(track.targets[i]), t, values, zero, zero))
                continue
            dt = np.diff(t)
            ts = (t[:-1, None] + dt[:, None] * u[None]).ravel()
            target = evaluate_at(track, np.full(len(ts), i), ts, "splines").reshape(n - 1, len(u), -1)
            if track.kind == ROTATION:
                values, target = _along_the_path(values, target)
            rest = target - H[None, :, 0, None] * values[:-1, None] - H[None, :, 2, None] * values[1:, None]
            fit = np.einsum("kn,snd->skd", pinv, rest)  # (S, 2, D): out and in tangents times dt
            tan_out = np.zeros_like(values)
            tan_in = np.zeros_like(values)
            tan_out[:-1] = fit[:, 0] / dt[:, None]
            tan_in[1:] = fit[:, 1] / dt[:, None]
            out.append(Keys(track.kind, int(track.targets[i]), t, values, tan_in, tan_out))
    return out


def _along_the_path(values: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keys (K, 4) and samples (K-1, N, 4) with the signs the spline's path
    takes: each sample on the side of the one before it from the segment's
    first key, and each key on the side the path arrives at.  A segment that
    turns more than half a turn (a pirouette between two knots) ends at the
    key's negative, and the Hermite must go there."""
    target = target.copy()
    prev = values[:-1]
    for n in range(target.shape[1]):
        flip = np.sum(target[:, n] * prev, axis=1) < 0
        target[flip, n] *= -1
        prev = target[:, n]
    arrives = np.where(np.sum(prev * values[1:], axis=1) < 0, -1.0, 1.0)
    sign = np.concatenate([[1.0], np.cumprod(arrives)])
    return values * sign[:, None], target * sign[:-1, None, None]


def _unrolled(q: np.ndarray) -> np.ndarray:
    """``q`` (K, 4) with each key on the side of the one before."""
    q = q.copy()
    for k in range(1, len(q)):
        if np.dot(q[k], q[k - 1]) < 0:
            q[k] = -q[k]
    return q
