"""``staggered batch`` survives its workers and does not outlive its parent.

A worker is made to die for real by :mod:`tests.batch_faults`, which wraps
the function the workers run on each file from outside the production code
and then runs the command line: a segmentation fault
(``ctypes.string_at(0)``), ``os._exit`` or SIGKILL (what the out-of-memory
killer sends) before it reads a given file, or a hang.  The library is a temporary copy of small files of
../shared/mocap.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from staggered_cli.io.bvh import read_bvh

from .conftest import mocap

ROOT = Path(__file__).resolve().parents[1]
#: ``staggered`` whose batch workers run tests.batch_faults' faults (the spec comes first)
FAULTY = [sys.executable, "-c", "from tests.batch_faults import main; main()"]

FILES = {
    "run.bvh": "bandai2_run_normal_001.bvh",
    "bow.bvh": "bandai1_bow_normal_001.bvh",
    "sub/idle.bvh": "games105_idle.bvh",
    "sub/walk.bvh": "cmu_02_01_walk.bvh",
}


def _library(root: Path) -> Path:
    lib = root / "in"
    for rel, name in FILES.items():
        (lib / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(mocap(name), lib / rel)
    return lib


def _batch(lib: Path, out: Path, jobs: int, fault: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*FAULTY, fault, "batch", str(lib), str(out), "--jobs", str(jobs)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )


def _rows(stdout: str) -> dict[str, tuple[str, str]]:
    """file -> (status, reason) from the summary table."""
    rows = {}
    for line in stdout.splitlines()[1:]:
        parts = line.split(None, 3)
        if len(parts) >= 3 and parts[0] in FILES:
            rows[parts[0]] = (parts[1], parts[3] if len(parts) > 3 else "")
    return rows


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_dying_worker_fails_its_file_only(tmp_path, jobs):
    lib = _library(tmp_path)
    out = tmp_path / "out"
    r = _batch(lib, out, jobs, "sub/idle.bvh=segv;walk.bvh=kill;bow.bvh=exit")
    assert r.returncode == 1, r.stdout + r.stderr
    rows = _rows(r.stdout)
    assert set(rows) == set(FILES), r.stdout
    assert rows["run.bvh"] == ("unchanged", "")  # bake(extract(x)) is x, to the byte
    assert rows["sub/idle.bvh"] == ("failed", "worker process died (SIGSEGV: a crash in native code)")
    assert rows["sub/walk.bvh"] == ("failed", "worker process died (SIGKILL: out of memory?)")
    assert rows["bow.bvh"] == ("failed", "worker process died (exit code 3)")
    assert "4 files: 0 built, 1 unchanged, 0 skipped, 3 failed" in r.stdout
    # one stderr line per failed file, no traceback
    errors = r.stderr.splitlines()
    assert len(errors) == 3 and all(e.startswith("staggered: ") for e in errors), r.stderr
    # the good file is built, the failed ones leave nothing (not even a temporary file)
    np.testing.assert_allclose(
        read_bvh(str(out / "run.bvh")).channels, read_bvh(str(lib / "run.bvh")).channels, atol=1e-6, rtol=0
    )
    assert sorted(p.name for p in out.rglob("*")) == ["run.bvh"]


def test_the_pool_is_replaced_for_the_files_after_a_death(tmp_path):
    # one worker, and it dies on the largest file, drawn first: every other
    # file still needs a worker after it
    lib = _library(tmp_path)
    r = _batch(lib, tmp_path / "out", 1, "sub/walk.bvh=segv")
    rows = _rows(r.stdout)
    assert rows["sub/walk.bvh"][0] == "failed"
    assert [rows[f][0] for f in ("run.bvh", "bow.bvh", "sub/idle.bvh")] == ["unchanged"] * 3, r.stdout


def _children(pid: int) -> list[int]:
    kids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids += [int(k) for k in (task / "children").read_text().split()]
    return kids


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")  # a zombie has ended


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig, code", [(signal.SIGKILL, -signal.SIGKILL), (signal.SIGTERM, 143)])
@pytest.mark.parametrize("fault", ["hang", "hang-writing"])
def test_workers_end_with_their_parent(tmp_path, sig, code, fault):
    """Whether the batch is killed while its workers compute or while they
    write (a temporary file on disk), the workers end and leave no file behind."""
    lib = _library(tmp_path)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [*FAULTY, f"run.bvh={fault};bow.bvh={fault}", "batch", str(lib), str(out), "--jobs", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        workers: list[int] = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the two workers run, busy on the hanging files
            workers = [k for k in _children(proc.pid) if "multiprocessing" in Path(f"/proc/{k}/cmdline").read_text()]
            if len(workers) >= 2:
                break
            time.sleep(0.2)
        assert len(workers) >= 2, "the workers did not start"
        time.sleep(1.0)
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=30)
        assert proc.returncode == code, stderr
        if sig == signal.SIGTERM:
            assert stderr.splitlines()[-1] == "staggered: terminated"
        deadline = time.monotonic() + 10
        while any(_running(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_running(w) for w in workers), "workers outlived the batch"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # files a worker finished before the signal are whole; nothing half-written is left
    if out.exists():
        assert not [p for p in out.rglob("*") if p.is_file() and p.suffix == ".tmp"]
        for p in out.rglob("*.bvh"):
            read_bvh(p)
