"""Bake: the identity at the nominal rate, resampling BVH and C3D (markers
and analogs), the output kind, and the contact layer's word on an edit it
takes back."""

from __future__ import annotations

import tempfile
from pathlib import Path

import ezc3d
import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.io.c3d import read_c3d
from staggered_cli.ops import edit_pose as E
from staggered_cli.ops.bake import bake

from .conftest import cli_document, dev_document, dev_motion, document_file, mocap, one_line_error, staggered_warnings


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


@pytest.mark.parametrize("name, fps", [("bandai2_run_normal_001.bvh", 30.0), ("cmu_02_01_walk.bvh", 120.0)])
def test_baking_at_the_nominal_rate_is_the_identity(name, fps):
    m, doc = dev_motion(name), dev_document(name)
    out = bake(doc, fps=fps)
    assert out.n_frames == m.n_frames
    np.testing.assert_array_equal(out.channels, m.channels)


def test_resampling_never_flips_to_the_twin_triple(bandai_run):
    m, doc = bandai_run
    for fps in (24.0, 60.0, 100.0):
        ch = bake(doc, fps=fps).channels
        # consecutive output frames are at most a source frame apart: no jump near 180 degrees
        assert np.abs(np.diff(ch[:, 3:], axis=0)).max() < 90.0


@pytest.mark.parametrize("at, shift", [(5.3, 0.03), (4.1, 0.03), (4.1, -0.03), (5.0, 0.03), (5.0, -0.03)])
def test_a_retime_that_meets_a_twin_switch_of_the_source_keeps_its_angles_continuous(at, shift):
    """cmu3dsmax's RThumb switches between the twin triples in the source
    (frame 623 -> 624).  Retimed 0.03 s later, the motion still has the
    first triple there, and the source's angles, the reference, are the
    twin: the nearest triple took one angle a whole turn off (Y 259.9
    between -100.4 and -97.8 at frames 624-625).  Far from the reference,
    the previous frame's angles choose: no angle jumps by a turn.  The pose
    at 5.3 s moved 0.03 s later meets the switch (RThumb changes by up to
    264 degrees at frames 622-625); the others are retimes elsewhere.  (The
    pose at 5.167 s moved 0.03 s earlier still steps RThumb's Y by 359.5
    degrees at the switch, where the followed triple rejoins the source's:
    the same rotation, a whole turn apart; not fixed.)"""
    from staggered_cli.motion import rotation_columns
    from staggered_cli.ops.timing import retime_pose

    name = "cmu3dsmax_131_02_start_walk_stop.bvh"
    m, doc = dev_motion(name), dev_document(name)
    k = int(np.argmin(np.abs(doc.pose_t - at)))
    assert abs(doc.pose_t[k] - at) < 0.01, doc.pose_t[k]
    cols = [c for _, cc, _ in rotation_columns(m.skeleton) for c in cc]
    assert np.abs(np.diff(m.channels[:, cols], axis=0)).max() < 270.0  # the source has no such jump
    out = bake(retime_pose(doc, k, float(doc.pose_t[k] + shift))).channels
    assert np.abs(np.diff(out[:, cols], axis=0)).max() < 270.0


def test_resampled_c3d_markers_do_not_judder():
    m, doc = dev_motion("c3dorg_sample01_Eb015pi_walk.c3d"), dev_document("c3dorg_sample01_Eb015pi_walk.c3d")
    with_layer = bake(doc, fps=100.0).points
    without = bake(doc, fps=100.0, ik=False).points
    # the layer used to hold markers on the nearest source frame: a staircase
    # whose every other step was exactly zero
    for c in doc.constraints:
        m_i = m.labels.index(c.joint)
        t = np.arange(len(with_layer)) / 100.0
        inside = (t >= c.start) & (t <= c.end)
        steps = np.linalg.norm(np.diff(with_layer[inside, m_i], axis=0), axis=1)
        ref = np.linalg.norm(np.diff(without[inside, m_i], axis=0), axis=1)
        assert np.sum(steps == 0.0) <= np.sum(ref == 0.0) + 1
    assert np.nanmax(np.abs(with_layer - without)) < 5e-3 * m.figure_height()


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def _extract(src: Path, out: Path) -> Path:
    """``staggered extract SRC -o OUT``, its bytes made once per session."""
    out.write_bytes(cli_document(src.name))
    return out


def _analogs(path: Path) -> tuple[np.ndarray, float, float, int]:
    import ezc3d

    c = ezc3d.c3d(str(path))
    p = c["parameters"]
    analogs = np.asarray(c["data"]["analogs"], dtype=float)[0]  # (A, S)
    return (
        analogs,
        float(p["POINT"]["RATE"]["value"][0]),
        float(p["ANALOG"]["RATE"]["value"][0]),
        c["data"]["points"].shape[2],
    )


@pytest.mark.parametrize(
    "fps, analog_rate",
    [
        (25, 200.0),  # 200 Hz is a whole multiple of 25: kept (8 samples a frame)
        (30, 210.0),  # 200 / 30 = 6.67: the nearest whole multiple, 7 x 30
        (120, 240.0),  # faster than a frame per 4 analog samples: 2 x 120
        (50, 200.0),  # the source's own rate: unchanged
    ],
)
def test_c3d_bake_at_a_new_rate_keeps_the_analog_timing(tmp_path, fps, analog_rate):
    src = mocap("c3dorg_sample01_Eb015pi_walk.c3d")  # points 50 Hz, 16 analogs at 200 Hz
    doc = _extract(src, tmp_path / "tr.stag")
    out = tmp_path / f"tr{fps}.c3d"
    result = _run("bake", doc, "--fps", fps, "-o", out)
    assert result.exit_code == 0, result.stderr
    a0, pr0, ar0, n0 = _analogs(src)
    a1, pr1, ar1, n1 = _analogs(out)
    assert (pr0, ar0) == (50.0, 200.0) and a0.shape[0] == a1.shape[0] == 16
    assert pr1 == fps and ar1 == analog_rate
    per_frame = a1.shape[1] / n1
    assert per_frame == round(analog_rate / fps), (a1.shape, n1)
    # the analog block spans the clip, whose duration is the source's (to a frame)
    assert a1.shape[1] / ar1 == pytest.approx(n1 / pr1)
    assert a0.shape[1] / ar0 == pytest.approx(n0 / pr0)
    assert 0 <= (n0 - 1) / pr0 - (n1 - 1) / pr1 < 1.0 / fps
    # each sample has the source's signal at its own time (linear interpolation)
    t0 = np.arange(a0.shape[1]) / ar0
    t1 = np.arange(a1.shape[1]) / ar1
    scale = np.ptp(a0, axis=1) + 1.0
    for ch in range(a0.shape[0]):
        want = np.interp(t1, t0, a0[ch])
        err = np.abs(a1[ch] - want).max()
        assert err <= 1e-5 * scale[ch], (ch, err, scale[ch])
    # and on the smoothest channel the new samples follow the signal itself,
    # not just the interpolation: within a few percent of its range
    rough = np.abs(np.diff(a0, 2, axis=1)).mean(axis=1) / scale
    smooth = int(np.argmin(rough))
    nearest = np.clip(np.rint(t1 * ar0).astype(int), 0, a0.shape[1] - 1)
    assert np.abs(a1[smooth] - a0[smooth][nearest]).max() <= 0.05 * scale[smooth]


def test_c3d_bake_at_half_rate_keeps_the_second_half_of_the_analogs(tmp_path):
    """The reported case: at 25 fps the file held the source's first 900
    samples stretched over the clip; the last second must be the source's."""
    src = mocap("c3dorg_sample01_Eb015pi_walk.c3d")
    doc = _extract(src, tmp_path / "tr.stag")
    out = tmp_path / "tr25.c3d"
    assert _run("bake", doc, "--fps", "25", "-o", out).exit_code == 0
    a0, _, ar0, _ = _analogs(src)
    a1, _, ar1, _ = _analogs(out)
    assert ar1 == ar0 and a1.shape == a0.shape
    np.testing.assert_allclose(a1[:, -200:], a0[:, -200:], rtol=1e-6, atol=1e-3)


def test_bake_refuses_an_output_extension_of_the_other_kind():
    bvh_doc = cli_document("bandai2_run_normal_001.bvh")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "walk.c3d"
        r = run(["bake", "-", "-o", str(out)], input=bvh_doc)
        one_line_error(r, 2, "walk.c3d", "a BVH document bakes to BVH, but the name says C3D")
        assert not out.exists()
        r = run(["bake", "-", "-o", str(Path(tmp) / "walk.stag")], input=bvh_doc)
        one_line_error(r, 2, "walk.stag", "the name says a document")
        r = run(["bake", "-", "-o", str(Path(tmp) / "walk.BVH")], input=bvh_doc)
        assert r.exit_code == 0, r.stderr
        assert (Path(tmp) / "walk.BVH").read_bytes().startswith(b"HIERARCHY")
        c3d_doc = cli_document("c3dorg_sample01_Eb015pi_walk.c3d")
        out = Path(tmp) / "trial.bvh"
        r = run(["bake", "-", "-o", str(out)], input=c3d_doc)
        one_line_error(r, 2, "trial.bvh", "a C3D document bakes to C3D, but the name says BVH")
        assert not out.exists()


def test_export_poses_plot_and_preview_refuse_an_output_name_of_another_kind(tmp_path):
    """``export-poses -o poses.c3d`` used to write BVH text under a C3D name
    and ``plot -o c.bvh`` a PNG under a BVH name, exit 0: refused in one
    line, before any work, with nothing written; a name without a known
    extension is taken as it is."""
    doc = document_file(dev_document("bandai2_run_normal_001.bvh"), tmp_path / "run.stag")
    for argv, name, needle in (
        (["export-poses"], "poses.c3d", "export-poses writes BVH, but the name says C3D"),
        (["export-poses"], "poses.stag", "export-poses writes BVH, but the name says a document"),
        (["plot", "--kind", "timing"], "timing.bvh", "this writes a PNG picture, but the name says BVH"),
        (["preview"], "strip.stag", "this writes a picture, but the name says a document"),
    ):
        out = tmp_path / name
        r = run([*argv, str(doc), "-o", str(out)])
        one_line_error(r, 2, name, needle)
        assert not out.exists()
    r = run(["plot", "--kind", "timing", str(doc), "-o", str(tmp_path / "timing.img")])
    assert r.exit_code == 0, r.stderr
    assert (tmp_path / "timing.img").read_bytes().startswith(b"\x89PNG")


@pytest.mark.parametrize("fps, per_frame", [(100, 2), (29.97, 7)])
def test_c3d_bake_at_a_new_rate_keeps_its_analogs_to_the_end(fps, per_frame):
    src_path = mocap("c3dorg_sample01_Eb015pi_walk.c3d")  # 50 Hz, 16 analog channels at 200 Hz
    source = ezc3d.c3d(str(src_path))["data"]["analogs"][0]  # (16, 1800)
    doc = cli_document("c3dorg_sample01_Eb015pi_walk.c3d")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "trial.c3d"
        r = run(["bake", "-", "--fps", str(fps), "-o", str(out)], input=doc)
        assert r.exit_code == 0, r.stderr
        baked = read_c3d(out)  # at 29.97 Hz this was refused: the analog rate divided back to 6 samples a frame
        assert baked.rate == pytest.approx(fps, rel=1e-6)
        c = ezc3d.c3d(str(out))
        analogs = c["data"]["analogs"][0]
        T = c["data"]["points"].shape[2]
        assert analogs.shape == (16, T * per_frame)
        rate = c["parameters"]["ANALOG"]["RATE"]["value"][0]
        assert int(rate / c["parameters"]["POINT"]["RATE"]["value"][0]) == per_frame
        assert analogs.shape[1] / rate == pytest.approx(T / fps, rel=1e-6)  # the analogs span every frame
        # sample times j / rate in the source's 200 Hz grid: linear interpolation, the last sample held
        pos = np.minimum(np.arange(analogs.shape[1]) * 200.0 / rate, source.shape[1] - 1)
        expected = np.array([np.interp(pos, np.arange(source.shape[1]), ch) for ch in source])
        np.testing.assert_allclose(analogs, expected, atol=1e-3 * np.abs(source).max())
        tail = analogs[:, -per_frame:]
        assert np.all(np.abs(tail - source[:, -1:]) <= 0.05 * np.abs(source).max() + 1e-9)  # no zeros at the end
        np.testing.assert_allclose(baked.points[0], read_c3d(src_path).points[0], atol=1e-3, equal_nan=True)


def test_bake_warns_when_the_contact_layer_takes_back_an_edit(cmu_walk, tmp_path):
    m, doc = cmu_walk
    k = 2  # inside LeftFoot's contact (constraint 1, 0.033 to 0.633 s)
    assert doc.constraints[1].joint == "LeftFoot" and doc.constraints[1].start < doc.pose_t[k] < doc.constraints[1].end
    edited = E.edit_pose(doc, k, rotate={"LeftUpLeg": (15.0, 0.0, 0.0)})
    f = int(round(doc.pose_t[k] / doc.frame_time))
    j = m.skeleton.index("LeftUpLeg")
    with staggered_warnings() as lines:
        kept = bake(edited).local_rotations()[f, j]
    about = [x for x in lines if "LeftUpLeg" in x]
    assert len(about) == 1, lines
    for needle in ("pose 2", "asked 15.0°, got ", "constraint 1", "LeftFoot", "ik=False", "constraints --remove 1"):
        assert needle in about[0], about[0]
    # the layer kept less than half of the 15° (4.9°)
    assert np.degrees(quat.angle_between(kept, m.local_rotations()[f, j])) < 7.5
    with staggered_warnings() as seen:
        free = bake(edited, ik=False).local_rotations()[f, j]
    assert not seen
    assert np.degrees(quat.angle_between(free, m.local_rotations()[f, j])) == pytest.approx(15.0, abs=1e-6)
    # the CLI prints it as one line on stderr and still writes the motion
    doc_path = document_file(edited, tmp_path / "doc.stag")
    r = CliRunner().invoke(cli, ["bake", str(doc_path), "-o", str(tmp_path / "out.bvh")])
    assert r.exit_code == 0, r.stderr
    warned = [x for x in r.stderr.splitlines() if "LeftUpLeg" in x]
    assert len(warned) == 1 and "--no-ik" in warned[0], r.stderr
    r = CliRunner().invoke(cli, ["bake", str(doc_path), "--no-ik", "-o", str(tmp_path / "free.bvh")])
    assert r.exit_code == 0 and "LeftUpLeg" not in r.stderr, r.stderr


@pytest.mark.parametrize("edited", [False, True])
def test_a_bake_by_blocks_of_frames_is_the_bake_of_the_whole_pose(monkeypatch, edited):
    """Each frame is its own: baking 97 frames at a time gives the bytes of
    the whole-clip path (the one the contact layer needs), and a block that
    finds a disturbed contact hands over to it."""
    import staggered_cli.ops.bake as B
    from staggered_cli.contacts import layer as contact_layer
    from staggered_cli.io.bvh import bvh_bytes

    doc = dev_document("cmu_02_01_walk.bvh")
    if edited:
        doc = E.edit_pose(doc, doc.n_poses // 2, rotate={"LeftUpLeg": (15.0, 0.0, 0.0)})
    monkeypatch.setattr(B, "_BAKE_BLOCK", 97)
    blocks = bvh_bytes(bake(doc))
    with monkeypatch.context() as m:
        m.setattr(contact_layer, "disturbed_in", lambda *a: True)  # always the whole pose
        whole = bvh_bytes(bake(doc))
    assert blocks == whole
    assert (blocks == bvh_bytes(bake(doc, ik=False))) is not edited  # the edit disturbs a contact
