"""glTF 2.0 out (issue 36): ``bake -o x.glb``, ``st.write(motion, "x.glb")``.

A reader here (pygltflib for the container, this file's own forward
kinematics over the nodes) recomputes each joint's and marker's world
position from the written file and compares them with the bake's, frame by
frame.  The Khronos glTF-Validator (node, ``tools/gltf``) checks every
output: the tests marked ``gltf_validator`` run under ``make test-gltf``,
which installs it; under ``make test`` they skip with a reason when node or
the package is missing (``GLTF_VALIDATOR_REQUIRED=1``, set by ``make
test-gltf``, makes that a failure).
"""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import staggered_cli as st
from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.skeleton import end_site_positions, forward_kinematics

from .conftest import C3D_FILES, dev_bake, dev_bvh_files, dev_document, one_line_error

ROOT = Path(__file__).resolve().parent.parent
TOOLS = ROOT / "tools" / "gltf"
SAMPLES = ROOT / "data" / "samples"

#: Metres per unit the default must assume, by the file name's start.
UNIT_OF = {"cmu": 0.0254 / 0.45, "bandai": 0.01, "games105": 1.0, "march": 0.01}


def glb_bytes(motion, **options) -> bytes:
    buffer = io.BytesIO()
    st.write(motion, buffer, format=options.pop("format", "glb"), **options)
    return buffer.getvalue()


# --------------------------------------------------------------------------- the reader


class Gltf:
    """A glTF file read back: nodes, and accessors as numpy arrays."""

    def __init__(self, data: bytes):
        import pygltflib

        if data[:4] == b"glTF":
            self.doc = pygltflib.GLTF2.load_from_bytes(data)
            self.blob = self.doc.binary_blob()
        else:
            self.doc = pygltflib.GLTF2.from_json(data.decode("utf-8"))
            uri = self.doc.buffers[0].uri
            assert uri.startswith("data:application/octet-stream;base64,")
            self.blob = base64.b64decode(uri.partition(",")[2])
        assert len(self.doc.buffers) == 1 and self.doc.buffers[0].byteLength == len(self.blob)

    def array(self, index: int) -> np.ndarray:
        acc = self.doc.accessors[index]
        view = self.doc.bufferViews[acc.bufferView]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc.type]
        dtype = {5126: np.float32, 5123: np.uint16, 5121: np.uint8}[acc.componentType]
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        flat = np.frombuffer(self.blob, dtype=dtype, count=acc.count * width, offset=start)
        return flat.reshape(acc.count, width).astype(np.float64)

    def tracks(self) -> tuple[np.ndarray, dict]:
        """The animation's key times (of its first channel) and
        {(node, path): (interpolation, values)}."""
        return self.keyed()[0][0], {key: (how, v) for key, (_, how, v) in self.keyed()[1].items()}

    def keyed(self) -> tuple[list, dict]:
        """Each channel's key times, and {(node, path): (times, interpolation, values)}."""
        (anim,) = self.doc.animations
        out, times = {}, []
        for ch in anim.channels:
            sampler = anim.samplers[ch.sampler]
            t = self.array(sampler.input)[:, 0]
            times.append(t)
            out[(ch.target.node, ch.target.path)] = (t, sampler.interpolation, self.array(sampler.output))
        return times, out

    def sampled(self, at: np.ndarray) -> dict:
        """{(node, path): values (T, D)} at times ``at``: keys of LINEAR and
        STEP channels must be at those times; CUBICSPLINE is evaluated as
        glTF defines it (cubic Hermite on the components, rotations then
        normalized)."""
        out = {}
        for (node, path), (t, how, v) in self.keyed()[1].items():
            if how != "CUBICSPLINE":
                idx = np.searchsorted(t, at - 1e-6)
                assert np.allclose(t[idx], at, atol=1e-5), "dense keys at the frames"
                out[(node, path)] = v[idx]
                continue
            rows = v.reshape(len(t), 3, -1)
            a, val, b = rows[:, 0], rows[:, 1], rows[:, 2]
            k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 1)
            k1 = np.minimum(k + 1, len(t) - 1)
            dt = t[k1] - t[k]
            u = np.where(dt > 0, (np.clip(at, t[0], t[-1]) - t[k]) / np.where(dt > 0, dt, 1), 0.0)[:, None]
            u2, u3 = u * u, u * u * u
            p = (
                (2 * u3 - 3 * u2 + 1) * val[k]
                + (u3 - 2 * u2 + u) * b[k] * dt[:, None]
                + (-2 * u3 + 3 * u2) * val[k1]
                + (u3 - u2) * a[k1] * dt[:, None]
            )
            out[(node, path)] = p
        return out

    def world(self, at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World positions (T, N, 3), rotations (T, N, 4, w first) and
        scales (T, N) of every node at times ``at`` (default: the first
        channel's keys), by forward kinematics."""
        nodes = self.doc.nodes
        times = self.keyed()[0][0] if at is None else np.asarray(at, dtype=float)
        tracks = {key: (None, v) for key, v in self.sampled(times).items()}
        T, N = len(times), len(nodes)
        parent = np.full(N, -1)
        for i, n in enumerate(nodes):
            for c in n.children:
                parent[c] = i
        pos, rot, scl = np.zeros((T, N, 3)), np.zeros((T, N, 4)), np.ones((T, N))
        done = np.zeros(N, bool)

        def visit(i: int) -> None:
            n = nodes[i]
            t = tracks.get((i, "translation"), (None, np.tile(n.translation or [0, 0, 0], (T, 1))))[1]
            r = tracks.get((i, "rotation"), (None, np.tile(n.rotation or [0, 0, 0, 1], (T, 1))))[1]
            s = tracks.get((i, "scale"), (None, np.tile(n.scale or [1, 1, 1], (T, 1))))[1][:, 0]
            r = np.concatenate([r[:, 3:], r[:, :3]], axis=1)  # (x, y, z, w) -> w first
            r = r / np.linalg.norm(r, axis=1, keepdims=True)
            p = parent[i]
            if p < 0:
                pos[:, i], rot[:, i], scl[:, i] = t, r, s
            else:
                pos[:, i] = pos[:, p] + quat.mul_vec(rot[:, p], t) * scl[:, p, None]
                rot[:, i], scl[:, i] = quat.mul(rot[:, p], r), scl[:, p] * s
            done[i] = True
            for c in n.children:
                visit(c)

        for root in self.doc.scenes[self.doc.scene].nodes:
            visit(root)
        assert done.all(), "every node is in the scene"
        return pos, rot, scl


def _unit(name: str) -> float:
    return next(v for k, v in UNIT_OF.items() if name.startswith(k))


# --------------------------------------------------------------------------- BVH: the skeleton


def _check_skeleton(gl: Gltf, motion, scale: float) -> float:
    """The file's skeleton and motion against ``motion`` at ``scale``; the
    largest world position error as a fraction of the figure's height."""
    sk = motion.skeleton
    J, E = sk.n_joints, len(sk.end_parents)
    doc = gl.doc
    (skin,) = doc.skins
    assert skin.joints == list(range(J + E))
    assert [n.name for n in doc.nodes[:J]] == list(sk.names)
    # the skin is used: a skinned mesh at the scene's root
    (mesh_node,) = [n for n in doc.nodes if n.skin is not None]
    assert mesh_node.mesh is not None and doc.nodes.index(mesh_node) in doc.scenes[0].nodes
    # inverse bind matrices: the rest pose's world positions, negated
    ibm = gl.array(skin.inverseBindMatrices).reshape(J + E, 4, 4).transpose(0, 2, 1)
    rest_rot = np.zeros((1, J, 4))
    rest_rot[..., 0] = 1
    _, rest = forward_kinematics(sk, rest_rot, sk.offsets[None])
    rest_ends = rest[:, sk.end_parents] + sk.end_offsets[None]
    np.testing.assert_allclose(-ibm[:, :3, 3], np.concatenate([rest[0], rest_ends[0]]) * scale, atol=1e-5)
    np.testing.assert_allclose(ibm[:, :3, :3], np.tile(np.eye(3), (J + E, 1, 1)), atol=0)

    times, tracks = gl.tracks()
    np.testing.assert_allclose(times, np.arange(motion.n_frames) * motion.frame_time, rtol=1e-6, atol=1e-6)
    assert all(how == "LINEAR" for how, _ in tracks.values())
    assert sum(sk.has_rotation(j) for j in range(J)) + sum(sk.has_position(j) for j in range(J)) == len(tracks)

    pos, _, _ = gl.world()
    wr, wp = motion.world()
    want = np.concatenate([wp, end_site_positions(sk, wr, wp)], axis=1) * scale
    height = motion.figure_height() * scale
    return float(np.max(np.abs(pos[:, : J + E] - want)) / height)


@pytest.mark.parametrize("name", dev_bvh_files())
def test_dense_bvh_equals_the_bake(name):
    """Every joint and end site, every frame, within 1e-5 of the figure's
    height of the BVH bake, in metres with the unit the figure's height
    says (CMU 1/0.45 inch, Bandai cm, GAMES-105 m)."""
    baked = dev_bake(name)
    from staggered_cli.io.gltf import unit_scale_for

    scale, why = unit_scale_for(baked)
    assert scale == _unit(name), why
    assert 1.0 <= baked.figure_height() * scale <= 2.2
    error = _check_skeleton(Gltf(glb_bytes(baked)), baked, scale)
    assert error < 1e-5, error


def test_gltf_json_holds_the_same_motion_as_glb():
    baked = dev_bake(dev_bvh_files()[0])
    binary, text = glb_bytes(baked), glb_bytes(baked, format="gltf")
    assert binary[:4] == b"glTF" and json.loads(text)["asset"]["version"] == "2.0"
    a, b = Gltf(binary), Gltf(text)
    assert a.blob == b.blob
    assert _check_skeleton(b, baked, _unit(dev_bvh_files()[0])) < 1e-5


def test_unit_scale_scales_and_a_file_in_metres_stays():
    baked = dev_bake("games105_idle.bvh")
    p1 = Gltf(glb_bytes(baked)).world()[0]
    p2 = Gltf(glb_bytes(baked, unit_scale=0.5)).world()[0]
    np.testing.assert_allclose(p2, 0.5 * p1, atol=1e-6)
    # the clip in metres: the file's own numbers
    np.testing.assert_allclose(p1[:, : baked.skeleton.n_joints], baked.world_positions(), atol=2e-6)


# --------------------------------------------------------------------------- C3D: markers

#: Up axis of each C3D, by the file's name: the data's, measured once.
Z_UP = {
    "c3dorg_sample01_Eb015pi_walk.c3d": True,
    "cmu_85_12_breakdance_long.c3d": True,
    "ezc3d_BTS_walk_gaps.c3d": False,
}


def _check_markers(gl: Gltf, motion, z_up: bool) -> None:
    pts = motion.points * 0.001  # POINT:UNITS mm
    if z_up:
        pts = np.stack([pts[..., 0], pts[..., 2], -pts[..., 1]], axis=-1)
    pos, _, scl = gl.world()
    root = gl.doc.scenes[0].nodes[0]
    assert [gl.doc.nodes[i + 1].name for i in range(len(motion.labels))] == list(motion.labels)
    assert root == 0
    got, shown = pos[:, 1:], scl[:, 1:]
    seen = np.all(np.isfinite(pts), axis=2)
    np.testing.assert_array_equal(shown, seen.astype(float))  # hidden exactly in the gaps
    height = motion.figure_height() * 0.001
    assert np.max(np.abs(got[seen] - pts[seen])) < 1e-6 * height
    for m in range(pts.shape[1]):  # in a gap: the last place seen (the first, before it)
        f = np.flatnonzero(seen[:, m])
        for t in np.flatnonzero(~seen[:, m])[:50]:
            before = f[f < t]
            held = pts[before[-1] if len(before) else f[0], m]
            np.testing.assert_allclose(got[t, m], held, atol=1e-6)
    _, tracks = gl.tracks()
    assert all(how == "STEP" for (n, path), (how, _) in tracks.items() if path == "scale")


@pytest.mark.parametrize("name", C3D_FILES or ["(no ../shared/mocap)"])
def test_dense_c3d_markers_equal_the_points(name):
    if name not in Z_UP:
        pytest.skip("../shared/mocap is not there")
    baked = dev_bake(name)
    gl = Gltf(glb_bytes(baked))
    _check_markers(gl, baked, Z_UP[name])
    if name.startswith("ezc3d"):  # every marker has gaps: every one hides in them
        assert sum(path == "scale" for _, path in gl.tracks()[1]) == len(baked.labels)


def test_sample_c3d_is_turned_to_y_up():
    doc = st.extract(st.read(SAMPLES / "march.c3d"))
    baked = st.bake(doc)
    gl = Gltf(glb_bytes(baked))
    _check_markers(gl, baked, True)
    # Y up: the figure stands on its feet in glTF's frame
    pos = gl.world()[0][:, 1:]
    assert np.nanmedian(pos[..., 1]) > 0.5


# --------------------------------------------------------------------------- the command line


def test_bake_writes_glb_and_says_the_unit(tmp_path):
    doc = tmp_path / "march.stag"
    st.write(st.extract(st.read(SAMPLES / "march.bvh")), doc)
    out = tmp_path / "march.glb"
    result = CliRunner().invoke(cli, ["bake", str(doc), "-o", str(out)])
    assert result.exit_code == 0, result.stderr
    assert result.stderr == (
        "staggered: glTF in metres: assumed the file is in cm (figure 1.60 m tall); "
        "--unit-scale S sets metres per unit\n"
    )
    baked = st.bake(st.read(doc))
    assert _check_skeleton(Gltf(out.read_bytes()), baked, 0.01) < 1e-5
    result = CliRunner().invoke(cli, ["bake", str(doc), "-o", str(tmp_path / "m.gltf"), "--unit-scale", "0.01"])
    assert result.exit_code == 0 and result.stderr == ""
    assert Gltf((tmp_path / "m.gltf").read_bytes()).blob == Gltf(out.read_bytes()).blob


@pytest.mark.parametrize(
    "scale, needle",
    [
        ("0", "must be positive"),
        ("-1", "must be positive"),
        ("1e9", "m tall"),
        ("1e-9", "m tall"),
        ("nan", "not a finite number"),
        ("x", "not a number"),
    ],
)
def test_bad_unit_scale_is_one_line_and_no_file(tmp_path, scale, needle):
    doc = tmp_path / "march.stag"
    st.write(st.extract(st.read(SAMPLES / "march.bvh")), doc)
    out = tmp_path / "x.glb"
    result = CliRunner().invoke(cli, ["bake", str(doc), "-o", str(out), "--unit-scale", scale])
    one_line_error(result, 2, "--unit-scale", needle)
    assert not out.exists() and os.listdir(tmp_path) == ["march.stag"]


def test_unit_scale_without_gltf_output_is_refused(tmp_path):
    doc = tmp_path / "march.stag"
    st.write(st.extract(st.read(SAMPLES / "march.bvh")), doc)
    result = CliRunner().invoke(cli, ["bake", str(doc), "-o", str(tmp_path / "x.bvh"), "--unit-scale", "0.01"])
    one_line_error(result, 2, "--unit-scale", "glTF")


def test_non_finite_motion_is_refused_without_a_file(tmp_path):
    clip = st.read(SAMPLES / "march.bvh")
    channels = clip.channels.copy()
    channels[5, 4] = np.inf
    bad = clip.with_channels(channels, same_text=False)
    with pytest.raises(st.DataError, match="not finite"):
        st.write(bad, tmp_path / "x.glb")
    huge = channels.copy()
    huge[5, 4], huge[5, 0] = 0.0, 1e300  # a root translation glTF's floats cannot hold
    with pytest.raises(st.DataError, match="32-bit"):
        st.write(clip.with_channels(huge, same_text=False), tmp_path / "x.glb", unit_scale=0.01)
    assert not list(tmp_path.iterdir())


def test_names_say_what_is_written(tmp_path):
    clip = st.read(SAMPLES / "march.bvh")
    with pytest.raises(st.UsageError, match="glTF"):
        st.write(st.extract(clip), tmp_path / "doc.glb")
    with pytest.raises(st.UsageError, match="unit_scale"):
        st.write(clip, tmp_path / "x.bvh", unit_scale=0.01)
    with pytest.raises(st.UsageError, match="format"):
        st.write(clip, io.BytesIO(), format="fbx")
    st.write(clip, tmp_path / "x.GLB")
    assert (tmp_path / "x.GLB").read_bytes()[:4] == b"glTF"


def test_size_per_minute_of_motion():
    """Dense glTF costs about what the BVH text does: 4 floats a rotation
    and 3 a translation per frame (plus times), 32-bit."""
    for name in dev_bvh_files():
        baked = dev_bake(name)
        minutes = baked.n_frames * baked.frame_time / 60
        size = len(glb_bytes(baked))
        sk = baked.skeleton
        floats = sum(4 * sk.has_rotation(j) + 3 * sk.has_position(j) for j in range(sk.n_joints)) + 1
        assert floats * 4 * baked.n_frames < size < floats * 4 * baked.n_frames + 60_000, (name, size / minutes)


# --------------------------------------------------------------------------- the Khronos validator


def _validator() -> list[str]:
    """The command that runs tools/gltf/validate.js, or a skip (a failure
    under ``make test-gltf``) saying what is missing."""
    node = shutil.which("node")
    missing = None
    if node is None:
        missing = "node is not installed"
    elif not (TOOLS / "node_modules" / "gltf-validator").is_dir():
        missing = "tools/gltf/node_modules/gltf-validator is not installed (npm ci in tools/gltf)"
    if missing:
        if os.environ.get("GLTF_VALIDATOR_REQUIRED"):
            pytest.fail(f"GLTF_VALIDATOR_REQUIRED: {missing}", pytrace=False)
        pytest.skip(f"{missing}: make test-gltf installs it and runs these tests")
    return [node, str(TOOLS / "validate.js")]


def _validate(paths: list[Path]) -> list[dict]:
    run = subprocess.run(_validator() + [str(p) for p in paths], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    return [json.loads(line) for line in run.stdout.splitlines()]


@pytest.mark.gltf_validator
def test_validator_passes_every_output(tmp_path):
    """0 errors and 0 warnings on the .glb of every dev BVH and C3D, dense
    and (BVH) pose keys, the bundled samples, and a .gltf (JSON) of each."""
    cmd = _validator()  # skip before the work when it is missing
    assert cmd
    paths = []
    names = list(dev_bvh_files()) + list(C3D_FILES)
    for name in names:
        path = tmp_path / (Path(name).stem + ".glb")
        path.write_bytes(glb_bytes(dev_bake(name)))
        paths.append(path)
    for name in dev_bvh_files():  # and the pose keys (CUBICSPLINE)
        path = tmp_path / (Path(name).stem + "_poses.glb")
        buffer = io.BytesIO()
        st.write(dev_document(name), buffer, format="glb", keys="poses")
        path.write_bytes(buffer.getvalue())
        paths.append(path)
    for sample in ("march.bvh", "march.c3d"):
        baked = st.bake(st.extract(st.read(SAMPLES / sample)))
        for fmt in ("glb", "gltf"):
            path = tmp_path / f"sample_{Path(sample).suffix[1:]}.{fmt}"
            path.write_bytes(glb_bytes(baked, format=fmt))
            paths.append(path)
    reports = _validate(paths)
    assert [r["file"] for r in reports] == [str(p) for p in paths]
    for r in reports:
        assert (r["errors"], r["warnings"]) == (0, 0), (r["file"], r["messages"][:5])
    # the validator does look: a broken file has errors
    broken = tmp_path / "broken.gltf"
    data = json.loads(paths[-1].read_text())
    data["animations"][0]["channels"][0]["target"]["node"] = 10_000
    broken.write_text(json.dumps(data))
    assert _validate([broken])[0]["errors"] > 0


# --------------------------------------------------------------------------- --keys poses


def _pose_errors(doc, gl: Gltf, scale: float) -> tuple[float, float, float]:
    """Mean and max local rotation error (degrees) and max world position
    error (fraction of the height) of the pose keys against ``bake --layers
    splines``, at every frame."""
    from staggered_cli.ops.bake import bake

    smooth = bake(doc, layers="splines", ik=False)
    sk = smooth.skeleton
    times = np.arange(smooth.n_frames) * smooth.frame_time
    sampled = gl.sampled(times)
    want = smooth.local_rotations()
    errors = []
    for j in range(sk.n_joints):
        if sk.has_rotation(j):
            r = sampled[(j, "rotation")]
            r = np.concatenate([r[:, 3:], r[:, :3]], axis=1)
            r /= np.linalg.norm(r, axis=1, keepdims=True)
            errors.append(np.degrees(quat.angle_between(r, want[:, j])))
    errors = np.concatenate(errors)
    pos = gl.world(times)[0][:, : sk.n_joints]
    height = smooth.figure_height() * scale
    return (
        float(errors.mean()),
        float(errors.max()),
        float(np.max(np.abs(pos - smooth.world_positions() * scale)) / height),
    )


#: What --keys poses promises against bake --layers splines (docs/commands.md).
POSE_MEAN_DEG, POSE_MAX_DEG, POSE_POSITION = 0.05, 8.0, 0.015


@pytest.mark.parametrize("name", dev_bvh_files())
def test_pose_keys_follow_the_splines(name):
    """Each channel keyed at its variable's knots (the key counts are the
    knot counts), and the motion they give within the stated error of the
    spline layer."""
    doc = dev_document(name)
    gl = _pose_glb(doc)
    _, keyed = gl.keyed()
    for track in doc.tracks:
        path = "rotation" if track.kind == "rotation" else "translation"
        for i in range(track.n_vars):
            t, how, _ = keyed[(int(track.targets[i]), path)]
            assert how == "CUBICSPLINE"
            np.testing.assert_allclose(t, track.knots.t[track.knots.of(i)], atol=1e-6)
    mean, worst, position = _pose_errors(doc, gl, _unit(name))
    assert mean < POSE_MEAN_DEG and worst < POSE_MAX_DEG and position < POSE_POSITION, (mean, worst, position)


def _pose_glb(doc) -> Gltf:
    data = io.BytesIO()
    st.write(doc, data, format="glb", keys="poses")
    return Gltf(data.getvalue())


def test_edits_show_in_the_pose_keys():
    """succession shifts the arm's keys to the new knot times; edit-pose
    --rotate changes the elbow's key at the edited pose and nowhere else.
    The poses are extract's, unrefined (extract refines the arm at some of
    them: its extreme knots on the hand's swing), so that every key is a pose's."""
    from staggered_cli.model.variables import from_motion

    culled = st.cull(st.extract(st.read(SAMPLES / "march.bvh")), keep=12)
    doc = from_motion(st.read(SAMPLES / "march.bvh"), culled.pose_t, constraints=culled.constraints)
    j = doc.source.skeleton.index("LeftForeArm")
    before = _pose_glb(doc).keyed()[1][(j, "rotation")]
    later = st.succession(doc, joint="LeftArm", offset=0.05)
    moved = _pose_glb(later).keyed()[1][(j, "rotation")]
    # each inner pose: an editing key at its time, and its extreme 0.05 s later (depth 1 below LeftArm)
    track = next(t for t in later.tracks if t.kind == "rotation")
    editing = track.knots.editing[track.knots.of(track.index("LeftForeArm"))]
    assert len(moved[0]) == len(editing) == len(before[0]) + (len(before[0]) - 2)
    np.testing.assert_allclose(moved[0][editing], before[0][1:-1], atol=1e-6)
    np.testing.assert_allclose(moved[0][~editing][1:-1], before[0][1:-1] + 0.05, atol=1e-6)
    edited = st.edit_pose(doc, 5, rotate={"LeftForeArm": (0, 0, 30)})
    after = _pose_glb(edited).keyed()[1][(j, "rotation")]
    np.testing.assert_array_equal(after[0], before[0])
    keys_before, keys_after = before[2].reshape(-1, 3, 4)[:, 1], after[2].reshape(-1, 3, 4)[:, 1]
    angle = np.degrees(quat.angle_between(keys_before[:, [3, 0, 1, 2]], keys_after[:, [3, 0, 1, 2]]))
    track = next(t for t in doc.tracks if t.kind == "rotation")
    pose = track.knots.pose[track.knots.of(track.index("LeftForeArm"))]
    assert np.all(angle[pose == 5] > 25) and np.all(angle[pose != 5] < 1e-3), (angle, pose)


def test_pose_keys_refuse_stacked_layers_and_c3d(tmp_path):
    doc = st.extract(st.read(SAMPLES / "march.bvh"))
    stacked = st.add_layer(doc, keep=4)
    with pytest.raises(st.UsageError, match="2 layers"):
        st.write(stacked, tmp_path / "x.glb", keys="poses")
    with pytest.raises(st.UsageError, match="keys"):
        st.write(doc, tmp_path / "x.glb")  # a document as glTF: its pose keys only
    c3d = st.extract(st.read(SAMPLES / "march.c3d"))
    with pytest.raises(st.UsageError, match="BVH document"):
        st.write(c3d, tmp_path / "x.glb", keys="poses")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("option", [["--fps", "60"], ["--no-ik"], ["--layers", "splines"]])
def test_pose_keys_refuse_bake_options(tmp_path, option):
    doc = tmp_path / "march.stag"
    st.write(st.extract(st.read(SAMPLES / "march.bvh")), doc)
    out = tmp_path / "x.glb"
    result = CliRunner().invoke(cli, ["bake", str(doc), "--keys", "poses", "-o", str(out), *option])
    one_line_error(result, 2, "--keys", option[0])
    assert not out.exists()
