"""Edge cases that must work, not fail (issue 10): tiny clips, no contacts, a
single joint, frame rates from 30 to 250 Hz, a motion where nothing moves,
a marker that is never seen.  Each goes through ``extract -> cull ->
succession -> randomize -> bake`` and ``info``; the output is checked for
sense (same layout, finite values, the source back where nothing was edited).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import bvh_bytes, read_bvh
from staggered_cli.io.c3d import c3d_bytes, read_c3d

from .conftest import SAMPLES, mocap
from .fuzz import mutate as mu


def run(*args, ok: bool = True):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    if ok:
        assert result.exit_code == 0, (args, result.stderr, result.exception)
        assert "Traceback" not in result.stderr and "internal error" not in result.stderr
    return result


def info_json(path: Path) -> dict:
    def refuse(token):
        raise AssertionError(f"{token} in info --json")

    return json.loads(run("info", "--json", path).stdout, parse_constant=refuse)


def pipeline(src: Path, tmp: Path, edit: list[str]) -> tuple[Path, Path, dict]:
    """extract -> cull -> succession -> randomize -> bake; also the unedited bake.

    Returns (edited output, unedited output, info of the document).
    """
    ext = src.suffix
    doc = tmp / "doc.stag"
    run("extract", src, "-o", doc)
    summary = info_json(doc)
    run("info", doc)
    run("cull", doc, "--keep", "50%", "-o", tmp / "cull.stag")
    run("succession", tmp / "cull.stag", *edit, "--offset", "0.01", "--power", "2", "--clamp", "-o", tmp / "s.json")
    run("randomize", tmp / "s.json", "--tau", "0.01", "--seed", "3", "--clamp", "-o", tmp / "r.stag")
    info_json(tmp / "r.stag")
    run("bake", tmp / "r.stag", "-o", tmp / f"edited{ext}")
    run("bake", doc, "-o", tmp / f"plain{ext}")
    for out in (tmp / f"edited{ext}", tmp / f"plain{ext}"):
        assert info_json(out)["frames"] == summary["frames"]
    return tmp / f"edited{ext}", tmp / f"plain{ext}", summary


def check_bvh(src: Path, tmp: Path, joint: str = "LeftArm", still: bool = False) -> dict:
    source = read_bvh(src)
    edited, plain, summary = pipeline(src, tmp, ["--joint", joint])
    assert summary["frames"] == source.n_frames
    assert summary["frame_time"] == pytest.approx(source.frame_time)
    for out in (edited, plain):
        baked = read_bvh(out)
        assert baked.skeleton.names == source.skeleton.names
        assert baked.skeleton.channels == source.skeleton.channels
        assert baked.channels.shape == source.channels.shape
        assert baked.frame_time_text == source.frame_time_text
        assert np.isfinite(baked.channels).all()
    # nothing edited: the source comes back (to the file's printed precision)
    np.testing.assert_allclose(read_bvh(plain).channels, source.channels, atol=2e-3)
    if still:  # retiming a motion that does not move changes nothing
        np.testing.assert_allclose(read_bvh(edited).channels, source.channels, atol=2e-3)
    return summary


def check_c3d(src: Path, tmp: Path, still: bool = False) -> dict:
    source = read_c3d(src)
    chain = ",".join(source.labels[:3])
    edited, plain, summary = pipeline(src, tmp, ["--chain", chain])
    assert summary["frames"] == source.n_frames
    for out in (edited, plain):
        baked = read_c3d(out)
        assert baked.labels == source.labels
        assert baked.points.shape == source.points.shape
        assert baked.rate == pytest.approx(source.rate)
        assert not np.isinf(baked.points).any()
        # gaps stay gaps, and samples stay samples
        np.testing.assert_array_equal(np.isnan(baked.points).any(-1), np.isnan(source.points).any(-1))
    seen = ~np.isnan(source.points)
    tol = 1e-3 * max(1.0, float(np.abs(source.points[seen]).max(initial=0.0)))  # float32 in the file
    np.testing.assert_allclose(read_c3d(plain).points[seen], source.points[seen], atol=tol)
    if still:
        np.testing.assert_allclose(read_c3d(edited).points[seen], source.points[seen], atol=tol)
    return summary


@pytest.fixture(scope="module")
def march():
    return read_bvh(SAMPLES / "march.bvh")


@pytest.fixture(scope="module")
def march_c3d():
    return read_c3d(SAMPLES / "march.c3d")


# --------------------------------------------------------------------------- tiny clips


@pytest.mark.parametrize("frames", [1, 2])
def test_tiny_bvh_clip(tmp_path, march, frames):
    src = tmp_path / "tiny.bvh"
    src.write_bytes(bvh_bytes(replace(march, channels=march.channels[:frames])))
    summary = check_bvh(src, tmp_path)
    assert summary["duration"] == pytest.approx(frames * march.frame_time)  # frames x frame time, as for the clip


@pytest.mark.parametrize("frames", [1, 2])
def test_tiny_c3d_clip(tmp_path, march_c3d, frames):
    src = tmp_path / "tiny.c3d"
    src.write_bytes(c3d_bytes(replace(march_c3d, points=march_c3d.points[:frames])))
    check_c3d(src, tmp_path)


def test_tiny_real_clip(tmp_path):
    # the first two frames of real mocap, as the file writes them
    text = mocap("bandai2_run_normal_001.bvh").read_text()
    head, body = text.split("Frames:", 1)
    lines = body.splitlines()
    src = tmp_path / "two.bvh"
    src.write_text(head + "Frames: 2\n" + lines[1] + "\n" + "\n".join(lines[2:4]) + "\n")
    check_bvh(src, tmp_path, joint="Hips")


# --------------------------------------------------------------------------- no contacts, one joint


def test_clip_without_contacts(tmp_path, march):
    # the figure glides at 2 m/s: no foot is ever still
    channels = march.channels.copy()
    x = march.skeleton.channels[0].index("Xposition")
    channels[:, x] += 200.0 * np.arange(march.n_frames) * march.frame_time
    src = tmp_path / "glide.bvh"
    src.write_bytes(bvh_bytes(replace(march, channels=channels)))
    summary = check_bvh(src, tmp_path)
    assert summary["constraints"] == []


_SINGLE = """HIERARCHY
ROOT Hips
{{
\tOFFSET 0 0 0
\tCHANNELS {n} {channels}
\tEnd Site
\t{{
\t\tOFFSET 0 10 0
\t}}
}}
MOTION
Frames: 60
Frame Time: 0.0333333
"""


@pytest.mark.parametrize(
    "channels",
    [
        "Xposition Yposition Zposition Zrotation Xrotation Yrotation",
        "Zrotation Xrotation Yrotation",
        "Xposition Yposition Zposition",
        "Yrotation",
    ],
    ids=["6 channels", "rotations only", "positions only", "one channel"],
)
def test_single_joint_skeleton(tmp_path, channels):
    names = channels.split()
    t = np.arange(60) / 30
    curves = {
        "Xposition": 5 * np.sin(t),
        "Yposition": 90 + np.cos(t),
        "Zposition": 10 * t,
        "Zrotation": 20 * np.sin(2 * t),
        "Xrotation": 10 * np.cos(t),
        "Yrotation": 5 * t,
    }
    rows = np.stack([curves[c] for c in names], axis=1)
    src = tmp_path / "single.bvh"
    body = "".join(" ".join(f"{v:.4f}" for v in row) + "\n" for row in rows)
    src.write_text(_SINGLE.format(n=len(names), channels=channels) + body)
    summary = check_bvh(src, tmp_path, joint="Hips")
    assert summary["joints"] == ["Hips"]


def test_single_marker_c3d(tmp_path, march_c3d):
    one = replace(march_c3d, labels=march_c3d.labels[:1], points=march_c3d.points[:, :1])
    src = tmp_path / "one.c3d"
    src.write_bytes(c3d_bytes(one))
    check_c3d(src, tmp_path)


# --------------------------------------------------------------------------- frame rates


@pytest.mark.parametrize("rate", [30, 60, 100, 120, 250])
def test_frame_rates_bvh(tmp_path, march, rate):
    src = tmp_path / f"r{rate}.bvh"
    src.write_bytes(bvh_bytes(replace(march, frame_time=1 / rate, frame_time_text=f"{1 / rate:.7g}")))
    summary = check_bvh(src, tmp_path)
    assert summary["rate"] == pytest.approx(rate, rel=1e-4)


@pytest.mark.parametrize("rate", [30, 60, 100, 120, 250])
def test_frame_rates_c3d(tmp_path, march_c3d, rate):
    src = tmp_path / f"r{rate}.c3d"
    src.write_bytes(c3d_bytes(replace(march_c3d, rate=float(rate))))
    summary = check_c3d(src, tmp_path)
    assert summary["rate"] == pytest.approx(rate)


# --------------------------------------------------------------------------- nothing moves


def test_still_bvh(tmp_path, march):
    src = tmp_path / "still.bvh"
    src.write_bytes(bvh_bytes(replace(march, channels=np.repeat(march.channels[40:41], 90, axis=0))))
    check_bvh(src, tmp_path, still=True)


def test_still_c3d(tmp_path, march_c3d):
    src = tmp_path / "still.c3d"
    src.write_bytes(c3d_bytes(replace(march_c3d, points=np.repeat(march_c3d.points[10:11], 90, axis=0))))
    check_c3d(src, tmp_path, still=True)


# --------------------------------------------------------------------------- a marker never seen


@pytest.mark.parametrize("name", ["march.c3d", "c3dorg_sample01_Eb015pi_walk.c3d"])
def test_c3d_with_a_marker_missing_in_every_frame(tmp_path, name):
    path = SAMPLES / name if name == "march.c3d" else mocap(name)
    base = mu.c3d_base(path)
    src = tmp_path / "gap.c3d"
    src.write_bytes(mu.c3d_without_marker(base, 1))
    motion = read_c3d(src)
    assert np.isnan(motion.points[:, 1]).all()
    info = info_json(src)
    assert info["markers_with_gaps"] >= 1
    check_c3d(src, tmp_path)
    assert np.isnan(read_c3d(tmp_path / "edited.c3d").points[:, 1]).all()


def test_c3d_where_no_marker_is_ever_seen(tmp_path, march_c3d):
    src = tmp_path / "blind.c3d"
    src.write_bytes(c3d_bytes(replace(march_c3d, points=np.full_like(march_c3d.points, np.nan))))
    check_c3d(src, tmp_path)
    assert np.isnan(read_c3d(tmp_path / "edited.c3d").points).all()


def test_preview_of_a_c3d_where_no_marker_is_ever_seen(tmp_path, march_c3d):
    src = tmp_path / "blind.c3d"
    src.write_bytes(c3d_bytes(replace(march_c3d, points=np.full_like(march_c3d.points, np.nan))))
    result = run("preview", src, "-o", tmp_path / "blind.png", ok=False)
    assert result.exit_code == 0, result.stderr


def test_curves_of_a_one_frame_clip(tmp_path, march):
    src = tmp_path / "one.bvh"
    src.write_bytes(bvh_bytes(replace(march, channels=march.channels[:1])))
    run("extract", src, "-o", tmp_path / "one.stag")
    result = run("plot", tmp_path / "one.stag", "--kind", "curves", "-o", tmp_path / "one.png", ok=False)
    assert result.exit_code == 0 and result.stderr == "", result.stderr
