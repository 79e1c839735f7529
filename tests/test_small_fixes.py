"""The small lies of issue 14, item 7: README or --help claims that did not hold.

Each test runs the command on real data from ../shared/mocap and checks the
claim with numbers: GIF timing, bake's output kind, preview --compare of
another figure, times in messages, constraints/--subtree refusals, C3D
analogs at a new rate, and the byte-for-byte BVH round trip.
"""

from __future__ import annotations

import io
import re
import tempfile
from pathlib import Path

import ezc3d
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import parse_bvh
from staggered_cli.io.c3d import read_c3d
from staggered_cli.plots import gif_durations

from .conftest import BVH_FILES, mocap, one_line_error


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


def document(name: str, *steps: list[str]) -> bytes:
    """``extract NAME | STEP | ...`` as NPZ bytes, in memory."""
    r = run(["extract", str(mocap(name)), "-o", "-"])
    assert r.exit_code == 0, r.stderr
    data = r.stdout_bytes
    for step in steps:
        r = run([*step, "-", "-o", "-"], input=data)
        assert r.exit_code == 0, r.stderr
        data = r.stdout_bytes
    return data


# --- GIF timing ---------------------------------------------------------------


def _gif_frames(data: bytes) -> list[int]:
    im = Image.open(io.BytesIO(data))
    out = []
    for i in range(im.n_frames):
        im.seek(i)
        out.append(int(im.info["duration"]))
    return out


def test_gif_durations_spread_the_centisecond_rounding():
    # the case: 133 frames of 8/120 s each (8.87 s) played in 7.98 s
    d = gif_durations(np.full(133, 8 / 120))
    assert all(x % 10 == 0 for x in d) and set(d) == {60, 70}
    assert sum(d) / 1000 == pytest.approx(133 * 8 / 120, rel=1e-3)


def test_gif_preview_lasts_as_long_as_the_clip():
    path = mocap("bandai2_run_normal_001.bvh")
    m = parse_bvh(path.read_bytes())
    r = run(["preview", str(path), "--dpi", "20", "-o", "-", "--format", "gif"])
    assert r.exit_code == 0, r.stderr
    durations = _gif_frames(r.stdout_bytes)
    clip = m.n_frames * m.frame_time  # 2.27 s, as `info` reports it
    assert len(durations) == 34  # every second frame of 68: about 15 a second
    assert abs(sum(durations) / 1000 - clip) <= 0.01 * clip, (sum(durations), clip)  # was 2.04 s (10 % fast)


# --- bake writes what its output name says ---------------------------------------


def test_bake_refuses_an_output_extension_of_the_other_kind():
    bvh_doc = document("bandai2_run_normal_001.bvh")
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
        c3d_doc = document("c3dorg_sample01_Eb015pi_walk.c3d")
        out = Path(tmp) / "trial.bvh"
        r = run(["bake", "-", "-o", str(out)], input=c3d_doc)
        one_line_error(r, 2, "trial.bvh", "a C3D document bakes to C3D, but the name says BVH")
        assert not out.exists()


# --- preview --compare of another figure --------------------------------------------


def test_preview_compare_warns_about_another_skeleton():
    run_, walk, idle = (
        str(mocap(n)) for n in ("bandai2_run_normal_001.bvh", "bandai1_walk_normal_001.bvh", "games105_idle.bvh")
    )
    r = run(["preview", run_, "--compare", walk, "--dpi", "20", "-o", "-"])
    assert r.exit_code == 0 and r.stderr == "", r.stderr  # the same skeleton: no word
    r = run(["preview", run_, "--compare", idle, "--dpi", "20", "-o", "-"])
    assert r.exit_code == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("staggered: WARNING: --compare games105_idle.bvh"), r.stderr
    assert "20 joints against 22, no joint joint_Root" in lines[0]
    assert r.stdout_bytes.startswith(b"\x89PNG")


# --- times in messages to the frame's precision ------------------------------------


def test_messages_print_times_to_the_frames_precision():
    doc = document("cmu_02_01_walk.bvh", ["cull", "--keep", "6"])  # 120 Hz: three decimals
    r = run(["edit-pose", "-", "--pose", "2", "--shift", "0.9", "-o", "-"], input=doc)
    assert r.exit_code == 2
    msg = r.stderr.strip()
    assert re.search(r"neighbours \(\d+\.\d{3} s and \d+\.\d{3} s\), got \d+\.\d{3} s$", msg), msg
    assert not re.search(r"\d\.\d{5,}", msg), msg  # no raw float such as 0.9332980000000001
    doc30 = document("bandai2_run_normal_001.bvh")  # 30 Hz: two decimals
    r = run(["cull", "-", "--add-time", "9.123456789", "-o", "-"], input=doc30)
    one_line_error(r, 2, "(0 to 2.23 s), got 9.12346")


# --- refusals -----------------------------------------------------------------------


def test_constraints_remove_twice_and_subtree_without_joints_are_refused():
    doc = document("bandai2_run_normal_001.bvh")
    listed = run(["constraints", "-"], input=doc).stdout.splitlines()
    n = len(listed) - 1
    assert n >= 3
    one_line_error(run(["constraints", "-", "--remove", "1", "--remove", "1"], input=doc), 2, "--remove 1")
    alias = str(1 - n)  # the same constraint counted from the end
    r = run(["constraints", "-", "--remove", "1", "--remove", alias], input=doc)
    one_line_error(r, 2, f"--remove {alias}: constraint 1 is named more than once")
    r = run(["constraints", "-", "--remove", "1", "--remove", "2", "-o", "-"], input=doc)
    assert r.exit_code == 0, r.stderr
    assert len(run(["constraints", "-"], input=r.stdout_bytes).stdout.splitlines()) - 1 == n - 2
    r = run(["randomize", "-", "--tau", "0.02", "--seed", "1", "--subtree", "-o", "-"], input=doc)
    one_line_error(r, 2, "--subtree needs --joints")
    r = run(["edit-pose", "-", "--pose", "2", "--exaggerate", "1.5", "--subtree", "-o", "-"], input=doc)
    one_line_error(r, 2, "--subtree needs --joints")


# --- C3D analogs at a new rate --------------------------------------------------------


@pytest.mark.parametrize("fps, per_frame", [(100, 2), (29.97, 7)])
def test_c3d_bake_at_a_new_rate_keeps_its_analogs_to_the_end(fps, per_frame):
    src_path = mocap("c3dorg_sample01_Eb015pi_walk.c3d")  # 50 Hz, 16 analog channels at 200 Hz
    source = ezc3d.c3d(str(src_path))["data"]["analogs"][0]  # (16, 1800)
    doc = document("c3dorg_sample01_Eb015pi_walk.c3d")
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


# --- the BVH round trip -------------------------------------------------------------------


@pytest.mark.parametrize("name", BVH_FILES)
def test_unedited_round_trip_is_byte_identical_on_every_dev_bvh(name):
    src = mocap(name).read_bytes()
    r = run(["bake", "-", "-o", "-"], input=document(name, ["cull", "--keep", "30%"]))
    assert r.exit_code == 0, r.stderr
    assert r.stdout_bytes == src  # header numbers, CRLF, tabs, column spacing and every token as written


def _motion_tokens(data: bytes) -> tuple[list[bytes], list[bytes]]:
    at = data.index(b"MOTION")
    rest = data[at:].split(None, 6)  # MOTION Frames: N Frame Time: t
    return data[:at].split(), rest[6].split()


def test_an_edit_rewrites_only_the_numbers_it_changes():
    name = "cmu3dsmax_131_02_start_walk_stop.bvh"  # mixed CRLF/LF, numbers like -46.182 among %.4f ones
    src = mocap(name).read_bytes()
    m = parse_bvh(src)
    sk = m.skeleton
    doc = document(
        name, ["cull", "--keep", "30%"], ["succession", "--joint", "@left-arm", "--offset", "0.03", "--clamp"]
    )
    out = run(["bake", "-", "-o", "-"], input=doc).stdout_bytes
    assert out[: src.index(b"MOTION")] == src[: src.index(b"MOTION")]
    assert out.count(b"\r\n") == src.count(b"\r\n") and out.count(b"\n") == src.count(b"\n")
    head_a, a = _motion_tokens(src)
    head_b, b = _motion_tokens(out)
    C = m.channels.shape[1]
    changed = (np.array(a) != np.array(b)).reshape(-1, C)
    arm = np.zeros(C, dtype=bool)
    for j in sk.subtree(sk.index("@left-arm")):
        s, e = m.channel_slices()[j]
        arm[s:e] = True
    assert changed[:, arm].sum() > 1000 and not changed[:, ~arm].any()


def test_a_resampled_bake_keeps_the_header_as_written():
    src = mocap("games105_idle.bvh").read_bytes()  # CRLF, offsets like 0.100000
    out = run(["bake", "-", "--fps", "30", "-o", "-"], input=document("games105_idle.bvh")).stdout_bytes
    at = src.index(b"MOTION")
    assert out[:at] == src[:at]
    lines = out[at:].split(b"\r\n")
    assert lines[1:3] == [b"Frames: 100", b"Frame Time:   0.0333333"]
    assert b"\n" not in out.replace(b"\r\n", b"")
    assert parse_bvh(out).channels.shape == (100, 63)


def test_a_document_whose_source_text_is_not_the_source_is_refused():
    from staggered_cli.io.document import document_bytes, parse_document

    manifest, arrays = parse_document(document("bandai2_run_normal_001.bvh"), "doc")
    text = arrays["source.bvh"].copy()
    text[text.tobytes().index(b"Hips")] = ord("X")  # a header that no longer matches
    arrays["source.bvh"] = text
    r = run(["bake", "-", "-o", "-"], input=document_bytes(manifest, arrays, "npz"))
    one_line_error(r, 1, "<stdin>", "source.bvh is not the source file")
    del arrays["source.bvh"]  # a document without the text still bakes, in the source's number format
    r = run(["bake", "-", "-o", "-"], input=document_bytes(manifest, arrays, "npz"))
    assert r.exit_code == 0, r.stderr
    np.testing.assert_allclose(
        parse_bvh(r.stdout_bytes).channels,
        parse_bvh(mocap("bandai2_run_normal_001.bvh").read_bytes()).channels,
        atol=1e-6,
    )
