"""Batch processing: ``make -j2 -k batch`` and ``staggered batch`` over a small library.

The library is a temporary copy of a few small files of ../shared/mocap in
a folder tree (a space in a folder name, an upper-case extension) plus a
truncated BVH in a subfolder.  Both forms must bake every good file to the
mirrored path, report the broken one with its reason and a failing exit
code, leave no output for it, and rebuild nothing on a second run.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli.cli.main import cli
from staggered_cli.io.bvh import read_bvh
from staggered_cli.io.c3d import read_c3d

from .conftest import MOCAP, SAMPLES, mocap

ROOT = Path(__file__).resolve().parents[1]
STAGGERED = Path(sys.executable).parent / "staggered"
MAKE = shutil.which("make")

#: relative path in the library -> source file in ../shared/mocap
GOOD = {
    "bandai2_run_normal_001.bvh": "bandai2_run_normal_001.bvh",
    "sub dir/cmu_02_01_walk.bvh": "cmu_02_01_walk.bvh",
    "sub dir/deeper/idle.BVH": "games105_idle.bvh",
    "walk.c3d": "c3dorg_sample01_Eb015pi_walk.c3d",
}
BROKEN = "broken/truncated.bvh"
STEPS = "cull --keep 30%|succession --joint LeftShoulder --offset 0.02 --power 2 --clamp"


def _library(root: Path) -> Path:
    lib = root / "in"
    for rel, name in GOOD.items():
        (lib / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(mocap(name), lib / rel)
    (lib / BROKEN).parent.mkdir(parents=True)
    (lib / BROKEN).write_bytes(mocap("bandai2_run_normal_001.bvh").read_bytes()[:40_000])
    (lib / "notes.txt").write_text("not motion capture: ignored\n")
    return lib


def _make(*args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}
    return subprocess.run(
        [MAKE, "-C", str(ROOT), *args, f"STAGGERED={STAGGERED}", "-o", ".venv/.staggered-installed"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


def _mtimes(out: Path) -> dict[str, int]:
    return {rel: (out / rel).stat().st_mtime_ns for rel in GOOD}


def _batch(*args: str):
    return CliRunner().invoke(cli, ["batch", *args], catch_exceptions=False)


def _channels(path: Path) -> np.ndarray:
    return read_bvh(str(path)).channels


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Both forms, each run twice over the same library."""
    if not MOCAP.is_dir():
        pytest.skip(f"{MOCAP} is not there")
    root = tmp_path_factory.mktemp("batch")
    lib = _library(root)
    out = {}
    if MAKE is not None and STAGGERED.exists():
        first = _make("-j2", "-k", "batch", f"IN={lib}", f"OUT={root / 'make'}")
        before = _mtimes(root / "make") if first.returncode != 0 else {}
        second = _make("-j2", "-k", "batch", f"IN={lib}", f"OUT={root / 'make'}")
        out["make"] = (first, second, before, _mtimes(root / "make") if before else {})
    first = _batch(str(lib), str(root / "cli"), "--jobs", "2")
    before = _mtimes(root / "cli")
    second = _batch(str(lib), str(root / "cli"), "--jobs", "2")
    out["cli"] = (first, second, before, _mtimes(root / "cli"))
    return root, lib, out


def _check_outputs(lib: Path, out: Path) -> None:
    for rel in GOOD:
        src, dst = lib / rel, out / rel
        assert dst.is_file(), f"{dst} missing"
        if rel.lower().endswith(".c3d"):
            a, b = read_c3d(str(src)), read_c3d(str(dst))
            assert b.points.shape == a.points.shape
            np.testing.assert_array_equal(np.isnan(b.points), np.isnan(a.points))
        else:
            assert dst.read_bytes().startswith(b"HIERARCHY")
            np.testing.assert_allclose(_channels(dst), _channels(src), atol=1e-6, rtol=0)
    # no output, temporary or partial, for the broken file
    left = sorted(p.name for p in (out / "broken").iterdir()) if (out / "broken").exists() else []
    assert left in ([], ["truncated.bvh.err"])


def _statuses(stdout: str) -> dict[str, str]:
    """file -> status from the summary table."""
    lines = [line for line in stdout.splitlines() if not line.startswith("make: ")]
    rows = {}
    for line in lines[1:-1]:
        rel, _, rest = line.partition("  ")
        rows[rel.strip()] = rest.split()[0]
    return rows


#: bake(extract(x)) is x to the byte for a BVH; the C3D writer lays the file out anew
FIRST = {rel: ("built" if rel.endswith(".c3d") else "unchanged") for rel in GOOD}


@pytest.mark.skipif(MAKE is None, reason="GNU make is not installed")
def test_make_batch_bakes_good_files_and_reports_the_broken_one(runs):
    """``make batch`` is ``staggered batch`` (one implementation): same table, same rules."""
    root, lib, out = runs
    first, second, before, after = out["make"]
    assert first.returncode != 0, first.stdout + first.stderr
    _check_outputs(lib, root / "make")
    assert _statuses(first.stdout) == {**FIRST, BROKEN: "failed"}, first.stdout
    assert f"staggered: {BROKEN}: extract: line" in first.stderr
    assert "5 files: 1 built, 3 unchanged, 0 skipped, 1 failed" in first.stdout
    assert "with 2 jobs" in first.stdout  # make's -j2
    # second run: nothing rebuilt, the broken file tried (and reported) again
    assert second.returncode != 0
    assert after == before
    assert "5 files: 0 built, 0 unchanged, 4 skipped, 1 failed" in second.stdout


def test_cli_batch_bakes_good_files_and_reports_the_broken_one(runs):
    root, lib, out = runs
    first, second, before, after = out["cli"]
    assert first.exit_code == 1, first.output
    _check_outputs(lib, root / "cli")
    assert _statuses(first.stdout) == {**FIRST, BROKEN: "failed"}, first.stdout
    rows = {line.split("  ")[0]: line for line in first.stdout.splitlines()}
    assert " failed " in rows[BROKEN] and "extract: line" in rows[BROKEN]
    assert f"staggered: {BROKEN}: extract: line" in first.stderr
    assert "5 files: 1 built, 3 unchanged, 0 skipped, 1 failed" in first.stdout
    assert second.exit_code == 1
    assert after == before
    assert "5 files: 0 built, 0 unchanged, 4 skipped, 1 failed" in second.stdout


@pytest.mark.skipif(MAKE is None, reason="GNU make is not installed")
def test_make_and_cli_write_the_same_files(runs):
    root, _, out = runs
    for rel in GOOD:
        assert (root / "make" / rel).read_bytes() == (root / "cli" / rel).read_bytes(), rel


def test_steps_change_the_motion_and_cull_alone_does_not(tmp_path):
    lib = tmp_path / "in"
    lib.mkdir()
    shutil.copyfile(mocap("cmu_02_01_walk.bvh"), lib / "walk.bvh")
    source = _channels(lib / "walk.bvh")

    r = _batch(str(lib), str(tmp_path / "cull"), "--steps", "cull --keep 30%", "--jobs", "1")
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(_channels(tmp_path / "cull" / "walk.bvh"), source, atol=1e-6, rtol=0)

    r = _batch(str(lib), str(tmp_path / "stag"), "--steps", STEPS, "--jobs", "1")
    assert r.exit_code == 0, r.output
    staggered = _channels(tmp_path / "stag" / "walk.bvh")
    assert staggered.shape == source.shape
    assert np.abs(staggered - source).max() > 1.0  # degrees: the left arm's timing moved

    # layer and detail are steps too: without its detail the walk changes
    r = _batch(str(lib), str(tmp_path / "soft"), "--steps", "layer --add --keep 4|detail --gain 0", "--jobs", "1")
    assert r.exit_code == 0, r.output
    soft = _channels(tmp_path / "soft" / "walk.bvh")
    assert soft.shape == source.shape and np.abs(soft - source).max() > 0.1

    if MAKE is not None and STAGGERED.exists():
        m = _make("-j2", "batch", f"IN={lib}", f"OUT={tmp_path / 'make'}", f"STEPS={STEPS}")
        assert m.returncode == 0, m.stdout + m.stderr
        assert (tmp_path / "make" / "walk.bvh").read_bytes() == (tmp_path / "stag" / "walk.bvh").read_bytes()


def test_batch_bakes_what_the_pipe_bakes(tmp_path):
    """A step parsed from --steps words becomes an API call; what the batch
    bakes is what the commands piped through document files bake, to the
    byte, BVH and C3D."""
    from staggered_cli.batching import BUILT, Job, Plan, run_file
    from staggered_cli.cli.batch import parse_steps

    assert parse_steps("cull --keep 30%|succession --joint @left-arm --offset 0.03 --clamp") == [
        ("cull", {"keep": "30%", "interval": None, "select": None, "add_time": [], "part": None, "by": "error",
                  "ignore_contacts": False}),
        ("succession", {"offset": 0.03, "power": 1.0, "joint": "@left-arm", "chain": None, "poses": None,
                        "time": None, "clamp": True}),
    ]
    for name, steps in (("cmu_02_01_walk.bvh", STEPS), ("c3dorg_sample01_Eb015pi_walk.c3d", "cull --keep 30%")):
        src = mocap(name)
        doc = tmp_path / f"{name}.0.stag"
        assert CliRunner().invoke(cli, ["-q", "extract", str(src), "-o", str(doc)]).exit_code == 0
        for i, step in enumerate(steps.split("|")):
            nxt = tmp_path / f"{name}.{i + 1}.stag"
            r = CliRunner().invoke(cli, ["-q", *step.split(), str(doc), "-o", str(nxt)])
            assert r.exit_code == 0, r.output
            doc = nxt
        piped = tmp_path / f"piped_{name}"
        assert CliRunner().invoke(cli, ["-q", "bake", str(doc), "-o", str(piped)]).exit_code == 0
        out = tmp_path / f"batch_{name}"
        calls = tuple(parse_steps(steps))
        result = run_file(Job(name, str(src), str(out)), Plan(steps_bvh=calls, steps_c3d=calls))
        assert result.status == BUILT, result.reason
        assert out.read_bytes() == piped.read_bytes(), name


@pytest.mark.parametrize(
    "steps, words",
    [
        ("frobnicate --now", ["step 1", "unknown command 'frobnicate'"]),
        ("cull --keep 30%|bake", ["step 2", "extract and bake are implied"]),
        ("cull --keep 30%|succession --jont LeftArm --offset 0.1", ["step 2", "succession --jont", "--jont"]),
        ("succession --joint LeftArm --offset fast", ["step 1", "--offset", "'fast' is not a number"]),
        ("randomize --tau 0.1", ["step 1", "--seed"]),
        ("cull --keep 30% -o x.stag", ["step 1", "no -o"]),
        ("cull --keep 30% walk.stag", ["step 1", "no FILE"]),
        ("cull --keep 30%||cull --keep 5", ["step 2", "empty step"]),
        ("layer --add --keep 4|layer --list", ["step 2", "'layer --list' does not turn a document"]),
        # values out of range, which the commands used to check only once a
        # document was read: each file then failed on its own
        ("cull --keep -5", ["step 1", "--keep must keep at least one pose"]),
        ("cull --keep 30%|cull --keep 0%", ["step 2", "--keep percentage"]),
        ("cull --interval 5:1", ["step 1", "--interval"]),
        ("detail --gain 50", ["step 1", "--gain must be a number from 0 to 10"]),
        ("edit-pose --pose 3 --exaggerate 999", ["step 1", "--exaggerate must be a number"]),
        ("edit-pose --pose 3 --ease 20", ["step 1", "--ease must be a number"]),
        ("layer --add --keep -3", ["step 1", "--keep must keep at least one pose"]),
    ],
)
def test_bad_steps_fail_before_any_file(tmp_path, steps, words):
    lib = tmp_path / "in"
    lib.mkdir()
    (lib / "x.bvh").write_text("not read: the steps are checked first\n")
    r = _batch(str(lib), str(tmp_path / "out"), "--steps", steps)
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("staggered: --steps: "), r.stderr
    for word in words:
        assert word in lines[0]
    assert r.stdout == ""
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(MAKE is None, reason="GNU make is not installed")
def test_make_batch_checks_steps_first(tmp_path):
    lib = tmp_path / "in"
    lib.mkdir()
    (lib / "x.bvh").write_text("not read\n")
    m = _make("batch", f"IN={lib}", f"OUT={tmp_path / 'out'}", "STEPS=cull --kep 30%")
    assert m.returncode != 0
    assert "staggered: --steps: step 1 ('cull --kep 30%'): No such option" in m.stderr
    assert not (tmp_path / "out").exists()


def test_batch_refuses_an_output_inside_the_input(tmp_path):
    r = _batch(str(tmp_path), str(tmp_path / "out"))
    assert r.exit_code == 2 and "must not be inside the input folder" in r.stderr


def test_dry_run_lists_and_builds_nothing(tmp_path):
    lib = tmp_path / "in"
    (lib / "a").mkdir(parents=True)
    shutil.copyfile(mocap("games105_idle.bvh"), lib / "a" / "idle.bvh")
    r = _batch(str(lib), str(tmp_path / "out"), "--dry-run", "--steps", "cull --keep 50%")
    assert r.exit_code == 0, r.output
    assert "a/idle.bvh" in r.stdout and "todo" in r.stdout and "1 to build" in r.stdout
    assert not (tmp_path / "out").exists()
    # a dry run checks the steps as a run does
    r = _batch(str(lib), str(tmp_path / "out"), "--dry-run", "--steps", "cull --keep -5")
    assert r.exit_code == 2 and "--keep must keep at least one pose" in r.stderr and r.stdout == ""


def test_batch_help_imports_no_numpy():
    code = (
        "import sys\n"
        "from staggered_cli.cli.main import cli\n"
        "try:\n    cli(['batch', '--help'], prog_name='staggered')\n"
        "except SystemExit:\n    pass\n"
        "print(sorted(m for m in ('numpy', 'scipy', 'tqdm') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"


needs_make = pytest.mark.skipif(
    MAKE is None or not STAGGERED.exists(), reason="GNU make or the staggered executable is not there"
)


def _make_in(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """The repository's Makefile run from ``cwd`` (a temporary folder: any
    stray file lands there, never in the checkout)."""
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}
    return subprocess.run(
        [MAKE, "-f", str(ROOT / "Makefile"), *args, f"STAGGERED={STAGGERED}", "-o", ".venv/.staggered-installed"],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


def _usage_error(m: subprocess.CompletedProcess, needle: str) -> None:
    """Exit 2, the message on one line (then make's own ``*** [batch] Error 2``)."""
    assert m.returncode == 2, (m.stdout, m.stderr)
    lines = [line for line in m.stderr.splitlines() if not line.startswith("make: *** ")]
    assert len(lines) == 1 and needle in lines[0], m.stderr
    assert m.stdout == ""


@needs_make
@pytest.mark.parametrize("name", ["in sp", "o$x", "a;b", "p=q", "c:d", "50%", "it's", 'q"', "h#1", "b\\s"])
def test_make_batch_takes_any_folder_name(tmp_path, name):
    """IN and OUT reach `staggered batch` as given: spaces and the characters
    make or the shell would read ($ ; = : % ' " # \\) included."""
    work = tmp_path / "work"
    work.mkdir()
    src = tmp_path / f"{name} in"
    src.mkdir()
    shutil.copy(SAMPLES / "march.bvh", src / "march.bvh")
    dst = tmp_path / f"{name} out"
    m = _make_in(work, "batch", f"IN={src}", f"OUT={dst}", "STEPS=cull --keep 50%")
    assert m.returncode == 0, (m.stdout, m.stderr)
    assert (dst / "march.bvh").read_bytes().startswith(b"HIERARCHY")
    assert "1 files: 0 built, 1 unchanged, 0 skipped, 0 failed" in m.stdout
    assert list(work.iterdir()) == []  # nothing where make ran


@needs_make
def test_make_batch_without_in_is_a_usage_error(tmp_path):
    _usage_error(_make_in(tmp_path, "batch", f"OUT={tmp_path / 'out'}"), "usage: make")


@needs_make
def test_make_batch_passes_every_option(tmp_path):
    """STEPS_BVH, STEPS_C3D, EXTRACT_OPTS, BAKE_OPTS, JOBS and FORCE reach the command."""
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(SAMPLES / "march.bvh", src / "march.bvh")
    shutil.copy(mocap("c3dorg_sample01_Eb015pi_walk.c3d"), src / "walk.c3d")
    dst = tmp_path / "out"
    args = ["batch", f"IN={src}", f"OUT={dst}", "STEPS=cull --keep 1", "JOBS=2", "BAKE_OPTS=--fps 60",
            "STEPS_BVH=cull --keep 50%|succession --joint @left-arm --offset 0.03 --clamp",
            "STEPS_C3D=cull --keep 30%", "EXTRACT_OPTS=--min-spacing 0.15"]
    m = _make_in(tmp_path, *args)
    assert m.returncode == 0, (m.stdout, m.stderr)
    assert "2 files: 2 built, 0 unchanged, 0 skipped, 0 failed" in m.stdout and "with 2 jobs" in m.stdout
    assert read_bvh(str(dst / "march.bvh")).n_frames == 241  # 121 frames at 30 Hz -> 60 Hz
    m = _make_in(tmp_path, *args)
    assert "2 skipped" in m.stdout
    m = _make_in(tmp_path, *args, "FORCE=1")
    assert "2 files: 2 built" in m.stdout


@needs_make
def test_make_batch_goes_on_after_a_failure(tmp_path):
    """One broken file fails alone (no -k needed): the others are built, the exit code says it."""
    src = tmp_path / "in"
    src.mkdir()
    (src / "a_broken.bvh").write_bytes((SAMPLES / "march.bvh").read_bytes()[:5000])
    for rel in ("b.bvh", "c.bvh"):
        shutil.copy(SAMPLES / "march.bvh", src / rel)
    dst = tmp_path / "out"
    m = _make_in(tmp_path, "batch", f"IN={src}", f"OUT={dst}")
    assert m.returncode != 0
    assert _statuses(m.stdout) == {"a_broken.bvh": "failed", "b.bvh": "unchanged", "c.bvh": "unchanged"}
    assert m.stderr.startswith("staggered: a_broken.bvh: extract: ")
    assert not (dst / "a_broken.bvh").exists()
