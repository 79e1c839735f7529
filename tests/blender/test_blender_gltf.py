"""Issue 36: the glTF the tool writes, read by Blender's own importer
(``bpy.ops.import_scene.gltf``), `make test-blender`.

What the importer does (io_scene_gltf2 of Blender 5.0, read in its source
and checked here on the data):

* a glTF node in the skin becomes a bone of the same name, its head at the
  node's origin; an end site (``PARENT_End``) becomes a bone too.  The
  ``bone_heuristic`` option only turns the bones' rest orientation (where
  the tail goes), never a head.
* glTF's Y up becomes Blender's Z up in the data, on the armature's own
  object at identity: (x, y, z) in glTF is (x, -z, y) in Blender.
* a key at t seconds lands on frame ``t * fps`` (not +1) of the scene's
  fps, which the importer reads and does not set (glTF has no frame rate):
  the test sets it to the clip's rate first.  A clip whose frame time is
  not 1/fps exactly (CMU's 0.0083333 s) has its keys off the whole frames,
  so the joints are read where the keys are, at a subframe.
* CUBICSPLINE keys come in at their times with their values; their
  tangents are dropped (AUTO Bezier handles), so only the key times and
  values are Blender's to check, not the curve between them.

Under `make test` there is no bpy and every test here is skipped.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="needs Blender's bpy module (Python 3.11): run `make test-blender`")

from bpy_extras import anim_utils  # noqa: E402

import staggered_cli as st  # noqa: E402
from staggered_cli.io.bvh import read_bvh  # noqa: E402
from staggered_cli.io.gltf import unit_scale_for  # noqa: E402
from staggered_cli.model.evaluate import evaluate_at  # noqa: E402
from staggered_cli.ops.bake import bake  # noqa: E402
from staggered_cli.ops.extract import extract  # noqa: E402
from staggered_cli.skeleton import end_site_positions  # noqa: E402

from ..conftest import mocap, staggered_warnings  # noqa: E402

CLIPS = ["cmu_02_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cmu3dsmax_131_02_start_walk_stop.bvh"]


def _blender_axes(p: np.ndarray) -> np.ndarray:
    """glTF (Y up) positions (..., 3) in Blender's axes (Z up): (x, -z, y)."""
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def _import(path: Path, fps: int, **options):
    """An empty scene at ``fps``, the file imported: its armature object."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = fps, 1.0
    bpy.ops.import_scene.gltf(filepath=str(path), **options)
    (armature,) = [o for o in scene.objects if o.type == "ARMATURE"]
    return armature


def _at_time(seconds: float) -> None:
    """The scene at ``seconds``: frame ``seconds * fps``, as the importer keys it."""
    scene = bpy.context.scene
    frame = seconds * scene.render.fps
    whole = math.floor(frame)
    scene.frame_set(whole, subframe=frame - whole)


def _heads(ob, names) -> np.ndarray:
    return np.array([tuple(ob.matrix_world @ ob.pose.bones[n].head) for n in names])


@pytest.fixture(scope="module", params=CLIPS)
def clip(request):
    m = read_bvh(mocap(request.param))
    doc = extract(m, source_name=request.param)
    return request.param, doc, bake(doc)


@pytest.mark.parametrize("heuristic", ["BLENDER", "TEMPERANCE", "FORTUNE"])
def test_blender_imports_the_dense_glb_at_the_baked_joints(clip, heuristic):
    """Bone heads (joints and end sites) at five frames spread over the clip
    equal the bake's world positions, in metres and Z up, within 1e-4 of
    the figure's height, whichever bone heuristic the importer is given."""
    name, _, baked = clip
    sk = baked.skeleton
    scale, _ = unit_scale_for(baked)
    height = baked.figure_height() * scale
    fps = round(1 / baked.frame_time)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "dense.glb"
        st.write(baked, path)
        ob = _import(path, fps, bone_heuristic=heuristic)
    assert ob.matrix_world == ob.matrix_world.Identity(4)
    ends = [f"{sk.names[p]}_End" for p in sk.end_parents]
    assert sorted(b.name for b in ob.data.bones) == sorted(list(sk.names) + ends)
    wr, wp = baked.world()
    want = _blender_axes(np.concatenate([wp, end_site_positions(sk, wr, wp)], axis=1) * scale)
    frames = np.linspace(0, baked.n_frames - 1, 5).round().astype(int)
    errors = []
    for f in frames:
        _at_time(f * baked.frame_time)
        errors.append(np.abs(_heads(ob, list(sk.names) + ends) - want[f]).max() / height)
    print(f"{name} {heuristic}: bone heads vs bake, max error / height per frame {np.round(errors, 8)}")
    assert max(errors) < 1e-4, (name, errors)
    # the mapping is Blender's Z up: the figure stands along +Z
    up = want[frames[0], :, 2]
    assert np.ptp(up) > 0.8 * height


def test_blender_axes_are_not_gltf_axes_unturned(clip):
    """The check above would catch a wrong axis mapping: the glTF positions
    taken as Blender's as they are, or turned the other way, are far off."""
    _, _, baked = clip
    sk = baked.skeleton
    scale, _ = unit_scale_for(baked)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "dense.glb"
        st.write(baked, path)
        ob = _import(path, round(1 / baked.frame_time))
    _at_time(0.0)
    got = _heads(ob, sk.names)
    p = baked.world_positions()[0] * scale
    height = baked.figure_height() * scale
    assert np.abs(got - _blender_axes(p)).max() < 1e-4 * height
    assert np.abs(got - p).max() > 0.3 * height
    assert np.abs(got - np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1)).max() > 0.3 * height


def test_pose_keys_are_keyframes_at_the_staggered_times():
    """``--keys poses``: every joint's rotation_quaternion F-curves
    (and the root's location) have one keyframe per knot of that variable,
    at the knot's time times the scene's fps, holding the key's value (the
    spline's at the knot, in Blender's axes for the root's place).  The
    arm is staggered first (``succession``: the forearm 0.02 s and the hand
    0.04 s after the arm), so its joints' keys sit at different times."""
    name = CLIPS[0]
    doc = extract(read_bvh(mocap(name)), source_name=name)
    with staggered_warnings():  # the fingers' knots near the next pose: a steep warp there, said and fine
        doc = st.succession(doc, joint="LeftArm", offset=0.02, clamp=True)
    sk = doc.source.skeleton
    scale, _ = unit_scale_for(doc.source)
    fps = round(1 / doc.source.frame_time)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "poses.glb"
        st.write(doc, path, keys="poses")
        ob = _import(path, fps)
    bag = anim_utils.animdata_get_channelbag_for_assigned_slot(ob.animation_data)  # Blender 5: layered actions
    curves = {(c.data_path, c.array_index): c for c in bag.fcurves}
    rotations = next(t for t in doc.tracks if t.kind == "rotation")
    staggered = {}
    for i, joint in enumerate(sk.names[j] for j in rotations.targets):
        knots = rotations.knots.t[rotations.knots.of(i)]
        staggered[joint] = frozenset(np.round(knots, 6))
        for axis in range(4):
            c = curves[(f'pose.bones["{joint}"].rotation_quaternion', axis)]
            frames = np.array([k.co[0] for k in c.keyframe_points])
            assert len(frames) == len(knots), (joint, axis, len(frames), len(knots))
            np.testing.assert_allclose(frames, knots * fps, atol=1e-3)
            assert all(k.interpolation == "BEZIER" for k in c.keyframe_points)
    rotation_curves = [key for key in curves if key[0].endswith(".rotation_quaternion")]
    assert len(rotation_curves) == 4 * rotations.n_vars
    arm = [staggered[j] for j in ("LeftArm", "LeftForeArm", "LeftHand")]
    assert len(set(arm)) == 3 and staggered["RightUpLeg"] != staggered["Hips"], "keys at each joint's own times"

    translations = next(t for t in doc.tracks if t.kind == "translation")
    root = sk.names[0]
    i = int(np.flatnonzero(translations.targets == 0)[0])
    knots = translations.knots.t[translations.knots.of(i)]
    values = _blender_axes(evaluate_at(translations, np.full(len(knots), i), knots, "splines") * scale)
    height = doc.source.figure_height() * scale
    for axis in range(3):
        c = curves[(f'pose.bones["{root}"].location', axis)]
        frames = np.array([k.co[0] for k in c.keyframe_points])
        np.testing.assert_allclose(frames, knots * fps, atol=1e-3)
    # at each of the root's keys its bone's head is the spline's place
    heads = []
    for t in knots:
        _at_time(t)
        heads.append(_heads(ob, [root])[0])
    error = np.abs(np.array(heads) - values).max() / height
    print(f"{name}: {len(knots)} root keys, head vs spline at the keys, max error / height {error:.2e}")
    assert error < 1e-5, error
