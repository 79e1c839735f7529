"""Issue 15: the poses of a document through Blender and back (`make test-blender`).

Runs in the venv that `make test-blender` builds (Python 3.11, bpy 5.0.1);
under `make test` there is no bpy and every test here is skipped.
"""

from __future__ import annotations

import math
import os
import tempfile

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="needs Blender's bpy module (Python 3.11): run `make test-blender`")

from staggered_cli.errors import DataError  # noqa: E402
from staggered_cli.io.bvh import bvh_bytes, read_bvh  # noqa: E402
from staggered_cli.ops import pose_file as P  # noqa: E402
from staggered_cli.ops.bake import bake  # noqa: E402
from staggered_cli.ops.extract import extract  # noqa: E402

from ..conftest import mocap  # noqa: E402

# Blender's BVH importer leaves its file open (a ResourceWarning in its code, not ours)
pytestmark = pytest.mark.filterwarnings("ignore::ResourceWarning", "ignore::pytest.PytestUnraisableExceptionWarning")

CLIPS = ["cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu3dsmax_131_02_start_walk_stop.bvh"]

#: The settings the README gives: no axis conversion, native Euler orders, frame k+1 = pose k.
IMPORT = dict(rotate_mode="NATIVE", axis_forward="Y", axis_up="Z", use_fps_scale=False, global_scale=1.0, frame_start=1)


def _arm(names) -> str:
    return next(n for n in names if "arm" in n.lower() or "elbow" in n.lower())


def _import(path: str, **changes):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(filepath=path, **{**IMPORT, **changes})
    return bpy.context.object


def _export(path: str, n_frames: int) -> None:
    bpy.ops.export_anim.bvh(
        filepath=path, rotate_mode="NATIVE", root_transform_only=False, frame_start=1, frame_end=n_frames
    )


def _heads(ob, names, frame: int) -> np.ndarray:
    """World positions (J, 3) of the bones' heads (the joints) at a Blender frame."""
    bpy.context.scene.frame_set(frame)
    return np.array([tuple(ob.matrix_world @ ob.pose.bones[n].head) for n in names])


@pytest.fixture(scope="module", params=CLIPS)
def clip(request):
    m = read_bvh(mocap(request.param))
    return m, extract(m, source_name=request.param)


def test_two_poses_posed_in_blender_come_back_with_one_all(clip):
    m, doc = clip
    sk = m.skeleton
    size = m.figure_height()
    K = doc.n_poses
    k1, k2 = K // 3, 2 * K // 3
    with tempfile.TemporaryDirectory() as d:
        poses, edited = os.path.join(d, "poses.bvh"), os.path.join(d, "edited.bvh")
        with open(poses, "wb") as fh:
            fh.write(bvh_bytes(P.export_poses(doc)))
        ob = _import(poses)
        arm = ob.pose.bones[_arm(sk.names)]
        root = ob.pose.bones[sk.names[0]]
        scene = bpy.context.scene
        scene.frame_set(k1 + 1)  # Blender's frame k+1 is pose k
        arm.rotation_euler[0] += math.radians(15.0)
        arm.keyframe_insert("rotation_euler", frame=k1 + 1)
        scene.frame_set(k2 + 1)
        arm.rotation_euler[2] -= math.radians(10.0)
        arm.keyframe_insert("rotation_euler", frame=k2 + 1)
        root.location[0] += 0.05 * size
        root.keyframe_insert("location", frame=k2 + 1)
        blender = np.stack([_heads(ob, sk.names, k + 1) for k in range(K)])
        _export(edited, K)
        out, n_poses, n_joints = P.apply_pose_file(doc, read_bvh(edited))
    assert (n_poses, n_joints) == (2, 2 if sk.has_position(0) else 1)
    # the poses themselves: without the contact layer, which repairs the feet
    # the root move disturbed (on the neighbouring frames too)
    baked = bake(out, ik=False)
    f = np.rint(doc.pose_t / m.frame_time).astype(int)
    err = np.abs(baked.world()[1][f] - blender).max(axis=(1, 2)) / size
    assert err.max() <= 1e-4, err
    # the untouched poses are where they were, the edited ones moved
    before = bake(doc, ik=False).world()[1][f]
    moved = np.abs(baked.world()[1][f] - before).max(axis=(1, 2)) / size
    assert set(np.flatnonzero(moved > 1e-6)) == {k1, k2}
    for tr_a, tr_b in zip(doc.tracks, out.tracks, strict=True):
        others = ~np.isin(tr_a.knot_pose, [k1, k2])
        assert np.array_equal(tr_a.knot_v[others], tr_b.knot_v[others])


def test_blender_reads_the_exported_poses_exactly(clip):
    """Unchanged: Blender's joints at frame k+1 are the document's pose k,
    and exporting them back changes nothing."""
    m, doc = clip
    size = m.figure_height()
    with tempfile.TemporaryDirectory() as d:
        poses, back = os.path.join(d, "poses.bvh"), os.path.join(d, "back.bvh")
        exported = P.export_poses(doc)
        with open(poses, "wb") as fh:
            fh.write(bvh_bytes(exported))
        ob = _import(poses)
        blender = np.stack([_heads(ob, m.skeleton.names, k + 1) for k in range(doc.n_poses)])
        _export(back, doc.n_poses)
        out, n_poses, _ = P.apply_pose_file(doc, read_bvh(back))
    assert np.abs(blender - exported.world()[1]).max() <= 1e-4 * size
    assert n_poses == 0
    assert np.abs(bake(out).world()[1] - bake(doc).world()[1]).max() <= 1e-9 * size


def test_the_default_axis_conversion_is_refused(clip):
    m, doc = clip
    with tempfile.TemporaryDirectory() as d:
        poses, back = os.path.join(d, "poses.bvh"), os.path.join(d, "back.bvh")
        with open(poses, "wb") as fh:
            fh.write(bvh_bytes(P.export_poses(doc)))
        _import(poses, axis_forward="-Z", axis_up="Y")  # Blender's default: Y up -> Z up
        _export(back, doc.n_poses)
        with pytest.raises(DataError, match="axis conversion"):
            P.apply_pose_file(doc, read_bvh(back))
