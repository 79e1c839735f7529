"""The editing commands end to end through the CLI: files, pipes and errors."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import parse_bvh, read_bvh
from staggered_cli.io.container import document_bytes, parse_document
from staggered_cli.io.schema import from_parts, to_parts
from staggered_cli.model import variables
from staggered_cli.model.kinds import ROTATION, TRANSLATION
from staggered_cli.ops import edit_pose as E

from .conftest import SAMPLES, cli_document, mocap, one_line_error


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


@pytest.fixture(scope="module")
def doc_file(tmp_path_factory):
    m = read_bvh(SAMPLES / "march.bvh")
    doc = variables.from_motion(m, np.arange(0.0, 4.0, 0.3))
    manifest, arrays = to_parts(doc)
    path = tmp_path_factory.mktemp("docs") / "march.stag"
    path.write_bytes(document_bytes(manifest, arrays, "npz"))
    return path


def load(data: bytes):
    return from_parts(*parse_document(data, "test"))


def test_pipeline_through_stdin_and_stdout(doc_file, tmp_path):
    src = read_bvh(SAMPLES / "march.bvh")
    culled = run(["cull", str(doc_file), "--keep", "40%", "-o", "-"])
    assert culled.exit_code == 0, culled.stderr
    succ = run(
        ["succession", "-", "--joint", "LeftArm", "--offset", "0.03", "--power", "2", "-o", "-"],
        input=culled.stdout_bytes,
    )
    assert succ.exit_code == 0, succ.stderr
    rnd = run(
        ["randomize", "-", "--tau", "0.02", "--seed", "3", "--joints", "Head", "-o", "-"], input=succ.stdout_bytes
    )
    assert rnd.exit_code == 0, rnd.stderr
    out = tmp_path / "loose.bvh"
    baked = run(["bake", "-", "-o", str(out)], input=rnd.stdout_bytes)
    assert baked.exit_code == 0, baked.stderr
    m = read_bvh(out)
    assert m.skeleton.names == src.skeleton.names and m.n_frames == src.n_frames
    # the legs were not touched: bit-for-bit the source's numbers
    legs = [src.skeleton.index(n) for n in ("LeftUpLeg", "LeftLeg", "RightUpLeg")]
    cols = [c for j, (a, b) in enumerate(src.channel_slices()) if j in legs for c in range(a, b)]
    np.testing.assert_array_equal(m.channels[:, cols], src.channels[:, cols])
    assert np.abs(m.channels - src.channels).max() > 0.1


def test_cull_then_bake_is_lossless_and_json_documents_work(doc_file, tmp_path):
    out = tmp_path / "c.json"
    r = run(["cull", str(doc_file), "--keep", "3", "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    assert out.read_bytes().lstrip().startswith(b"{")
    info = json.loads(run(["info", "--json", str(out)]).stdout)
    assert len(info["poses"]) == 3 and info["frames"] == 121
    baked = run(["bake", str(out), "-o", "-"])
    src = (SAMPLES / "march.bvh").read_bytes()
    assert parse_bvh(baked.stdout_bytes).channels.tolist() == parse_bvh(src).channels.tolist()
    assert baked.stdout_bytes == src  # the same file, byte for byte


def test_edit_pose_commands(doc_file, tmp_path):
    out = tmp_path / "e.stag"
    r = run(
        [
            "edit-pose",
            str(doc_file),
            "--pose",
            "4",
            "--rotate",
            "LeftArm=0,0,20",
            "--translate",
            "Hips=5,0,0",
            "-o",
            str(out),
        ]
    )
    assert r.exit_code == 0, r.stderr
    doc = load(out.read_bytes())
    assert doc.n_poses == 15
    r = run(
        [
            "edit-pose",
            str(doc_file),
            "--pose",
            "4",
            "--exaggerate",
            "1.5",
            "--relative-to",
            "prev",
            "--joints",
            "LeftArm",
            "--subtree",
            "-o",
            "-",
        ]
    )
    assert r.exit_code == 0, r.stderr
    r = run(["edit-pose", str(doc_file), "--pose", "4", "--shift", "0.05", "-o", "-"])
    assert r.exit_code == 0, r.stderr
    assert load(r.stdout_bytes).pose_t[4] == pytest.approx(1.25)
    r = run(
        [
            "edit-pose",
            str(doc_file),
            "--pose",
            "4",
            "--from-bvh",
            str(SAMPLES / "march.bvh"),
            "--frame",
            "10",
            "-o",
            "-",
        ]
    )
    assert r.exit_code == 0, r.stderr


@pytest.mark.parametrize(
    "args, code, needle",
    [
        (["edit-pose", "{doc}", "--pose", "99", "--rotate", "LeftArm=0,0,1"], 2, "out of range"),
        (["edit-pose", "{doc}", "--pose", "3", "--rotate", "Tail=0,0,1"], 2, "Tail"),
        (["edit-pose", "{doc}", "--pose", "3", "--rotate", "LeftArm=0,1"], 2, "JOINT=x,y,z"),
        (["edit-pose", "{doc}", "--pose", "3", "--exaggerate", "2", "--relative-to", "sideways"], 2, "relative-to"),
        (["edit-pose", "{doc}", "--pose", "3", "--from-bvh", "{other}", "--frame", "0"], 2, "different skeleton"),
        (["edit-pose", "{doc}", "--pose", "3", "--time", "9"], 2, "between its neighbours"),
        (["cull", "{doc}", "--keep", "0%"], 2, "--keep"),
        (["cull", "{doc}", "--keep", "lots"], 2, "--keep"),
        (["cull", "{doc}", "--add-time", "99"], 2, "within the clip"),
        (["randomize", "{doc}", "--tau", "-1", "--seed", "1"], 2, "tau"),
        (["randomize", "{doc}", "--tau", "nan", "--seed", "1"], 2, "tau"),
        (["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--power", "-1"], 2, "power"),
        (["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.5", "--power", "1"], 2, "cross"),
        (["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--time", "50:60"], 2, "outside the clip"),
        (["bake", "{doc}", "--fps", "0"], 2, "fps"),
        (["bake", "{bvh}"], 2, "run `staggered extract`"),
    ],
)
def test_bad_options_are_one_line_usage_errors(doc_file, args, code, needle):
    other = mocap("bandai1_walk_normal_001.bvh")
    args = [a.format(doc=doc_file, other=other, bvh=SAMPLES / "march.bvh") for a in args]
    r = run(args + ["-o", "-"])
    one_line_error(r, code, needle)


def test_existing_output_needs_force(doc_file, tmp_path):
    out = tmp_path / "x.bvh"
    out.write_bytes(b"keep me")
    r = run(["bake", str(doc_file), "-o", str(out)])
    one_line_error(r, 2, str(out))
    assert out.read_bytes() == b"keep me"
    r = run(["bake", str(doc_file), "-o", str(out), "--force"])
    assert r.exit_code == 0 and out.read_bytes().startswith(b"HIERARCHY")


def test_corrupted_document_fails_cleanly(doc_file, tmp_path):
    data = doc_file.read_bytes()
    bad = tmp_path / "bad.stag"
    bad.write_bytes(data[: len(data) // 2])
    r = run(["bake", str(bad), "-o", str(tmp_path / "o.bvh")])
    one_line_error(r, 1, str(bad))
    assert not (tmp_path / "o.bvh").exists()


def test_exaggerate_through_the_cli(tmp_path):
    m = read_bvh(SAMPLES / "march.bvh")
    doc = variables.from_motion(m, np.arange(0.0, 4.0, 0.3))
    manifest, arrays = to_parts(doc)
    path = tmp_path / "march.stag"
    path.write_bytes(document_bytes(manifest, arrays, "npz"))
    r = run(["edit-pose", str(path), "--pose", "4", "--exaggerate", "2", "--format", "json"])
    assert r.exit_code == 0, r.stderr
    ex = load(r.stdout_bytes)
    for tr, a, b in zip(doc.tracks, E.pose_values(doc, 4, "true"), E.pose_values(ex, 4, "true"), strict=True):
        if tr.kind == TRANSLATION:
            np.testing.assert_allclose(b, a, atol=1e-12)
        else:
            assert tr.kind == ROTATION and np.degrees(quat.angle_between(a, b)).max() > 0.5
    root = m.skeleton.names[0]
    r = run(
        ["edit-pose", str(path), "--pose", "4", "--exaggerate", "2", "--joints", root, "--root", "--format", "json"]
    )
    assert r.exit_code == 0, r.stderr
    named = load(r.stdout_bytes)
    tr = next(tr for tr in doc.tracks if tr.kind == TRANSLATION)
    ti = doc.tracks.index(tr)
    i = tr.names.index(f"{root}.position")
    assert np.abs(E.pose_values(named, 4, "true")[ti][i] - E.pose_values(doc, 4, "true")[ti][i]).max() > 1e-3


def test_messages_print_times_to_the_frames_precision():
    doc = cli_document("cmu_02_01_walk.bvh", ["cull", "--keep", "6"])  # 120 Hz: three decimals
    r = run(["edit-pose", "-", "--pose", "2", "--shift", "0.9", "-o", "-"], input=doc)
    assert r.exit_code == 2
    msg = r.stderr.strip()
    assert re.search(
        r"neighbours \(\d+\.\d{3} s and \d+\.\d{3} s\) and at least half a frame from each, got \d+\.\d{3} s$", msg
    ), msg
    assert not re.search(r"\d\.\d{5,}", msg), msg  # no raw float such as 0.9332980000000001
    doc30 = cli_document("bandai2_run_normal_001.bvh")  # 30 Hz: two decimals
    r = run(["cull", "-", "--add-time", "9.123456789", "-o", "-"], input=doc30)
    one_line_error(r, 2, "(0 to 2.23 s), got 9.12346")


def test_constraints_remove_twice_and_subtree_without_joints_are_refused():
    doc = cli_document("bandai2_run_normal_001.bvh")
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
