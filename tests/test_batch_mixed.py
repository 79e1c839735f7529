"""``staggered batch`` over a mixed library (issue 33, item 6), and ``st.batch``.

The library is a temporary copy of two BVH (CMU, Bandai Namco) and two C3D
files of ../shared/mocap.  A body part (``@left-arm``) names a skeleton's
joint: per-kind steps let one run edit both kinds; extract and bake take
their own options; the table tells an output that is its input's bytes
(unchanged) from one that is not (built); ``-v`` says what each stage did.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from click.testing import CliRunner

import staggered_cli as st
from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import read_bvh
from staggered_cli.io.c3d import read_c3d

from .conftest import MOCAP, mocap

FILES = {
    "bvh/walk.bvh": "cmu_02_01_walk.bvh",
    "bvh/run.bvh": "bandai2_run_normal_001.bvh",
    "c3d/walk.c3d": "c3dorg_sample01_Eb015pi_walk.c3d",
    "c3d/gaps.c3d": "ezc3d_BTS_walk_gaps.c3d",
}
STEPS = "cull --keep 30%|succession --joint @left-arm --offset 0.03 --power 1.5 --clamp"
STEPS_C3D = "cull --keep 30%"
API_STEPS_BVH = [
    ("cull", {"keep": "30%"}),
    ("succession", {"joint": "@left-arm", "offset": 0.03, "power": 1.5, "clamp": True}),
]


def _batch(*args: str):
    return CliRunner().invoke(cli, ["batch", *args], catch_exceptions=False)


def _rows(stdout: str) -> dict[str, tuple[str, str]]:
    """file -> (status, reason) from the summary table."""
    rows = {}
    for line in stdout.splitlines()[1:-1]:
        parts = line.split(None, 3)
        rows[parts[0]] = (parts[1], parts[3] if len(parts) > 3 else "")
    return rows


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    if not MOCAP.is_dir():
        pytest.skip(f"{MOCAP} is not there")
    root = tmp_path_factory.mktemp("mixed")
    for rel, name in FILES.items():
        (root / "in" / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(mocap(name), root / "in" / rel)
    return root


@pytest.fixture(scope="module")
def runs(library):
    """The README's steps for both kinds, then per-kind steps with bake options (CLI and API)."""
    lib = str(library / "in")
    same = _batch(lib, str(library / "same"), "--steps", STEPS, "-j", "2")
    kinds = _batch(
        lib,
        str(library / "kinds"),
        "--steps",
        STEPS,
        "--steps-c3d",
        STEPS_C3D,
        "--bake-opts",
        "--fps 30",
        "--extract-opts",
        "--min-spacing 0.15",
        "-j",
        "2",
        "-v",
    )
    api = st.batch(
        lib,
        library / "api",
        steps=API_STEPS_BVH,
        steps_c3d=[("cull", {"keep": "30%"})],
        bake_opts={"fps": 30},
        extract_opts={"min_spacing": 0.15},
        jobs=2,
    )
    return same, kinds, api


def test_one_set_of_steps_fails_the_c3d_files(runs):
    same, _, _ = runs
    rows = _rows(same.stdout)
    assert same.exit_code == 1
    assert {rel: rows[rel][0] for rel in FILES} == {
        "bvh/walk.bvh": "built",
        "bvh/run.bvh": "built",
        "c3d/walk.c3d": "failed",
        "c3d/gaps.c3d": "failed",
    }
    assert rows["c3d/walk.c3d"][1] == (
        "succession: C3D documents have no hierarchy: give the markers in order with --chain M1,M2,M3"
    )
    assert "4 files: 2 built, 0 unchanged, 0 skipped, 2 failed" in same.stdout


def test_per_kind_steps_build_every_file(runs, library):
    _, kinds, _ = runs
    assert kinds.exit_code == 0, kinds.output
    assert {rel: s for rel, (s, _) in _rows(kinds.stdout).items()} == dict.fromkeys(FILES, "built")
    assert "4 files: 4 built, 0 unchanged, 0 skipped, 0 failed" in kinds.stdout
    # the C3D steps ran on the C3D files only: 30 % of the poses of a C3D
    # walk, baked at 30 Hz, hold the source's markers and gaps
    for rel in ("c3d/walk.c3d", "c3d/gaps.c3d"):
        src, out = read_c3d(str(library / "in" / rel)), read_c3d(str(library / "kinds" / rel))
        assert out.rate == pytest.approx(30.0)
        assert out.points.shape[1] == src.points.shape[1]
        duration = (src.n_frames - 1) / src.rate
        assert out.n_frames == int(np.floor(duration * 30 + 1e-3)) + 1


def test_bake_opts_fps_30(runs, library):
    _, kinds, _ = runs
    for rel in ("bvh/walk.bvh", "bvh/run.bvh"):
        src, out = read_bvh(str(library / "in" / rel)), read_bvh(str(library / "kinds" / rel))
        assert out.frame_time == pytest.approx(1 / 30, abs=1e-6)
        duration = (src.n_frames - 1) * src.frame_time
        assert out.n_frames == int(np.floor(duration * 30 + 1e-3)) + 1
    # the CMU walk is 120 Hz: 343 frames over 2.85 s become 86
    assert read_bvh(str(library / "kinds" / "bvh/walk.bvh")).n_frames == 86


def test_verbose_says_what_each_stage_did(runs, library):
    _, kinds, _ = runs
    lines = [line for line in kinds.stderr.splitlines() if line.startswith("staggered: bvh/walk.bvh: ")]
    stages = [line.split(": ", 3)[2] for line in lines if "WARNING" not in line]
    assert stages == ["extract", "cull", "succession", "bake"], kinds.stderr
    doc = st.extract(st.read(str(library / "in" / "bvh/walk.bvh")), min_spacing=0.15)
    kept = st.cull(doc, keep="30%").n_poses
    text = "\n".join(lines)
    assert f"extract: {doc.n_poses} poses, {len(doc.constraints)} contacts, " in text
    assert f"cull: {kept} of {doc.n_poses} poses kept, " in text
    assert "succession: the knots of " in text and " variables retimed, " in text
    assert f"bake: 86 frames at 30 Hz, 1 layer, {len(doc.constraints)} contacts held, " in text
    # the C3D files ran their own steps: extract, cull and bake, no succession
    c3d = [line.split(": ", 3)[2] for line in kinds.stderr.splitlines() if line.startswith("staggered: c3d/walk.c3d: ")]
    assert [s for s in c3d if s != "WARNING"] == ["extract", "cull", "bake"]


def test_the_api_writes_what_the_command_line_writes(runs, library):
    _, _, api = runs
    assert [(r.rel, r.status) for r in api] == sorted((rel, "built") for rel in FILES)
    assert all(len(r.stages) == (4 if r.rel.endswith(".bvh") else 3) for r in api)
    for rel in FILES:
        assert (library / "api" / rel).read_bytes() == (library / "kinds" / rel).read_bytes(), rel


def test_unchanged_tells_an_output_that_is_its_input(tmp_path):
    """Two poses of a short idle: 30 % keeps the ends only, the succession
    has nothing to retime: the output is the input's bytes, and says so."""
    lib = tmp_path / "in"
    lib.mkdir()
    shutil.copyfile(mocap("games105_idle.bvh"), lib / "idle.bvh")
    shutil.copyfile(mocap("bandai2_run_normal_001.bvh"), lib / "run.bvh")
    r = _batch(str(lib), str(tmp_path / "out"), "--steps", STEPS, "-j", "1")
    assert r.exit_code == 0, r.output
    assert _rows(r.stdout) == {"idle.bvh": ("unchanged", ""), "run.bvh": ("built", "")}
    assert (tmp_path / "out" / "idle.bvh").read_bytes() == (lib / "idle.bvh").read_bytes()
    assert (tmp_path / "out" / "run.bvh").read_bytes() != (lib / "run.bvh").read_bytes()
    assert "staggered: idle.bvh: WARNING: --keep 30%: keeping 2 poses" in r.stderr
    assert "2 files: 1 built, 1 unchanged, 0 skipped, 0 failed" in r.stdout


@pytest.mark.parametrize(
    "args, words",
    [
        (["--bake-opts", "--fps -3"], ["--bake-opts ('--fps -3')", "--fps must be a positive number"]),
        (["--bake-opts", "--fps 100000"], ["--bake-opts", "out of range"]),
        (["--bake-opts", "--layers some"], ["--bake-opts", "'some' is not one of 'all', 'splines'"]),
        (["--bake-opts", "-o x.bvh"], ["--bake-opts", "no -o"]),
        (["--extract-opts", "--min-spacing -1"], ["--extract-opts", "--min-spacing must be a non-negative number"]),
        (["--extract-opts", "--min-spacin 1"], ["--extract-opts", "No such option '--min-spacin'"]),
        (["--extract-opts", "x.bvh"], ["--extract-opts", "no FILE"]),
        (["--steps", "bake --fps 30"], ["--steps: step 1", "extract and bake are implied (see --bake-opts)"]),
        (["--steps-c3d", "cull --keep 0"], ["--steps-c3d: step 1 ('cull --keep 0')", "--keep must keep at least"]),
        (["--steps-bvh", "succession --offset 1"], ["--steps-bvh: step 1", "give exactly one of --joint and --chain"]),
    ],
)
def test_bad_options_fail_before_any_file(tmp_path, args, words):
    lib = tmp_path / "in"
    lib.mkdir()
    (lib / "x.bvh").write_text("not read: the options are checked first\n")
    r = _batch(str(lib), str(tmp_path / "out"), *args)
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and r.stdout == "", r.output
    for word in words:
        assert word in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"steps": "cull --keep 30%"}, "steps are (name, kwargs) pairs"),
        ({"steps": [("cull", {"kep": "30%"})]}, "steps: step 1 ('cull'): cull takes no argument 'kep'"),
        ({"steps": [("bake", {})]}, "steps: step 1 ('bake'): extract and bake are implied"),
        ({"steps_c3d": [("randomize", {"tau": -1, "seed": 1})]}, "steps_c3d: step 1 ('randomize'): tau must not"),
        ({"bake_opts": {"fps": 0}}, "fps must be a positive number"),
        ({"extract_opts": {"significance": -1}}, "extract_opts: significance must be a non-negative number"),
        ({"shard": "3/2"}, "shard '3/2': I must be between 1 and 2"),
        ({"jobs": 0}, "jobs must be at least 1"),
    ],
)
def test_st_batch_checks_its_arguments_first(tmp_path, kwargs, message):
    lib = tmp_path / "in"
    lib.mkdir()
    (lib / "x.bvh").write_text("not read\n")
    with pytest.raises(st.UsageError) as err:
        st.batch(lib, tmp_path / "out", **kwargs)
    assert message in str(err.value)
    assert not (tmp_path / "out").exists()
