"""The paper's operators, one set per kind of control variable (SPEC section 2).

Motion is composed as ``v = s ⊕ d`` (spline, then displacement map), and
edits are offsets ``value ⊕ delta``.  What ``⊕`` means depends on the kind:

* translations (``D = 3``, file units): ``a ⊕ b = a + b``, ``c ⊖ a = c - a``,
  scaling ``w · d``, linear interpolation, identity 0;
* rotations (``D = 4``, unit quaternions w first): ``a ⊕ b = a * b`` (``b``
  in ``a``'s local frame), ``c ⊖ a = a⁻¹ * c`` so that ``a ⊕ (c ⊖ a) = c``,
  scaling ``exp(w · log(d))``, slerp, identity ``(1, 0, 0, 0)``.

Code looks the operations up with :func:`ops_for` rather than branching on
the kind.  Every function broadcasts over leading axes and never mutates its
inputs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import quat
from . import bezier, rotation_spline

TRANSLATION = "translation"
ROTATION = "rotation"
KINDS = (TRANSLATION, ROTATION)


@dataclass(frozen=True)
class KindOps:
    """The operators of one kind of variable.

    ``oplus(a, b)``, ``ominus(c, a)``, ``scale(d, w)`` (``w`` a float or an
    array broadcasting against the leading axes), ``interpolate(a, b, u)``
    (``u`` against the leading axes), ``identity(shape)`` and ``dim``; and
    the kind's cubic segments (:mod:`.bezier`, :mod:`.rotation_spline`): ``spline_at(p0, a, b, p3,
    seg, u)`` evaluates segments ``seg`` at ``u``, ``linear_controls(p0, p3)``
    gives the inner controls of the uniform-speed segment; ``normalize(v)``
    returns values to the kind's set after arithmetic (unit quaternions; a
    translation is any vector, returned as it is).
    """

    kind: str
    dim: int
    oplus: Callable[[np.ndarray, np.ndarray], np.ndarray]
    ominus: Callable[[np.ndarray, np.ndarray], np.ndarray]
    scale: Callable[[np.ndarray, np.ndarray | float], np.ndarray]
    interpolate: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    identity: Callable[[tuple[int, ...]], np.ndarray]
    normalize: Callable[[np.ndarray], np.ndarray]
    spline_at: Callable[..., np.ndarray]
    linear_controls: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _weights(w, lead: int) -> np.ndarray:
    w = np.asarray(w, dtype=float)
    return w.reshape(w.shape + (1,) * (lead - w.ndim)) if w.ndim else w


def _t_scale(d: np.ndarray, w) -> np.ndarray:
    d = np.asarray(d, dtype=float)
    return d * _weights(w, d.ndim)


def _t_interpolate(a: np.ndarray, b: np.ndarray, u) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    return a + (np.asarray(b, dtype=float) - a) * np.asarray(u, dtype=float)[..., None]


def _t_identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    return np.zeros(tuple(shape) + (3,))


def _r_scale(d: np.ndarray, w) -> np.ndarray:
    return quat.pow(d, w)


def _r_interpolate(a: np.ndarray, b: np.ndarray, u) -> np.ndarray:
    """Slerp; ``u == 0`` gives ``a`` exactly (no round off at the knots)."""
    u = np.asarray(u, dtype=float)
    a = np.asarray(a, dtype=float)
    shape = np.broadcast_shapes(a.shape, np.shape(b), u.shape + (4,))
    out = np.array(np.broadcast_to(a, shape))
    move = np.broadcast_to(u != 0.0, shape[:-1])
    if np.any(move):  # on a bake at the source's frames, none do
        ab = np.broadcast_to(a, shape)[move], np.broadcast_to(b, shape)[move]
        out[move] = quat.slerp(*ab, np.broadcast_to(u, shape[:-1])[move])
    return out


TRANSLATION_OPS = KindOps(
    TRANSLATION,
    3,
    oplus=lambda a, b: np.asarray(a, dtype=float) + b,
    ominus=lambda c, a: np.asarray(c, dtype=float) - a,
    scale=_t_scale,
    interpolate=_t_interpolate,
    identity=_t_identity,
    normalize=lambda v: v,
    spline_at=bezier.bezier_eval_at,
    linear_controls=bezier.default_translation_tangents,
)

ROTATION_OPS = KindOps(
    ROTATION,
    4,
    oplus=quat.oplus,
    ominus=quat.ominus,
    scale=_r_scale,
    interpolate=_r_interpolate,
    identity=quat.identity,
    normalize=quat.normalize,
    spline_at=rotation_spline.rotation_eval_at,
    linear_controls=rotation_spline.default_rotation_tangents,
)

_OPS = {TRANSLATION: TRANSLATION_OPS, ROTATION: ROTATION_OPS}


def ops_for(kind: str) -> KindOps:
    """The operators of ``kind`` (``'translation'`` or ``'rotation'``)."""
    try:
        return _OPS[kind]
    except KeyError:
        raise ValueError(f"unknown kind of variable {kind!r}") from None
