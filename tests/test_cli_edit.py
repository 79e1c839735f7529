"""The editing commands end to end through the CLI: files, pipes and errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import variables
from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import parse_bvh, read_bvh
from staggered_cli.io.document import document_bytes, from_parts, parse_document, to_parts

from .conftest import SAMPLES, mocap, one_line_error


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
