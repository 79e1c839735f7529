"""The paper's operators per kind of variable (staggered_cli.model.kinds): ⊕, ⊖,
scale, interpolate and identity of translations and rotations, on seeded
random values and on a real capture's values."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from staggered_cli import quat
from staggered_cli.model.kinds import KINDS, ROTATION, ROTATION_OPS, TRANSLATION, TRANSLATION_OPS, ops_for

from .conftest import dev_motion

N = 400


def values(kind: str, rng, shape=(N,)) -> np.ndarray:
    if kind == TRANSLATION:
        return rng.normal(scale=30.0, size=shape + (3,))
    q = quat.normalize(rng.normal(size=shape + (4,)))
    return np.where(q[..., :1] < 0, -q, q)


def close(kind: str, a, b, atol: float) -> None:
    """Equal values: vectors within ``atol``, rotations within ``atol`` radians (q ~ -q)."""
    if kind == TRANSLATION:
        np.testing.assert_allclose(a, b, rtol=0, atol=atol)
    else:
        assert quat.angle_between(a, b).max() < atol


@pytest.fixture
def rng():
    return np.random.default_rng(16)


def test_lookup_by_kind():
    assert KINDS == (TRANSLATION, ROTATION)
    assert ops_for(TRANSLATION) is TRANSLATION_OPS and ops_for(ROTATION) is ROTATION_OPS
    assert (TRANSLATION_OPS.dim, ROTATION_OPS.dim) == (3, 4)
    assert all(ops_for(k).kind == k for k in KINDS)
    with pytest.raises(ValueError, match="unknown kind of variable 'scale'"):
        ops_for("scale")


@pytest.mark.parametrize("kind", KINDS)
def test_identity_is_neutral(kind, rng):
    ops = ops_for(kind)
    one = ops.identity((N,))
    assert one.shape == (N, ops.dim) and ops.identity().shape == (ops.dim,)
    a = values(kind, rng)
    np.testing.assert_array_equal(ops.oplus(a, one), a)
    np.testing.assert_array_equal(ops.oplus(one, a), a)
    np.testing.assert_allclose(ops.ominus(a, a), one, atol=1e-15)
    np.testing.assert_array_equal(ops.ominus(a, one), a)


@pytest.mark.parametrize("kind", KINDS)
def test_a_oplus_c_ominus_a_is_c(kind, rng):
    ops = ops_for(kind)
    a, c = values(kind, rng), values(kind, rng)
    d = ops.ominus(c, a)
    np.testing.assert_allclose(ops.oplus(a, d), c, atol=1e-12)
    # the offset of c from a, added to b, moves b as a moved to c (in b's frame for rotations)
    b = values(kind, rng)
    np.testing.assert_allclose(ops.ominus(ops.oplus(b, d), b), d, atol=1e-12)


def test_translation_operators_are_vector_arithmetic(rng):
    ops = TRANSLATION_OPS
    a, b = values(TRANSLATION, rng), values(TRANSLATION, rng)
    np.testing.assert_array_equal(ops.oplus(a, b), a + b)
    np.testing.assert_array_equal(ops.ominus(a, b), a - b)
    np.testing.assert_array_equal(ops.scale(a, 1.5), 1.5 * a)
    np.testing.assert_allclose(ops.interpolate(a, b, np.full(N, 0.25)), 0.75 * a + 0.25 * b, atol=1e-12)


def test_rotation_operators_are_products_in_the_local_frame(rng):
    ops = ROTATION_OPS
    a, b = values(ROTATION, rng), values(ROTATION, rng)
    v = rng.normal(size=(N, 3))
    np.testing.assert_allclose(quat.mul_vec(ops.oplus(a, b), v), quat.mul_vec(a, quat.mul_vec(b, v)), atol=1e-12)
    # scaling an offset scales its angle about the same axis
    w = rng.uniform(0.0, 1.0, N)
    np.testing.assert_allclose(quat.angle(ops.scale(b, w)), w * quat.angle(b), atol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_scale_zero_is_the_identity_and_one_the_same(kind, rng):
    ops = ops_for(kind)
    d = values(kind, rng)
    np.testing.assert_allclose(ops.scale(d, 0.0), ops.identity((N,)), atol=0)
    close(kind, ops.scale(d, 1.0), d, 1e-12)
    close(kind, ops.scale(d, 2.0), ops.oplus(d, d), 1e-11)
    half = ops.scale(d, 0.5)
    close(kind, ops.oplus(half, half), d, 1e-11)
    # weights per leading index broadcast: (N,) against (N, D) and (T, N) against (T, N, D)
    w = rng.uniform(-1.0, 1.0, N)
    out = ops.scale(d, w)
    assert out.shape == d.shape
    close(kind, out[7], ops.scale(d[7], float(w[7])), 1e-12)
    dd = values(kind, rng, (3, 5))
    ww = rng.uniform(0.0, 1.0, (3, 5))
    close(kind, ops.scale(dd, ww)[2, 4], ops.scale(dd[2, 4], float(ww[2, 4])), 1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_interpolate_ends_and_middle(kind, rng):
    ops = ops_for(kind)
    a, b = values(kind, rng), values(kind, rng)
    np.testing.assert_array_equal(ops.interpolate(a, b, np.zeros(N)), a)  # exactly: no round off at the knots
    close(kind, ops.interpolate(a, b, np.ones(N)), b, 1e-12)
    mid = ops.interpolate(a, b, np.full(N, 0.5))
    # the middle is the same offset from a as b is from it
    close(kind, ops.ominus(mid, a), ops.ominus(b, mid), 1e-11)
    # one u per leading index
    u = rng.uniform(0.0, 1.0, N)
    out = ops.interpolate(a, b, u)
    close(kind, out[3], ops.interpolate(a[3], b[3], u[3]), 1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_operators_do_not_change_their_inputs(kind, rng):
    ops = ops_for(kind)
    a, b = values(kind, rng), values(kind, rng)
    a0, b0 = a.copy(), b.copy()
    ops.oplus(a, b), ops.ominus(a, b), ops.scale(a, 0.3), ops.interpolate(a, b, np.full(N, 0.2))
    np.testing.assert_array_equal(a, a0)
    np.testing.assert_array_equal(b, b0)


def test_offsets_between_real_poses_add_back_to_the_poses():
    """On the CMU walk: the offset from frame 0 to every frame of every joint,
    added to frame 0, is that frame; scaled by 0 it is frame 0."""
    m = dev_motion("cmu_02_01_walk.bvh")
    rot, tr = m.local_rotations(), m.local_translations()
    for kind, v in ((ROTATION, rot), (TRANSLATION, tr)):
        ops = ops_for(kind)
        first = np.broadcast_to(v[:1], v.shape)
        d = ops.ominus(v, first)
        close(kind, ops.oplus(first, d), v, 1e-9 if kind == TRANSLATION else 1e-12)
        np.testing.assert_allclose(ops.oplus(first, ops.scale(d, 0.0)), first, atol=1e-12)


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(
    kind=st.sampled_from(KINDS),
    seed=st.integers(0, 2**32 - 1),
    w=st.floats(-1.0, 1.0, allow_nan=False),
    u=st.floats(0.0, 1.0, allow_nan=False),
)
def test_operator_identities_property(kind, seed, w, u):
    rng = np.random.default_rng(seed)
    ops = ops_for(kind)
    a, c = values(kind, rng, (4,)), values(kind, rng, (4,))
    d = ops.ominus(c, a)
    close(kind, ops.oplus(a, d), c, 1e-10)
    # scaling composes: (w·d) ⊕ ((1-w)·d) = d, both about d's own axis for rotations
    close(kind, ops.oplus(ops.scale(d, w), ops.scale(d, 1.0 - w)), d, 1e-10)
    # interpolation walks the offset: interpolate(a, c, u) = a ⊕ u·(c ⊖ a)
    close(kind, ops.interpolate(a, c, np.full(4, u)), ops.oplus(a, ops.scale(d, u)), 1e-10)
