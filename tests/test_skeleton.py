"""Skeletons (staggered_cli.skeleton): the hierarchy's queries, forward
kinematics against positions worked out by hand, End Sites, the body's
joints and the figure height; bone lengths on the real captures."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli import quat
from staggered_cli.errors import UsageError
from staggered_cli.skeleton import Skeleton, body_joints, end_site_positions, figure_height, forward_kinematics

from .conftest import BVH_FILES, dev_motion

ROT = ("Zrotation", "Xrotation", "Yrotation")
POS = ("Xposition", "Yposition", "Zposition")


def figure() -> Skeleton:
    """A placeholder root above the hips (as Bandai's joint_Root), two legs
    and a spine with a head; End Sites at the feet and the head."""
    names = ("Root", "Hips", "LeftLeg", "LeftFoot", "RightLeg", "RightFoot", "Spine", "Head")
    parents = np.array([-1, 0, 1, 2, 1, 4, 1, 6])
    offsets = np.array(
        [
            [0, 0, 0],
            [0, 90, 0],
            [10, -5, 0],
            [0, -40, 0],
            [-10, -5, 0],
            [0, -40, 0],
            [0, 20, 0],
            [0, 40, 0],
        ],
        dtype=float,
    )
    channels = (POS + ROT, POS + ("Xrotation", "Yrotation", "Zrotation"), ROT, ROT, ROT, ("Xrotation",), (), ROT)
    return Skeleton(
        names,
        parents,
        offsets,
        channels,
        end_parents=np.array([3, 5, 7]),
        end_offsets=np.array([[0, -5, 12], [0, -5, 12], [0, 15, 0]], dtype=float),
    )


def test_hierarchy_queries():
    sk = figure()
    assert sk.n_joints == 8 and sk.index("LeftFoot") == 3
    with pytest.raises(UsageError, match="LeftFoot"):
        sk.index("LeftFut")  # an unknown name suggests the close ones
    assert [sk.rotation_order(j) for j in range(8)] == ["ZXY", "XYZ", "ZXY", "ZXY", "ZXY", "X", "", "ZXY"]
    assert [sk.has_position(j) for j in range(8)] == [True, True] + [False] * 6
    assert [sk.has_rotation(j) for j in range(8)] == [True] * 6 + [False, True]
    assert sk.children(1).tolist() == [2, 4, 6] and sk.children(3).tolist() == []
    assert sk.depth_below(1).tolist() == [-1, 0, 1, 2, 1, 2, 1, 2]
    assert sk.subtree(4).tolist() == [4, 5] and sk.subtree(0).tolist() == list(range(8))
    np.testing.assert_array_equal(sk.tips(1), [[10, -5, 0], [-10, -5, 0], [0, 20, 0]])
    np.testing.assert_array_equal(sk.tips(3), [[0, -5, 12]])  # the End Site
    assert sk.tips(7).shape == (1, 3) and figure().tips(6).tolist() == [[0, 40, 0]]


def test_forward_kinematics_by_hand():
    sk = figure()
    T, J = 2, sk.n_joints
    rot = quat.identity((T, J))
    tr = np.broadcast_to(sk.offsets, (T, J, 3)).copy()
    # frame 1: the root moved to (5, 0, -3) and turned 90° about Y; the left leg swung 90° about X
    tr[1, 0] = [5, 0, -3]
    rot[1, 0] = quat.from_axis_angle("Y", np.radians(90.0))
    rot[1, 2] = quat.from_axis_angle("X", np.radians(90.0))
    world_rot, world_pos = forward_kinematics(sk, rot, tr)
    # frame 0: offsets add up
    np.testing.assert_allclose(
        world_pos[0],
        [[0, 0, 0], [0, 90, 0], [10, 85, 0], [10, 45, 0], [-10, 85, 0], [-10, 45, 0], [0, 110, 0], [0, 150, 0]],
        atol=1e-12,
    )
    np.testing.assert_allclose(world_rot[0], quat.identity((J,)), atol=0)
    # frame 1: R_y(90) takes x to -z and z to x; the leg's X turn takes its -y offset to -z
    hips = np.array([5, 90, -3])
    np.testing.assert_allclose(world_pos[1, 1], hips, atol=1e-12)
    np.testing.assert_allclose(world_pos[1, 2], hips + [0, -5, -10], atol=1e-12)
    np.testing.assert_allclose(world_pos[1, 3], hips + [0, -5, -10] + [-40, 0, 0], atol=1e-12)
    np.testing.assert_allclose(world_pos[1, 4], hips + [0, -5, 10], atol=1e-12)
    np.testing.assert_allclose(world_pos[1, 7], hips + [0, 60, 0], atol=1e-12)
    np.testing.assert_allclose(world_rot[1, 3], quat.mul(rot[1, 0], rot[1, 2]), atol=1e-15)
    np.testing.assert_allclose(world_rot[1, 7], rot[1, 0], atol=1e-15)
    ends = end_site_positions(sk, world_rot, world_pos)
    assert ends.shape == (T, 3, 3)
    np.testing.assert_allclose(ends[0], [[10, 40, 12], [-10, 40, 12], [0, 165, 0]], atol=1e-12)
    # the left toe: (0, -5, 12) turned by R_y(90) R_x(90)
    toe = quat.mul_vec(quat.mul(rot[1, 0], rot[1, 2]), [0.0, -5.0, 12.0])
    np.testing.assert_allclose(ends[1, 0], world_pos[1, 3] + toe, atol=1e-12)


def test_body_joints_skip_a_placeholder_root_and_the_figure_height():
    sk = figure()
    assert body_joints(sk).tolist() == [1, 2, 3, 4, 5, 6, 7]  # below Root, from the first branching joint
    rot = quat.identity((1, sk.n_joints))
    tr = sk.offsets[None].copy()
    wr, wp = forward_kinematics(sk, rot, tr)
    ends = end_site_positions(sk, wr, wp)
    # the body's box: y from the feet's End Sites (40) to the head's (165); x 20; z 12
    assert figure_height(sk, wp, ends) == pytest.approx(125.0)
    assert figure_height(sk, wp) == pytest.approx(105.0)  # joints alone: the feet (45) to the head (150)
    # the median over frames: one crouched frame among three does not change it
    wp3 = np.repeat(wp, 3, axis=0)
    wp3[1] *= 0.5
    assert figure_height(sk, wp3) == pytest.approx(105.0)
    # no usable positions: the sum of the offsets' lengths
    lengths = float(np.linalg.norm(sk.offsets, axis=1).sum())
    assert figure_height(sk, np.full_like(wp, np.nan)) == pytest.approx(lengths)
    assert figure_height(sk, np.zeros_like(wp)) == pytest.approx(lengths)
    # a chain that never branches: every joint is the body
    chain = Skeleton(
        ("A", "B", "C"), np.array([-1, 0, 1]), np.array([[0, 0, 0], [0, 1, 0], [0, 1, 0]], float), ((),) * 3
    )
    assert body_joints(chain).tolist() == [0, 1, 2]


@pytest.mark.parametrize("name", ["cmu_02_01_walk.bvh", "bandai2_run_normal_001.bvh", "cmu_05_06_modern_dance.bvh"])
def test_bones_keep_their_lengths_in_every_frame_of_a_real_capture(name):
    if name not in BVH_FILES:
        pytest.skip(f"{name} is not in ../shared/mocap")
    m = dev_motion(name)
    sk = m.skeleton
    world_rot, world_pos = m.world()
    tr = m.local_translations()
    for j in range(1, sk.n_joints):
        p = sk.parents[j]
        bone = np.linalg.norm(world_pos[:, j] - world_pos[:, p], axis=-1)
        np.testing.assert_allclose(bone, np.linalg.norm(tr[:, j], axis=-1), rtol=1e-9, atol=1e-9)
        # and the child sits where the parent's rotation carries the offset
        np.testing.assert_allclose(
            world_pos[:, j], world_pos[:, p] + quat.mul_vec(world_rot[:, p], tr[:, j]), atol=1e-9
        )
    np.testing.assert_allclose(np.linalg.norm(world_rot, axis=-1), 1.0, atol=1e-12)
    size = m.figure_height()
    ends = end_site_positions(sk, world_rot, world_pos)
    assert size == pytest.approx(figure_height(sk, world_pos, ends))
    # the median largest side of the body's box, as measured (CMU units, Bandai centimetres)
    assert size == pytest.approx(HEIGHTS[name], rel=1e-9)


HEIGHTS = {
    "cmu_02_01_walk.bvh": 25.108664798390567,
    "bandai2_run_normal_001.bvh": 124.9769389429223,
    "cmu_05_06_modern_dance.bvh": 24.800614010288434,
}


@pytest.mark.parametrize("name", ["cmu_01_01_forward_jumps.bvh", "bandai1_walk_normal_001.bvh"])
def test_forward_kinematics_has_the_bits_of_the_quaternion_products(name):
    """The component-major chain gives, to the bit, what ``quat.mul`` and
    ``quat.mul_vec`` give joint by joint on frame-major arrays (the real
    clip's rotations, and random ones with translations broadcast from one
    frame)."""
    m = dev_motion(name)
    sk = m.skeleton
    rng = np.random.default_rng(5)
    rot = m.local_rotations()
    tr = m.local_translations()
    cases = [
        (rot, tr),
        (quat.normalize(rng.normal(size=(57, sk.n_joints, 4))), np.broadcast_to(tr[:1] * 3.0, (57, sk.n_joints, 3))),
    ]
    for r, t in cases:
        want_r, want_p = np.empty(r.shape), np.empty(t.shape)
        for j, p in enumerate(sk.parents):
            if p < 0:
                want_r[:, j], want_p[:, j] = r[:, j], t[:, j]
            else:
                want_r[:, j] = quat.mul(want_r[:, p], r[:, j])
                want_p[:, j] = want_p[:, p] + quat.mul_vec(want_r[:, p], t[:, j])
        got_r, got_p = forward_kinematics(sk, r, t)
        assert np.array_equal(got_r, want_r) and np.array_equal(got_p, want_p)
        assert got_r.flags.c_contiguous and got_p.flags.c_contiguous
