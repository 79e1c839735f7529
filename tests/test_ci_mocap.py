"""Without ../shared/mocap the tests skip on a developer's machine but fail
the run under ``CI=true``.  Checked by running pytest on a tiny test file in
a checkout of its own (the real conftest.py copied into tmp/repo/tests), whose
../shared/mocap is absent or a folder made here."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

CONFTEST = Path(__file__).with_name("conftest.py")
PLUGINS = ("cacheprovider", "xdist", "xdist.looponfail", "timeout", "hypothesispytest")

TINY = """
from conftest import mocap


def test_needs_the_real_data():
    assert mocap("cmu_02_01_walk.bvh").read_bytes().startswith(b"HIERARCHY")


def test_needs_nothing():
    assert 1 + 1 == 2
"""


def _pytest(root: Path, ci: str | None) -> subprocess.CompletedProcess:
    repo = root / "repo"
    (repo / "tests").mkdir(parents=True, exist_ok=True)
    shutil.copy(CONFTEST, repo / "tests" / "conftest.py")
    (repo / "tests" / "test_tiny.py").write_text(TINY)
    env = {k: v for k, v in os.environ.items() if k != "CI" and not k.startswith(("PYTEST_", "COV_"))}
    if ci is not None:
        env["CI"] = ci
    args = [sys.executable, "-m", "pytest", "-q", "tests"]
    for plugin in PLUGINS:  # the tiny file needs none of them: each run starts quicker
        args += ["-p", f"no:{plugin}"]
    return subprocess.run(
        args,
        cwd=repo,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_missing_mocap_skips_outside_ci(tmp_path):
    r = _pytest(tmp_path, None)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1 passed, 1 skipped" in r.stdout, r.stdout
    r = _pytest(tmp_path, "false")
    assert r.returncode == 0 and "1 passed, 1 skipped" in r.stdout, r.stdout


def test_missing_mocap_fails_the_run_under_ci(tmp_path):
    r = _pytest(tmp_path, "true")
    assert r.returncode != 0, r.stdout + r.stderr
    out = r.stdout + r.stderr
    assert f"CI=true: {tmp_path / 'shared' / 'mocap'} is not there" in out, out
    assert "passed" not in r.stdout and "skipped" not in r.stdout, r.stdout  # nothing ran


def test_a_missing_file_fails_under_ci_when_the_folder_is_there(tmp_path):
    mocap = tmp_path / "shared" / "mocap"
    mocap.mkdir(parents=True)
    r = _pytest(tmp_path, "true")
    assert r.returncode == 1, r.stdout + r.stderr
    assert "1 failed, 1 passed" in r.stdout, r.stdout
    assert f"CI=true: {mocap / 'cmu_02_01_walk.bvh'} is not there" in r.stdout, r.stdout
    (mocap / "cmu_02_01_walk.bvh").write_bytes(b"HIERARCHY\n")
    r = _pytest(tmp_path, "true")
    assert r.returncode == 0 and "2 passed" in r.stdout, r.stdout + r.stderr
