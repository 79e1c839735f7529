"""Quaternion algebra (staggered_cli.quat): identities on seeded random
arrays and hypothesis-drawn angles, (w, x, y, z) with the Hamilton product."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from staggered_cli import quat

ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]
N = 500

deterministic = settings(max_examples=300, deadline=None, derandomize=True, database=None)
angle = st.floats(-179.0, 179.0, allow_nan=False)
middle = st.floats(-89.0, 89.0, allow_nan=False)


def random_unit(rng, n: int = N) -> np.ndarray:
    return quat.normalize(rng.normal(size=(n, 4)))


def same_rotation(a, b, atol=1e-12) -> None:
    """``a`` and ``b`` are the same rotations within ``atol`` radians (q and -q are one rotation)."""
    worst = quat.angle_between(a, b).max()
    assert worst < atol, worst


@pytest.fixture
def rng():
    return np.random.default_rng(20260101)


# --------------------------------------------------------------------------- products


def test_identity_is_neutral_and_conj_is_the_inverse(rng):
    q = random_unit(rng)
    one = quat.identity((N,))
    np.testing.assert_allclose(quat.mul(one, q), q, atol=0)
    np.testing.assert_allclose(quat.mul(q, one), q, atol=0)
    np.testing.assert_allclose(quat.mul(q, quat.conj(q)), one, atol=1e-15)
    np.testing.assert_allclose(quat.mul(quat.inv(q), q), one, atol=1e-15)
    np.testing.assert_array_equal(quat.conj(quat.conj(q)), q)


def test_product_is_associative_and_norms_multiply(rng):
    a, b, c = (rng.normal(size=(N, 4)) for _ in range(3))
    np.testing.assert_allclose(quat.mul(quat.mul(a, b), c), quat.mul(a, quat.mul(b, c)), atol=1e-12)
    np.testing.assert_allclose(
        np.linalg.norm(quat.mul(a, b), axis=-1), np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), rtol=1e-13
    )
    # (ab)* = b* a*, and the product is not commutative
    np.testing.assert_allclose(quat.conj(quat.mul(a, b)), quat.mul(quat.conj(b), quat.conj(a)), atol=1e-13)
    assert np.abs(quat.mul(a, b) - quat.mul(b, a)).max() > 0.1


def test_hamilton_units():
    one, i, j, k = np.eye(4)
    np.testing.assert_array_equal(quat.mul(i, j), k)
    np.testing.assert_array_equal(quat.mul(j, k), i)
    np.testing.assert_array_equal(quat.mul(k, i), j)
    np.testing.assert_array_equal(quat.mul(j, i), -k)
    for u in (i, j, k):
        np.testing.assert_array_equal(quat.mul(u, u), -one)


def test_products_broadcast_over_leading_axes(rng):
    a = random_unit(rng, 6).reshape(2, 3, 4)
    b = random_unit(rng, 3)
    out = quat.mul(a, b)
    assert out.shape == (2, 3, 4)
    np.testing.assert_allclose(out[1, 2], quat.mul(a[1, 2], b[2]), atol=0)


def test_rotating_vectors_agrees_with_matrices_and_composes(rng):
    a, b = random_unit(rng), random_unit(rng)
    v = rng.normal(size=(N, 3))
    m = quat.to_matrix(a)
    np.testing.assert_allclose(quat.mul_vec(a, v), np.einsum("nij,nj->ni", m, v), atol=1e-12)
    np.testing.assert_allclose(quat.mul_vec(quat.mul(a, b), v), quat.mul_vec(a, quat.mul_vec(b, v)), atol=1e-12)
    np.testing.assert_allclose(quat.mul_vec(-a, v), quat.mul_vec(a, v), atol=1e-12)  # q and -q
    np.testing.assert_allclose(np.linalg.norm(quat.mul_vec(a, v), axis=-1), np.linalg.norm(v, axis=-1), rtol=1e-12)
    # matrices are rotations, and the matrix of a product is the product of the matrices
    np.testing.assert_allclose(np.einsum("nji,njk->nik", m, m), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat.to_matrix(quat.mul(a, b)), m @ quat.to_matrix(b), atol=1e-12)
    # to_matrix normalizes: a scaled quaternion is the same rotation
    np.testing.assert_allclose(quat.to_matrix(3.0 * a), m, atol=1e-12)


def test_axis_angle_about_z_turns_x_into_y():
    q = quat.from_axis_angle("Z", np.radians(90.0))
    np.testing.assert_allclose(quat.mul_vec(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(q, [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], atol=1e-16)
    np.testing.assert_allclose(quat.angle(q), np.pi / 2, rtol=1e-15)


# --------------------------------------------------------------------------- log, exp, angles, slerp


def test_log_and_exp_are_inverse(rng):
    q = random_unit(rng)
    q = np.where(q[:, :1] < 0, -q, q)  # the hemisphere log picks
    np.testing.assert_allclose(quat.exp(quat.log(q)), q, atol=1e-13)
    np.testing.assert_allclose(quat.exp(quat.log(-q)), q, atol=1e-13)  # -q: the same rotation, the shorter arc
    r = rng.normal(size=(N, 3))
    r *= (rng.uniform(0.0, np.pi - 1e-6, N) / np.linalg.norm(r, axis=-1))[:, None]
    np.testing.assert_allclose(quat.log(quat.exp(r)), r, atol=1e-12)
    np.testing.assert_allclose(quat.angle(quat.exp(r)), np.linalg.norm(r, axis=-1), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(quat.exp(r), axis=-1), 1.0, atol=1e-15)


@pytest.mark.parametrize("size", [1e-6, 1e-9, 1e-12, 1e-15, 0.0])
def test_log_and_exp_stay_accurate_for_tiny_angles(rng, size):
    r = rng.normal(size=(50, 3)) * size
    q = quat.exp(r)
    np.testing.assert_allclose(q[:, 1:], 0.5 * r, rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(quat.log(q), r, rtol=1e-9, atol=1e-300)
    assert np.all(np.isfinite(quat.log(quat.identity((3,)))))
    np.testing.assert_array_equal(quat.log(quat.identity((3,))), 0.0)


def test_angle_between_is_symmetric_and_sign_blind(rng):
    a, b = random_unit(rng), random_unit(rng)
    d = quat.angle_between(a, b)
    assert np.all((d >= 0) & (d <= np.pi + 1e-15))
    np.testing.assert_allclose(quat.angle_between(b, a), d, atol=1e-12)
    np.testing.assert_allclose(quat.angle_between(a, -b), d, atol=1e-12)
    np.testing.assert_allclose(quat.angle_between(a, a), 0.0, atol=1e-7)


def test_slerp_ends_midpoint_and_constant_speed(rng):
    a, b = random_unit(rng), random_unit(rng)
    np.testing.assert_allclose(quat.slerp(a, b, np.zeros(N)), a, atol=1e-15)
    same_rotation(quat.slerp(a, b, np.ones(N)), b, atol=1e-12)
    total = quat.angle_between(a, b)
    for u in (0.25, 0.5, 0.9):
        s = quat.slerp(a, b, np.full(N, u))
        np.testing.assert_allclose(np.linalg.norm(s, axis=-1), 1.0, atol=1e-14)
        np.testing.assert_allclose(quat.angle_between(a, s), u * total, atol=1e-11)
        np.testing.assert_allclose(quat.angle_between(s, b), (1 - u) * total, atol=1e-11)
    # the shorter arc: b and -b give the same path
    np.testing.assert_allclose(quat.slerp(a, -b, np.full(N, 0.3)), quat.slerp(a, b, np.full(N, 0.3)), atol=1e-13)


def test_pow_scales_the_angle_about_the_same_axis(rng):
    q = random_unit(rng)
    q = np.where(q[:, :1] < 0, -q, q)
    np.testing.assert_allclose(quat.pow(q, 0.0), quat.identity((N,)), atol=0)
    np.testing.assert_allclose(quat.pow(q, 1.0), q, atol=1e-13)
    same_rotation(quat.pow(q, 2.0), quat.mul(q, q), atol=1e-12)
    half = quat.pow(q, 0.5)
    same_rotation(quat.mul(half, half), q, atol=1e-12)
    w = rng.uniform(-1, 1, N)  # |w| * angle stays within pi: log gives w * log(q) back
    np.testing.assert_allclose(quat.log(quat.pow(q, w)), quat.log(q) * w[:, None], atol=1e-12)
    same_rotation(quat.pow(q, -1.0), quat.conj(q), atol=1e-12)


def test_oplus_and_ominus_are_the_papers(rng):
    a, c = random_unit(rng), random_unit(rng)
    np.testing.assert_allclose(quat.oplus(a, quat.ominus(c, a)), c, atol=1e-13)
    np.testing.assert_allclose(quat.ominus(a, a), quat.identity((N,)), atol=1e-15)
    # b is applied in a's local frame: a ⊕ b rotates a vector by b first
    b = random_unit(rng)
    v = rng.normal(size=(N, 3))
    np.testing.assert_allclose(quat.mul_vec(quat.oplus(a, b), v), quat.mul_vec(a, quat.mul_vec(b, v)), atol=1e-12)


def test_unroll_and_hemisphere(rng):
    # a smooth track, its signs flipped at random
    t = np.linspace(0.0, 4 * np.pi, 400)
    smooth = quat.exp(np.stack([np.sin(t), 0.5 * np.cos(0.7 * t), 0.9 * t], axis=-1))
    signs = rng.choice([-1.0, 1.0], size=400)
    flipped = smooth * signs[:, None]
    out = quat.unroll(flipped)
    assert np.all(np.sum(out[1:] * out[:-1], axis=-1) >= 0.0)
    np.testing.assert_array_equal(np.abs(out), np.abs(smooth))
    np.testing.assert_allclose(out, smooth * signs[0], atol=0)  # the first keeps its sign
    np.testing.assert_array_equal(flipped, smooth * signs[:, None])  # the input is not changed
    # along another axis: (J, T, 4) unrolled over T
    two = np.stack([flipped, -flipped])
    np.testing.assert_allclose(quat.unroll(two, axis=1), np.stack([out, -out]), atol=0)
    assert quat.unroll(flipped[:1]).shape == (1, 4)
    ref = random_unit(rng)
    q = random_unit(rng)
    h = quat.hemisphere(q, ref)
    assert np.all(np.sum(h * ref, axis=-1) >= 0.0)
    np.testing.assert_array_equal(np.abs(h), np.abs(q))


# --------------------------------------------------------------------------- Euler angles


@pytest.mark.parametrize("order", ORDERS)
def test_euler_round_trip_for_every_order(rng, order):
    angles = np.stack([rng.uniform(-180, 180, N), rng.uniform(-89.9, 89.9, N), rng.uniform(-180, 180, N)], -1)
    q = quat.from_euler(angles, order)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    np.testing.assert_allclose(quat.to_euler(q, order), angles, atol=1e-9)  # the principal triple
    # the first axis listed is the outermost: q = q_0 * q_1 * q_2
    parts = [quat.from_axis_angle(order[i], np.radians(angles[:, i])) for i in range(3)]
    np.testing.assert_allclose(q, quat.mul(quat.mul(parts[0], parts[1]), parts[2]), atol=1e-15)
    # whole turns away, the reference picks them
    turns = 360.0 * rng.integers(-3, 4, size=(N, 3))
    np.testing.assert_allclose(quat.to_euler(q, order, angles + turns + 1.0), angles + turns, atol=1e-9)
    # near the twin (a+180, 180-b, c+180) the reference picks the twin, which is the same rotation
    twin = angles + np.array([180.0, 0.0, 180.0])
    twin[:, 1] = 180.0 - angles[:, 1]
    same_rotation(quat.from_euler(twin, order), q, atol=1e-12)
    np.testing.assert_allclose(quat.to_euler(q, order, twin + 0.5), twin, atol=1e-9)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("lock", [90.0, -90.0])
def test_euler_near_gimbal_lock_gives_the_rotation_back(rng, order, lock):
    n = 200
    off = rng.choice([0.0, 1e-12, -1e-9, 1e-7, -1e-5, 1e-3], size=n)
    angles = np.stack([rng.uniform(-180, 180, n), lock + off, rng.uniform(-180, 180, n)], -1)
    q = quat.from_euler(angles, order)
    for ref in (None, angles):
        e = quat.to_euler(q, order, ref)
        assert np.all(np.isfinite(e))
        # the outer angles come from entries of size cos(b): 3e-9 rad at worst (measured)
        same_rotation(quat.from_euler(e, order), q, atol=1e-8)
    # with a reference the first angle is the reference's where only a ± c is known
    e = quat.to_euler(q, order, angles)
    at_lock = np.abs(off) < 1e-12
    np.testing.assert_allclose(e[at_lock, 0], angles[at_lock, 0], atol=1e-6)
    np.testing.assert_allclose(e[at_lock, 1], lock, atol=1e-6)
    # away from the lock proper the reference triple comes back as it was
    np.testing.assert_allclose(e[np.abs(off) >= 1e-3], angles[np.abs(off) >= 1e-3], atol=1e-6)


@deterministic
@given(a=angle, b=middle, c=angle, order=st.sampled_from(ORDERS))
def test_euler_round_trip_property(a, b, c, order):
    e = np.array([a, b, c])
    q = quat.from_euler(e, order)
    np.testing.assert_allclose(quat.to_euler(q, order), e, atol=1e-8)
    np.testing.assert_allclose(quat.to_euler(q, order, e), e, atol=1e-8)


@deterministic
@given(
    a=st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
    b=st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
    u=st.floats(0.0, 1.0),
)
def test_slerp_stays_on_the_arc_property(a, b, u):
    a, b = quat.normalize(np.array(a)), quat.normalize(np.array(b))
    s = quat.slerp(a, b, u)
    total = quat.angle_between(a, b)
    assert abs(np.linalg.norm(s) - 1.0) < 1e-12
    assert quat.angle_between(a, s) + quat.angle_between(s, b) == pytest.approx(total, abs=1e-7)


def test_dot_norm_cross_have_numpys_bits():
    """The written-out forms give exactly numpy's numbers (the same order of
    additions), including cancellation that a different order would show."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(500, 6, 3)) * 10.0 ** rng.integers(-8, 9, size=(500, 6, 1))
    b = rng.normal(size=(500, 6, 3))
    b[0, 0] = [1.0, 1e16, -1e16]  # (x0 + x1) + x2 = 0, x0 + (x1 + x2) = 1
    ones = np.ones_like(a)
    assert np.array_equal(quat.dot(ones, b), np.sum(ones * b, axis=-1))
    assert quat.dot(ones, b)[0, 0] == 0.0
    assert np.array_equal(quat.dot(a, b), np.sum(a * b, axis=-1))
    assert np.array_equal(quat.norm(a), np.linalg.norm(a, axis=-1))
    assert np.array_equal(quat.norm(a.astype(np.float32)), np.linalg.norm(a.astype(np.float32), axis=-1))
    assert np.array_equal(quat.cross(a, b), np.cross(a, b))
    q = rng.normal(size=(300, 4))
    assert np.array_equal(quat.normalize(q), q / np.linalg.norm(q, axis=-1, keepdims=True))
