"""Where poses earn their keep: a fast stand-in for the spline fit.

Extraction places poses and cull ranks them by how well the spline layer
alone would reproduce the motion (issue 13: the paper's priority
``P(t_k)(t_{k+1} - t_{k-1})`` ignores the fit).  Refitting the real splines
for every trial would cost a whole extract per trial, so trials use a
*proxy*: every control variable becomes a Euclidean signal (translations as
they are; rotations as their hemisphere-unrolled quaternion components, whose
distance is half the rotation angle for small errors), and a segment between
two knots costs the squared residual of the least-squares cubic Bézier that
interpolates its end values, as the translation fit does, measured by the
length of the misfit.  Each
variable is weighted by how far its error moves the body: a rotation error
of ``θ`` at joint ``j`` moves each joint below it by ``θ |x_d - x_j|``, a
root translation moves every joint below it.  The cost of a segment is then
(roughly) the summed world-position error of the joints it drives, the
measure the spline layer is judged by; the controls are still the
least-squares ones, as in the real fit.  Segment costs are computed for many segments at once.

All times here are in frames (floats: a knot need not sit on a frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.lib.stride_tricks import as_strided

from ..model.kinds import ROTATION
from ..motion import BvhMotion, MarkerMotion, local_rotations_from_channels, local_translations_from_channels
from ..skeleton import forward_kinematics

#: The proxy keeps the variables that make up this share of the body's motion.
KEEP = 0.999
#: Rough bound on the number of floats one batch of segment costs gathers
#: (about 1 MB per array: they stay in cache).
_COST_BATCH = 1 << 17
#: The same for :func:`window_costs`: residual values of one batch of
#: segments (float32: 1 MB).
_WINDOW_BATCH = 1 << 18


@dataclass(frozen=True)
class Proxy:
    """Dense motion as Euclidean signals.

    Attributes
    ----------
    x : (T, V, 4) values per frame and variable (translations padded with 0).
    w : (V,) weights: how far an error of each variable moves the body.
    cols : (V,) int, the variables of the clip these are (see :func:`proxy_from_dense`).
    """

    x: np.ndarray
    w: np.ndarray
    cols: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.x.shape[0]

    @cached_property
    def by_channel(self) -> np.ndarray:
        """The values channel first, (C, T * V) (made once: segment costs
        read them so, and a long clip's copy, the size of ``x``, made at
        every call was most of their time)."""
        T, V, C = self.x.shape
        return np.ascontiguousarray(self.x.reshape(T * V, C).T)


def variable_weights(motion: BvhMotion | MarkerMotion, variables) -> np.ndarray:
    """Weights (V,) of the variables ``(kind, names, targets, dense)``.

    BVH: a rotation of joint ``j`` weighs ``2 Σ_d |x_d - x_j|`` over the
    joints ``d`` below it (a quaternion distance is half the angle), a
    translation of ``j`` weighs the number of joints it moves, itself
    included; positions are taken at the middle frame.  C3D: every marker
    weighs 1.
    """
    if not isinstance(motion, BvhMotion):
        return np.ones(sum(len(names) for _, names, _, _ in variables))
    sk = motion.skeleton
    pos = _middle_frame_positions(motion)  # (J, 3)
    out = []
    for kind, _names, targets, _ in variables:
        for j in np.asarray(targets, dtype=int):
            below = sk.subtree(int(j))
            if kind == ROTATION:
                out.append(2.0 * float(np.sum(np.linalg.norm(pos[below] - pos[j], axis=1))))
            else:
                out.append(float(len(below)))
    return np.asarray(out, dtype=float)


def _middle_frame_positions(motion: BvhMotion) -> np.ndarray:
    """World joint positions (J, 3) at the middle frame, ``motion.world_positions()[T // 2]``
    to the bit, from that frame alone: cull's document has no world
    transforms at hand, and those of every frame took 40 ms of cmu_01_01's.
    Kinematics go frame by frame, and the sign of a quaternion (which
    unrolling over the clip picks) does not change a bit of a position: each
    term of a rotated vector is a product of two of its components."""
    mid = motion.n_frames // 2
    frame = motion.channels[mid : mid + 1]
    rot = local_rotations_from_channels(motion.skeleton, frame)
    trans = local_translations_from_channels(motion.skeleton, frame)
    return forward_kinematics(motion.skeleton, rot, trans)[1][0]


def proxy_from_dense(variables, w: np.ndarray, keep: float | None = None) -> Proxy:
    """The proxy of dense variables ``(kind, names, targets, dense (T, V, D))``.

    Only the variables that matter are kept: those that move, heaviest first
    (weight times the length of their path), until ``keep`` of the total; a
    finger or a constant channel does not decide where a pose goes.  Values
    are float32, which is plenty for comparing fits.
    """
    cols = [np.asarray(dense, dtype=float) for _kind, _names, _targets, dense in variables]
    if not cols:
        return Proxy(np.zeros((0, 0, 4), dtype=np.float32), np.zeros(0), np.zeros(0, dtype=int))
    keep = KEEP if keep is None else keep
    T = cols[0].shape[0]
    V = sum(d.shape[1] for d in cols)

    def x_of(lo: int, hi: int) -> np.ndarray:
        """Frames ``lo:hi`` of all the variables (n, V, 4), translations padded with zeros."""
        parts = []
        for d in cols:
            d = d[lo:hi]
            if d.shape[-1] < 4:
                d = np.concatenate([d, np.zeros(d.shape[:-1] + (4 - d.shape[-1],))], axis=-1)
            parts.append(d)
        return np.concatenate(parts, axis=1)

    # a block of frames at a time (each step's length is its own), so that
    # no (T, V, 4) float64 copy of the clip is made
    rows = max(1, _PROXY_BLOCK // max(V, 1))
    w = np.asarray(w, dtype=float)
    if T > 1:
        # summed a block at a time, row after row as np.sum(steps, axis=0)
        # adds them (the same bits), without a (T - 1, V) array of the steps
        path = None
        for lo in range(0, T - 1, rows):
            hi = min(lo + rows, T - 1)
            steps = np.linalg.norm(np.diff(x_of(lo, hi + 1), axis=0), axis=2)
            path = np.sum(steps if path is None else np.concatenate([path[None], steps]), axis=0)
        del steps
    else:
        path = np.zeros(V)
    size = w * path
    order = np.argsort(-size, kind="stable")
    total = float(size.sum())
    if total <= 0:
        return Proxy(np.zeros((T, 0, 4), dtype=np.float32), w[:0], np.zeros(0, dtype=int))
    n = int(np.searchsorted(np.cumsum(size[order]), keep * total) + 1)
    pick = np.sort(order[: min(n, len(order))])
    pick = pick[size[pick] > 0]
    x = np.empty((T, len(pick), 4), dtype=np.float32)
    for lo in range(0, T, rows):
        x[lo : lo + rows] = x_of(lo, lo + rows)[:, pick]
    return Proxy(x, w[pick], pick)


#: Variable values handled at once by :func:`proxy_from_dense`.
_PROXY_BLOCK = 1 << 16


def _values_at(x: np.ndarray, var: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``x (T, V, C)`` at fractional frames ``f`` (n,) of variables ``var`` (n,)."""
    T = x.shape[0]
    f = np.clip(f, 0.0, T - 1)
    lo = np.minimum(np.floor(f).astype(int), T - 1)
    hi = np.minimum(lo + 1, T - 1)
    w = (f - lo)[:, None]
    return x[lo, var] * (1.0 - w) + x[hi, var] * w


def _channel_values_at(xc: np.ndarray, V: int, var: np.ndarray, f: np.ndarray) -> np.ndarray:
    """:func:`_values_at` (the same numbers) on ``xc`` (C, T * V), the
    proxy's values channel first: (C, n)."""
    T = xc.shape[1] // V
    f = np.clip(f, 0.0, T - 1)
    lo = np.minimum(np.floor(f).astype(int), T - 1)
    hi = np.minimum(lo + 1, T - 1)
    w = f - lo
    out = np.take(xc, lo * V + var, axis=1) * (1.0 - w)
    out += np.take(xc, hi * V + var, axis=1) * w
    return out


#: A segment's residual is measured on at most this many samples, evenly
#: spread in its normalized time and scaled to its frame count: placement
#: compares thousands of trial segments, and 16 samples tell a cubic's misfit
#: about as well as 120.
SAMPLES = 16


def segment_costs(proxy: Proxy, var: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Weighted misfit (n,) (the sum of residual lengths) of the least-squares cubic Bézier through the
    values at frames ``a`` and ``b`` (fractional, ``a < b``) of variable
    ``var``, over the frames strictly between them (measured on at most
    :data:`SAMPLES` of them).  Segments with one frame inside cost nothing
    (the fit bends its straight controls through it); none inside, nothing
    to miss."""
    var = np.asarray(var, dtype=int).ravel()
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    n = len(var)
    out = np.zeros(n)
    if n == 0:
        return out
    first = np.floor(a + 1e-9) + 1.0
    count = np.maximum(np.ceil(b - 1e-9) - first, 0.0).astype(int)  # frames strictly inside
    C = proxy.x.shape[2]
    xc = proxy.by_channel
    # batches whose (C, SAMPLES, n) arrays stay in cache: each segment's cost
    # is computed alone, so the batch size does not change a bit of it
    step = max(1, _COST_BATCH // (SAMPLES * C))
    for s in range(0, n, step):
        sl = slice(s, s + step)
        out[sl] = _costs(xc, proxy.w, var[sl], a[sl], b[sl], first[sl], count[sl])
    return out


def _costs(xc, weight, var, a, b, first, count) -> np.ndarray:
    """The costs of :func:`segment_costs` on ``xc`` (C, T * V).

    The values are laid out (C, L, n), so that numpy's loops run along the
    segments rather than along 4 channels, and every sum adds its terms in
    the order the (n, L, C) layout it replaced did, so no bit changes: the
    sums over the samples of a product (``einsum('nl,nlc->nc')``) and over
    the channels add one term after the other, the sums over the samples
    of the Gram entries and of the misfit run on C-ordered (n, L) arrays.
    """
    V = len(weight)
    L = SAMPLES
    n = len(var)
    j = np.arange(L)[None, :]
    dense = count <= L
    # frames themselves where there are few; else evenly spread fractional frames
    spread = a[:, None] + (b - a)[:, None] * (j + 0.5) / L
    frames = np.where(dense[:, None], first[:, None] + j, spread)
    inside = np.where(dense[:, None], j < count[:, None], True)
    u = np.where(inside, (frames - a[:, None]) / (b - a)[:, None], 0.0)
    m = inside.astype(float)
    v = 1.0 - u
    b0, b1, b2, b3 = v**3 * m, 3 * u * v * v * m, 3 * u * u * v * m, u**3 * m  # (n, L)
    g11 = np.sum(b1 * b1, axis=1)
    g12 = np.sum(b1 * b2, axis=1)
    g22 = np.sum(b2 * b2, axis=1)
    b0t, b1t, b2t, b3t, mt = (np.ascontiguousarray(q.T) for q in (b0, b1, b2, b3, m))  # (L, n)
    C = xc.shape[0]
    r = _channel_values_at(xc, V, np.tile(var, L), frames.T.ravel()).reshape(C, L, n)
    xa = _channel_values_at(xc, V, var, a)[:, None, :]  # (C, 1, n)
    xb = _channel_values_at(xc, V, var, b)[:, None, :]
    # r = (y - b0 xa - b3 xb) m, in place
    tmp = np.multiply(b0t, xa)
    r -= tmp
    np.multiply(b3t, xb, out=tmp)
    r -= tmp
    r *= mt
    np.multiply(b1t, r, out=tmp)
    h1 = _sum_in_order(tmp)  # (C, n)
    np.multiply(b2t, r, out=tmp)
    h2 = _sum_in_order(tmp)
    det = g11 * g22 - g12 * g12
    fitted = (count >= 2) & (det > 1e-12 * np.maximum(g11 * g22, 1e-300))
    safe = np.where(fitted, det, 1.0)
    c1 = (g22 * h1 - g12 * h2) / safe
    c2 = (g11 * h2 - g12 * h1) / safe
    c1 = np.where(fitted, c1, xa[:, 0] + (xb[:, 0] - xa[:, 0]) / 3.0)
    c2 = np.where(fitted, c2, xa[:, 0] + 2.0 * (xb[:, 0] - xa[:, 0]) / 3.0)
    # res = r - b1 c1 - b2 c2, in place; the size of the misfit, not its
    # square: world errors add up as lengths
    np.multiply(b1t, c1[:, None, :], out=tmp)
    r -= tmp
    np.multiply(b2t, c2[:, None, :], out=tmp)
    r -= tmp
    r *= r
    length = np.sqrt(_sum_in_order(r, axis=0))  # (L, n)
    cost = np.sum(np.multiply(length.T, m, out=np.empty((n, L))), axis=1)
    scale = np.where(dense, 1.0, count / L)
    # one frame inside: the fit bends the straight controls through it
    # (bezier._through_one_sample), so the spline misses nothing there
    scale = np.where(count == 1, 0.0, scale)
    return cost * scale * weight[var]


def _sum_in_order(x: np.ndarray, axis: int = 1) -> np.ndarray:
    """The sum of ``x`` along ``axis`` (0 or 1) as ``((0 + x_0) + x_1) + ...``."""
    out = np.zeros(x.shape[:axis] + x.shape[axis + 1 :])
    for k in range(x.shape[axis]):
        out += x[k] if axis == 0 else x[:, k]
    return out


def span_costs(proxy: Proxy, knots: np.ndarray) -> np.ndarray:
    """Cost (n, V) of chains of knots: ``knots (n, V, m)`` gives, per row and
    variable, ``m`` non-decreasing knot frames; the cost sums the segments
    between consecutive distinct knots."""
    n, V, k = knots.shape
    if k < 2 or n == 0:
        return np.zeros((n, V))
    a = knots[..., :-1]
    b = knots[..., 1:]
    var = np.broadcast_to(np.arange(V)[None, :, None], a.shape)
    real = b > a + 1e-9
    cost = np.zeros(a.shape)
    cost[real] = segment_costs(proxy, var[real], a[real], b[real])
    return cost.sum(axis=2)


def window_costs(proxy: Proxy, frames: np.ndarray, width: int) -> np.ndarray:
    """Costs (G, width) of the segments between nodes: entry ``[i, w-1]`` is
    the segment from node ``i`` to node ``i + w`` (``inf`` past the last
    node), measured on the nodes between them.

    Parameters
    ----------
    frames : (G,) increasing whole frames, the nodes (a regular grid keeps
        the measure comparable between segments).
    width : the longest segment, in nodes.

    A segment's values at its ``w + 1`` nodes are the rows of ``X (w+1, V C)``;
    its controls are ``A @ X`` (least squares, :func:`_window_basis`), its
    residual at the inner nodes ``X[1:w] - B @ [x_a, x_b, c_1, c_2]``: two
    matrix products per segment on the proxy's values (float32), read in place
    from the clip (each segment's rows are a strided view of it).  The sums
    of products run in BLAS, in its order: the costs are those of the plain
    formula to float32 rounding (the tests compare with a float64 one).
    """
    frames = np.asarray(frames, dtype=int)
    G = len(frames)
    V, C = proxy.x.shape[1], proxy.x.shape[2]
    VC = V * C
    x = np.ascontiguousarray(proxy.x[frames].reshape(G, VC), dtype=np.float32)
    out = np.full((G, width), np.inf)
    top = min(width, G - 1)
    out[:, :top][np.arange(G)[:, None] + np.arange(1, top + 1)[None, :] < G] = 0.0
    if top < 2 or VC == 0:
        return out
    node_f = frames.astype(float)
    weight = proxy.w.astype(np.float32)
    # every buffer is made once: a fresh temporary of a few hundred kB costs
    # its page faults again at every use
    # basis rows (segments times inner nodes) made at once: a batch's at least
    rows = max(_BASIS_BATCH, _WINDOW_BATCH // VC, top)
    scratch = np.empty(_BASIS_SCRATCH * rows)
    b_buf = np.empty(rows * 4, np.float32)
    a_buf = np.empty(2 * (rows + 2 * rows), np.float32)
    p_buf = np.empty(4 * (_WINDOW_BATCH + top * VC), np.float32)
    r_buf = np.empty(_WINDOW_BATCH + top * VC, np.float32)
    row = VC * x.itemsize
    for w in range(2, top + 1):
        n = G - w
        nodes = as_strided(node_f, (n, w + 1), node_f.strides * 2, writeable=False)
        # span[i]: the values at nodes i .. i + w (a view: rows overlap)
        span = as_strided(x, (n, w + 1, VC), (row, row, x.itemsize), writeable=False)
        w_inner = np.tile(weight, w - 1)
        block = max(1, _WINDOW_BATCH // ((w - 1) * VC))
        chunk = block * max(1, rows // ((w - 1) * block))  # segments whose basis is made at once
        for c in range(0, n, chunk):
            k = min(c + chunk, n) - c
            B = b_buf[: k * (w - 1) * 4].reshape(k, w - 1, 4)
            A = a_buf[: k * 2 * (w + 1)].reshape(k, 2, w + 1)
            _window_basis(nodes[c : c + k], scratch, B, A)
            for s in range(c, c + k, block):
                e = min(s + block, c + k)
                m = e - s
                X = span[s:e]
                P = p_buf[: m * 4 * VC].reshape(m, 4, VC)  # x_a, x_b, c_1, c_2
                P[:, 0] = X[:, 0]
                P[:, 1] = X[:, w]
                np.matmul(A[s - c : e - c], X, out=P[:, 2:])
                r = r_buf[: m * (w - 1) * VC].reshape(m, w - 1, VC)
                np.matmul(B[s - c : e - c], P, out=r)
                np.subtract(X[:, 1:w], r, out=r)
                np.multiply(r, r, out=r)
                # the size of the misfit per variable: the sum over the 4
                # channels written out (a tenth of np.sum's time), its root
                r4 = r.reshape(m, (w - 1) * V, C)
                err = r4[..., 0] + r4[..., 1]
                err += r4[..., 2]
                err += r4[..., 3]
                np.sqrt(err, out=err)
                out[s:e, w - 1] = np.einsum("nk,k->n", err, w_inner)
    return out


#: Rows of the scratch :func:`_window_basis` works in.
_BASIS_SCRATCH = 7
#: Basis values (segments times inner nodes) :func:`window_costs` makes at
#: once: its scratch stays under 1 MB, as fast as all of a width's at once
#: (whose scratch grew with the piece: 7 float64 per node and width).
_BASIS_BATCH = 1 << 14


def _window_basis(nodes: np.ndarray, scratch: np.ndarray, B: np.ndarray, A: np.ndarray) -> None:
    """The Bézier basis and least-squares controls of segments of ``w`` nodes.

    Parameters
    ----------
    nodes : (n, w+1) float frames of each segment's nodes (``w - 1`` inner ones).
    scratch : (>= _BASIS_SCRATCH n (w-1),) float64 work space.
    B : (n, w-1, 4) float32, filled with ``b0, b3, b1, b2`` at the inner nodes.
    A : (n, 2, w+1) float32, filled so that the controls are ``A @ X`` for
        the values ``X`` at the segment's nodes: least squares ``G⁻¹ [b1 b2]ᵀ
        (y - b0 x_a - b3 x_b)`` from two inner nodes on, else the straight
        controls ``(2 x_a + x_b) / 3`` and ``(x_a + 2 x_b) / 3`` (as the fit).
    """
    n, w = nodes.shape[0], nodes.shape[1] - 1
    # packed one after the other
    u, v, t, b0, b1, b2, b3 = scratch[: _BASIS_SCRATCH * n * (w - 1)].reshape(_BASIS_SCRATCH, n, w - 1)
    fa = nodes[:, :1]
    np.subtract(nodes[:, 1:w], fa, out=u)
    u /= nodes[:, w:] - fa
    np.subtract(1.0, u, out=v)
    np.multiply(v, v, out=t)
    np.multiply(t, v, out=b0)
    np.multiply(t, u, out=b1)
    b1 *= 3.0
    np.multiply(u, u, out=t)
    np.multiply(t, u, out=b3)
    np.multiply(t, v, out=b2)
    b2 *= 3.0
    for k, b in enumerate((b0, b3, b1, b2)):
        B[..., k] = b
    if w - 1 < 2:
        A[:, :, 1] = 0.0
        A[:, 0, 0] = A[:, 1, 2] = 2.0 / 3.0
        A[:, 0, 2] = A[:, 1, 0] = 1.0 / 3.0
        return
    g11 = np.einsum("nt,nt->n", b1, b1)
    g12 = np.einsum("nt,nt->n", b1, b2)
    g22 = np.einsum("nt,nt->n", b2, b2)
    det = g11 * g22 - g12 * g12
    g11 /= det
    g12 /= det
    g22 /= det
    a1, a2 = u, v  # the rows of G⁻¹ [b1 b2]ᵀ, in u's and v's place
    np.multiply(b1, g22[:, None], out=a1)
    np.multiply(b2, g12[:, None], out=t)
    a1 -= t
    np.multiply(b2, g11[:, None], out=a2)
    np.multiply(b1, g12[:, None], out=t)
    a2 -= t
    A[:, 0, 1:w] = a1
    A[:, 1, 1:w] = a2
    for j, a in enumerate((a1, a2)):
        A[:, j, 0] = -np.einsum("nt,nt->n", a, b0)
        A[:, j, w] = -np.einsum("nt,nt->n", a, b3)
