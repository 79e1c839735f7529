"""The rotation spline's rewritten kernels give the bits of the plain formulas
they replace (the same operations in the same order), on arguments that
take every branch: none, some or all of the angles small, zero, pi, NaN."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli import quat, quat_rows
from staggered_cli.model import rotation_fit, rotation_spline


def _same(a, b) -> None:
    a, b = np.asarray(a, dtype=float), np.broadcast_to(np.asarray(b, dtype=float), np.shape(a))
    assert a.shape == b.shape
    assert a.tobytes() == np.ascontiguousarray(b).tobytes()


def _angles() -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    return [
        rng.random(300) * np.pi,  # none small
        rng.random(300) * 0.049,  # all small
        rng.permutation(np.concatenate([rng.random(150) * 0.04, rng.random(150) * 3.0])),
        np.array([0.0, 1e-300, 0.0499999999, 0.05, 0.0500001, 1.0, np.pi, np.nan]),
        np.array([np.nan, 2.0]),
    ]


# the plain formulas: each function on its own, masks always applied
def _plain(x, closed, c0, c2, c4):
    x2 = x * x
    small = x < quat_rows._SERIES
    with np.errstate(divide="ignore", invalid="ignore"):
        exact = closed(np.where(small, 1.0, x))
    return np.where(small, c0 + x2 * (c2 + x2 * c4), exact)


# sine and 1 - cosine from the tangent of the half angle (quat.sin_cos)
def _sin(t):
    u = np.tan(0.5 * t)
    return 2.0 * u / (1.0 + u * u)


def _one_minus_cos(t):
    u = np.tan(0.5 * t)
    return 2.0 * (u * u) / (1.0 + u * u)


PLAIN = {
    "f1": lambda x: _plain(x, lambda t: _one_minus_cos(t) / (t * t), 0.5, -1.0 / 24.0, 1.0 / 720.0),
    "f2": lambda x: _plain(x, lambda t: (t - _sin(t)) / (t * t * t), 1.0 / 6.0, -1.0 / 120.0, 1.0 / 5040.0),
    "sinc": lambda x: _plain(x, lambda t: _sin(t) / t, 1.0, -1.0 / 6.0, 1.0 / 120.0),
    "g": lambda x: _plain(
        x, lambda t: (1.0 - 0.5 * t / np.tan(0.5 * t)) / (t * t), 1.0 / 12.0, 1.0 / 720.0, 1.0 / 30240.0
    ),
}


def test_sin_cos_from_the_half_tangent_is_as_accurate_as_libm():
    """quat.sin_cos against numpy's sin and cos: a few units in the last
    place of absolute error from 0 to many turns, near the tangent's poles
    (odd multiples of pi) included; exact at 0; into ``out`` the same bits."""
    rng = np.random.default_rng(11)
    x = np.concatenate(
        [
            rng.uniform(0.0, np.pi, 20000),
            rng.uniform(-40.0, 40.0, 20000),
            np.pi * np.array([1, -1, 3, 5, 0.5, 2]) + rng.uniform(-1e-9, 1e-9, (200, 6)).ravel()[:6],
            np.pi * np.arange(-9, 10),
            [0.0, -0.0, 1e-300, 1e-8],
        ]
    )
    s, c = quat.sin_cos(x)
    assert np.abs(s - np.sin(x)).max() <= 8 * np.finfo(float).eps
    assert np.abs(c - np.cos(x)).max() <= 8 * np.finfo(float).eps
    assert np.abs(s * s + c * c - 1.0).max() <= 8 * np.finfo(float).eps
    assert quat.sin_cos(np.array([0.0]))[0][0] == 0.0 and quat.sin_cos(np.array([0.0]))[1][0] == 1.0
    out = (np.empty_like(x), np.empty_like(x))
    got = quat.sin_cos(x, out=out)
    assert got[0] is out[0] and got[1] is out[1]
    _same(out[0], s)
    _same(out[1], c)
    # the rotations of principal axes built on it are unit and exact at whole quarter turns
    q = quat.from_axis_angle("Y", np.radians([0.0, 90.0, 180.0, -90.0, 360.0]))
    assert (
        np.abs(
            q
            - [
                [1, 0, 0, 0],
                [np.sqrt(0.5), 0, np.sqrt(0.5), 0],
                [0, 0, 1, 0],
                [np.sqrt(0.5), 0, -np.sqrt(0.5), 0],
                [-1, 0, 0, 0],
            ]
        ).max()
        <= 4 * np.finfo(float).eps
    )


@pytest.mark.parametrize("case", range(len(_angles())))
def test_coefficients_are_the_plain_functions(case):
    x = _angles()[case]
    for names in (("f1",), ("f2",), ("sinc",), ("g",), ("f1", "f2"), ("f1", "f2", "sinc"), ("g", "sinc", "f1")):
        for name, got in zip(names, quat_rows.coefficients(x, *names), strict=True):
            _same(got, PLAIN[name](x))
    _same(quat_rows.jr_inv_k2(x), PLAIN["g"](x))


def _plain_qexp(v, angle):
    half = 0.5 * angle
    small = angle < 1e-8
    u = np.tan(0.5 * half)
    sin, cos = 2.0 * u / (1.0 + u * u), (1.0 - u * u) / (1.0 + u * u)
    k = np.where(small, 0.5 - angle * angle / 48.0, sin / np.where(small, 1.0, angle))
    return np.concatenate([cos[None], v * k])


def _plain_qlog(q):
    sign = np.where(q[0] < 0.0, -1.0, 1.0)
    w = q[0] * sign
    s = np.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    half = np.arctan2(s, w)
    small = s < 1e-8
    scale = np.where(small, 2.0 / np.maximum(w, 1e-12), 2.0 * half / np.where(small, 1.0, s))
    return q[1:] * (scale * sign), 2.0 * half


@pytest.mark.parametrize("scale", [1.0, 1e-3, 1e-9, 0.0])
def test_qexp_and_qlog_are_the_plain_formulas(scale):
    rng = np.random.default_rng(3)
    for n in (5, 3000):
        v = rng.normal(size=(3, n)) * scale
        v[:, ::7] *= 1e-10  # some angles below 1e-8 among the others
        angle = np.sqrt(np.sum(v * v, axis=0))
        _same(quat_rows.exp(v, angle), _plain_qexp(v, angle))
        q = rng.normal(size=(4, n))
        q[1:] *= scale
        q[1:, ::5] *= 1e-10
        q[0, ::3] *= -1.0
        q /= np.sqrt(np.sum(q * q, axis=0))
        for got, want in zip(quat_rows.log(q), _plain_qlog(q), strict=True):
            _same(got, want)
    edge = np.array([[1.0, -1.0, 0.0, -0.0, 0.6], [0.0, 0.0, 1.0, 1.0, 0.8], [0.0] * 5, [0.0] * 5])
    for got, want in zip(quat_rows.log(edge), _plain_qlog(edge), strict=True):
        _same(got, want)


@pytest.mark.parametrize("n", [1, 7, 2047, 2048, 5000])
def test_matrix_kernels_are_the_plain_formulas(n):
    rng = np.random.default_rng(n)
    for k in (3, 6):
        a, b = rng.normal(size=(3, 3, n)), rng.normal(size=(3, k, n))
        _same(quat_rows.mm(a, b), np.einsum("ijn,jkn->ikn", a, b, order="C"))
        out = np.empty((3, 2 * k, n))
        quat_rows.mm(a, b, out=out[:, k:])
        _same(out[:, k:], np.einsum("ijn,jkn->ikn", a, b, order="C"))
    w = rng.normal(size=(3, n))
    t2 = np.sum(w * w, axis=0)
    for p in (tuple(rng.normal(size=(3, n))), (1.0, 0.5, rng.normal(size=n))):
        p0, p1, p2 = p
        d = p0 - p2 * t2
        k_ = p1 * w
        want = np.empty((3, 3, n))
        # p2 * w[i] * w[j] is (p2 w_i) w_j, and adding d to the product is the kernel's order
        for i in range(3):
            for j in range(3):
                base = (p2 * w[i]) * w[j]
                entry = base + d if i == j else base
                if (i, j) in ((0, 1), (1, 2), (2, 0)):
                    entry = entry - k_[3 - i - j]
                elif (i, j) in ((1, 0), (2, 1), (0, 2)):
                    entry = entry + k_[3 - i - j]
                want[i, j] = entry
        _same(quat_rows.pmatrix(p, w, t2), want)


def test_gram_sums_are_the_whole_product():
    rng = np.random.default_rng(11)
    counts = rng.integers(1, 12, size=200)
    n = int(counts.sum())
    j = rng.normal(size=(3, 6, n))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    jj = j[0][:, None] * j[0][None] + j[1][:, None] * j[1][None] + j[2][:, None] * j[2][None]
    want = np.moveaxis(np.add.reduceat(jj, starts, axis=-1), -1, 0)
    _same(rotation_fit._gram_sums(j, starts), want)


def _fit_case(seed: int, n_seg: int = 60):
    rng = np.random.default_rng(seed)
    knots = quat.normalize(rng.normal(size=(n_seg + 1, 4)) * [4.0, 1.0, 1.0, 1.0])
    per = rng.integers(0, 10, size=n_seg)
    seg = np.repeat(np.arange(n_seg), per)
    u = rng.random(seg.size)
    mid = quat.slerp(knots[seg], knots[seg + 1], u)
    noise = quat.exp(rng.normal(size=(seg.size, 3)) * 0.05)
    return knots[:-1], knots[1:], seg, u, quat.mul(mid, noise), n_seg


@pytest.mark.parametrize("chunk", [16, 97, 1024])
def test_fit_and_eval_do_not_depend_on_the_chunks(monkeypatch, chunk):
    q0, q3, seg, u, values, n = _fit_case(5)
    a, b = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n)
    s = rotation_spline.rotation_eval_at(q0, a, b, q3, seg, u)
    monkeypatch.setattr(rotation_spline, "CHUNK", chunk)
    a2, b2 = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n)
    _same(a2, a)
    _same(b2, b)
    _same(rotation_spline.rotation_eval_at(q0, a, b, q3, seg, u), s)


def test_fit_jacobians_where_used_match_jacobians_everywhere(monkeypatch):
    """The fit builds J^T J only at the points a step is taken from, and
    takes the errors of evaluations without it: with the Jacobian built at
    every evaluation (as the plain loop does) the tangents are the same."""
    q0, q3, seg, u, values, n = _fit_case(9, 120)
    a, b = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n, iterations=30)
    call = rotation_fit._NormalEquations.__call__

    def always(self, rows, x, jacobian=True, curve=None, **kw):  # every evaluation with its Jacobian
        cost, jtj, jtr = call(self, rows, x, True, curve, **kw)
        return (cost, jtj, jtr) if jacobian else (cost, None, None)

    monkeypatch.setattr(rotation_fit._NormalEquations, "__call__", always)
    a2, b2 = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n, iterations=30)
    _same(a2, a)
    _same(b2, b)


@pytest.mark.parametrize("tail", [0, 200, 10**9])
def test_tail_steps_with_their_jacobian_in_one_call_are_the_same_fit(monkeypatch, tail):
    """On few samples a trial step's error and Jacobian come from one call
    (``_TAIL_SAMPLES``): never, sometimes or always doing so gives the
    same tangents and curve, and saves calls."""
    q0, q3, seg, u, values, n = _fit_case(9, 120)
    calls = []
    call = rotation_fit._NormalEquations.__call__

    def counted(self, rows, x, jacobian=True, curve=None, **kw):
        calls.append(jacobian)
        return call(self, rows, x, jacobian, curve, **kw)

    monkeypatch.setattr(rotation_fit._NormalEquations, "__call__", counted)
    ref = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n, iterations=30, return_curve=True)
    default_calls = len(calls)
    calls.clear()
    monkeypatch.setattr(rotation_fit, "_TAIL_SAMPLES", tail)
    got = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n, iterations=30, return_curve=True)
    for x, y in zip(got, ref, strict=True):
        _same(x, y)
    if tail == 0:
        assert len(calls) > default_calls  # the default merged some
    if tail == 10**9:
        assert len(calls) <= default_calls


@pytest.mark.parametrize("budget", [0, 256, 10**9])
def test_next_steps_tried_in_one_call_are_the_same_fit(monkeypatch, budget):
    """At the end of a fit the steps a segment would take after failures
    are tried in the same call (``_TRIAL_SAMPLES``) and replayed: never,
    at the end or from the first step on, the same tangents and curve, in
    fewer calls.  Noisy samples make steps fail; 10 steps (as extract
    takes) and 30 spend some segments' iterations."""
    q0, q3, seg, u, values, n = _fit_case(9, 120)
    rng = np.random.default_rng(4)
    values = quat.normalize(values + rng.normal(scale=0.4, size=values.shape) * (seg % 5 == 0)[:, None])
    call = rotation_fit._NormalEquations.__call__
    calls = []

    def counted(self, *args, **kw):
        calls.append(1)
        return call(self, *args, **kw)

    monkeypatch.setattr(rotation_fit._NormalEquations, "__call__", counted)
    for iterations in (10, 30):
        monkeypatch.setattr(rotation_fit, "_TRIAL_SAMPLES", 0)
        calls.clear()
        ref = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n, iterations=iterations, return_curve=True)
        plain = len(calls)
        monkeypatch.setattr(rotation_fit, "_TRIAL_SAMPLES", budget)
        calls.clear()
        got = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n, iterations=iterations, return_curve=True)
        for x, y in zip(got, ref, strict=True):
            _same(x, y)
        assert len(calls) < plain if budget else len(calls) == plain


def test_next_steps_tried_in_one_call_on_random_fits(monkeypatch):
    """Random fits (1 to 40 segments of 0 to 11 samples, noise from 0.01 to
    1.5 rad, samples at u = 0, a NaN, 0 to 14 steps, with and without the
    curve): never, at the end and from the start, the same bits.  (Among the
    segments between two still moving can be as many samples as the trial
    steps: they once were taken for them.)"""
    rng = np.random.default_rng(123)
    for _ in range(150):
        S = int(rng.integers(1, 40))
        knots = quat.normalize(rng.normal(size=(S + 1, 4)) * [rng.uniform(0.5, 5), 1, 1, 1])
        seg = np.repeat(np.arange(S), rng.integers(0, 12, size=S))
        u = rng.random(seg.size)
        if rng.random() < 0.2:
            u[rng.random(seg.size) < 0.1] = 0.0
        noise = quat.exp(rng.normal(size=(seg.size, 3)) * rng.uniform(0.01, 1.5))
        values = quat.mul(quat.slerp(knots[seg], knots[seg + 1], u), noise)
        if rng.random() < 0.1 and seg.size:
            values[0] = np.nan
        iterations, curve = int(rng.integers(0, 15)), bool(rng.random() < 0.7)
        fits = []
        for budget in (0, 256, 10**9):
            monkeypatch.setattr(rotation_fit, "_TRIAL_SAMPLES", budget)
            fits.append(
                rotation_fit.fit_rotation_tangents(
                    knots[:-1], knots[1:], seg, u, values, S, iterations=iterations, return_curve=curve
                )
            )
        for got in fits[1:]:
            for x, y in zip(got, fits[0], strict=True):
                _same(x, y)


@pytest.mark.parametrize("n", [3, 2047, 2048, 3000])
def test_qmul_conj_is_the_product_with_the_negated_copy(n):
    rng = np.random.default_rng(n)
    a, b = rng.normal(size=(4, n)), rng.normal(size=(4, n))
    a[:, ::4] = [[1.0], [0.0], [-0.0], [0.0]]  # signed zeros on both sides
    b[:, ::3] = [[-0.0], [0.0], [1.0], [-0.0]]
    _same(quat_rows.mul_conj(a, b), quat_rows.mul(a * quat_rows._CONJ, b))


@pytest.mark.parametrize("iterations", [0, 1, 30])
def test_fit_returns_the_curve_rotation_eval_at_gives(iterations):
    q0, q3, seg, u, values, n = _fit_case(13, 80)
    u[::11] = 0.0  # samples the fit does not use
    a, b = rotation_fit.fit_rotation_tangents(q0, q3, seg, u, values, n, iterations=iterations)
    a2, b2, at, curve = rotation_fit.fit_rotation_tangents(
        q0, q3, seg, u, values, n, iterations=iterations, return_curve=True
    )
    _same(a2, a)
    _same(b2, b)
    assert np.all(np.diff(np.sort(at)) > 0) and np.all((u[at] > 0.0) & (u[at] < 1.0))
    if iterations:
        assert at.size > 0.8 * seg.size
    _same(curve, rotation_spline.rotation_eval_at(q0, a, b, q3, seg[at], u[at]))
